//! The emulated rig behind its serial line, on virtual time.
//!
//! [`SimPort`] joins an [`EmulatedRig`] to two [`Wire`]s (host -> MCU and
//! MCU -> host) and the link-level faults of a [`FaultConfig`]: disconnect at
//! a chosen time and an MCU reset at a chosen moment. It is still pure virtual
//! time: the host writes with [`SimPort::host_write`], time moves with
//! [`SimPort::advance_to`], and the host reads what has arrived with
//! [`SimPort::host_read`]. The real-time drivers in [`crate::link`] and
//! [`crate::pty`] wrap it; deterministic tests use it directly.

use crate::SimError;
use crate::fault::{FaultConfig, ResetFault, Wire, WireStats};
use crate::rig::{EmulatedRig, RigConfig};

/// Baud rate of the reference board's ST-LINK virtual COM port.
pub const DEFAULT_BAUD: u32 = 115_200;

/// A serial line's parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LinkConfig {
    /// Modelled line rate (8N1), bits/s; 0 = no transmission delay.
    pub baud: u32,
    pub faults: FaultConfig,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self {
            baud: DEFAULT_BAUD,
            faults: FaultConfig::none(),
        }
    }
}

/// The rig and its line, on virtual time.
#[derive(Debug)]
pub struct SimPort {
    rig: EmulatedRig,
    up: Wire,
    down: Wire,
    faults: FaultConfig,
    /// Non-empty frames (delimiters after data) delivered to the MCU so far.
    frames_in: u32,
    /// A non-delimiter byte reached the MCU since the last delimiter.
    in_frame: bool,
    reset_at_us: Option<u64>,
    reset_done: bool,
    disconnected: bool,
}

impl SimPort {
    /// A powered-on rig behind a line.
    pub fn new(rig: RigConfig, link: LinkConfig) -> Result<Self, SimError> {
        Self::with_rig(EmulatedRig::new(rig)?, link)
    }

    /// An existing rig behind a line.
    pub fn with_rig(mut rig: EmulatedRig, link: LinkConfig) -> Result<Self, SimError> {
        link.faults.validate()?;
        rig.set_uart_baud(link.baud);
        let f = link.faults;
        let reset_at_us = match f.reset {
            Some(ResetFault::AtUs(t)) => Some(t),
            _ => None,
        };
        Ok(Self {
            rig,
            up: Wire::new(link.baud, f.host_to_mcu, f.seed),
            down: Wire::new(link.baud, f.mcu_to_host, f.seed ^ 0x9e37_79b9_7f4a_7c15),
            faults: f,
            frames_in: 0,
            in_frame: false,
            reset_at_us,
            reset_done: false,
            disconnected: false,
        })
    }

    pub fn rig(&self) -> &EmulatedRig {
        &self.rig
    }

    pub fn rig_mut(&mut self) -> &mut EmulatedRig {
        &mut self.rig
    }

    pub fn now_us(&self) -> u64 {
        self.rig.now_us()
    }

    /// The host writes bytes now. Ignored once disconnected.
    pub fn host_write(&mut self, bytes: &[u8]) {
        if !self.disconnected {
            self.up.send(self.rig.now_us(), bytes);
        }
    }

    /// Bytes that have reached the host by now.
    pub fn host_read(&mut self) -> Vec<u8> {
        let mut out = Vec::new();
        if !self.disconnected {
            self.down.take_due(self.rig.now_us(), &mut out);
        }
        out
    }

    /// Run rig and line until `t_us`: each byte reaches the MCU at its
    /// arrival time, each byte the MCU sends goes on the line when it was
    /// sent, and faults fire at their moments.
    pub fn advance_to(&mut self, t_us: u64) {
        loop {
            if self.disconnected {
                self.rig.advance_to(t_us);
                return;
            }
            let mut next = t_us;
            if let Some(d) = self.up.next_due_us() {
                next = next.min(d);
            }
            if let Some(r) = self.reset_at_us.filter(|_| !self.reset_done) {
                next = next.min(r);
            }
            if let Some(d) = self.faults.disconnect_at_us {
                next = next.min(d);
            }
            let next = next.max(self.rig.now_us());
            self.rig.advance_to(next);
            self.forward_tx();
            if self.faults.disconnect_at_us.is_some_and(|d| d <= next) {
                self.disconnect();
                continue;
            }
            if !self.reset_done && self.reset_at_us.is_some_and(|r| r <= next) {
                self.reset_done = true;
                self.rig.reset_mcu(self.faults.reset_by_watchdog);
                self.forward_tx();
            }
            let mut delivered = false;
            while let Some((_, b)) = self.up.pop_due(next) {
                delivered = true;
                self.rig.receive(&[b]);
                if b != 0 {
                    self.in_frame = true;
                } else if std::mem::take(&mut self.in_frame) {
                    self.frame_arrived();
                }
            }
            self.forward_tx();
            if !delivered && next >= t_us {
                return;
            }
        }
    }

    /// Run for `dt_us` of virtual time.
    pub fn advance(&mut self, dt_us: u64) {
        self.advance_to(self.rig.now_us().saturating_add(dt_us));
    }

