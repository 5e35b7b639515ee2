//! Unit tests of the Controller, one behaviour each, on the virtual rig of
//! `testkit`; property tests of the safety invariants are in `proptests.rs`.

use crate::testkit::{Host, Rig, params, run_until};
use crate::{Controller, galvo};
use protocol::{
    Axis, Command, CommandError, Event, FaultCause, LaserColour, MoveTarget, Reply, Sweep,
};
use std::vec::Vec;

const MS: u64 = 1000;

/// A booted, identified controller with outputs initialised.
fn setup() -> (Controller, Rig, Host) {
    let mut c = Controller::new(42, false);
    let mut rig = Rig::default();
    c.poll(0, &mut rig);
    let mut host = Host::new();
    let r = host.send(&mut c, &mut rig, 10, Command::Identify).unwrap();
    assert!(matches!(r, Reply::Identity(_)));
    (c, rig, host)
}

/// Keep the heartbeat fresh (every 100 ms) while time runs to `until`.
fn run_hb(c: &mut Controller, rig: &mut Rig, host: &mut Host, from: u64, until: u64) {
    let mut t = from;
    while t < until {
        let next = (t + 100 * MS).min(until);
        run_until(c, rig, t, next);
        let ack = host.events.last().map_or(0, |e| e.0);
        host.send(c, rig, next, Command::Heartbeat { event_ack: ack })
            .unwrap();
        t = next;
    }
}

fn move_cmd(axis: Axis, target: MoveTarget) -> Command {
    Command::Move {
        axis,
        target,
        speed_urad_s: 0,
        accel_urad_s2: 0,
    }
}

#[test]
fn first_poll_drives_safe_outputs_and_boot_is_reported() {
    let mut c = Controller::new(7, false);
    let mut rig = Rig::default();
    c.poll(0, &mut rig);
    assert_eq!(rig.lasers, [false; 3]);
    assert_eq!(
        (rig.laser_power, rig.lamps, rig.triggers, rig.galvo),
        (0, 0, 0, 2048)
    );
    assert_eq!(rig.enable, [false; 2]);
    let mut host = Host::new();
    host.drain(&mut c);
    assert_eq!(
        host.distinct_events(),
        [Event::Booted {
            boot_id: 7,
            watchdog: false
        }]
    );
    // no command before Identify
    assert_eq!(
        host.send(&mut c, &mut rig, 5, Command::Status),
        Err(CommandError::NotIdentified)
    );
}

#[test]
fn watchdog_boot_latches_a_fault() {
    let mut c = Controller::new(1, true);
    let mut rig = Rig::default();
    c.poll(0, &mut rig);
    let mut host = Host::new();
    host.send(&mut c, &mut rig, 1, Command::Identify).unwrap();
    assert_eq!(
        host.send(&mut c, &mut rig, 2, Command::Lamps { mask: 1 }),
        Err(CommandError::Faulted(FaultCause::Watchdog))
    );
    assert_eq!(
        host.send(&mut c, &mut rig, 3, Command::ClearFault),
        Ok(Reply::Ok)
    );
    assert_eq!(
        host.send(&mut c, &mut rig, 4, Command::Lamps { mask: 1 }),
        Ok(Reply::Ok)
    );
}

#[test]
fn identity_advertises_the_rig() {
    let mut c = Controller::new(9, false);
    let mut rig = Rig::default();
    let mut host = Host::new();
    let Ok(Reply::Identity(id)) = host.send(&mut c, &mut rig, 0, Command::Identify) else {
        panic!()
    };
    assert_eq!(id.boot_id, 9);
    assert_eq!(id.board.as_str(), hardware::BOARD);
    assert_eq!(id.schema_hash, protocol::SCHEMA_HASH);
    assert_eq!(id.limits.steps_per_rev, [16_000, 32_000]);
    assert_eq!(id.limits.galvo_max_urad, 350_000);
    assert_eq!(id.limits.heartbeat_timeout_us, 250_000);
    assert!(id.limits.soft_max_urad[1] <= 3_241_593 && id.limits.soft_max_urad[1] > 3_240_000);
}

