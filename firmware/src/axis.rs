//! One stepper axis: limits in steps, moves, and the homing state machine.
//!
//! Homing (`hardware::AxisMechanics`): fast approach in the negative direction
//! until the home switch actuates (decelerating past it), back off at least
//! `home_backoff` and until the switch releases, re-approach slowly and zero
//! the axis at the switch edge (`home_offset`). More than 1.1 revolutions
//! without the switch, or a switch that never releases within a quarter turn,
//! fails with `FaultCause::HomingFailed`.

use crate::profile::Profile;
use hardware::AxisMechanics;
use protocol::{Axis, AxisStatus};

/// An axis' mechanics converted to steps once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisParams {
    pub mech: AxisMechanics,
    pub steps_per_rev: u32,
    /// steps/s and steps/s^2
    pub max_speed: f32,
    pub max_accel: f32,
    /// Inclusive soft limits, steps from home.
    pub soft_min: i32,
    pub soft_max: i32,
    pub home_position: i32,
    pub home_fast: f32,
    pub home_slow: f32,
    pub home_backoff: u32,
}

impl AxisParams {
    pub fn of(mech: AxisMechanics) -> Self {
        let steps_per_rad = 1.0 / mech.rad_per_step();
        // Soft limits round inwards so no position beyond them is ever reachable.
        let soft_min = -((-mech.soft_min * steps_per_rad) as i64) as i32;
        let soft_max = (mech.soft_max * steps_per_rad) as i64 as i32;
        AxisParams {
            mech,
            steps_per_rev: mech.steps_per_rev(),
            max_speed: (mech.max_speed * steps_per_rad) as f32,
            max_accel: (mech.max_accel * steps_per_rad) as f32,
            soft_min,
            soft_max,
            home_position: mech.steps_from_rad(mech.home_offset) as i32,
            home_fast: (mech.home_fast_speed * steps_per_rad) as f32,
            home_slow: (mech.home_slow_speed * steps_per_rad) as f32,
            home_backoff: (mech.home_backoff * steps_per_rad) as u32,
        }
    }

    /// Nearest step for an angle in µrad (the host rounds the same way).
    pub fn steps_from_urad(&self, urad: i32) -> i64 {
        self.mech.steps_from_rad(urad as f64 * 1e-6)
    }

    /// A wire speed (µrad/s) or acceleration (µrad/s^2) in steps, clamped to
    /// `max`; 0 means "the maximum".
    pub fn rate_from_urad(&self, urad: u32, max: f32) -> f32 {
        if urad == 0 {
            return max;
        }
        let r = (urad as f64 * 1e-6 / self.mech.rad_per_step()) as f32;
        r.clamp(1.0, max)
    }
}

/// Homing phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HomePhase {
    /// Fast approach; `found` once the switch actuated (then decelerating).
    Fast { found: bool },
    /// Moving off the switch; `travelled` steps so far.
    BackOff { travelled: u32, released: bool },
    /// Slow re-approach, stops at the switch edge.
    Slow,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mode {
    Idle,
    Moving(Profile),
    Homing(HomePhase, Profile),
    /// Decelerating to rest after an abort or fault; then `Idle`.
    Stopping(Profile),
}

/// What a step of the axis led to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisOutcome {
    /// The move, homing or stop ended (report `MotionDone`).
    Done,
    HomingFailed,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisState {
    pub axis: Axis,
    pub p: AxisParams,
    pub position: i32,
    pub homed: bool,
    pub mode: Mode,
}

impl AxisState {
    pub fn new(axis: Axis, mech: AxisMechanics) -> Self {
        AxisState {
            axis,
            p: AxisParams::of(mech),
            position: 0,
            homed: false,
            mode: Mode::Idle,
        }
    }

    pub fn active(&self) -> bool {
        !matches!(self.mode, Mode::Idle)
    }

    fn profile_mut(&mut self) -> Option<&mut Profile> {
        match &mut self.mode {
            Mode::Idle => None,
            Mode::Moving(p) | Mode::Homing(_, p) | Mode::Stopping(p) => Some(p),
        }
    }

    pub fn profile(&self) -> Option<&Profile> {
        match &self.mode {
            Mode::Idle => None,
            Mode::Moving(p) | Mode::Homing(_, p) | Mode::Stopping(p) => Some(p),
        }
    }

