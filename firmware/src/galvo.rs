//! The galvo mirror: angle <-> 12-bit DAC code, and the sweep schedule.
//!
//! A sweep visits `steps` angles from `start` to `end` inclusive. At each it
//! sets the mirror, waits `GALVO.settle_time`, then holds for `dwell_us`; the
//! camera trigger pulse sits in the middle of the dwell so the exposure sees a
//! settled stripe. `SweepStepDone` follows each dwell, `SweepDone` the last.

use hardware::GALVO;
use protocol::{CommandError, Sweep};

/// Full-scale galvo angle, µrad (either side of 0).
pub const GALVO_MAX_URAD: i32 = (GALVO.max_angle * 1e6) as i32;
/// Settling time after each angle change, µs.
pub const GALVO_SETTLE_US: u64 = (GALVO.settle_time * 1e6) as u64;
/// Largest DAC code (12 bits).
pub const DAC_MAX: u16 = ((1u32 << GALVO.dac_bits) - 1) as u16;
/// DAC code of 0 rad.
pub const DAC_MID: u16 = DAC_MAX / 2 + 1;
/// Longest dwell a sweep step may ask for, µs (a typo guard, not a physical limit).
pub const MAX_DWELL_US: u32 = 60_000_000;

/// DAC code for an angle, clamped to the DAC range: ±max_angle maps to
/// DAC_MID ± (DAC_MID - 1).
pub fn galvo_code(angle_urad: i32) -> u16 {
    let half = (DAC_MID - 1) as i64;
    let a = (angle_urad as i64).clamp(-(GALVO_MAX_URAD as i64), GALVO_MAX_URAD as i64);
    // round half away from zero
    let num = a * half;
    let den = GALVO_MAX_URAD as i64;
    let q = if num >= 0 {
        (num + den / 2) / den
    } else {
        (num - den / 2) / den
    };
    (DAC_MID as i64 + q).clamp(0, DAC_MAX as i64) as u16
}

/// Angle of a DAC code, µrad (inverse of `galvo_code` up to quantisation).
pub fn galvo_angle(code: u16) -> i32 {
    let half = (DAC_MID - 1) as i64;
    ((code as i64 - DAC_MID as i64) * GALVO_MAX_URAD as i64 / half) as i32
}

/// Reject sweeps the rig cannot do.
pub fn check_sweep(s: &Sweep) -> Result<(), CommandError> {
    let in_range = |a: i32| a.unsigned_abs() <= GALVO_MAX_URAD as u32;
    let trigger_ok = s.trigger_mask == 0 || (s.pulse_us > 0 && s.pulse_us <= s.dwell_us);
    if s.steps == 0
        || !in_range(s.start_urad)
        || !in_range(s.end_urad)
        || s.dwell_us > MAX_DWELL_US
        || !trigger_ok
    {
        return Err(CommandError::BadArgument);
    }
    Ok(())
}

/// Angle of sweep step `i`, µrad.
pub fn sweep_angle(s: &Sweep, i: u16) -> i32 {
    if s.steps <= 1 {
        return s.start_urad;
    }
    let span = s.end_urad as i64 - s.start_urad as i64;
    (s.start_urad as i64 + span * i as i64 / (s.steps as i64 - 1)) as i32
}

/// Where a running sweep is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepPhase {
    /// Mirror moving to step's angle; dwell starts at `until`.
    Settle { until: u64 },
    /// Holding; trigger due at `trigger_at` (if not yet `fired`), step ends at `end`.
    Dwell {
        trigger_at: u64,
        fired: bool,
        end: u64,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SweepRun {
    pub sweep: Sweep,
    pub step: u16,
    pub phase: SweepPhase,
}

/// What advancing a sweep asks the controller to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepAction {
    /// Raise the trigger lines (`mask`, for `pulse_us`).
    Trigger { mask: u8, pulse_us: u32 },
    /// Step `step` at `angle_urad` finished.
    StepDone { step: u16, angle_urad: i32 },
    /// The sweep finished.
    Finished,
}

impl SweepRun {
    /// Start at `now_us`: the caller sets the mirror to `sweep_angle(.., 0)`.
    pub fn new(now_us: u64, sweep: Sweep) -> Self {
        SweepRun {
            sweep,
            step: 0,
            phase: SweepPhase::Settle {
                until: now_us.saturating_add(GALVO_SETTLE_US),
            },
        }
    }

    pub fn next_due(&self) -> u64 {
        match self.phase {
            SweepPhase::Settle { until } => until,
            SweepPhase::Dwell {
                trigger_at,
                fired,
                end,
            } => {
                if fired {
                    end
                } else {
                    trigger_at
                }
            }
        }
    }

