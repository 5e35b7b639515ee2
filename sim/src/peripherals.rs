//! Virtual peripherals: the physical rig as the emulated MCU's pins see it.
//!
//! [`Peripherals`] implements [`firmware::io::Io`]. Step pulses move the
//! physical axes (steps -> radians via `hardware::TURNTABLE` / `LIGHT_ARC`);
//! home switches sit at their physical places, so the Controller has to find
//! them; the arc's end-of-travel switch opens a little beyond the soft limits;
//! the galvo angle follows the DAC code; lasers, lamps and trigger lines are
//! levels. Interlock and e-stop are inputs the tests set.
//!
//! The physical axis angle is measured from the axis zero (where the home
//! switch edge is at `home_offset`), and each axis starts at a seeded random
//! angle, so homing is real work. Everything the laser and the trigger lines
//! do is recorded for assertions, and trigger pulses are published to
//! subscribers as [`TriggerEvent`]s carrying the physical [`RigState`].

use std::f64::consts::PI;

use firmware::io::{Inputs, Io};
use hardware::{AxisMechanics, GALVO, LIGHT_ARC, TURNTABLE};
use protocol::{Axis, LaserColour};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde::{Deserialize, Serialize};
use tokio::sync::mpsc::UnboundedSender;

/// Mechanics of an axis, by protocol axis.
pub fn mechanics(axis: Axis) -> &'static AxisMechanics {
    match axis {
        Axis::Turntable => &TURNTABLE,
        Axis::LightArc => &LIGHT_ARC,
    }
}

/// Galvo mirror angle (radians) for a DAC code: 2048 is 0 rad, full scale is
/// `GALVO.max_angle` (the driver's analogue input is linear in angle).
pub fn galvo_rad_from_code(code: u16) -> f64 {
    let half = (1u32 << (GALVO.dac_bits - 1)) as f64;
    (code.min(4095) as f64 - half) / (half - 1.0) * GALVO.max_angle
}

/// Laser drive fraction 0..=1 for a power DAC code.
pub fn laser_power_from_code(code: u16) -> f32 {
    (code.min(4095) as f32) / 4095.0
}

/// Where the physical rig starts and where its switches are.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PhysicalConfig {
    /// Seed of the random start angles.
    pub seed: u64,
    /// Start angle of each axis (turntable, light arc) from its zero, radians;
    /// `None` draws it from the seed (turntable anywhere in a turn, light arc
    /// between its home cam and its positive end switch).
    pub start_rad: [Option<f64>; 2],
    /// Angular width of each home switch's cam, radians. The switch is
    /// actuated while the axis is within `[home_offset - width, home_offset]`.
    pub home_width_rad: f64,
    /// How far beyond the light arc's soft limits its end-of-travel switch opens.
    pub arc_limit_margin_rad: f64,
}

impl Default for PhysicalConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            start_rad: [None, None],
            home_width_rad: 0.1,
            arc_limit_margin_rad: 0.05,
        }
    }
}

/// The physical state of the rig at one instant (true positions, not what the
/// Controller believes). Angles in radians from each axis' zero: the light
/// arc unwrapped, the turntable wrapped into `[-pi, pi)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigState {
    pub turntable_rad: f64,
    pub light_arc_rad: f64,
    pub galvo_rad: f64,
    /// The laser that emits and its drive fraction 0..=1; `None` while dark.
    pub laser: Option<(LaserColour, f32)>,
    /// Lamp outputs, one bit per lamp.
    pub lamps: u8,
}

/// A camera trigger pulse, published once its lines fall again.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriggerEvent {
    /// Virtual time the lines went high, µs since the emulator started.
    pub at_us: u64,
    /// Trigger lines that went high together.
    pub mask: u8,
    /// Measured high time, µs (cut short if the MCU reset during the pulse).
    pub pulse_us: u32,
    /// Physical rig state when the lines went high.
    pub state: RigState,
}

/// A change of the laser's physical emission, recorded for assertions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserChange {
    pub at_us: u64,
    /// Emitting laser and drive fraction after the change; `None` = dark.
    pub laser: Option<(LaserColour, f32)>,
}