#[test]
fn retransmission_is_answered_not_executed() {
    let (mut c, mut rig, mut host) = setup();
    let cmd = Command::Trigger {
        mask: 0b101,
        pulse_us: 500,
    };
    let seq = host.seq + 1;
    host.seq = seq;
    let r1 = host.send_seq(&mut c, &mut rig, 1000, seq, cmd.clone());
    let r2 = host.send_seq(&mut c, &mut rig, 1100, seq, cmd.clone());
    let r3 = host.send_seq(&mut c, &mut rig, 1200, seq, cmd);
    assert_eq!((r1.clone(), r2), (r1.clone(), r3));
    assert_eq!(r1, Ok(Reply::Ok));
    run_until(&mut c, &mut rig, 1200, 5000);
    host.drain(&mut c);
    let fired = host
        .distinct_events()
        .iter()
        .filter(|e| matches!(e, Event::TriggerFired { .. }))
        .count();
    assert_eq!(fired, 1);
    assert_eq!(rig.trigger_rises, [0b101]);
    assert_eq!(rig.triggers, 0);
    // a gap is refused, not executed
    assert_eq!(
        host.send_seq(&mut c, &mut rig, 6000, seq + 2, Command::Lamps { mask: 3 }),
        Err(CommandError::OutOfSequence { expected: seq + 1 })
    );
    assert_eq!(rig.lamps, 0);
}

#[test]
fn laser_needs_arm_interlock_and_the_host_heard() {
    let (mut c, mut rig, mut host) = setup();
    let t = 1000;
    host.send(
        &mut c,
        &mut rig,
        t,
        Command::LaserSelect {
            colour: LaserColour::Green,
        },
    )
    .unwrap();
    host.send(&mut c, &mut rig, t, Command::LaserPower { permille: 500 })
        .unwrap();
    host.send(&mut c, &mut rig, t, Command::LaserArm { armed: true })
        .unwrap();
    // the arming frame is itself heard: any valid frame keeps the heartbeat fresh
    assert!(rig.laser_on() && c.laser_emitting());
    host.send(
        &mut c,
        &mut rig,
        t + 10,
        Command::Heartbeat { event_ack: 0 },
    )
    .unwrap();
    assert_eq!(rig.lasers, [false, true, false]);
    assert_eq!(rig.laser_power, 2047);
    assert!(c.status(t).laser.emitting);
    // interlock opens: off at the next poll, event reported, no fault
    rig.interlock_closed = false;
    c.poll(t + 20, &mut rig);
    assert!(!rig.laser_on());
    assert_eq!(rig.laser_power, 0);
    rig.interlock_closed = true;
    c.poll(t + 30, &mut rig);
    assert!(rig.laser_on());
    host.drain(&mut c);
    let ev = host.distinct_events();
    assert!(ev.contains(&Event::Interlock { closed: false }));
    assert!(ev.contains(&Event::Interlock { closed: true }));
    // switching colour while emitting never shows two at once
    host.send(
        &mut c,
        &mut rig,
        t + 40,
        Command::LaserSelect {
            colour: LaserColour::Blue,
        },
    )
    .unwrap();
    assert_eq!(rig.lasers, [false, false, true]);
    assert!(!rig.two_lasers_seen);
    // the host goes quiet after its last frame (the colour switch at t + 40):
    // off within the poll after the heartbeat expires
    let expiry = t + 40 + 250 * MS;
    run_until(&mut c, &mut rig, t + 50, expiry);
    assert!(rig.laser_on());
    let deadline = c.poll(expiry, &mut rig);
    assert!(deadline <= expiry + 1);
    c.poll(deadline, &mut rig);
    assert!(!rig.laser_on());
    assert_eq!(c.fault(), Some(FaultCause::HeartbeatLost));
    // disarmed by the fault: clearing does not bring the laser back
    host.send(
        &mut c,
        &mut rig,
        deadline + 10,
        Command::Heartbeat { event_ack: 0 },
    )
    .unwrap();
    host.send(&mut c, &mut rig, deadline + 20, Command::ClearFault)
        .unwrap();
    c.poll(deadline + 30, &mut rig);
    assert!(!rig.laser_on());
    assert!(!c.status(deadline).laser.armed);
}

