//! The emulated MCU driven with raw protocol frames on virtual time: the
//! firmware's Controller on virtual peripherals must home against physical
//! switches, move with trapezoidal timing, sweep with triggers, and keep the
//! laser safe (interlock, heartbeat, reset in the middle of a sweep).

use hardware::{AxisMechanics, LIGHT_ARC, TURNTABLE};
use protocol::{
    Axis, Command, CommandError, Event, FaultCause, LaserColour, MoveTarget, PROTOCOL_VERSION,
    Reply, SCHEMA_HASH, Sweep,
};
use sim::peripherals::wrap_pi;
use sim::{FaultConfig, LinkConfig, PhysicalConfig, RawHost, ResetFault, RigConfig, SimPort};

fn host_with(rig: RigConfig, link: LinkConfig) -> RawHost {
    let mut h = RawHost::new(SimPort::new(rig, link).expect("valid config"));
    match h.identify() {
        Ok(Ok(Reply::Identity(_))) => {}
        other => panic!("handshake failed: {other:?}"),
    }
    h
}

fn host(seed: u64) -> RawHost {
    let mut h = host_with(RigConfig::seeded(seed), LinkConfig::default());
    h.heartbeat_us = Some(100_000);
    h
}

/// A rig whose axes start at the given physical angles.
fn host_at(start: [f64; 2]) -> RawHost {
    let mut cfg = RigConfig::seeded(1);
    cfg.physical = PhysicalConfig {
        start_rad: [Some(start[0]), Some(start[1])],
        ..cfg.physical
    };
    let mut h = host_with(cfg, LinkConfig::default());
    h.heartbeat_us = Some(100_000);
    h
}

fn ok(h: &mut RawHost, c: Command) {
    assert_eq!(h.call(c.clone()), Ok(Ok(Reply::Ok)), "{c:?}");
}

fn mech(axis: Axis) -> AxisMechanics {
    match axis {
        Axis::Turntable => TURNTABLE,
        Axis::LightArc => LIGHT_ARC,
    }
}

/// Home both axes at once; returns the MotionDone position of each.
fn home_both(h: &mut RawHost) -> [i32; 2] {
    ok(
        h,
        Command::Home {
            axis: Axis::Turntable,
        },
    );
    ok(
        h,
        Command::Home {
            axis: Axis::LightArc,
        },
    );
    let mut done = [None, None];
    while done.iter().any(|d| d.is_none()) {
        let e = h
            .run_until_event(60_000_000, |e| matches!(e, Event::MotionDone { .. }))
            .expect("homing finishes within 60 s");
        if let Event::MotionDone {
            axis,
            position_steps,
            homed,
        } = e.event
        {
            assert!(homed, "{axis:?} not homed");
            done[axis.index()] = Some(position_steps);
        }
    }
    done.map(|d| d.unwrap_or_default())
}

#[test]
fn handshake_reports_identity_and_boot() {
    let mut h = RawHost::new(SimPort::new(RigConfig::seeded(9), LinkConfig::default()).unwrap());
    // Before the handshake every command is refused.
    assert_eq!(
        h.call(Command::Status),
        Ok(Err(CommandError::NotIdentified))
    );
    let id = match h.identify() {
        Ok(Ok(Reply::Identity(id))) => id,
        other => panic!("{other:?}"),
    };
    assert_eq!(id.protocol_version, PROTOCOL_VERSION);
    assert_eq!(id.schema_hash, SCHEMA_HASH);
    assert_eq!(id.boot_id, h.port.rig().boot_id());
    assert_eq!(id.limits.steps_per_rev, [16_000, 32_000]);
    h.run_for(10_000);
    let booted = h.events_where(|e| matches!(e, Event::Booted { .. }));
    assert_eq!(booted.len(), 1);
    assert_eq!(
        booted[0].event,
        Event::Booted {
            boot_id: id.boot_id,
            watchdog: false
        }
    );
}