/// One axis' physical state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisPhysics {
    /// Angle at power-on, radians from the axis zero.
    pub start_rad: f64,
    /// Net steps moved since power-on (forward positive).
    pub steps: i64,
    pub enabled: bool,
    /// Steps the Controller emitted while the driver was disabled (lost).
    pub lost_steps: u64,
    /// Times of the first and last step since the history was cleared.
    pub first_step_us: Option<u64>,
    pub last_step_us: Option<u64>,
    /// Steps emitted since the history was cleared.
    pub step_count: u64,
}

impl AxisPhysics {
    fn new(start_rad: f64) -> Self {
        Self {
            start_rad,
            steps: 0,
            enabled: false,
            lost_steps: 0,
            first_step_us: None,
            last_step_us: None,
            step_count: 0,
        }
    }
}

/// A copy of every peripheral's state, for tests.
#[derive(Debug, Clone, PartialEq)]
pub struct PeripheralSnapshot {
    pub now_us: u64,
    pub axes: [AxisPhysics; 2],
    /// Physical angles (as in [`RigState`]).
    pub state: RigState,
    pub galvo_code: u16,
    pub laser_enable: [bool; 3],
    pub laser_power_code: u16,
    pub triggers: u8,
    pub inputs: Inputs,
    /// Microseconds any laser line was high while the interlock was open
    /// (counted between Controller polls: the reaction time is at most one
    /// poll interval).
    pub laser_on_interlock_open_us: u64,
    /// Times two laser enable lines were high at once.
    pub two_lasers_on: u64,
}

/// Pulse in progress on some trigger lines.
#[derive(Debug, Clone, Copy)]
struct OpenPulse {
    at_us: u64,
    mask: u8,
    high: u8,
    state: RigState,
}

/// The virtual board.
#[derive(Debug)]
pub struct Peripherals {
    cfg: PhysicalConfig,
    now_us: u64,
    axes: [AxisPhysics; 2],
    galvo_code: u16,
    laser_enable: [bool; 3],
    laser_power_code: u16,
    lamps: u8,
    triggers: u8,
    interlock_closed: bool,
    estop_pressed: bool,
    open_pulses: Vec<OpenPulse>,
    trigger_log: Vec<TriggerEvent>,
    laser_log: Vec<LaserChange>,
    subscribers: Vec<UnboundedSender<TriggerEvent>>,
    laser_on_interlock_open_us: u64,
    two_lasers_on: u64,
    last_account_us: u64,
}

impl Peripherals {
    /// Power on the rig: axes at their (seeded) start angles, outputs safe.
    pub fn new(cfg: PhysicalConfig) -> Self {
        let mut rng = Pcg64::seed_from_u64(cfg.seed);
        let tt = cfg.start_rad[0].unwrap_or_else(|| rng.random_range(-PI..PI));
        // The firmware homes in the negative direction and the arc cannot
        // turn through its end switches, so the rig is parked (as an operator
        // leaves it) on the positive side of the home cam, clear of the end
        // switch; the cam itself is a possible start.
        let arc_hi = LIGHT_ARC.soft_max - 0.3;
        let arc_lo = (LIGHT_ARC.home_offset - cfg.home_width_rad.abs() / 2.0).min(arc_hi - 1e-3);
        let arc = cfg.start_rad[1].unwrap_or_else(|| rng.random_range(arc_lo..arc_hi));
        Self {
            cfg,
            now_us: 0,
            axes: [AxisPhysics::new(tt), AxisPhysics::new(arc)],
            galvo_code: 2048,
            laser_enable: [false; 3],
            laser_power_code: 0,
            lamps: 0,
            triggers: 0,
            interlock_closed: true,
            estop_pressed: false,
            open_pulses: Vec::new(),
            trigger_log: Vec::new(),
            laser_log: Vec::new(),
            subscribers: Vec::new(),
            laser_on_interlock_open_us: 0,
            two_lasers_on: 0,
            last_account_us: 0,
        }
    }

    pub fn config(&self) -> &PhysicalConfig {
        &self.cfg
    }