#[test]
fn absolute_moves_need_homing_and_respect_soft_limits() {
    let (mut c, mut rig, mut host) = setup();
    let quarter = 1_570_796;
    assert_eq!(
        host.send(
            &mut c,
            &mut rig,
            100,
            move_cmd(Axis::Turntable, MoveTarget::Absolute(quarter))
        ),
        Err(CommandError::NotHomed(Axis::Turntable))
    );
    host.send(
        &mut c,
        &mut rig,
        200,
        Command::Home {
            axis: Axis::Turntable,
        },
    )
    .unwrap();
    assert_eq!(
        host.send(
            &mut c,
            &mut rig,
            300,
            Command::Home {
                axis: Axis::Turntable
            }
        ),
        Err(CommandError::Busy(Axis::Turntable))
    );
    run_hb(&mut c, &mut rig, &mut host, 300, 20_000 * MS);
    let st = c.status(0).axes[0];
    assert!(st.homed && !st.homing && st.position_steps == 0);
    // homed exactly at the switch edge of the virtual rig
    assert_eq!(rig.pos[0], 0);
    assert!(host.distinct_events().contains(&Event::MotionDone {
        axis: Axis::Turntable,
        position_steps: 0,
        homed: true
    }));
    let t0 = 20_000 * MS;
    assert_eq!(
        host.send(
            &mut c,
            &mut rig,
            t0,
            move_cmd(Axis::Turntable, MoveTarget::Absolute(7_000_000))
        ),
        Err(CommandError::OutOfLimits(Axis::Turntable))
    );
    host.send(
        &mut c,
        &mut rig,
        t0,
        move_cmd(Axis::Turntable, MoveTarget::Absolute(quarter)),
    )
    .unwrap();
    assert!(c.status(t0).axes[0].moving);
    assert_eq!(c.status(t0).axes[0].target_steps, 4000);
    // 90 deg at 60 deg/s and 120 deg/s^2: 0.5 s ramps, 1 s cruise -> ~2 s
    run_hb(&mut c, &mut rig, &mut host, t0, t0 + 1900 * MS);
    assert!(c.status(0).axes[0].moving);
    run_hb(&mut c, &mut rig, &mut host, t0 + 1900 * MS, t0 + 2100 * MS);
    assert_eq!(c.status(0).axes[0].position_steps, 4000);
    assert!(!c.status(0).axes[0].moving);
    assert_eq!(rig.pos[0], 4000);
    // relative moves go from the current target
    let p = params(Axis::Turntable);
    assert_eq!(
        host.send(
            &mut c,
            &mut rig,
            t0 + 2200 * MS,
            move_cmd(Axis::Turntable, MoveTarget::Relative(6_000_000))
        ),
        Err(CommandError::OutOfLimits(Axis::Turntable))
    );
    assert!(p.soft_max < 4000 + p.steps_from_urad(6_000_000) as i32);
}

#[test]
fn homing_without_switch_fails_and_latches() {
    let (mut c, mut rig, mut host) = setup();
    rig.home_width = -1; // switch never actuates
    host.send(
        &mut c,
        &mut rig,
        100,
        Command::Home {
            axis: Axis::LightArc,
        },
    )
    .unwrap();
    run_hb(&mut c, &mut rig, &mut host, 100, 60_000 * MS);
    assert_eq!(c.fault(), Some(FaultCause::HomingFailed(Axis::LightArc)));
    // 1.1 revolutions of the arc, then it gave up
    assert_eq!(rig.pos[1], -2000 - 35_200);
}