    /// Advance one transition if due at `now_us`.
    pub fn advance(&mut self, now_us: u64) -> Option<SweepAction> {
        let s = self.sweep;
        match self.phase {
            _ if self.step >= s.steps => Some(SweepAction::Finished),
            SweepPhase::Settle { until } if now_us >= until => {
                let dwell = s.dwell_us as u64;
                let pulse = if s.trigger_mask == 0 {
                    0
                } else {
                    s.pulse_us as u64
                };
                self.phase = SweepPhase::Dwell {
                    trigger_at: until.saturating_add((dwell - pulse) / 2),
                    fired: s.trigger_mask == 0,
                    end: until.saturating_add(dwell),
                };
                self.advance(now_us)
            }
            SweepPhase::Dwell {
                trigger_at,
                fired: false,
                end,
            } if now_us >= trigger_at => {
                self.phase = SweepPhase::Dwell {
                    trigger_at,
                    fired: true,
                    end,
                };
                Some(SweepAction::Trigger {
                    mask: s.trigger_mask,
                    pulse_us: s.pulse_us,
                })
            }
            SweepPhase::Dwell {
                fired: true, end, ..
            } if now_us >= end => {
                let done = self.step;
                let angle = sweep_angle(&s, done);
                if done + 1 >= s.steps {
                    // Stay in a finished state; the caller drops the run on `Finished`.
                    self.phase = SweepPhase::Settle { until: u64::MAX };
                    self.step = s.steps;
                } else {
                    self.step = done + 1;
                    self.phase = SweepPhase::Settle {
                        until: end.saturating_add(GALVO_SETTLE_US),
                    };
                }
                Some(SweepAction::StepDone {
                    step: done,
                    angle_urad: angle,
                })
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dac_codes() {
        assert_eq!(galvo_code(0), 2048);
        assert_eq!(galvo_code(GALVO_MAX_URAD), 4095);
        assert_eq!(galvo_code(-GALVO_MAX_URAD), 1);
        assert_eq!(galvo_code(i32::MAX), 4095);
        assert_eq!(galvo_code(i32::MIN), 1);
        for a in [-300_000, -1234, 0, 77_777, 349_999] {
            let back = galvo_angle(galvo_code(a));
            // one DAC LSB is 350000/2047 ≈ 171 µrad
            assert!((back - a).abs() <= 86, "{a} -> {back}");
        }
    }

    #[test]
    fn sweep_schedule() {
        let s = Sweep {
            start_urad: -100_000,
            end_urad: 100_000,
            steps: 3,
            dwell_us: 10_000,
            trigger_mask: 0b11,
            pulse_us: 2_000,
        };
        check_sweep(&s).unwrap();
        assert_eq!(sweep_angle(&s, 1), 0);
        assert_eq!(sweep_angle(&s, 2), 100_000);
        let mut run = SweepRun::new(0, s);
        let mut log = std::vec::Vec::new();
        loop {
            let now = run.next_due();
            match run.advance(now) {
                Some(SweepAction::Finished) => break,
                Some(a) => log.push((now, a)),
                // entering the dwell: the trigger is not due yet
                None => assert!(run.next_due() > now, "stuck at {now}"),
            }
        }
        // per step: settle 2 ms, trigger at settle + (10 - 2)/2 ms, done at settle + 10 ms
        assert_eq!(
            log[0],
            (
                6_000,
                SweepAction::Trigger {
                    mask: 3,
                    pulse_us: 2000
                }
            )
        );
        assert_eq!(
            log[1],
            (
                12_000,
                SweepAction::StepDone {
                    step: 0,
                    angle_urad: -100_000
                }
            )
        );
        assert_eq!(log.len(), 6);
        assert_eq!(
            log[5],
            (
                36_000,
                SweepAction::StepDone {
                    step: 2,
                    angle_urad: 100_000
                }
            )
        );
    }

    #[test]
    fn bad_sweeps_are_refused() {
        let ok = Sweep {
            start_urad: 0,
            end_urad: 0,
            steps: 1,
            dwell_us: 10,
            trigger_mask: 1,
            pulse_us: 10,
        };
        check_sweep(&ok).unwrap();
        for bad in [
            Sweep { steps: 0, ..ok },
            Sweep {
                start_urad: GALVO_MAX_URAD + 1,
                ..ok
            },
            Sweep {
                end_urad: i32::MIN,
                ..ok
            },
            Sweep { pulse_us: 11, ..ok },
            Sweep { pulse_us: 0, ..ok },
            Sweep {
                dwell_us: u32::MAX,
                pulse_us: 1,
                ..ok
            },
        ] {
            assert_eq!(check_sweep(&bad), Err(CommandError::BadArgument), "{bad:?}");
        }
    }
}