    /// Move the virtual clock (the rig calls this before each Controller call).
    pub fn set_now(&mut self, now_us: u64) {
        self.account_safety(now_us);
        self.now_us = now_us.max(self.now_us);
    }

    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Physical angle of an axis from its zero; unwrapped.
    pub fn axis_rad(&self, axis: Axis) -> f64 {
        let a = &self.axes[axis.index()];
        a.start_rad + mechanics(axis).rad_from_steps(a.steps)
    }

    /// Turn an axis by hand (the operator, with the driver off or on):
    /// the physical angle changes without any step.
    pub fn turn_by_hand(&mut self, axis: Axis, rad: f64) {
        self.axes[axis.index()].start_rad += rad;
    }

    pub fn set_interlock(&mut self, closed: bool) {
        self.account_safety(self.now_us);
        self.interlock_closed = closed;
    }

    pub fn set_estop(&mut self, pressed: bool) {
        self.estop_pressed = pressed;
    }

    /// The physically emitting laser, if any (enable line high; the first one
    /// if the Controller broke its promise and raised two).
    pub fn emitting(&self) -> Option<(LaserColour, f32)> {
        LaserColour::ALL
            .into_iter()
            .find(|c| self.laser_enable[c.index()])
            .map(|c| (c, laser_power_from_code(self.laser_power_code)))
    }

    pub fn rig_state(&self) -> RigState {
        RigState {
            turntable_rad: wrap_pi(self.axis_rad(Axis::Turntable)),
            light_arc_rad: self.axis_rad(Axis::LightArc),
            galvo_rad: galvo_rad_from_code(self.galvo_code),
            laser: self.emitting(),
            lamps: self.lamps,
        }
    }

    pub fn snapshot(&self) -> PeripheralSnapshot {
        PeripheralSnapshot {
            now_us: self.now_us,
            axes: self.axes,
            state: self.rig_state(),
            galvo_code: self.galvo_code,
            laser_enable: self.laser_enable,
            laser_power_code: self.laser_power_code,
            triggers: self.triggers,
            inputs: self.current_inputs(),
            laser_on_interlock_open_us: self.laser_on_interlock_open_us,
            two_lasers_on: self.two_lasers_on,
        }
    }

    /// Subscribe to trigger pulses. Unbounded tokio channel: `recv().await`
    /// from async code, `blocking_recv()` / `try_recv()` from plain threads.
    /// A dropped receiver is forgotten at the next pulse.
    pub fn subscribe(&mut self, tx: UnboundedSender<TriggerEvent>) {
        self.subscribers.push(tx);
    }

    /// Trigger pulses completed since the history was cleared.
    pub fn trigger_log(&self) -> &[TriggerEvent] {
        &self.trigger_log
    }

    /// Laser emission changes since the history was cleared.
    pub fn laser_log(&self) -> &[LaserChange] {
        &self.laser_log
    }

    /// Forget recorded triggers, laser changes and step timing.
    pub fn clear_history(&mut self) {
        self.trigger_log.clear();
        self.laser_log.clear();
        for a in &mut self.axes {
            a.first_step_us = None;
            a.last_step_us = None;
            a.step_count = 0;
        }
    }

    /// The MCU reset: every output goes to its power-on level (drivers off,
    /// lasers and lamps dark, triggers low, galvo centred). Axes stay where
    /// they physically are.
    pub fn reset_outputs(&mut self) {
        for a in &mut self.axes {
            a.enabled = false;
        }
        for c in LaserColour::ALL {
            self.set_laser(c, false);
        }
        self.set_laser_power(0);
        self.lamps = 0;
        self.set_triggers(0);
        self.galvo_code = 2048;
    }

    fn current_inputs(&self) -> Inputs {
        let home = Axis::ALL.map(|axis| {
            let m = mechanics(axis);
            let mut d = self.axis_rad(axis) - m.home_offset;
            if axis == Axis::Turntable {
                // The turntable turns freely: its cam passes once per turn.
                d = wrap_pi(d);
            }
            d <= 0.0 && d >= -self.cfg.home_width_rad
        });
        let arc = self.axis_rad(Axis::LightArc);
        let margin = self.cfg.arc_limit_margin_rad;
        Inputs {
            home,
            arc_limit_ok: arc >= LIGHT_ARC.soft_min - margin && arc <= LIGHT_ARC.soft_max + margin,
            interlock_closed: self.interlock_closed,
            estop_pressed: self.estop_pressed,
        }
    }

