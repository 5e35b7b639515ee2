//! A minimal host that speaks raw protocol frames to a [`SimPort`] on
//! virtual time: for tests and benchmarks of the emulator that must not
//! depend on the real link client.
//!
//! It numbers commands, waits for their acks (retransmitting the same
//! sequence on timeout, so the MCU executes each exactly once), deduplicates
//! and acknowledges events, and can send heartbeats while time runs.

use protocol::seq::EventReceiver;
use protocol::{
    Command, CommandError, Event, FrameDecoder, HostFrame, MAX_FRAME, McuFrame, Reply, encode_frame,
};

use crate::port::SimPort;

/// Virtual time between two steps of the host's receive loop, µs.
pub const TICK_US: u64 = 500;

/// Why a raw call failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RawError {
    #[error("no ack for sequence {seq} after {tries} tries")]
    NoAck { seq: u16, tries: u32 },
    #[error("the link is disconnected")]
    Disconnected,
}

/// An event as received, with the MCU's event sequence and clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReceivedEvent {
    pub eseq: u16,
    pub at_us: u64,
    pub event: Event,
    /// World time it arrived at the host.
    pub arrived_us: u64,
}

/// The raw-frame host.
pub struct RawHost {
    pub port: SimPort,
    next_seq: u16,
    decoder: FrameDecoder,
    events_rx: EventReceiver,
    boot_id: Option<u32>,
    /// Events delivered so far, duplicates removed, in order.
    pub events: Vec<ReceivedEvent>,
    /// Acks not yet claimed by a call.
    acks: Vec<(u16, Result<Reply, CommandError>)>,
    /// Send a heartbeat this often while running time (`None` = never).
    pub heartbeat_us: Option<u64>,
    last_heartbeat_us: Option<u64>,
    /// When the last frame of any kind was written (world clock).
    last_sent_us: Option<u64>,
    /// Frames that failed to decode (corruption on the line).
    pub bad_frames: u64,
    /// Retransmissions made by `call`.
    pub retransmissions: u64,
    /// Acknowledge delivered events before each command (default on), as a
    /// host must: unacknowledged events are re-sent every 50 ms and would
    /// fill the line.
    pub auto_ack: bool,
    /// Newest event sequence the MCU confirmed as acknowledged.
    acked: u16,
}

impl std::fmt::Debug for RawHost {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawHost")
            .field("port", &self.port)
            .field("next_seq", &self.next_seq)
            .field("events", &self.events.len())
            .finish_non_exhaustive()
    }
}

impl RawHost {
    pub fn new(port: SimPort) -> Self {
        Self {
            port,
            next_seq: 1,
            decoder: FrameDecoder::new(),
            events_rx: EventReceiver::new(),
            boot_id: None,
            events: Vec::new(),
            acks: Vec::new(),
            heartbeat_us: None,
            last_heartbeat_us: None,
            last_sent_us: None,
            bad_frames: 0,
            retransmissions: 0,
            auto_ack: true,
            acked: 0,
        }
    }

    pub fn now_us(&self) -> u64 {
        self.port.now_us()
    }

    /// Encode and write one command frame with sequence `seq`.
    pub fn send_raw(&mut self, seq: u16, command: Command) {
        let mut buf = [0u8; MAX_FRAME + 1];
        // A leading delimiter flushes any garbage the MCU's decoder holds.
        buf[0] = 0;
        // Every command fits a frame (protocol's largest_messages_fit test).
        let n = encode_frame(&HostFrame { seq, command }, &mut buf[1..]).unwrap_or(0);
        self.port.host_write(&buf[..n + 1]);
        self.last_sent_us = Some(self.now_us());
    }

    /// Send a command with the next sequence number and return it (no wait).
    pub fn send(&mut self, command: Command) -> u16 {
        let seq = self.next_seq;
        self.next_seq = seq.wrapping_add(1);
        self.send_raw(seq, command);
        seq
    }

    /// Send a command and wait for its ack, retransmitting after
    /// `timeout_us` up to `tries` times in all.
    pub fn call_with(
        &mut self,
        command: Command,
        timeout_us: u64,
        tries: u32,
    ) -> Result<Result<Reply, CommandError>, RawError> {
        let upto = self.events_rx.ack_upto();
        if self.auto_ack
            && upto != self.acked
            && !matches!(
                command,
                Command::AckEvents { .. } | Command::Heartbeat { .. } | Command::Identify
            )
        {
            // Refused only before the handshake; the command's own ack says so too.
            let _ = self.call_with(Command::AckEvents { upto }, timeout_us, tries)?;
        }
        let acks = match command {
            Command::AckEvents { upto } | Command::Heartbeat { event_ack: upto } => Some(upto),
            _ => None,
        };
        let seq = self.next_seq;
        self.next_seq = seq.wrapping_add(1);
        for attempt in 0..tries {
            if self.port.is_disconnected() {
                return Err(RawError::Disconnected);
            }
            if attempt > 0 {
                self.retransmissions += 1;
            }
            self.send_raw(seq, command.clone());
            let deadline = self.now_us() + timeout_us;
            while self.now_us() < deadline {
                if self.port.is_disconnected() {
                    return Err(RawError::Disconnected);
                }
                self.tick();
                if let Some(i) = self.acks.iter().position(|(s, _)| *s == seq) {
                    let (_, result) = self.acks.swap_remove(i);
                    self.acks.clear();
                    if let (Some(upto), Ok(_)) = (acks, &result) {
                        self.acked = upto;
                    }
                    return Ok(result);
                }
            }
        }
        Err(RawError::NoAck { seq, tries })
    }

