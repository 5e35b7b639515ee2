//! The serial line between host and MCU: baud-rate timing and seeded faults.
//!
//! A [`Wire`] carries bytes one way. Each byte occupies the line for 10 bit
//! times (8N1); a byte written while the line is busy waits its turn, so
//! bursts arrive at the rate a real UART delivers them. Faults are drawn per
//! byte from a seeded PCG stream: drop, corrupt (flip one bit), duplicate,
//! and delay (the line stalls before the byte, as a USB-serial adapter does;
//! order is kept, as on any serial line). Disconnects and MCU resets are
//! link-level faults handled by [`crate::port::SimPort`].

use std::collections::VecDeque;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde::{Deserialize, Serialize};

use crate::SimError;

/// Per-byte fault rates of one direction, each a probability in `0..=1`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ByteFaults {
    /// Probability a byte is lost.
    pub drop: f64,
    /// Probability one bit of a byte is flipped.
    pub corrupt: f64,
    /// Probability a byte arrives twice.
    pub duplicate: f64,
    /// Probability the line stalls before a byte...
    pub delay: f64,
    /// ...for a uniformly drawn time up to this, µs.
    pub delay_max_us: u64,
}

impl ByteFaults {
    /// No faults.
    pub const NONE: ByteFaults = ByteFaults {
        drop: 0.0,
        corrupt: 0.0,
        duplicate: 0.0,
        delay: 0.0,
        delay_max_us: 0,
    };

    fn validate(&self, name: &str) -> Result<(), SimError> {
        for (what, p) in [
            ("drop", self.drop),
            ("corrupt", self.corrupt),
            ("duplicate", self.duplicate),
            ("delay", self.delay),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(SimError::BadConfig(format!(
                    "{name}.{what} = {p} is not a probability in 0..=1"
                )));
            }
        }
        Ok(())
    }

    pub fn is_none(&self) -> bool {
        self.drop == 0.0 && self.corrupt == 0.0 && self.duplicate == 0.0 && self.delay == 0.0
    }
}

/// When to reset the MCU, to test recovery "in the middle of a command".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ResetFault {
    /// At this virtual time, µs.
    AtUs(u64),
    /// `delay_us` after the MCU received the `frames`-th complete frame (1 =
    /// the first). With `delay_us = 0` the command has been executed but its
    /// reply is lost with the MCU's transmit buffer; with a longer delay the
    /// MCU resets while the command runs (a move, a sweep).
    AfterFrames { frames: u32, delay_us: u64 },
}

/// Every fault the link can inject. Serde so tests and the CLI can set it
/// (e.g. from TOML or JSON); missing fields mean "no fault".
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct FaultConfig {
    /// Seed of the fault stream (both directions derive from it).
    pub seed: u64,
    /// Faults on bytes from the host to the MCU.
    pub host_to_mcu: ByteFaults,
    /// Faults on bytes from the MCU to the host.
    pub mcu_to_host: ByteFaults,
    /// Close the link at this virtual time, µs: the host's reads return EOF
    /// (in-process) or the pseudo-terminal hangs up.
    pub disconnect_at_us: Option<u64>,
    /// Reset the MCU once.
    pub reset: Option<ResetFault>,
    /// The injected reset is a watchdog reset: the new boot reports it and
    /// latches `FaultCause::Watchdog` until the host clears it.
    pub reset_by_watchdog: bool,
}

impl FaultConfig {
    /// No faults at all.
    pub fn none() -> Self {
        Self::default()
    }

    /// The same byte faults in both directions.
    pub fn symmetric(seed: u64, faults: ByteFaults) -> Self {
        Self {
            seed,
            host_to_mcu: faults,
            mcu_to_host: faults,
            ..Self::default()
        }
    }

    pub fn validate(&self) -> Result<(), SimError> {
        self.host_to_mcu.validate("host_to_mcu")?;
        self.mcu_to_host.validate("mcu_to_host")
    }
}

/// Counts of what a wire did, for assertions and reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WireStats {
    pub sent: u64,
    pub delivered: u64,
    pub dropped: u64,
    pub corrupted: u64,
    pub duplicated: u64,
    pub delayed: u64,
}

/// One direction of the serial line.
#[derive(Debug)]
pub struct Wire {
    /// Time one byte occupies the line, µs (0 = infinitely fast).
    byte_us: f64,
    faults: ByteFaults,
    rng: Pcg64,
    /// When the line is free for the next byte, µs.
    line_free_us: f64,
    in_flight: VecDeque<(u64, u8)>,
    stats: WireStats,
}

impl Wire {
    /// A line at `baud` (8N1; 0 = no delay) with the given faults. Rates
    /// outside `0..=1` are clamped (NaN counts as 0); configurations are
    /// checked with [`FaultConfig::validate`] before they get here.
    pub fn new(baud: u32, faults: ByteFaults, seed: u64) -> Self {
        let rate = |p: f64| if p.is_nan() { 0.0 } else { p.clamp(0.0, 1.0) };
        let faults = ByteFaults {
            drop: rate(faults.drop),
            corrupt: rate(faults.corrupt),
            duplicate: rate(faults.duplicate),
            delay: rate(faults.delay),
            delay_max_us: faults.delay_max_us,
        };
        Self {
            byte_us: if baud == 0 { 0.0 } else { 10.0e6 / baud as f64 },
            faults,
            rng: Pcg64::seed_from_u64(seed),
            line_free_us: 0.0,
            in_flight: VecDeque::new(),
            stats: WireStats::default(),
        }
    }