    /// Integrate the safety counters up to `now_us`.
    fn account_safety(&mut self, now_us: u64) {
        let dt = now_us.saturating_sub(self.last_account_us);
        if !self.interlock_closed && self.laser_enable.iter().any(|&on| on) {
            self.laser_on_interlock_open_us += dt;
        }
        self.last_account_us = self.last_account_us.max(now_us);
    }

    fn log_laser(&mut self) {
        let laser = self.emitting();
        if self.laser_log.last().map(|c| c.laser) != Some(laser) {
            self.laser_log.push(LaserChange {
                at_us: self.now_us,
                laser,
            });
        }
    }
}

impl Io for Peripherals {
    fn step(&mut self, axis: Axis, forward: bool) {
        let now = self.now_us;
        let a = &mut self.axes[axis.index()];
        if !a.enabled {
            a.lost_steps += 1;
            return;
        }
        a.steps += if forward { 1 } else { -1 };
        a.first_step_us.get_or_insert(now);
        a.last_step_us = Some(now);
        a.step_count += 1;
    }

    fn set_motor_enable(&mut self, axis: Axis, enabled: bool) {
        self.axes[axis.index()].enabled = enabled;
    }

    fn set_galvo(&mut self, code: u16) {
        self.galvo_code = code.min(4095);
    }

    fn set_laser(&mut self, colour: LaserColour, on: bool) {
        self.laser_enable[colour.index()] = on;
        if self.laser_enable.iter().filter(|&&e| e).count() > 1 {
            self.two_lasers_on += 1;
        }
        self.log_laser();
    }

    fn set_laser_power(&mut self, code: u16) {
        self.laser_power_code = code.min(4095);
        if self.emitting().is_some() {
            self.log_laser();
        }
    }

    fn set_lamps(&mut self, mask: u8) {
        self.lamps = mask;
    }

    fn set_triggers(&mut self, mask: u8) {
        let rose = mask & !self.triggers;
        let fell = self.triggers & !mask;
        self.triggers = mask;
        if fell != 0 {
            let now = self.now_us;
            let mut done = Vec::new();
            self.open_pulses.retain_mut(|p| {
                p.high &= !fell;
                if p.high == 0 {
                    done.push(TriggerEvent {
                        at_us: p.at_us,
                        mask: p.mask,
                        pulse_us: (now - p.at_us).min(u32::MAX as u64) as u32,
                        state: p.state,
                    });
                    false
                } else {
                    true
                }
            });
            for ev in done {
                self.subscribers.retain(|tx| tx.send(ev).is_ok());
                self.trigger_log.push(ev);
            }
        }
        if rose != 0 {
            self.open_pulses.push(OpenPulse {
                at_us: self.now_us,
                mask: rose,
                high: rose,
                state: self.rig_state(),
            });
        }
    }

    fn inputs(&mut self) -> Inputs {
        self.current_inputs()
    }
}