#[test]
fn homing_ends_at_the_physical_switch_from_random_starts() {
    for seed in [1, 2, 3] {
        let mut h = host(seed);
        let before = h.port.rig().rig_state();
        let pos = home_both(&mut h);
        let after = h.port.rig().rig_state();
        for axis in Axis::ALL {
            let m = mech(axis);
            assert_eq!(pos[axis.index()] as i64, m.steps_from_rad(m.home_offset));
            let phys = match axis {
                Axis::Turntable => wrap_pi(after.turntable_rad - m.home_offset),
                Axis::LightArc => after.light_arc_rad - m.home_offset,
            };
            // Approached from above, stopped on the first actuated step.
            assert!(
                phys <= 1e-9 && phys > -1.5 * m.rad_per_step(),
                "seed {seed} {axis:?}: {phys} rad from the switch edge (started at {before:?})"
            );
        }
        let st = h.port.rig().status();
        assert!(st.axes.iter().all(|a| a.homed && !a.moving && !a.homing));
        assert!(
            h.port
                .rig()
                .snapshot()
                .axes
                .iter()
                .all(|a| a.lost_steps == 0)
        );
    }
}

#[test]
fn homing_starting_on_the_switch_backs_off_first() {
    let mut h = host_at([-0.03, -0.03]);
    assert!(h.port.rig().snapshot().inputs.home.iter().all(|&x| x));
    home_both(&mut h);
    let s = h.port.rig().rig_state();
    assert!(s.turntable_rad.abs() < 1.5 * TURNTABLE.rad_per_step());
    assert!(s.light_arc_rad.abs() < 1.5 * LIGHT_ARC.rad_per_step());
}

/// Move `axis` to `target` rad at full speed; returns (physical duration s, ideal s).
fn timed_move(h: &mut RawHost, axis: Axis, target: f64) -> (f64, f64) {
    let m = mech(axis);
    let from = h.port.rig().status().axes[axis.index()].position_steps;
    h.port.rig_mut().peripherals_mut().clear_history();
    ok(
        h,
        Command::Move {
            axis,
            target: MoveTarget::Absolute((target * 1e6).round() as i32),
            speed_urad_s: 0,
            accel_urad_s2: 0,
        },
    );
    let e = h
        .run_until_event(30_000_000, |e| matches!(e, Event::MotionDone { .. }))
        .expect("move finishes");
    let goal = m.steps_from_rad(target);
    assert_eq!(
        e.event,
        Event::MotionDone {
            axis,
            position_steps: goal as i32,
            homed: true
        }
    );
    let a = h.port.rig().snapshot().axes[axis.index()];
    assert_eq!(a.step_count as i64, (goal - from as i64).abs());
    let took = (a.last_step_us.unwrap() - a.first_step_us.unwrap()) as f64 * 1e-6;
    let d = m.rad_from_steps(goal - from as i64);
    (took, m.move_time(d, m.max_speed, m.max_accel))
}

#[test]
fn moves_arrive_with_trapezoidal_timing() {
    let mut h = host_at([0.4, 0.4]);
    home_both(&mut h);
    // Trapezoidal (cruise reached) and triangular moves on both axes.
    for (axis, target) in [
        (Axis::Turntable, std::f64::consts::FRAC_PI_2),
        (Axis::Turntable, 1.4),
        (Axis::LightArc, -1.0),
        (Axis::LightArc, -0.95),
    ] {
        let (took, ideal) = timed_move(&mut h, axis, target);
        let rel = (took - ideal).abs() / ideal;
        // The discrete profile's first step goes out at once, about one
        // start interval (1/sqrt(a/2)) ahead of the ideal continuous ramp:
        // a few % of a short (triangular) move, well under 1% of a long one.
        let tol = if ideal > 1.0 { 0.01 } else { 0.04 };
        assert!(
            rel < tol,
            "{axis:?} to {target}: {took:.4} s vs ideal {ideal:.4} s"
        );
        let s = h.port.rig().rig_state();
        let phys = match axis {
            Axis::Turntable => s.turntable_rad,
            Axis::LightArc => s.light_arc_rad,
        };
        // Homing left the axis within a step below the edge; the move is exact.
        assert!(
            (phys - target).abs() < 2.0 * mech(axis).rad_per_step(),
            "{phys} vs {target}"
        );
    }
}

