//! Property tests of the Controller's invariants over random command
//! sequences, random input changes and random time steps (issue 2):
//! the laser is never on unless armed, interlock closed, host heard lately and no
//! fault; never two colours at once; homed positions never pass the soft
//! limits; no step after an e-stop; every command executed exactly once under
//! retransmission.

use crate::Controller;
use crate::controller::HEARTBEAT_TIMEOUT_US;
use crate::testkit::{Host, Rig, params};
use proptest::prelude::*;
use protocol::{Axis, Command, Event, FaultCause, LaserColour, MoveTarget, Sweep};
use std::vec;
use std::vec::Vec;

#[derive(Debug, Clone)]
enum Op {
    /// A new command with the next sequence number.
    Cmd(Command),
    /// The last frame again (a host retransmission).
    Retransmit,
    /// Time passes with a poll at every deadline the controller asks for.
    Run(u64),
    /// Time passes while the host sends a heartbeat every 100 ms.
    RunHb(u64),
    /// Time jumps with a single poll at the end (a late MCU loop).
    Jump(u64),
    Interlock(bool),
    EStop(bool),
    ArcLimit(bool),
    Garbage(Vec<u8>),
}

fn axis() -> impl Strategy<Value = Axis> {
    prop_oneof![Just(Axis::Turntable), Just(Axis::LightArc)]
}

fn colour() -> impl Strategy<Value = LaserColour> {
    prop_oneof![
        Just(LaserColour::Red),
        Just(LaserColour::Green),
        Just(LaserColour::Blue)
    ]
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        6 => any::<u16>().prop_map(|event_ack| Command::Heartbeat { event_ack }),
        1 => Just(Command::Status),
        1 => Just(Command::Identify),
        1 => axis().prop_map(|axis| Command::Home { axis }),
        3 => (
            axis(),
            any::<bool>(),
            -8_000_000i32..8_000_000,
            prop_oneof![Just(0u32), 1u32..2_000_000],
            prop_oneof![Just(0u32), 1u32..5_000_000],
        )
            .prop_map(|(axis, abs, urad, speed_urad_s, accel_urad_s2)| Command::Move {
                axis,
                target: if abs {
                    MoveTarget::Absolute(urad)
                } else {
                    MoveTarget::Relative(urad / 8)
                },
                speed_urad_s,
                accel_urad_s2,
            }),
        1 => (-400_000i32..400_000).prop_map(|angle_urad| Command::GalvoSet { angle_urad }),
        1 => (-400_000i32..400_000, -400_000i32..400_000, 0u16..20, 0u32..20_000, any::<u8>(), 0u32..20_000)
            .prop_map(|(start_urad, end_urad, steps, dwell_us, trigger_mask, pulse_us)| {
                Command::GalvoSweep(Sweep { start_urad, end_urad, steps, dwell_us, trigger_mask, pulse_us })
            }),
        2 => colour().prop_map(|colour| Command::LaserSelect { colour }),
        1 => (0u16..1200).prop_map(|permille| Command::LaserPower { permille }),
        3 => any::<bool>().prop_map(|armed| Command::LaserArm { armed }),
        1 => any::<u8>().prop_map(|mask| Command::Lamps { mask }),
        1 => (any::<u8>(), 0u32..20_000).prop_map(|(mask, pulse_us)| Command::Trigger { mask, pulse_us }),
        1 => Just(Command::Abort),
        1 => Just(Command::EStop),
        2 => Just(Command::ClearFault),
        1 => any::<u16>().prop_map(|upto| Command::AckEvents { upto }),
    ]
}