/// Wrap an angle into `[-pi, pi)`.
pub fn wrap_pi(a: f64) -> f64 {
    (a + PI).rem_euclid(2.0 * PI) - PI
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig(start: [f64; 2]) -> Peripherals {
        Peripherals::new(PhysicalConfig {
            start_rad: [Some(start[0]), Some(start[1])],
            ..PhysicalConfig::default()
        })
    }

    #[test]
    fn steps_move_only_enabled_axes() {
        let mut p = rig([0.5, 0.0]);
        p.step(Axis::Turntable, true);
        assert_eq!(p.snapshot().axes[0].lost_steps, 1);
        assert_eq!(p.axis_rad(Axis::Turntable), 0.5);
        p.set_motor_enable(Axis::Turntable, true);
        for _ in 0..TURNTABLE.steps_per_rev() / 4 {
            p.step(Axis::Turntable, false);
        }
        assert!((p.axis_rad(Axis::Turntable) - (0.5 - PI / 2.0)).abs() < 1e-9);
    }

    #[test]
    fn home_switch_sits_at_its_place_once_per_turn() {
        let mut p = rig([0.01, 0.5]);
        assert!(!p.inputs().home[0]);
        p.set_motor_enable(Axis::Turntable, true);
        // Walk back through the cam: actuated from 0 down to -width.
        let mut actuated = Vec::new();
        for _ in 0..600 {
            p.step(Axis::Turntable, false);
            actuated.push((p.axis_rad(Axis::Turntable), p.inputs().home[0]));
        }
        for (a, on) in &actuated {
            assert_eq!(*on, *a <= 0.0 && *a >= -0.1, "at {a}");
        }
        assert!(actuated.iter().any(|x| x.1));
        // One full turn later the same cam passes again.
        let mut p = rig([2.0 * PI - 0.01, 0.5]);
        assert!(p.inputs().home[0]);
        assert!(!p.inputs().home[1]);
    }

    #[test]
    fn arc_limit_opens_beyond_the_soft_limit() {
        let p = rig([0.0, LIGHT_ARC.soft_max + 0.04]);
        assert!(p.current_inputs().arc_limit_ok);
        let p = rig([0.0, LIGHT_ARC.soft_max + 0.06]);
        assert!(!p.current_inputs().arc_limit_ok);
        let p = rig([0.0, LIGHT_ARC.soft_min - 0.06]);
        assert!(!p.current_inputs().arc_limit_ok);
    }

    #[test]
    fn seeded_start_is_random_but_repeatable() {
        let cfg = |seed| PhysicalConfig {
            seed,
            ..PhysicalConfig::default()
        };
        let a = Peripherals::new(cfg(7)).rig_state();
        let b = Peripherals::new(cfg(7)).rig_state();
        let c = Peripherals::new(cfg(8)).rig_state();
        assert_eq!(a, b);
        assert_ne!(a.turntable_rad, c.turntable_rad);
        assert!(a.light_arc_rad.abs() < LIGHT_ARC.soft_max);
    }

    #[test]
    fn trigger_pulses_are_measured_and_published() {
        let mut p = rig([0.0, 0.0]);
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        p.subscribe(tx);
        p.set_now(100);
        p.set_galvo(4095);
        p.set_triggers(0b0110);
        p.set_now(150);
        p.set_triggers(0b0100);
        assert!(rx.try_recv().is_err(), "published before the pulse ended");
        p.set_now(300);
        p.set_triggers(0);
        let ev = rx.try_recv().unwrap();
        assert_eq!((ev.at_us, ev.mask, ev.pulse_us), (100, 0b0110, 200));
        assert!((ev.state.galvo_rad - GALVO.max_angle).abs() < 1e-3);
        assert_eq!(p.trigger_log(), &[ev]);
    }

    #[test]
    fn laser_history_and_interlock_accounting() {
        let mut p = rig([0.0, 0.0]);
        p.set_laser_power(4095);
        p.set_now(10);
        p.set_laser(LaserColour::Green, true);
        assert_eq!(p.rig_state().laser, Some((LaserColour::Green, 1.0)));
        p.set_interlock(false);
        p.set_now(60);
        p.set_laser(LaserColour::Green, false);
        p.set_now(1000);
        let s = p.snapshot();
        assert_eq!(s.laser_on_interlock_open_us, 50);
        assert_eq!(
            p.laser_log(),
            &[
                LaserChange {
                    at_us: 10,
                    laser: Some((LaserColour::Green, 1.0))
                },
                LaserChange {
                    at_us: 60,
                    laser: None
                }
            ]
        );
        p.set_laser(LaserColour::Red, true);
        p.set_laser(LaserColour::Blue, true);
        assert_eq!(p.snapshot().two_lasers_on, 1);
        p.reset_outputs();
        assert_eq!(p.rig_state().laser, None);
    }

    #[test]
    fn galvo_code_mapping() {
        assert_eq!(galvo_rad_from_code(2048), 0.0);
        assert!((galvo_rad_from_code(4095) - GALVO.max_angle).abs() < 1e-12);
        assert!((galvo_rad_from_code(1) + GALVO.max_angle).abs() < 1e-12);
    }
}