#[test]
fn estop_input_stops_at_once_and_latches_until_released() {
    let (mut c, mut rig, mut host) = setup();
    host.send(&mut c, &mut rig, 100, Command::Lamps { mask: 0xf0 })
        .unwrap();
    host.send(
        &mut c,
        &mut rig,
        100,
        move_cmd(Axis::LightArc, MoveTarget::Relative(1_000_000)),
    )
    .unwrap();
    run_hb(&mut c, &mut rig, &mut host, 100, 500 * MS);
    assert!(c.status(0).axes[1].moving);
    rig.estop_pressed = true;
    c.poll(500 * MS + 1, &mut rig);
    let steps = rig.steps;
    assert_eq!(rig.lamps, 0);
    assert_eq!(rig.enable, [false, false]);
    assert_eq!(c.fault(), Some(FaultCause::EStop));
    run_hb(&mut c, &mut rig, &mut host, 500 * MS + 1, 3000 * MS);
    assert_eq!(rig.steps, steps, "steps after e-stop");
    assert!(!c.status(0).axes[1].homed);
    assert_eq!(
        host.send(&mut c, &mut rig, 3001 * MS, Command::ClearFault),
        Err(CommandError::CauseActive(FaultCause::EStop))
    );
    assert_eq!(
        host.send(&mut c, &mut rig, 3001 * MS, Command::Lamps { mask: 1 }),
        Err(CommandError::Faulted(FaultCause::EStop))
    );
    rig.estop_pressed = false;
    assert_eq!(
        host.send(&mut c, &mut rig, 3002 * MS, Command::ClearFault),
        Ok(Reply::Ok)
    );
    assert_eq!(c.fault(), None);
}

#[test]
fn estop_command_and_limit_switch() {
    let (mut c, mut rig, mut host) = setup();
    host.send(&mut c, &mut rig, 100, Command::EStop).unwrap();
    assert_eq!(c.fault(), Some(FaultCause::EStop));
    host.send(&mut c, &mut rig, 200, Command::ClearFault)
        .unwrap();
    // arc limit opens during a move: fault, decelerate (more steps, but bounded)
    host.send(
        &mut c,
        &mut rig,
        300,
        move_cmd(Axis::LightArc, MoveTarget::Relative(2_000_000)),
    )
    .unwrap();
    run_hb(&mut c, &mut rig, &mut host, 300, 1500 * MS);
    let before = rig.pos[1];
    rig.arc_limit_ok = false;
    run_hb(&mut c, &mut rig, &mut host, 1500 * MS, 4000 * MS);
    assert_eq!(c.fault(), Some(FaultCause::LimitHit(Axis::LightArc)));
    let p = params(Axis::LightArc);
    let overrun = rig.pos[1] - before;
    // at most v^2 / 2a steps (plus one) to stop
    let stop = (p.max_speed * p.max_speed / (2.0 * p.max_accel)) as i64 + 2;
    assert!(overrun > 0 && overrun <= stop, "overrun {overrun} > {stop}");
    assert!(!rig.enable[1], "arc driver released to back off by hand");
    assert_eq!(
        host.send(&mut c, &mut rig, 4001 * MS, Command::ClearFault),
        Err(CommandError::CauseActive(FaultCause::LimitHit(
            Axis::LightArc
        )))
    );
    rig.arc_limit_ok = true;
    host.send(&mut c, &mut rig, 4002 * MS, Command::ClearFault)
        .unwrap();
}

#[test]
fn heartbeat_loss_while_moving_decelerates() {
    let (mut c, mut rig, mut host) = setup();
    host.send(&mut c, &mut rig, 100, Command::Heartbeat { event_ack: 0 })
        .unwrap();
    host.send(
        &mut c,
        &mut rig,
        100,
        move_cmd(Axis::Turntable, MoveTarget::Relative(3_000_000)),
    )
    .unwrap();
    run_until(&mut c, &mut rig, 100, 2000 * MS);
    assert_eq!(c.fault(), Some(FaultCause::HeartbeatLost));
    let st = c.status(0).axes[0];
    assert!(!st.moving);
    // stopped well short of the 3 rad target (fault at ~250 ms)
    assert!(st.position_steps > 0 && st.position_steps < 2000, "{st:?}");
    host.drain(&mut c);
    assert!(host.distinct_events().contains(&Event::Fault {
        cause: FaultCause::HeartbeatLost
    }));
}