/// Random operations; `chaos` weighs the input faults (e-stop, limit, interlock).
fn op(chaos: u32) -> impl Strategy<Value = Op> {
    prop_oneof![
        12 => command().prop_map(Op::Cmd),
        2 => Just(Op::Retransmit),
        4 => (0u64..300_000).prop_map(Op::Run),
        4 => (0u64..3_000_000).prop_map(Op::RunHb),
        1 => (0u64..1_000_000).prop_map(Op::Jump),
        chaos => any::<bool>().prop_map(Op::Interlock),
        chaos => prop::bool::weighted(0.1).prop_map(Op::EStop),
        chaos => prop::bool::weighted(0.8).prop_map(Op::ArcLimit),
        1 => prop::collection::vec(any::<u8>(), 0..40).prop_map(Op::Garbage),
    ]
}

struct World {
    c: Controller,
    rig: Rig,
    host: Host,
    now: u64,
    seq: u16,
    last_frame: Vec<u8>,
    /// When the controller last received a valid frame (as the host knows
    /// it): any frame keeps the heartbeat fresh, a retransmission too.
    last_hb: Option<u64>,
}

impl World {
    fn new() -> Self {
        let mut w = World {
            c: Controller::new(1, false),
            rig: Rig::default(),
            host: Host::new(),
            now: 0,
            seq: 0,
            last_frame: Vec::new(),
            last_hb: None,
        };
        // close to the home switches, so homing often completes within a case
        w.rig.pos = [400, 300];
        w.c.poll(0, &mut w.rig);
        w.deliver(Command::Identify);
        w
    }

    fn deliver(&mut self, command: Command) {
        if !matches!(command, Command::Identify) {
            self.seq = self.seq.wrapping_add(1);
        }
        // A leading delimiter flushes any garbage the link left in the decoder.
        self.last_frame = Host::encode(self.seq, command);
        self.last_frame.insert(0, 0);
        self.c.receive(self.now, &self.last_frame, &mut self.rig);
        self.last_hb = Some(self.now);
        self.host.drain(&mut self.c);
    }

    /// Check every invariant at the current time.
    fn check(&self) -> Result<(), TestCaseError> {
        let (rig, c) = (&self.rig, &self.c);
        prop_assert!(!rig.two_lasers_seen, "two lasers on at once");
        prop_assert_eq!(c.laser_emitting(), rig.laser_on());
        if rig.laser_on() {
            prop_assert!(rig.interlock_closed, "laser on with open interlock");
            prop_assert!(!rig.estop_pressed, "laser on with e-stop pressed");
            prop_assert!(c.fault().is_none(), "laser on with fault {:?}", c.fault());
            let fresh = self
                .last_hb
                .is_some_and(|t| self.now - t <= HEARTBEAT_TIMEOUT_US);
            prop_assert!(fresh, "laser on with stale heartbeat at {}", self.now);
            prop_assert!(c.status(self.now).laser.armed);
        } else {
            prop_assert_eq!(rig.laser_power, 0);
        }
        if c.fault().is_some() {
            prop_assert_eq!(rig.lamps, 0, "lamps on while faulted");
        }
        for axis in Axis::ALL {
            let st = c.status(self.now).axes[axis.index()];
            let p = params(axis);
            if st.homed {
                prop_assert!(
                    (p.soft_min..=p.soft_max).contains(&st.position_steps),
                    "{:?} at {} beyond soft limits",
                    axis,
                    st.position_steps
                );
                // The virtual switch edge is at 0 = home: belief equals physics.
                prop_assert_eq!(rig.pos[axis.index()], st.position_steps as i64);
            }
        }
        prop_assert_eq!(rig.steps_while_disabled, 0);
        Ok(())
    }