    /// Where the axis will come to rest if nothing changes.
    pub fn target(&self) -> i32 {
        match &self.mode {
            Mode::Moving(p) | Mode::Stopping(p) => {
                let r = p.remaining as i32;
                if p.forward {
                    self.position + r
                } else {
                    self.position - r
                }
            }
            _ => self.position,
        }
    }

    pub fn status(&self) -> AxisStatus {
        AxisStatus {
            homed: self.homed,
            moving: matches!(self.mode, Mode::Moving(_) | Mode::Stopping(_)),
            homing: matches!(self.mode, Mode::Homing(..)),
            position_steps: self.position,
            target_steps: self.target(),
        }
    }

    /// Start a move to `target` steps (already checked against soft limits).
    pub fn start_move(&mut self, now_us: u64, target: i32, speed: f32, accel: f32) {
        let d = target as i64 - self.position as i64;
        let profile = Profile::new(now_us, d > 0, d.unsigned_abs() as u32, speed, accel);
        self.mode = Mode::Moving(profile);
    }

    pub fn start_homing(&mut self, now_us: u64, switch: bool) {
        self.homed = false;
        self.mode = if switch {
            self.backoff(now_us, 0)
        } else {
            let max = self.p.steps_per_rev + self.p.steps_per_rev / 10;
            Mode::Homing(
                HomePhase::Fast { found: false },
                Profile::new(now_us, false, max, self.p.home_fast, self.p.max_accel),
            )
        };
    }

    fn backoff(&self, now_us: u64, travelled: u32) -> Mode {
        Mode::Homing(
            HomePhase::BackOff {
                travelled,
                released: false,
            },
            Profile::new(
                now_us,
                true,
                self.p.home_backoff.max(1),
                self.p.home_fast,
                self.p.max_accel,
            ),
        )
    }

    /// Decelerate to rest (abort, fault).
    pub fn stop(&mut self) {
        if let Some(mut p) = self.profile().copied() {
            p.stop();
            self.mode = Mode::Stopping(p);
        }
    }

    /// Stop at once (e-stop). Steps may be lost, so the axis is no longer homed.
    pub fn halt(&mut self) {
        if self.active() {
            self.mode = Mode::Idle;
            self.homed = false;
        }
    }

    /// Due time of the next step, if any.
    pub fn next_due(&self) -> Option<u64> {
        self.profile().filter(|p| !p.done()).map(|p| p.next_us)
    }

    /// Take one step if due, emitting it through `step`. Returns whether a
    /// step went out and whether it finished a move. A homing axis must then
    /// be told its switch level with [`AxisState::on_switch`].
    pub fn step_once(
        &mut self,
        now_us: u64,
        step: &mut impl FnMut(bool),
    ) -> (bool, Option<AxisOutcome>) {
        let Some(p) = self.profile_mut() else {
            return (false, None);
        };
        if !p.take_step(now_us) {
            return (false, None);
        }
        let forward = p.forward;
        step(forward);
        // Wrapping: an unhomed axis may drift through many failed homings.
        self.position = self.position.wrapping_add(if forward { 1 } else { -1 });
        let outcome = match self.mode {
            Mode::Moving(p) | Mode::Stopping(p) if p.done() => {
                self.mode = Mode::Idle;
                Some(AxisOutcome::Done)
            }
            _ => None,
        };
        (true, outcome)
    }