#[test]
fn sweep_moves_the_galvo_and_triggers_each_step() {
    let (mut c, mut rig, mut host) = setup();
    let sweep = Sweep {
        start_urad: -200_000,
        end_urad: 200_000,
        steps: 5,
        dwell_us: 20_000,
        trigger_mask: 0b0000_0110,
        pulse_us: 5_000,
    };
    host.send(&mut c, &mut rig, 1000, Command::GalvoSweep(sweep))
        .unwrap();
    assert_eq!(rig.galvo, galvo::galvo_code(-200_000));
    assert_eq!(
        host.send(&mut c, &mut rig, 1000, Command::GalvoSet { angle_urad: 0 }),
        Err(CommandError::SweepRunning)
    );
    let mut codes = Vec::new();
    let mut now = 1000;
    while now < 200 * MS {
        now = c.poll(now, &mut rig).max(now + 1);
        if codes.last() != Some(&rig.galvo) {
            codes.push(rig.galvo);
        }
    }
    assert_eq!(
        codes,
        [-200_000, -100_000, 0, 100_000, 200_000].map(galvo::galvo_code)
    );
    assert_eq!(rig.trigger_rises, [0b110; 5]);
    host.drain(&mut c);
    let ev = host.distinct_events();
    let done: Vec<_> = ev
        .iter()
        .filter_map(|e| match e {
            Event::SweepStepDone { step, angle_urad } => Some((*step, *angle_urad)),
            _ => None,
        })
        .collect();
    assert_eq!(done.len(), 5);
    assert_eq!(done[4], (4, 200_000));
    assert_eq!(ev.last(), Some(&Event::SweepDone { completed: true }));
    // trigger in the middle of the dwell: settle 2 ms + (20 - 5)/2 ms after start
    let first = ev
        .iter()
        .find_map(|e| match e {
            Event::TriggerFired { at_us, .. } => Some(*at_us),
            _ => None,
        })
        .unwrap();
    assert_eq!(first, 1000 + 2000 + 7500);
}

#[test]
fn abort_stops_a_sweep() {
    let (mut c, mut rig, mut host) = setup();
    let sweep = Sweep {
        start_urad: 0,
        end_urad: 100_000,
        steps: 100,
        dwell_us: 10_000,
        trigger_mask: 1,
        pulse_us: 100,
    };
    host.send(&mut c, &mut rig, 0, Command::GalvoSweep(sweep))
        .unwrap();
    run_until(&mut c, &mut rig, 0, 50 * MS);
    host.send(&mut c, &mut rig, 50 * MS, Command::Abort)
        .unwrap();
    host.drain(&mut c);
    assert_eq!(
        host.distinct_events().last(),
        Some(&Event::SweepDone { completed: false })
    );
    assert_eq!(c.status(0).sweep_step, None);
}

#[test]
fn events_are_resent_until_acknowledged() {
    let (mut c, mut rig, mut host) = setup();
    host.send(
        &mut c,
        &mut rig,
        0,
        Command::Trigger {
            mask: 1,
            pulse_us: 10,
        },
    )
    .unwrap();
    run_until(&mut c, &mut rig, 0, 300 * MS);
    host.drain(&mut c);
    let copies = host
        .events
        .iter()
        .filter(|e| matches!(e.2, Event::TriggerFired { .. }))
        .count();
    // sent once, then every 50 ms: about 6 times in 300 ms
    assert!((5..=8).contains(&copies), "{copies} copies");
    let last = host.events.iter().map(|e| e.0).max().unwrap();
    host.send(
        &mut c,
        &mut rig,
        300 * MS,
        Command::AckEvents { upto: last },
    )
    .unwrap();
    host.events.clear();
    run_until(&mut c, &mut rig, 300 * MS, 600 * MS);
    host.drain(&mut c);
    assert!(host.events.is_empty(), "{:?}", host.events);
}

