//! Random command sequences, input changes and time steps against the
//! emulated rig (proptest, virtual time). After every action the physical
//! world must agree with the safety rules and with what the Controller
//! believes: no laser without a closed interlock, a fresh heartbeat and no
//! fault; never two lasers; no step emitted to a disabled driver; motors off
//! while the e-stop is pressed; a homed, resting axis is physically where the
//! Controller says it is.

use hardware::{LIGHT_ARC, TURNTABLE};
use proptest::prelude::*;
use protocol::{Axis, Command, LaserColour, MoveTarget, Sweep};
use sim::peripherals::wrap_pi;
use sim::{LinkConfig, PhysicalConfig, RawHost, RigConfig, SimPort};

#[derive(Debug, Clone)]
enum Action {
    Send(Command),
    Interlock(bool),
    EStop(bool),
    Heartbeats(bool),
    Run(u64),
}

fn axis() -> impl Strategy<Value = Axis> {
    prop_oneof![Just(Axis::Turntable), Just(Axis::LightArc)]
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        axis().prop_map(|axis| Command::Home { axis }),
        (axis(), -400_000i32..400_000).prop_map(|(axis, d)| Command::Move {
            axis,
            target: MoveTarget::Relative(d),
            speed_urad_s: 0,
            accel_urad_s2: 0,
        }),
        (axis(), -1_000_000i32..1_000_000, 0u32..600_000).prop_map(|(axis, a, v)| {
            Command::Move {
                axis,
                target: MoveTarget::Absolute(a),
                speed_urad_s: v,
                accel_urad_s2: 0,
            }
        }),
        (-350_000i32..350_000).prop_map(|angle_urad| Command::GalvoSet { angle_urad }),
        (1u16..6, 1_000u32..20_000, any::<u8>()).prop_map(|(steps, dwell_us, trigger_mask)| {
            Command::GalvoSweep(Sweep {
                start_urad: -100_000,
                end_urad: 100_000,
                steps,
                dwell_us,
                trigger_mask,
                pulse_us: dwell_us / 2,
            })
        }),
        prop_oneof![
            Just(LaserColour::Red),
            Just(LaserColour::Green),
            Just(LaserColour::Blue)
        ]
        .prop_map(|colour| Command::LaserSelect { colour }),
        (0u16..1200).prop_map(|permille| Command::LaserPower { permille }),
        any::<bool>().prop_map(|armed| Command::LaserArm { armed }),
        any::<u8>().prop_map(|mask| Command::Lamps { mask }),
        (any::<u8>(), 1u32..5_000).prop_map(|(mask, pulse_us)| Command::Trigger { mask, pulse_us }),
        Just(Command::Abort),
        Just(Command::EStop),
        Just(Command::ClearFault),
        Just(Command::Status),
    ]
}

fn action() -> impl Strategy<Value = Action> {
    prop_oneof![
        6 => command().prop_map(Action::Send),
        1 => any::<bool>().prop_map(Action::Interlock),
        1 => any::<bool>().prop_map(Action::EStop),
        1 => any::<bool>().prop_map(Action::Heartbeats),
        3 => (0u64..400_000).prop_map(Action::Run),
    ]
}

/// Check every invariant at the current instant.
fn check(h: &RawHost, openings: u64) -> Result<(), TestCaseError> {
    let rig = h.port.rig();
    let snap = rig.snapshot();
    let status = rig.status();
    prop_assert_eq!(snap.two_lasers_on, 0);
    prop_assert!(
        snap.laser_on_interlock_open_us <= 1_000 * openings,
        "laser on {} µs with the interlock open ({} openings)",
        snap.laser_on_interlock_open_us,
        openings
    );
    if snap.state.laser.is_some() {
        prop_assert!(snap.inputs.interlock_closed && !snap.inputs.estop_pressed);
        prop_assert!(status.fault.is_none(), "emitting with {:?}", status.fault);
        let hb = h.last_sent_us().unwrap_or(0);
        prop_assert!(
            h.now_us() <= hb + 250_000 + 5_000,
            "emitting {} µs after the last heartbeat",
            h.now_us() - hb
        );
    }
    for (i, a) in snap.axes.iter().enumerate() {
        prop_assert_eq!(a.lost_steps, 0, "axis {} stepped while disabled", i);
    }
    if snap.inputs.estop_pressed {
        prop_assert!(
            snap.axes.iter().all(|a| !a.enabled),
            "motors on during e-stop"
        );
    }
    for axis in Axis::ALL {
        let st = status.axes[axis.index()];
        if st.homed && !st.moving && !st.homing {
            let m = if axis == Axis::Turntable {
                TURNTABLE
            } else {
                LIGHT_ARC
            };
            let believed = m.home_offset + m.rad_from_steps(st.position_steps as i64)
                - m.rad_from_steps(m.steps_from_rad(m.home_offset));
            let phys = match axis {
                Axis::Turntable => snap.state.turntable_rad,
                Axis::LightArc => snap.state.light_arc_rad,
            };
            let err = wrap_pi(phys - believed);
            let step = m.rad_per_step();
            prop_assert!(
                err <= 0.5 * step && err > -1.5 * step,
                "{:?}: physically {} rad, believed {} rad",
                axis,
                phys,
                believed
            );
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn physical_world_obeys_the_safety_rules(
        seed in 0u64..1000,
        actions in proptest::collection::vec(action(), 1..40),
    ) {
        let mut cfg = RigConfig::seeded(seed);
        // Near the home cams, so homing is part of many sequences.
        cfg.physical = PhysicalConfig {
            start_rad: [Some(0.3), Some(0.3)],
            ..cfg.physical
        };
        let mut h = RawHost::new(SimPort::new(cfg, LinkConfig::default()).unwrap());
        prop_assert!(h.identify().is_ok());
        h.heartbeat_us = Some(100_000);
        // Home first, so the belief-vs-physics check has homed axes to check.
        for axis in Axis::ALL {
            let _ = h.call(Command::Home { axis });
        }
        h.run_for(12_000_000);
        prop_assert!(h.port.rig().status().axes.iter().all(|a| a.homed));
        check(&h, 0)?;
        let mut openings = 0;
        let mut interlock = true;
        for a in actions {
            match a {
                Action::Send(c) => {
                    let _ = h.call(c);
                }
                Action::Interlock(closed) => {
                    if interlock && !closed {
                        openings += 1;
                    }
                    interlock = closed;
                    h.port.rig_mut().set_interlock(closed);
                }
                Action::EStop(pressed) => h.port.rig_mut().set_estop(pressed),
                Action::Heartbeats(on) => h.heartbeat_us = on.then_some(100_000),
                Action::Run(dt) => h.run_for(dt),
            }
            // Give the Controller one input scan to see any change.
            h.run_for(2_000);
            check(&h, openings)?;
        }
    }
}