    fn apply(&mut self, op: Op) -> Result<(), TestCaseError> {
        let estopped = self.rig.estop_pressed || self.c.fault() == Some(FaultCause::EStop);
        let steps_before = self.rig.steps;
        match op {
            Op::Cmd(command) => self.deliver(command),
            Op::Retransmit => {
                self.c.receive(self.now, &self.last_frame, &mut self.rig);
                self.last_hb = Some(self.now);
                self.host.drain(&mut self.c);
            }
            Op::Run(dt) => {
                let end = self.now + dt;
                loop {
                    let next = self.c.poll(self.now, &mut self.rig);
                    self.check()?;
                    if self.now >= end {
                        break;
                    }
                    self.now = next.clamp(self.now + 1, end);
                }
            }
            Op::RunHb(dt) => {
                let end = self.now + dt;
                while self.now < end {
                    let step = (end - self.now).min(100_000);
                    self.apply(Op::Run(step))?;
                    let ack = self.host.events.last().map_or(0, |e| e.0);
                    self.deliver(Command::Heartbeat { event_ack: ack });
                }
            }
            Op::Jump(dt) => {
                self.now += dt;
            }
            Op::Interlock(closed) => self.rig.interlock_closed = closed,
            Op::EStop(pressed) => self.rig.estop_pressed = pressed,
            Op::ArcLimit(ok) => self.rig.arc_limit_ok = ok,
            Op::Garbage(bytes) => self.c.receive(self.now, &bytes, &mut self.rig),
        }
        self.c.poll(self.now, &mut self.rig);
        self.host.drain(&mut self.c);
        self.check()?;
        if estopped {
            prop_assert_eq!(self.rig.steps, steps_before, "steps after e-stop");
        }
        Ok(())
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 192, ..ProptestConfig::default() })]

    #[test]
    fn safety_invariants_hold(ops in prop::collection::vec(op(3), 1..80)) {
        let mut w = World::new();
        for op in ops {
            w.apply(op)?;
        }
    }

    /// Fewer input faults, so moves, homing, sweeps and emission run long.
    #[test]
    fn safety_invariants_hold_in_long_runs(ops in prop::collection::vec(op(0), 1..60)) {
        let mut w = World::new();
        for op in ops {
            w.apply(op)?;
        }
    }

    /// Each command is executed exactly once whatever the link repeats or
    /// corrupts: count the trigger pulses and check the last lamp state.
    #[test]
    fn commands_execute_exactly_once(
        plan in prop::collection::vec((any::<bool>(), 1u8..=255, 0usize..4, any::<bool>()), 1..60)
    ) {
        let mut w = World::new();
        let mut triggers = 0;
        let mut lamps = 0u8;
        for (is_trigger, mask, copies, corrupt_first) in plan {
            let command = if is_trigger {
                triggers += 1;
                Command::Trigger { mask, pulse_us: 100 }
            } else {
                lamps = mask;
                Command::Lamps { mask }
            };
            w.seq = w.seq.wrapping_add(1);
            let frame = Host::encode(w.seq, command);
            if corrupt_first {
                let mut bad = frame.clone();
                bad[1] ^= 0x5a;
                w.c.receive(w.now, &bad, &mut w.rig);
            }
            for _ in 0..=copies {
                w.c.receive(w.now, &frame, &mut w.rig);
                w.now += 150;
                w.c.poll(w.now, &mut w.rig);
            }
            w.now += 1000;
            w.c.poll(w.now, &mut w.rig);
            w.host.drain(&mut w.c);
            let last = w.host.events.iter().map(|e| e.0).max().unwrap_or(0);
            w.c.receive(w.now, &Host::encode(w.seq.wrapping_add(1), Command::AckEvents { upto: last }), &mut w.rig);
            w.seq = w.seq.wrapping_add(1);
            w.host.drain(&mut w.c);
        }
        w.now += 1_000_000;
        w.c.poll(w.now, &mut w.rig);
        w.host.drain(&mut w.c);
        let fired = w.host.distinct_events().iter()
            .filter(|e| matches!(e, Event::TriggerFired { .. })).count();
        prop_assert_eq!(fired, triggers);
        prop_assert_eq!(w.rig.trigger_rises.len(), triggers);
        prop_assert_eq!(w.rig.lamps, lamps);
        prop_assert_eq!(w.c.status(w.now).events_dropped, 0);
    }
}
