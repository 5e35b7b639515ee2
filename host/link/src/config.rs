//! Timing of the link: heartbeat, retransmission timeout bounds, tries.

use std::time::Duration;

/// Link timing. Defaults suit a real rig (MCU heartbeat timeout 250 ms);
/// [`LinkConfig::scaled`] suits an emulated rig running faster than real time.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkConfig {
    /// Interval between heartbeats (the MCU faults after 250 ms without one
    /// while the laser is armed or a motor moves).
    pub heartbeat_interval: Duration,
    /// Retransmission timeout before the first RTT sample.
    pub initial_rto: Duration,
    /// Lower and upper bound of the retransmission timeout (Klipper: 25 ms, 5 s).
    pub min_rto: Duration,
    pub max_rto: Duration,
    /// Transmissions of one command before `LinkError::Timeout`.
    pub tries: u32,
    /// Capacity of the event broadcast: a subscriber further behind is told it lagged.
    pub event_capacity: usize,
    /// Unacknowledged events are acknowledged after at most this delay when idle.
    pub ack_delay: Duration,
    /// An event missing (later ones arrived) this long makes the link ask the
    /// MCU whether it dropped events (it re-sends unacknowledged ones every 50 ms).
    pub event_gap_timeout: Duration,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self {
            heartbeat_interval: Duration::from_millis(100),
            initial_rto: Duration::from_millis(200),
            min_rto: Duration::from_millis(25),
            max_rto: Duration::from_secs(5),
            tries: 10,
            event_capacity: 4096,
            ack_delay: Duration::from_millis(5),
            event_gap_timeout: Duration::from_millis(250),
        }
    }
}

impl LinkConfig {
    /// Timing for a rig whose clock runs `time_scale` times faster than real
    /// time: the heartbeat interval shrinks with the MCU's timeout, and so do
    /// the RTO bounds (never below 1 ms, the scheduler's granularity).
    pub fn scaled(time_scale: f64) -> Self {
        let d = Self::default();
        let s = if time_scale.is_finite() && time_scale > 0.0 {
            time_scale
        } else {
            1.0
        };
        let floor = Duration::from_millis(1);
        let scale = |t: Duration| t.div_f64(s).max(floor);
        Self {
            heartbeat_interval: scale(d.heartbeat_interval),
            initial_rto: scale(d.initial_rto),
            min_rto: scale(d.min_rto),
            max_rto: scale(d.max_rto),
            ack_delay: scale(d.ack_delay),
            event_gap_timeout: scale(d.event_gap_timeout),
            ..d
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_shrinks_times_with_a_floor() {
        let c = LinkConfig::scaled(10.0);
        assert_eq!(c.heartbeat_interval, Duration::from_millis(10));
        assert_eq!(c.min_rto, Duration::from_micros(2500));
        assert_eq!(c.max_rto, Duration::from_millis(500));
        let c = LinkConfig::scaled(1000.0);
        assert_eq!(c.min_rto, Duration::from_millis(1));
        assert_eq!(LinkConfig::scaled(f64::NAN), LinkConfig::default());
        assert_eq!(LinkConfig::scaled(1.0), LinkConfig::default());
    }
}
