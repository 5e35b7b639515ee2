//! Input conditioning for the board layer: raw pin levels -> [`Inputs`].
//!
//! Safety inputs are asymmetric: a change towards *unsafe* (interlock open,
//! e-stop pressed, limit loop open) is taken at once, a change back to safe
//! only after it has been stable for [`SETTLE_US`]. Contact bounce can thus
//! never briefly re-enable the laser or clear a limit. Home switches pass
//! unfiltered: homing wants the first edge, and its slow re-approach makes
//! bounce harmless.

use crate::io::Inputs;

/// How long a safety input must read safe before it counts as safe, µs.
pub const SETTLE_US: u64 = 5_000;

/// One input that switches to unsafe at once and back to safe after settling.
#[derive(Debug, Clone, Copy)]
struct SafeLatch {
    safe: bool,
    /// Since when the raw level has read safe while `safe` is false.
    safe_since: Option<u64>,
}

impl SafeLatch {
    const fn new() -> Self {
        // Boot unsafe: the first SETTLE_US of clean reads make it safe.
        SafeLatch {
            safe: false,
            safe_since: None,
        }
    }

    fn update(&mut self, now_us: u64, raw_safe: bool) -> bool {
        if !raw_safe {
            self.safe = false;
            self.safe_since = None;
        } else if !self.safe {
            let since = *self.safe_since.get_or_insert(now_us);
            if now_us.saturating_sub(since) >= SETTLE_US {
                self.safe = true;
                self.safe_since = None;
            }
        }
        self.safe
    }
}

/// Debouncer for all of the rig's inputs.
#[derive(Debug, Clone, Copy)]
pub struct Debouncer {
    interlock: SafeLatch,
    estop: SafeLatch,
    arc_limit: SafeLatch,
}

impl Default for Debouncer {
    fn default() -> Self {
        Self::new()
    }
}

impl Debouncer {
    pub const fn new() -> Self {
        Debouncer {
            interlock: SafeLatch::new(),
            estop: SafeLatch::new(),
            arc_limit: SafeLatch::new(),
        }
    }

    /// Condition raw active-high levels (already inverted for active-low wiring).
    pub fn update(&mut self, now_us: u64, raw: Inputs) -> Inputs {
        Inputs {
            home: raw.home,
            interlock_closed: self.interlock.update(now_us, raw.interlock_closed),
            estop_pressed: !self.estop.update(now_us, !raw.estop_pressed),
            arc_limit_ok: self.arc_limit.update(now_us, raw.arc_limit_ok),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unsafe_at_once_safe_after_settling() {
        let mut d = Debouncer::new();
        let safe = Inputs::SAFE;
        // boot: unsafe until settled
        let i = d.update(0, safe);
        assert!(!i.interlock_closed && i.estop_pressed && !i.arc_limit_ok);
        let i = d.update(SETTLE_US, safe);
        assert_eq!(i, safe);
        // a single bouncy open read drops the interlock immediately
        let open = Inputs {
            interlock_closed: false,
            ..safe
        };
        assert!(!d.update(SETTLE_US + 10, open).interlock_closed);
        // closing again bounces: open read in the middle restarts the settle time
        assert!(!d.update(SETTLE_US + 20, safe).interlock_closed);
        assert!(!d.update(SETTLE_US + 2000, open).interlock_closed);
        assert!(!d.update(SETTLE_US + 3000, safe).interlock_closed);
        assert!(!d.update(2 * SETTLE_US + 2999, safe).interlock_closed);
        assert!(d.update(2 * SETTLE_US + 3000, safe).interlock_closed);
        // e-stop press is immediate
        let pressed = Inputs {
            estop_pressed: true,
            ..safe
        };
        assert!(d.update(100_000, pressed).estop_pressed);
    }
}