#[test]
fn sweep_fires_triggers_with_the_right_count_and_times() {
    let mut h = host(4);
    let mut triggers = h.port.rig_mut().subscribe_triggers();
    let sweep = Sweep {
        start_urad: -200_000,
        end_urad: 200_000,
        steps: 11,
        dwell_us: 20_000,
        trigger_mask: 0b0000_0110,
        pulse_us: 4_000,
    };
    ok(&mut h, Command::GalvoSweep(sweep));
    let done = h
        .run_until_event(2_000_000, |e| matches!(e, Event::SweepDone { .. }))
        .expect("sweep finishes");
    assert_eq!(done.event, Event::SweepDone { completed: true });

    let mut got = Vec::new();
    while let Ok(t) = triggers.try_recv() {
        got.push(t);
    }
    assert_eq!(got.len(), 11);
    let settle = (hardware::GALVO.settle_time * 1e6) as u64;
    for (i, t) in got.iter().enumerate() {
        assert_eq!(t.mask, 0b0110);
        assert_eq!(t.pulse_us, 4_000);
        let angle = (-200_000 + 40_000 * i as i64) as f64 * 1e-6;
        // one DAC LSB is 171 µrad
        assert!(
            (t.state.galvo_rad - angle).abs() < 2e-4,
            "step {i}: {}",
            t.state.galvo_rad
        );
        if i > 0 {
            assert_eq!(t.at_us - got[i - 1].at_us, settle + 20_000);
        }
    }
    // The MCU reports the same pulses on its own clock (equal to the world
    // clock before any reset), and one step-done per step.
    let fired = h.events_where(|e| matches!(e, Event::TriggerFired { .. }));
    assert_eq!(fired.len(), 11);
    for (f, t) in fired.iter().zip(&got) {
        assert_eq!(
            f.event,
            Event::TriggerFired {
                mask: 0b0110,
                at_us: t.at_us,
                pulse_us: 4_000
            }
        );
    }
    let steps = h.events_where(|e| matches!(e, Event::SweepStepDone { .. }));
    assert_eq!(steps.len(), 11);
    assert_eq!(h.port.rig().peripherals().trigger_log().len(), 11);
}

fn arm_green(h: &mut RawHost) {
    ok(
        h,
        Command::LaserSelect {
            colour: LaserColour::Green,
        },
    );
    ok(h, Command::LaserPower { permille: 500 });
    ok(h, Command::LaserArm { armed: true });
    h.run_for(5_000);
    let (colour, power) = h.port.rig().rig_state().laser.expect("laser emits");
    assert_eq!(colour, LaserColour::Green);
    assert!((power - 0.5).abs() < 0.01, "power {power}");
}

#[test]
fn laser_goes_dark_when_the_interlock_opens() {
    let mut h = host(5);
    arm_green(&mut h);
    h.port.rig_mut().set_interlock(false);
    h.run_for(3_000);
    assert_eq!(h.port.rig().rig_state().laser, None);
    let snap = h.port.rig().snapshot();
    // Seen at the next input scan at the latest.
    assert!(snap.laser_on_interlock_open_us <= 1_000, "{snap:?}");
    assert_eq!(snap.two_lasers_on, 0);
    h.run_for(100_000);
    assert_eq!(
        h.events_where(|e| matches!(e, Event::Interlock { closed: false }))
            .len(),
        1
    );
    assert_eq!(
        h.port.rig().snapshot().laser_on_interlock_open_us,
        snap.laser_on_interlock_open_us
    );
}

#[test]
fn heartbeat_loss_darkens_the_laser_and_latches_a_fault() {
    let mut h = host(6);
    arm_green(&mut h);
    h.run_for(300_000);
    assert!(
        h.port.rig().rig_state().laser.is_some(),
        "heartbeats keep it on"
    );
    h.heartbeat_us = None;
    let last_hb = h.last_sent_us().unwrap();
    let e = h
        .run_until_event(1_000_000, |e| matches!(e, Event::Fault { .. }))
        .expect("fault raised");
    assert_eq!(
        e.event,
        Event::Fault {
            cause: FaultCause::HeartbeatLost
        }
    );
    assert_eq!(h.port.rig().rig_state().laser, None);
    let off = h
        .port
        .rig()
        .peripherals()
        .laser_log()
        .last()
        .copied()
        .unwrap();
    assert_eq!(off.laser, None);
    // 250 ms after the last heartbeat reached the MCU (its frame takes ~1 ms
    // on the line), seen within one input scan.
    let since = off.at_us - last_hb;
    assert!(
        (250_000..=253_000).contains(&since),
        "dark {since} µs after"
    );
    assert_eq!(
        h.call(Command::LaserArm { armed: true }),
        Ok(Err(CommandError::Faulted(FaultCause::HeartbeatLost)))
    );
}