#[test]
fn bad_bytes_are_counted_and_ignored() {
    let (mut c, mut rig, mut host) = setup();
    let mut frame = Host::encode(host.seq + 1, Command::Lamps { mask: 0x0f });
    frame[2] ^= 0x10;
    c.receive(10, &frame, &mut rig);
    c.receive(10, &[0x55; 1000], &mut rig);
    c.receive(10, &[0], &mut rig);
    assert_eq!(c.frames_dropped(), 2);
    assert_eq!(rig.lamps, 0);
    // the link still works afterwards
    host.send(&mut c, &mut rig, 20, Command::Lamps { mask: 0x0f })
        .unwrap();
    assert_eq!(rig.lamps, 0x0f);
}

#[test]
fn bad_arguments_are_refused() {
    let (mut c, mut rig, mut host) = setup();
    for cmd in [
        Command::LaserPower { permille: 1001 },
        Command::Trigger {
            mask: 0,
            pulse_us: 10,
        },
        Command::Trigger {
            mask: 1,
            pulse_us: 0,
        },
        Command::Trigger {
            mask: 1,
            pulse_us: 2_000_000,
        },
        Command::GalvoSet {
            angle_urad: 400_000,
        },
        Command::GalvoSweep(Sweep {
            start_urad: 0,
            end_urad: 0,
            steps: 0,
            dwell_us: 1,
            trigger_mask: 0,
            pulse_us: 0,
        }),
    ] {
        assert_eq!(
            host.send(&mut c, &mut rig, 10, cmd.clone()),
            Err(CommandError::BadArgument),
            "{cmd:?}"
        );
    }
}

#[test]
fn reset_is_requested_once_the_ack_is_taken() {
    let (mut c, mut rig, mut host) = setup();
    host.send(&mut c, &mut rig, 5, Command::Lamps { mask: 0xff })
        .unwrap();
    host.seq += 1;
    c.receive(10, &Host::encode(host.seq, Command::Reset), &mut rig);
    assert!(!c.reset_requested());
    assert_eq!(rig.lamps, 0, "safe outputs before the reset");
    let mut bytes = Vec::new();
    let mut small = [0u8; 4];
    loop {
        let n = c.take_tx(&mut small);
        if n == 0 {
            break;
        }
        // not before the last byte of the ack has gone
        assert!(!c.reset_requested() || n < 4 || small[n - 1] == 0);
        bytes.extend_from_slice(&small[..n]);
    }
    assert!(c.reset_requested());
    let mut dec = protocol::FrameDecoder::new();
    let mut acked = false;
    dec.push_slice::<protocol::McuFrame>(&bytes, |r| {
        acked |= r
            == Ok(protocol::McuFrame::Ack {
                seq: host.seq,
                result: Ok(Reply::Ok),
            })
    });
    assert!(acked);
    // nothing is executed after the reset ack
    c.receive(
        20,
        &Host::encode(host.seq + 1, Command::Lamps { mask: 1 }),
        &mut rig,
    );
    assert_eq!(rig.lamps, 0);
}

#[test]
fn controller_memory_is_small_and_static() {
    let size = core::mem::size_of::<Controller>();
    // The STM32 holds it in a static task future; keep it well under 8 KB.
    assert!(size < 8 * 1024, "Controller is {size} bytes");
    std::println!("size_of::<Controller>() = {size}");
}

