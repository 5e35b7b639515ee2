//! Retransmission timeout from round-trip samples (Jacobson's SRTT/RTTVAR,
//! RFC 6298), with Karn's rule: no sample from a retransmitted command, and
//! the backed-off timeout is kept until a clean sample arrives.
//!
//! Back-off stops at twice the estimate: one command is in flight on a
//! serial line, so a lost frame is damage, not congestion, and a longer wait
//! only delays the retry (and the heartbeat behind it).

use std::time::Duration;

#[derive(Debug, Clone)]
pub struct RttEstimator {
    srtt: Option<f64>,
    rttvar: f64,
    /// The estimate before back-off.
    base: f64,
    rto: f64,
    min: f64,
    max: f64,
}

impl RttEstimator {
    pub fn new(initial: Duration, min: Duration, max: Duration) -> Self {
        let (min, max) = (min.as_secs_f64(), max.as_secs_f64().max(min.as_secs_f64()));
        Self {
            srtt: None,
            rttvar: 0.0,
            base: initial.as_secs_f64().clamp(min, max),
            rto: initial.as_secs_f64().clamp(min, max),
            min,
            max,
        }
    }

    /// A round trip of a command sent once (Karn: never call this for a
    /// retransmitted one, its ack cannot be matched to a transmission).
    pub fn sample(&mut self, rtt: Duration) {
        let r = rtt.as_secs_f64();
        match self.srtt {
            None => {
                self.srtt = Some(r);
                self.rttvar = r / 2.0;
            }
            Some(srtt) => {
                // alpha = 1/8, beta = 1/4
                self.rttvar = 0.75 * self.rttvar + 0.25 * (srtt - r).abs();
                self.srtt = Some(0.875 * srtt + 0.125 * r);
            }
        }
        let srtt = self.srtt.unwrap_or(r);
        self.base = (srtt + 4.0 * self.rttvar).clamp(self.min, self.max);
        self.rto = self.base;
    }

    /// A timeout expired: double the timeout, up to twice the estimate.
    pub fn backoff(&mut self) {
        self.rto = (self.rto * 2.0)
            .min(2.0 * self.base)
            .clamp(self.min, self.max);
    }

    pub fn rto(&self) -> Duration {
        Duration::from_secs_f64(self.rto)
    }

    pub fn srtt(&self) -> Option<Duration> {
        self.srtt.map(Duration::from_secs_f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(x: u64) -> Duration {
        Duration::from_millis(x)
    }

    #[test]
    fn converges_to_steady_rtt_and_respects_min() {
        let mut e = RttEstimator::new(ms(200), ms(25), ms(5000));
        assert_eq!(e.rto(), ms(200));
        e.sample(ms(100));
        // srtt 100, rttvar 50: rto = 300
        assert!((e.rto().as_secs_f64() - 0.3).abs() < 1e-9);
        for _ in 0..200 {
            e.sample(ms(2));
        }
        assert_eq!(e.rto(), ms(25));
        assert!(e.srtt().unwrap() < ms(3));
    }

    #[test]
    fn backoff_doubles_up_to_twice_the_estimate_and_max() {
        let mut e = RttEstimator::new(ms(1000), ms(25), ms(5000));
        e.backoff();
        assert_eq!(e.rto(), ms(2000));
        e.backoff();
        assert_eq!(e.rto(), ms(2000));
        let mut e = RttEstimator::new(ms(3000), ms(25), ms(5000));
        e.backoff();
        assert_eq!(e.rto(), ms(5000));
        e.sample(ms(10));
        assert!(e.rto() < ms(100));
        let rto = e.rto();
        for _ in 0..5 {
            e.backoff();
        }
        assert_eq!(e.rto(), 2 * rto);
    }
}