#[test]
fn reset_in_the_middle_of_a_sweep_leaves_the_laser_off() {
    let mut link = LinkConfig::default();
    // Frames: Identify, Heartbeat, LaserSelect, LaserPower, LaserArm, GalvoSweep (6th).
    link.faults = FaultConfig {
        reset: Some(ResetFault::AfterFrames {
            frames: 6,
            delay_us: 100_000,
        }),
        ..FaultConfig::none()
    };
    let mut h = host_with(RigConfig::seeded(7), link);
    // No AckEvents frames in between, so the sweep is frame 6.
    h.auto_ack = false;
    let boot0 = h.port.rig().boot_id();
    ok(&mut h, Command::Heartbeat { event_ack: 0 });
    ok(
        &mut h,
        Command::LaserSelect {
            colour: LaserColour::Red,
        },
    );
    ok(&mut h, Command::LaserPower { permille: 1000 });
    ok(&mut h, Command::LaserArm { armed: true });
    let sweep = Sweep {
        start_urad: -100_000,
        end_urad: 100_000,
        steps: 20,
        dwell_us: 20_000,
        trigger_mask: 1,
        pulse_us: 1_000,
    };
    ok(&mut h, Command::GalvoSweep(sweep));
    assert_eq!(h.port.frames_in(), 6);
    h.heartbeat_us = Some(50_000);
    h.run_for(50_000);
    assert!(
        h.port.rig().rig_state().laser.is_some(),
        "sweeping with the laser on"
    );
    assert!(!h.port.reset_fired());
    h.run_for(100_000);
    assert!(h.port.reset_fired());
    let rig = h.port.rig();
    assert_eq!(rig.boots(), 2);
    assert_ne!(rig.boot_id(), boot0);
    let snap = rig.snapshot();
    assert_eq!(snap.state.laser, None);
    assert_eq!(snap.laser_enable, [false; 3]);
    assert_eq!(snap.triggers, 0);
    assert!(snap.axes.iter().all(|a| !a.enabled));
    let boot1 = rig.boot_id();
    h.run_for(20_000);
    assert!(
        h.events.iter().any(|e| e.event
            == Event::Booted {
                boot_id: boot1,
                watchdog: false
            }),
        "Booted event of the new boot"
    );
    // The sweep never completed, and the new boot wants a handshake.
    assert!(
        h.events_where(|e| matches!(e, Event::SweepDone { completed: true }))
            .is_empty()
    );
    assert_eq!(
        h.call(Command::Status),
        Ok(Err(CommandError::NotIdentified))
    );
    match h.identify() {
        Ok(Ok(Reply::Identity(id))) => assert_eq!(id.boot_id, boot1),
        other => panic!("{other:?}"),
    }
    match h.call(Command::Status) {
        Ok(Ok(Reply::Status(s))) => {
            assert!(!s.laser.armed && !s.laser.emitting && s.sweep_step.is_none());
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn reset_command_reboots_after_its_ack() {
    let mut h = host(8);
    let boot0 = h.port.rig().boot_id();
    ok(&mut h, Command::Lamps { mask: 0xff });
    h.run_for(2_000);
    assert_eq!(h.port.rig().rig_state().lamps, 0xff);
    ok(&mut h, Command::Reset);
    h.run_for(10_000);
    assert_eq!(h.port.rig().boots(), 2);
    assert_ne!(h.port.rig().boot_id(), boot0);
    assert_eq!(h.port.rig().rig_state().lamps, 0);
    // The new MCU's clock started at its boot, after the ack went out.
    let rig = h.port.rig();
    assert!(rig.mcu_now_us() <= 15_000 && rig.mcu_now_us() < rig.now_us());
}

#[test]
fn estop_stops_everything_at_once_and_stays_latched_while_pressed() {
    let mut h = host(10);
    ok(&mut h, Command::Lamps { mask: 0x0f });
    ok(
        &mut h,
        Command::Move {
            axis: Axis::Turntable,
            target: MoveTarget::Relative(3_000_000),
            speed_urad_s: 0,
            accel_urad_s2: 0,
        },
    );
    h.run_for(1_000_000);
    let moving = h.port.rig().snapshot().axes[0];
    assert!(moving.enabled && moving.step_count > 1000);
    h.port.rig_mut().set_estop(true);
    h.run_for(2_000);
    let stopped = h.port.rig().snapshot();
    h.run_for(200_000);
    let later = h.port.rig().snapshot();
    // No deceleration ramp: not a single step after the input scan saw it.
    assert_eq!(later.axes[0].steps, stopped.axes[0].steps);
    assert!(later.axes.iter().all(|a| !a.enabled));
    assert_eq!(later.state.lamps, 0);
    assert_eq!(later.state.laser, None);
    assert!(
        !h.events_where(|e| *e
            == Event::Fault {
                cause: FaultCause::EStop
            })
        .is_empty()
    );
    assert_eq!(
        h.call(Command::ClearFault),
        Ok(Err(CommandError::CauseActive(FaultCause::EStop)))
    );
    h.port.rig_mut().set_estop(false);
    h.run_for(2_000);
    ok(&mut h, Command::ClearFault);
    ok(&mut h, Command::Lamps { mask: 1 });
}

#[test]
fn arc_end_switch_stops_an_unhomed_arc_beyond_its_soft_limit() {
    // Not homed, the arc believes it is at 0 while it physically sits near
    // its positive end: a relative move within the soft limits runs it into
    // the end-of-travel switch.
    let mut h = host_at([0.0, 2.9]);
    ok(
        &mut h,
        Command::Move {
            axis: Axis::LightArc,
            target: MoveTarget::Relative(600_000),
            speed_urad_s: 0,
            accel_urad_s2: 0,
        },
    );
    let e = h
        .run_until_event(5_000_000, |e| matches!(e, Event::Fault { .. }))
        .expect("limit fault");
    assert_eq!(
        e.event,
        Event::Fault {
            cause: FaultCause::LimitHit(Axis::LightArc)
        }
    );
    h.run_for(1_000_000);
    let snap = h.port.rig().snapshot();
    let switch_at = LIGHT_ARC.soft_max + h.port.rig().peripherals().config().arc_limit_margin_rad;
    let arc = snap.state.light_arc_rad;
    // Decelerated to rest past the switch (v^2 / 2a at most), driver off.
    let v = LIGHT_ARC.max_speed;
    assert!(arc > switch_at && arc < switch_at + v * v / (2.0 * LIGHT_ARC.max_accel) + 0.01);
    assert!(arc < 2.9 + 0.6, "stopped before the commanded target");
    assert!(!snap.axes[1].enabled && !snap.inputs.arc_limit_ok);
    assert_eq!(
        h.call(Command::ClearFault),
        Ok(Err(CommandError::CauseActive(FaultCause::LimitHit(
            Axis::LightArc
        ))))
    );
    // The operator turns the arc back off the switch; then the fault clears.
    h.port
        .rig_mut()
        .peripherals_mut()
        .turn_by_hand(Axis::LightArc, -0.5);
    h.run_for(2_000);
    ok(&mut h, Command::ClearFault);
}

#[test]
fn watchdog_reset_latches_a_fault_until_cleared() {
    let link = LinkConfig {
        faults: FaultConfig {
            reset: Some(ResetFault::AtUs(50_000)),
            reset_by_watchdog: true,
            ..FaultConfig::none()
        },
        ..LinkConfig::default()
    };
    let mut h = host_with(RigConfig::seeded(11), link);
    h.run_for(100_000);
    assert!(h.port.reset_fired());
    let boot1 = h.port.rig().boot_id();
    assert!(h.events.iter().any(|e| e.event
        == Event::Booted {
            boot_id: boot1,
            watchdog: true
        }));
    assert!(
        !h.events_where(|e| *e
            == Event::Fault {
                cause: FaultCause::Watchdog
            })
        .is_empty()
    );
    assert!(matches!(h.identify(), Ok(Ok(Reply::Identity(_)))));
    assert_eq!(
        h.call(Command::Lamps { mask: 1 }),
        Ok(Err(CommandError::Faulted(FaultCause::Watchdog)))
    );
    ok(&mut h, Command::ClearFault);
    ok(&mut h, Command::Lamps { mask: 1 });
}