    /// `call_with` a 100 ms timeout and 5 tries.
    pub fn call(&mut self, command: Command) -> Result<Result<Reply, CommandError>, RawError> {
        self.call_with(command, 100_000, 5)
    }

    /// Handshake: `Identify` restarts the sequence at 1 (fresh numbering, as
    /// after a reset). Returns the reply.
    pub fn identify(&mut self) -> Result<Result<Reply, CommandError>, RawError> {
        self.next_seq = 1;
        let r = self.call(Command::Identify);
        if let Ok(Ok(Reply::Identity(id))) = &r {
            self.boot_id = Some(id.boot_id);
        }
        r
    }

    /// Run virtual time for `dt_us`, receiving (and heartbeating if enabled).
    pub fn run_for(&mut self, dt_us: u64) {
        let end = self.now_us() + dt_us;
        while self.now_us() < end {
            self.maybe_heartbeat();
            self.tick_until(end);
        }
    }

    /// Run until `pred` holds for a received event (searching only events
    /// received from now on) or `timeout_us` passes; returns the event.
    pub fn run_until_event(
        &mut self,
        timeout_us: u64,
        mut pred: impl FnMut(&Event) -> bool,
    ) -> Option<ReceivedEvent> {
        let end = self.now_us() + timeout_us;
        let mut seen = self.events.len();
        while self.now_us() < end {
            self.maybe_heartbeat();
            self.tick_until(end);
            while seen < self.events.len() {
                let e = self.events[seen];
                seen += 1;
                if pred(&e.event) {
                    return Some(e);
                }
            }
        }
        None
    }

    fn maybe_heartbeat(&mut self) {
        if let Some(every) = self.heartbeat_us
            && self
                .last_heartbeat_us
                .is_none_or(|t| self.now_us() >= t + every)
        {
            self.last_heartbeat_us = Some(self.now_us());
            let event_ack = self.events_rx.ack_upto();
            // Acked like any command, so a lost one cannot break the sequence;
            // a heartbeat that never gets through shows up as a fault later.
            let _ = self.call_with(Command::Heartbeat { event_ack }, 20_000, 5);
        }
    }

    fn tick(&mut self) {
        let end = self.now_us() + TICK_US;
        self.tick_until(end);
    }

    fn tick_until(&mut self, end: u64) {
        let t = (self.now_us() + TICK_US).min(end);
        self.port.advance_to(t);
        let bytes = self.port.host_read();
        for b in bytes {
            match self.decoder.push::<McuFrame>(b) {
                None => {}
                Some(Err(_)) => self.bad_frames += 1,
                Some(Ok(McuFrame::Ack { seq, result })) => self.acks.push((seq, result)),
                Some(Ok(McuFrame::Event { eseq, at_us, event })) => {
                    if let Event::Booted { boot_id, .. } = event
                        && self.boot_id != Some(boot_id)
                    {
                        // A new boot numbers its events from the start again.
                        self.boot_id = Some(boot_id);
                        self.events_rx.reset(eseq.wrapping_sub(1));
                        self.acked = eseq.wrapping_sub(1);
                    }
                    if self.events_rx.accept(eseq) {
                        self.events.push(ReceivedEvent {
                            eseq,
                            at_us,
                            event,
                            arrived_us: self.port.now_us(),
                        });
                    }
                }
            }
        }
    }

    /// Events delivered so far matching `pred`.
    pub fn events_where(&self, mut pred: impl FnMut(&Event) -> bool) -> Vec<ReceivedEvent> {
        self.events
            .iter()
            .filter(|e| pred(&e.event))
            .copied()
            .collect()
    }

    /// When the last frame was written (world clock). The MCU counts any
    /// valid frame as a heartbeat, so it bounds when the MCU last heard us.
    pub fn last_sent_us(&self) -> Option<u64> {
        self.last_sent_us
    }

    /// Acknowledge every event delivered so far.
    pub fn ack_events(&mut self) -> Result<Result<Reply, CommandError>, RawError> {
        let upto = self.events_rx.ack_upto();
        self.call(Command::AckEvents { upto })
    }
}