    fn frame_arrived(&mut self) {
        self.frames_in = self.frames_in.saturating_add(1);
        if let Some(ResetFault::AfterFrames { frames, delay_us }) = self.faults.reset
            && !self.reset_done
            && self.reset_at_us.is_none()
            && self.frames_in == frames
        {
            if delay_us == 0 {
                // Executed, but the reply dies in the MCU's transmit buffer.
                self.reset_done = true;
                self.rig.reset_mcu(self.faults.reset_by_watchdog);
            } else {
                self.reset_at_us = Some(self.rig.now_us() + delay_us);
            }
        }
    }

    fn forward_tx(&mut self) {
        for (t, b) in self.rig.take_tx_timed() {
            if !self.disconnected {
                self.down.send(t, &[b]);
            }
        }
    }

    /// When something next happens on the line (a byte arrives at either
    /// end, a fault fires): real-time drivers sleep until then at most.
    pub fn next_event_us(&self) -> Option<u64> {
        [
            self.up.next_due_us(),
            self.down.next_due_us(),
            self.reset_at_us.filter(|_| !self.reset_done),
            self.faults.disconnect_at_us.filter(|_| !self.disconnected),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Close the link: nothing more crosses it; the drivers close the host's end.
    pub fn disconnect(&mut self) {
        self.disconnected = true;
    }

    pub fn is_disconnected(&self) -> bool {
        self.disconnected
    }

    /// Non-empty frames the MCU received (valid or not).
    pub fn frames_in(&self) -> u32 {
        self.frames_in
    }

    /// Whether the configured reset fault has fired.
    pub fn reset_fired(&self) -> bool {
        self.reset_done
    }

    /// What each direction of the line did.
    pub fn wire_stats(&self) -> (WireStats, WireStats) {
        (self.up.stats(), self.down.stats())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Command, FrameDecoder, HostFrame, MAX_FRAME, McuFrame, encode_frame};

    fn frame(seq: u16, command: Command) -> Vec<u8> {
        let mut buf = [0u8; MAX_FRAME];
        let n = encode_frame(&HostFrame { seq, command }, &mut buf).unwrap();
        buf[..n].to_vec()
    }

    /// Run until the ack of `seq` arrives; returns the virtual time taken
    /// and the ack's length on the wire.
    fn until_ack(p: &mut SimPort, seq: u16) -> (u64, usize) {
        let t0 = p.now_us();
        let mut dec = FrameDecoder::new();
        loop {
            p.advance(10);
            let mut ack = None;
            dec.push_slice::<McuFrame>(&p.host_read(), |f| {
                if let Ok(f @ McuFrame::Ack { seq: s, .. }) = f
                    && s == seq
                {
                    ack = Some(f);
                }
            });
            if let Some(f) = ack {
                let mut buf = [0u8; MAX_FRAME];
                return (p.now_us() - t0, encode_frame(&f, &mut buf).unwrap());
            }
            assert!(p.now_us() - t0 < 1_000_000, "no ack");
        }
    }

    /// Round trip of a Status command on a quiet line (events acknowledged).
    fn status_rtt(baud: u32) -> (u64, usize) {
        let link = LinkConfig {
            baud,
            ..LinkConfig::default()
        };
        let mut p = SimPort::new(RigConfig::seeded(1), link).unwrap();
        p.host_write(&frame(1, Command::Identify));
        until_ack(&mut p, 1);
        // Booted is event 1: acknowledge it so nothing is re-sent.
        p.host_write(&frame(2, Command::AckEvents { upto: 1 }));
        until_ack(&mut p, 2);
        p.advance(200_000);
        p.host_read();
        let req = frame(3, Command::Status);
        p.host_write(&req);
        let (rtt, ack) = until_ack(&mut p, 3);
        (rtt, req.len() + ack)
    }

    #[test]
    fn round_trip_costs_the_bytes_on_the_line() {
        let (rtt, bytes) = status_rtt(115_200);
        let ideal = bytes as f64 * 10.0e6 / 115_200.0;
        // Within the 10 µs polling of this test and a µs of rounding per byte.
        assert!(
            rtt as f64 >= ideal - 1.0 && (rtt as f64) < ideal + 20.0 + bytes as f64,
            "{rtt} µs for {bytes} bytes, ideal {ideal:.0}"
        );
        let (rtt, _) = status_rtt(0);
        assert!(rtt <= 10, "instant line: {rtt} µs");
    }

    #[test]
    fn frames_are_counted_and_a_disconnect_silences_the_line() {
        let mut p = SimPort::new(RigConfig::seeded(2), LinkConfig::default()).unwrap();
        let f = frame(1, Command::Identify);
        p.host_write(&[0, 0, 0]);
        p.host_write(&f);
        p.host_write(&[0x55, 0x66, 0]);
        p.advance(10_000);
        assert_eq!(p.frames_in(), 2, "empty frames are not frames");
        assert!(!p.host_read().is_empty());
        p.disconnect();
        p.host_write(&f);
        p.advance(100_000);
        assert!(p.host_read().is_empty());
        assert_eq!(p.frames_in(), 2);
    }
}