    /// Put bytes on the line at `now_us`.
    pub fn send(&mut self, now_us: u64, bytes: &[u8]) {
        for &b in bytes {
            self.stats.sent += 1;
            let f = self.faults;
            if f.drop > 0.0 && self.rng.random_bool(f.drop) {
                self.stats.dropped += 1;
                continue;
            }
            let mut b = b;
            if f.corrupt > 0.0 && self.rng.random_bool(f.corrupt) {
                b ^= 1 << self.rng.random_range(0..8);
                self.stats.corrupted += 1;
            }
            let copies = if f.duplicate > 0.0 && self.rng.random_bool(f.duplicate) {
                self.stats.duplicated += 1;
                2
            } else {
                1
            };
            let mut start = self.line_free_us.max(now_us as f64);
            if f.delay > 0.0 && f.delay_max_us > 0 && self.rng.random_bool(f.delay) {
                start += self.rng.random_range(0..=f.delay_max_us) as f64;
                self.stats.delayed += 1;
            }
            for _ in 0..copies {
                let due = start + self.byte_us;
                self.line_free_us = due;
                start = due;
                self.in_flight.push_back((due.ceil() as u64, b));
            }
        }
    }

    /// Arrival time of the next byte in flight.
    pub fn next_due_us(&self) -> Option<u64> {
        self.in_flight.front().map(|&(t, _)| t)
    }

    /// Pop every byte that has arrived by `now_us`.
    pub fn take_due(&mut self, now_us: u64, out: &mut Vec<u8>) {
        while let Some(&(t, b)) = self.in_flight.front() {
            if t > now_us {
                break;
            }
            self.in_flight.pop_front();
            self.stats.delivered += 1;
            out.push(b);
        }
    }

    /// Pop the next byte if it has arrived by `now_us`, with its arrival time.
    pub fn pop_due(&mut self, now_us: u64) -> Option<(u64, u8)> {
        match self.in_flight.front() {
            Some(&(t, _)) if t <= now_us => {
                self.stats.delivered += 1;
                self.in_flight.pop_front()
            }
            _ => None,
        }
    }

    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    pub fn stats(&self) -> WireStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn baud_rate_spaces_bytes() {
        let mut w = Wire::new(115_200, ByteFaults::NONE, 1);
        w.send(1000, &[1, 2, 3]);
        let mut out = Vec::new();
        w.take_due(1086, &mut out);
        assert!(out.is_empty());
        w.take_due(1087, &mut out);
        assert_eq!(out, [1]);
        // three bytes take 3 * 86.8 µs
        w.take_due(1260, &mut out);
        assert_eq!(out, [1, 2]);
        w.take_due(1261, &mut out);
        assert_eq!(out, [1, 2, 3]);
        // a later byte starts when it is written, not back to back
        w.send(5000, &[4]);
        assert_eq!(w.next_due_us(), Some(5087));
    }

    #[test]
    fn fault_rates_match_and_are_seeded() {
        let faults = ByteFaults {
            drop: 0.01,
            corrupt: 0.02,
            duplicate: 0.03,
            delay: 0.0,
            delay_max_us: 0,
        };
        let data: Vec<u8> = (0..100_000u32).map(|i| i as u8).collect();
        let run = |seed| {
            let mut w = Wire::new(0, faults, seed);
            w.send(0, &data);
            let mut out = Vec::new();
            w.take_due(0, &mut out);
            (w.stats(), out)
        };
        let (s, out) = run(5);
        assert_eq!(run(5).1, out, "same seed, same faults");
        assert_ne!(run(6).1, out);
        let n = data.len() as f64;
        for (count, p) in [(s.dropped, 0.01), (s.corrupted, 0.02), (s.duplicated, 0.03)] {
            let sigma = (n * p * (1.0 - p)).sqrt();
            assert!((count as f64 - n * p).abs() < 5.0 * sigma, "{count} vs {p}");
        }
        assert_eq!(
            out.len() as u64,
            s.sent - s.dropped + s.duplicated,
            "every byte accounted for"
        );
    }

    #[test]
    fn delay_stalls_the_line_keeping_order() {
        let faults = ByteFaults {
            delay: 1.0,
            delay_max_us: 500,
            ..ByteFaults::NONE
        };
        let mut w = Wire::new(0, faults, 3);
        w.send(0, &[1, 2, 3, 4]);
        let mut out = Vec::new();
        w.take_due(u64::MAX, &mut out);
        assert_eq!(out, [1, 2, 3, 4]);
        assert_eq!(w.stats().delayed, 4);
    }

    #[test]
    fn a_wire_built_from_unchecked_rates_does_not_panic() {
        let f = ByteFaults {
            drop: f64::NAN,
            corrupt: 7.0,
            duplicate: -1.0,
            delay: 0.5,
            delay_max_us: u64::MAX / 4,
        };
        let mut w = Wire::new(9600, f, 1);
        w.send(0, &[1, 2, 3]);
        assert_eq!(w.stats().corrupted, 3);
        assert_eq!(w.stats().dropped + w.stats().duplicated, 0);
    }

    #[test]
    fn bad_rates_are_refused() {
        let mut c = FaultConfig::none();
        c.mcu_to_host.drop = 1.5;
        assert!(c.validate().is_err());
        c.mcu_to_host.drop = f64::NAN;
        assert!(c.validate().is_err());
        assert!(FaultConfig::none().validate().is_ok());
    }

    #[test]
    fn config_from_json_with_defaults() {
        let c: FaultConfig = serde_json::from_str(
            r#"{"seed": 9, "host_to_mcu": {"drop": 0.01}, "reset": {"AfterFrames": {"frames": 3, "delay_us": 100}}}"#,
        )
        .unwrap();
        assert_eq!(c.seed, 9);
        assert_eq!(c.host_to_mcu.drop, 0.01);
        assert!(c.mcu_to_host.is_none());
        assert_eq!(
            c.reset,
            Some(ResetFault::AfterFrames {
                frames: 3,
                delay_us: 100
            })
        );
    }
}
