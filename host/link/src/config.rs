//! Timing of the link: heartbeat, retransmission timeout bounds, tries.

use std::time::Duration;

/// Link timing. Defaults suit a real rig (MCU heartbeat timeout 250 ms);
/// [`LinkConfig::scaled`] suits an emulated rig running faster than real time.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkConfig {
    /// Interval between heartbeats when the link is idle (the MCU faults
    /// after 250 ms without hearing a valid frame while the laser is armed
    /// or a motor moves). Commands answered with a short `Ok` are resent at
    /// least every quarter of it while unanswered.
    pub heartbeat_interval: Duration,
    /// Retransmission timeout before the first RTT sample.
    pub initial_rto: Duration,
    /// Lower and upper bound of the retransmission timeout. The upper bound
    /// only matters after silent tries; it stays well below `silence_timeout`
    /// so a live MCU is asked several times before it is given up.
    pub min_rto: Duration,
    pub max_rto: Duration,
    /// Silent tries of one command (timeouts with no damaged frame received,
    /// i.e. the request or the whole answer vanished) before
    /// `LinkError::Timeout`. Tries whose answer arrived damaged do not
    /// count, nor keep-alive resends cut short of the RTO.
    /// The default is high enough that a silent MCU meets `silence_timeout`
    /// first (and the link reports it gone rather than one command lost).
    pub tries: u32,
    /// Longest time one command may take, however many tries (a line so
    /// damaged that no answer gets through): then `LinkError::Timeout`.
    pub answer_timeout: Duration,
    /// Nothing at all (no frame, valid or damaged) received from the MCU for
    /// this long after a command or heartbeat was sent: the MCU stopped
    /// answering (frozen, unplugged, powered off). The link dies with
    /// `LinkError::Disconnected`; `reconnect()` may revive it.
    pub silence_timeout: Duration,
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
            heartbeat_interval: Duration::from_millis(50),
            initial_rto: Duration::from_millis(200),
            min_rto: Duration::from_millis(25),
            max_rto: Duration::from_secs(1),
            tries: 100,
            answer_timeout: Duration::from_secs(10),
            silence_timeout: Duration::from_secs(3),
            event_capacity: 4096,
            ack_delay: Duration::from_millis(5),
            event_gap_timeout: Duration::from_millis(250),
        }
    }
}

impl LinkConfig {
    /// Timing for a rig whose clock runs `time_scale` times faster than real
    /// time: the heartbeat interval shrinks with the MCU's timeout, and so do
    /// the RTO bounds (never below 1 ms, the scheduler's granularity; the
    /// upper one never below 250 ms, as process scheduling does not speed up
    /// with the rig). `answer_timeout` and `silence_timeout` are the
    /// caller's patience in wall time and stay as they are.
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
            max_rto: scale(d.max_rto).max(MAX_RTO_FLOOR),
            ack_delay: scale(d.ack_delay),
            event_gap_timeout: scale(d.event_gap_timeout),
            ..d
        }
    }
}

/// Lowest upper bound of the retransmission timeout for a scaled rig.
const MAX_RTO_FLOOR: Duration = Duration::from_millis(250);

impl LinkConfig {
    /// Timing for a serial line at `baud` whose far end runs `time_scale`
    /// times faster than real time: [`LinkConfig::scaled`], with every
    /// retransmission timeout at least the time a largest request and a
    /// largest answer take on the line (10 bits per byte), so a slow line is
    /// not flooded with retransmissions, and the silence bound at least
    /// three times the largest retransmission timeout.
    pub fn for_line(baud: u32, time_scale: f64) -> Self {
        let mut c = Self::scaled(time_scale);
        let s = if time_scale.is_finite() && time_scale > 0.0 {
            time_scale
        } else {
            1.0
        };
        if baud > 0 {
            let line =
                Duration::from_secs_f64(2.0 * protocol::MAX_FRAME as f64 * 10.0 / baud as f64 / s);
            c.min_rto = c.min_rto.max(line);
            c.initial_rto = c.initial_rto.max(2 * line);
            c.max_rto = c.max_rto.max(4 * line);
            c.silence_timeout = c.silence_timeout.max(3 * c.max_rto);
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_shrinks_times_with_a_floor() {
        let c = LinkConfig::scaled(10.0);
        assert_eq!(c.heartbeat_interval, Duration::from_millis(5));
        assert_eq!(c.min_rto, Duration::from_micros(2500));
        assert_eq!(c.max_rto, Duration::from_millis(250));
        assert_eq!(c.silence_timeout, Duration::from_secs(3));
        let c = LinkConfig::scaled(1000.0);
        assert_eq!(c.min_rto, Duration::from_millis(1));
        assert_eq!(LinkConfig::scaled(f64::NAN), LinkConfig::default());
        assert_eq!(LinkConfig::scaled(1.0), LinkConfig::default());
    }

    #[test]
    fn a_slow_line_stretches_the_timeouts() {
        // 2 x 164 bytes at 9600 baud: 342 ms.
        let c = LinkConfig::for_line(9600, 1.0);
        assert!(c.min_rto > Duration::from_millis(300), "{:?}", c.min_rto);
        assert!(c.max_rto >= 4 * c.min_rto);
        assert!(c.silence_timeout >= 3 * c.max_rto);
        // Fast lines keep the defaults.
        assert_eq!(
            LinkConfig::for_line(115_200 * 8, 1.0),
            LinkConfig::default()
        );
        assert_eq!(LinkConfig::for_line(0, 10.0), LinkConfig::scaled(10.0));
    }
}