#[test]
fn unacknowledged_events_are_resent_in_bounded_bursts() {
    let (mut c, mut rig, mut host) = setup();
    host.send(&mut c, &mut rig, 0, Command::AckEvents { upto: 1 })
        .unwrap();
    for i in 0..20 {
        host.send(
            &mut c,
            &mut rig,
            10 + i,
            Command::Trigger {
                mask: 1,
                pulse_us: 1,
            },
        )
        .unwrap();
    }
    host.events.clear();
    // one resend period later: only the oldest RESEND_BURST go out again
    run_until(&mut c, &mut rig, 100, 60 * MS);
    host.drain(&mut c);
    let resent: Vec<u16> = host.events.iter().map(|e| e.0).collect();
    assert_eq!(resent.len(), crate::controller::RESEND_BURST, "{resent:?}");
    assert_eq!(resent[0], 2);
    // acknowledging moves the window on
    host.send(&mut c, &mut rig, 60 * MS, Command::AckEvents { upto: 15 })
        .unwrap();
    host.events.clear();
    run_until(&mut c, &mut rig, 60 * MS, 120 * MS);
    host.drain(&mut c);
    let resent: Vec<u16> = host.events.iter().map(|e| e.0).collect();
    assert_eq!(resent, [16, 17, 18, 19, 20, 21]);
}

#[test]
fn speed_and_acceleration_are_clamped_to_the_mechanics() {
    let duration = |speed_urad_s, accel_urad_s2| {
        let (mut c, mut rig, mut host) = setup();
        host.send(
            &mut c,
            &mut rig,
            0,
            Command::Move {
                axis: Axis::Turntable,
                target: MoveTarget::Relative(3_141_593),
                speed_urad_s,
                accel_urad_s2,
            },
        )
        .unwrap();
        let mut t = 0;
        while c.status(t).axes[0].moving {
            run_hb(&mut c, &mut rig, &mut host, t, t + 10 * MS);
            t += 10 * MS;
        }
        assert_eq!(rig.pos[0], 3000 + 8000);
        t
    };
    let at_limit = duration(0, 0);
    // half a turn at 60 deg/s, 120 deg/s^2: 0.5 s ramps + 2.5 s cruise = 3.5 s
    assert!((3_450 * MS..=3_560 * MS).contains(&at_limit), "{at_limit}");
    assert_eq!(duration(u32::MAX, u32::MAX), at_limit);
    // slower on request: 30 deg/s
    let slow = duration(523_599, 0);
    assert!(slow > 6_000 * MS, "{slow}");
}

#[test]
fn identify_restarts_the_sequence() {
    let (mut c, mut rig, mut host) = setup();
    host.send(&mut c, &mut rig, 1, Command::Lamps { mask: 1 })
        .unwrap();
    host.seq = 9000;
    let r = host.send_seq(&mut c, &mut rig, 2, 9000, Command::Identify);
    assert!(matches!(r, Ok(Reply::Identity(_))));
    assert_eq!(
        host.send_seq(&mut c, &mut rig, 3, 9001, Command::Lamps { mask: 2 }),
        Ok(Reply::Ok)
    );
    assert_eq!(rig.lamps, 2);
    assert_eq!(c.status(3).last_seq, 9001);
}

#[test]
fn estop_command_aborts_a_sweep_and_drops_triggers() {
    let (mut c, mut rig, mut host) = setup();
    let sweep = Sweep {
        start_urad: 0,
        end_urad: 0,
        steps: 10,
        dwell_us: 10_000,
        trigger_mask: 0xff,
        pulse_us: 9_000,
    };
    host.send(&mut c, &mut rig, 0, Command::GalvoSweep(sweep))
        .unwrap();
    run_until(&mut c, &mut rig, 0, 5 * MS);
    assert_eq!(rig.triggers, 0xff);
    host.send(&mut c, &mut rig, 5 * MS, Command::EStop).unwrap();
    assert_eq!(rig.triggers, 0);
    host.drain(&mut c);
    let ev = host.distinct_events();
    assert!(ev.contains(&Event::SweepDone { completed: false }));
    assert!(ev.contains(&Event::Fault {
        cause: FaultCause::EStop
    }));
}