    /// Homing: the switch level read after the last step.
    pub fn on_switch(&mut self, now_us: u64, actuated: bool) -> Option<AxisOutcome> {
        match self.mode {
            Mode::Homing(phase, mut p) => {
                match phase {
                    HomePhase::Fast { found } => {
                        let found = found || actuated;
                        if actuated {
                            p.stop();
                        }
                        if !p.done() {
                            self.mode = Mode::Homing(HomePhase::Fast { found }, p);
                            None
                        } else if found {
                            self.mode = self.backoff(p.next_us.max(now_us), 0);
                            None
                        } else {
                            self.mode = Mode::Idle;
                            Some(AxisOutcome::HomingFailed)
                        }
                    }
                    HomePhase::BackOff {
                        travelled,
                        released,
                    } => {
                        let travelled = travelled + 1;
                        let released = released || !actuated;
                        if !p.done() {
                            self.mode = Mode::Homing(
                                HomePhase::BackOff {
                                    travelled,
                                    released,
                                },
                                p,
                            );
                            None
                        } else if released && !actuated {
                            // Re-approach: at most the back-off distance plus margin.
                            let max = travelled + self.p.home_backoff.max(1);
                            self.mode = Mode::Homing(
                                HomePhase::Slow,
                                Profile::new(
                                    now_us,
                                    false,
                                    max,
                                    self.p.home_slow,
                                    self.p.max_accel,
                                ),
                            );
                            None
                        } else if travelled < self.p.steps_per_rev / 4 {
                            self.mode = self.backoff(now_us, travelled);
                            None
                        } else {
                            self.mode = Mode::Idle;
                            Some(AxisOutcome::HomingFailed)
                        }
                    }
                    HomePhase::Slow => {
                        if actuated {
                            self.position = self.p.home_position;
                            self.homed = true;
                            self.mode = Mode::Idle;
                            Some(AxisOutcome::Done)
                        } else if p.done() {
                            self.mode = Mode::Idle;
                            Some(AxisOutcome::HomingFailed)
                        } else {
                            self.mode = Mode::Homing(HomePhase::Slow, p);
                            None
                        }
                    }
                }
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hardware::{LIGHT_ARC, TURNTABLE};

    #[test]
    fn params_match_the_mechanics() {
        let t = AxisParams::of(TURNTABLE);
        assert_eq!(t.steps_per_rev, 16_000);
        // 60 deg/s = 1/6 rev/s
        assert!((t.max_speed - 16_000.0 / 6.0).abs() < 0.01);
        assert!(t.soft_max > 16_000 && t.soft_max < 16_600);
        assert_eq!(t.soft_min, -t.soft_max);
        let a = AxisParams::of(LIGHT_ARC);
        assert_eq!(a.steps_per_rev, 32_000);
        assert_eq!(a.steps_from_urad(3_141_593), 16_000);
        assert_eq!(a.rate_from_urad(0, a.max_speed), a.max_speed);
        assert_eq!(a.rate_from_urad(u32::MAX, a.max_speed), a.max_speed);
    }

    /// Home against a switch window [lo, hi] steps of a virtual axis starting at `start`.
    fn home(start: i32, lo: i32, hi: i32) -> (AxisState, Option<AxisOutcome>, i32) {
        let mut ax = AxisState::new(Axis::Turntable, TURNTABLE);
        ax.position = 0;
        let mut phys = start;
        ax.start_homing(0, (lo..=hi).contains(&phys));
        let mut outcome = None;
        let mut now = 0;
        while outcome.is_none() {
            let Some(due) = ax.next_due() else { break };
            now = now.max(due);
            let (stepped, o) = ax.step_once(now, &mut |fwd| phys += if fwd { 1 } else { -1 });
            assert!(stepped);
            outcome = o.or_else(|| ax.on_switch(now, (lo..=hi).contains(&phys)));
        }
        (ax, outcome, phys)
    }

    #[test]
    fn homing_zeroes_at_the_switch_edge() {
        for start in [3000, 200, 100, -40] {
            let (ax, outcome, phys) = home(start, -50, 0);
            assert_eq!(outcome, Some(AxisOutcome::Done), "start {start}");
            assert!(ax.homed);
            assert_eq!(ax.position, 0);
            // approached from above: stopped at the switch's upper edge
            assert_eq!(phys, 0, "start {start}");
        }
    }

    #[test]
    fn homing_fails_without_switch() {
        let (ax, outcome, phys) = home(0, 100_000, 100_001);
        assert_eq!(outcome, Some(AxisOutcome::HomingFailed));
        assert!(!ax.homed);
        assert!(!ax.active());
        // gave up after 1.1 revolutions
        assert_eq!(phys, -17_600);
    }

    #[test]
    fn homing_fails_on_stuck_switch() {
        let (_, outcome, _) = home(0, -1_000_000, 1_000_000);
        assert_eq!(outcome, Some(AxisOutcome::HomingFailed));
    }
}
