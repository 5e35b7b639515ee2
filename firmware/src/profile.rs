//! Trapezoidal step schedules in f32 on the MCU clock (µs).
//!
//! A profile emits `remaining` steps in one direction. The first step goes out
//! at once; after each step the rate `v` (steps/s) is updated per step so that
//! `v^2` grows (or shrinks) by `2 a`, the constant-acceleration relation over a
//! distance of one step. The profile decelerates as soon as the steps left are
//! no more than the steps needed to stop, `v^2 / 2a`, so moves that never reach
//! `v_max` come out triangular. Step times are scheduled from the previous
//! step's due time, not from when `poll` happened to run, so a late poll
//! catches up instead of stretching the move.

/// One point-to-point run of steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    pub forward: bool,
    /// Steps still to emit.
    pub remaining: u32,
    /// Current step rate, steps/s.
    v: f32,
    /// Rate of the first step from rest, steps/s.
    v_start: f32,
    v_max: f32,
    accel: f32,
    /// Due time of the next step, µs.
    pub next_us: u64,
}

impl Profile {
    /// A run of `steps` steps starting at `now_us`, limited to `v_max` steps/s
    /// and `accel` steps/s^2 (both > 0).
    pub fn new(now_us: u64, forward: bool, steps: u32, v_max: f32, accel: f32) -> Self {
        let v_max = v_max.max(1.0);
        let accel = accel.max(1.0);
        // One step from rest at `accel` takes sqrt(2/a) s: average rate sqrt(a/2).
        let v_start = libm::sqrtf(accel * 0.5).min(v_max);
        Profile {
            forward,
            remaining: steps,
            v: v_start,
            v_start,
            v_max,
            accel,
            next_us: now_us,
        }
    }

    pub fn done(&self) -> bool {
        self.remaining == 0
    }

    /// Steps needed to come to rest from the current rate.
    pub fn steps_to_stop(&self) -> u32 {
        let s = self.v * self.v / (2.0 * self.accel);
        libm::ceilf(s) as u32
    }

    /// Decelerate to rest as fast as the acceleration limit allows.
    pub fn stop(&mut self) {
        self.remaining = self.remaining.min(self.steps_to_stop().max(1));
    }

    /// Stop without deceleration (e-stop).
    pub fn halt(&mut self) {
        self.remaining = 0;
    }

    /// If a step is due at `now_us`, account for it and schedule the next one;
    /// returns whether the caller must emit a step now.
    pub fn take_step(&mut self, now_us: u64) -> bool {
        if self.remaining == 0 || now_us < self.next_us {
            return false;
        }
        self.remaining -= 1;
        if self.remaining > 0 {
            let two_a = 2.0 * self.accel;
            let v2 = self.v * self.v;
            self.v = if self.steps_to_stop() >= self.remaining {
                libm::sqrtf((v2 - two_a).max(self.v_start * self.v_start))
            } else if self.v < self.v_max {
                libm::sqrtf(v2 + two_a).min(self.v_max)
            } else {
                self.v_max
            };
            let interval_us = (1.0e6 / self.v) as u64;
            self.next_us = self.next_us.saturating_add(interval_us.max(1));
        }
        true
    }

    /// Current rate, steps/s.
    pub fn rate(&self) -> f32 {
        self.v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Run a profile to completion, polling exactly at each due time; returns step times.
    fn run(mut p: Profile) -> std::vec::Vec<u64> {
        let mut t = std::vec::Vec::new();
        while !p.done() {
            let now = p.next_us;
            assert!(p.take_step(now));
            t.push(now);
        }
        t
    }

    #[test]
    fn trapezoid_reaches_v_max_and_takes_about_the_ideal_time() {
        // 10000 steps at 2000 steps/s, 4000 steps/s^2: ramps of 0.5 s, 500 steps each.
        let p = Profile::new(0, true, 10_000, 2000.0, 4000.0);
        let t = run(p);
        assert_eq!(t.len(), 10_000);
        let total_s = *t.last().unwrap() as f64 * 1e-6;
        // ideal: 2 v/a + (d - v^2/a)/v = 1 + 9000/2000 = 5.5 s
        assert!((total_s - 5.5).abs() < 0.03, "took {total_s} s");
        // cruise in the middle: intervals of 500 µs
        let mid = t[5001] - t[5000];
        assert!((499..=501).contains(&mid), "mid interval {mid}");
        // symmetric ramps: the first and last intervals are the longest
        let first = t[1] - t[0];
        let last = t[9999] - t[9998];
        assert!(first > 5 * mid && last > 5 * mid);
    }

    #[test]
    fn short_move_is_triangular() {
        let mut p = Profile::new(0, false, 100, 1.0e6, 4000.0);
        let mut max_rate: f32 = 0.0;
        let mut n = 0;
        while !p.done() {
            let now = p.next_us;
            p.take_step(now);
            max_rate = max_rate.max(p.rate());
            n += 1;
        }
        assert_eq!(n, 100);
        // peak of a triangle over 100 steps: sqrt(a * d) = sqrt(4000 * 100) ≈ 632
        assert!(max_rate < 700.0 && max_rate > 550.0, "peak {max_rate}");
    }

    #[test]
    fn stop_decelerates_within_steps_to_stop() {
        let mut p = Profile::new(0, true, 100_000, 2000.0, 4000.0);
        for _ in 0..2000 {
            let now = p.next_us;
            p.take_step(now);
        }
        let needed = p.steps_to_stop();
        // v^2 / 2a = 2000^2 / 8000 = 500
        assert!((499..=501).contains(&needed), "{needed}");
        p.stop();
        assert_eq!(p.remaining, needed);
        let t = run(p);
        assert_eq!(t.len() as u32, needed);
    }

    #[test]
    fn late_poll_catches_up_without_stretching() {
        let mut p = Profile::new(0, true, 1000, 2000.0, 4000.0);
        let mut n = 0;
        // poll only every 10 ms, take every due step
        let mut now = 0;
        while !p.done() {
            while p.take_step(now) {
                n += 1;
            }
            now += 10_000;
        }
        assert_eq!(n, 1000);
        // ideal: 1 s of ramps + (1000 - 1000)/v = 1 s (triangle reaching 2000 exactly)
        assert!(now < 1_100_000, "finished at {now} µs");
    }
}
