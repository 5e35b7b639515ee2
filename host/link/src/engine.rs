//! The link's engine task: owns the sequence number, the RTT estimate and the
//! event receiver; sends one command at a time (stop and wait), retransmits on
//! timeout, interleaves heartbeats and event acknowledgements between
//! commands, and recovers from MCU resets without re-issuing anything.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use protocol::seq::EventReceiver;
use protocol::{
    Command, CommandError, Event, FrameError, HostFrame, Identity, MAX_FRAME, McuFrame,
    PROTOCOL_VERSION, Reply, SCHEMA_HASH, Status, encode_frame,
};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::time::{sleep, sleep_until};

use crate::rto::RttEstimator;
use crate::{LinkConfig, LinkError, LinkEvent, LinkStats};

/// Out-of-order events kept while waiting for a missing one.
const MAX_HELD: usize = 64;

/// Acknowledge before the next command once this many events are unacknowledged
/// (the firmware's queue holds 32).
const ACK_EAGER: u16 = 8;

/// What the reader and writer tasks tell the engine.
pub(crate) enum FromWire {
    Frame(McuFrame),
    Bad(FrameError),
    Closed(String),
}

pub(crate) struct Request {
    pub command: Command,
    pub reply: oneshot::Sender<Result<Reply, LinkError>>,
}

/// State the handle reads without a round trip.
#[derive(Default)]
pub(crate) struct Shared {
    pub identity: Option<Identity>,
    pub status: Option<Status>,
    /// Newest MotionDone per axis: (eseq, position_steps, homed).
    pub motion_done: [Option<(u16, i32, bool)>; 2],
    /// Newest SweepDone: (eseq, completed).
    pub sweep_done: Option<(u16, bool)>,
    /// Newest event delivered (this boot), so a reconnect goes on from it.
    pub delivered_upto: Option<u16>,
    /// A reset noticed between calls, reported once to the next caller.
    pub pending_reset: Option<LinkError>,
    pub stats: LinkStats,
}

pub(crate) struct Engine {
    pub config: LinkConfig,
    pub shared: Arc<Mutex<Shared>>,
    pub events: broadcast::Sender<LinkEvent>,
    pub out: mpsc::UnboundedSender<Vec<u8>>,
    pub wire: mpsc::Receiver<FromWire>,
    pub requests: mpsc::Receiver<Request>,
    pub beats: mpsc::Receiver<()>,
    pub seq: u16,
    pub rtt: RttEstimator,
    pub receiver: EventReceiver,
    /// Newest event sequence acknowledged to the MCU.
    pub acked: u16,
    /// Identified and status read since the last (re)boot seen.
    pub synced: bool,
    /// Events after a gap, waiting for the missing one: (eseq, at_us, event).
    pub held: Vec<(u16, u64, Event)>,
    /// Since when the oldest gap has been open.
    pub gap_since: Option<Instant>,
    /// The gap is older than the timeout: a status read decides.
    pub gap_check_due: bool,
    /// Numbering already re-based on this new boot's Booted event.
    pub booted_base: Option<u32>,
    pub boot_id: Option<u32>,
    pub dropped_seen: u16,
    pub active_moves: [Option<Command>; 2],
    pub active_sweep: Option<Command>,
    /// A Booted event (or a boot id change) was seen and not yet handled.
    pub reset_seen: bool,
    pub dead: Option<String>,
    /// The handle ended this session on purpose (`reconnect()`, `close()`):
    /// the stream closing is not news for the subscribers.
    pub retired: Arc<AtomicBool>,
    /// Since when frames have been sent with nothing at all received back.
    pub silent_since: Option<Instant>,
    /// When the MCU last answered a heartbeat.
    pub last_beat: Option<Instant>,
}

impl Engine {
    fn stats(&self, f: impl FnOnce(&mut LinkStats)) {
        if let Ok(mut s) = self.shared.lock() {
            f(&mut s.stats);
        }
    }

    /// The engine loop: until every handle is dropped.
    pub async fn run(mut self) {
        loop {
            if self.reset_seen && self.dead.is_none() {
                let err = self.recover_reset(None).await;
                self.report_pending(err);
            }
            if self.gap_check_due && self.synced && self.dead.is_none() {
                self.resolve_gap().await;
            }
            let gap_deadline = self
                .gap_since
                .map(|t| tokio::time::Instant::from_std(t + self.config.event_gap_timeout));
            let alive = self.dead.is_none();
            let ack_due = alive && self.synced && self.receiver.ack_upto() != self.acked;
            tokio::select! {
                biased;
                msg = self.wire.recv(), if alive => self.on_wire_idle(msg),
                Some(()) = self.beats.recv(), if alive => {
                    if self.synced {
                        self.heartbeat().await;
                    }
                }
                _ = sleep(self.config.ack_delay), if ack_due => self.heartbeat().await,
                _ = sleep_until(gap_deadline.unwrap_or_else(tokio::time::Instant::now)), if gap_deadline.is_some() && alive => self.check_gap(),
                req = self.requests.recv() => match req {
                    None => break,
                    Some(r) => {
                        let res = self.call(r.command).await;
                        let _ = r.reply.send(res);
                    }
                },
            }
        }
    }

    fn report_pending(&mut self, err: LinkError) {
        if let Ok(mut s) = self.shared.lock() {
            s.pending_reset = Some(err);
        }
    }

    fn on_wire_idle(&mut self, msg: Option<FromWire>) {
        if matches!(msg, Some(FromWire::Frame(_) | FromWire::Bad(_))) {
            self.silent_since = None;
        }
        match msg {
            None => self.die("reader stopped".into()),
            Some(FromWire::Closed(reason)) => self.die(reason),
            Some(FromWire::Bad(e)) => self.bad_frame(e),
            Some(FromWire::Frame(McuFrame::Ack { .. })) => self.stats(|s| s.stale_acks += 1),
            Some(FromWire::Frame(McuFrame::Event { eseq, at_us, event })) => {
                self.on_event(eseq, at_us, event)
            }
        }
    }

    fn bad_frame(&self, e: FrameError) {
        tracing::debug!("dropped a frame: {e}");
        self.stats(|s| s.bad_frames += 1);
    }

    fn die(&mut self, reason: String) {
        if self.dead.is_none() && self.retired.load(Ordering::SeqCst) {
            self.dead = Some(reason);
            self.synced = false;
        } else if self.dead.is_none() {
            // "reader stopped" is the runtime shutting down, not news.
            if reason == "reader stopped" {
                tracing::debug!("link lost: {reason}");
            } else {
                tracing::warn!("link lost: {reason}");
            }
            let _ = self.events.send(LinkEvent::Disconnected {
                reason: reason.clone(),
            });
            self.dead = Some(reason);
            self.synced = false;
        }
    }

    fn disconnected(&self) -> LinkError {
        LinkError::Disconnected {
            reason: self.dead.clone().unwrap_or_else(|| "closed".into()),
        }
    }

    /// One command, stop and wait: send, retransmit until the matching answer
    /// arrives, return it. Events arriving meanwhile are handled.
    ///
    /// A read-only command (`Status`, `AckEvents`) that is still retrying when
    /// a heartbeat falls due steps aside: the heartbeat goes first (the MCU
    /// only counts executed heartbeats, and a large answer on a damaged line
    /// may take many tries), then the command is sent again under a new
    /// sequence number. Anything else keeps its number until answered, so it
    /// never executes twice.
    async fn transact(
        &mut self,
        command: &Command,
    ) -> Result<Result<Reply, CommandError>, LinkError> {
        let first_sent = Instant::now();
        let rereadable = matches!(command, Command::Status | Command::AckEvents { .. });
        loop {
            let beat_due = (rereadable && self.synced)
                .then(|| self.last_beat.unwrap_or(first_sent) + self.config.heartbeat_interval);
            match self
                .send_until_answered(command, first_sent, beat_due)
                .await?
            {
                Some(answer) => return Ok(answer),
                None => {
                    self.stats(|s| s.heartbeats_first += 1);
                    // Boxed: a heartbeat is itself a transaction (never re-read).
                    Box::pin(self.heartbeat()).await;
                    if self.dead.is_some() {
                        return Err(self.disconnected());
                    }
                }
            }
        }
    }

    /// One sequence number: transmit `command` until its answer arrives.
    /// `None` if `beat_due` passed before a retransmission (the caller sends
    /// a heartbeat and the command again).
    ///
    /// A timeout after which a damaged frame arrived is line damage (the
    /// answer was probably hit): retransmit at once, no back-off, and it does
    /// not count against `tries`. A timeout with nothing damaged is a silent
    /// try: back off, and `tries` of them end in `Timeout`. Whatever the line
    /// does, the command ends `answer_timeout` after `first_sent`, and if
    /// nothing at all arrives for `silence_timeout` the MCU is declared gone
    /// (the link dies).
    async fn send_until_answered(
        &mut self,
        command: &Command,
        first_sent: Instant,
        beat_due: Option<Instant>,
    ) -> Result<Option<Result<Reply, CommandError>>, LinkError> {
        if self.dead.is_some() {
            return Err(self.disconnected());
        }
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let mut buf = [0u8; MAX_FRAME];
        let frame = HostFrame {
            seq,
            command: command.clone(),
        };
        let n = encode_frame(&frame, &mut buf)
            .map_err(|e| LinkError::BadArgument(format!("cannot encode {command:?}: {e}")))?;
        let bytes = &buf[..n];
        let give_up_at = first_sent + self.config.answer_timeout;
        let mut tries = 0;
        let mut silent_tries = 0;
        loop {
            if tries > 0 && beat_due.is_some_and(|t| Instant::now() >= t) {
                return Ok(None);
            }
            tries += 1;
            let sent_at = Instant::now();
            tracing::trace!("send {command:?} seq {seq} try {tries}");
            self.silent_since.get_or_insert(sent_at);
            // A leading delimiter flushes any garbage the MCU's decoder holds.
            let mut wire = Vec::with_capacity(n + 1);
            wire.push(0);
            wire.extend_from_slice(bytes);
            if self.out.send(wire).is_err() {
                self.die("writer stopped".into());
                return Err(self.disconnected());
            }
            self.stats(|s| {
                s.transmissions += 1;
                if tries > 1 {
                    s.retransmissions += 1;
                }
            });
            let rto = self.rtt.rto();
            let wait = self.retransmit_wait(command, rto);
            let mut retransmit_at = sent_at + wait;
            let mut damaged = false;
            loop {
                let wake = retransmit_at.min(self.silence_deadline()).min(give_up_at);
                tokio::select! {
                    msg = self.wire.recv() => {
                        if matches!(msg, Some(FromWire::Frame(_) | FromWire::Bad(_))) {
                            self.silent_since = None;
                        }
                        match msg {
                            None => {
                                self.die("reader stopped".into());
                                return Err(self.disconnected());
                            }
                            Some(FromWire::Closed(reason)) => {
                                self.die(reason);
                                return Err(self.disconnected());
                            }
                            Some(FromWire::Bad(e)) => {
                                self.bad_frame(e);
                                // Give a frame still on its way a moment, then resend.
                                damaged = true;
                                retransmit_at = retransmit_at
                                    .min(Instant::now() + self.config.min_rto);
                            }
                            Some(FromWire::Frame(McuFrame::Ack { seq: s, result })) if s == seq => {
                                if tries == 1 {
                                    // Karn: only unambiguous round trips are samples.
                                    self.rtt.sample(sent_at.elapsed());
                                }
                                if matches!(command, Command::Heartbeat { .. }) {
                                    self.last_beat = Some(Instant::now());
                                }
                                tracing::trace!("answer to seq {seq} after {tries} tries");
                                return Ok(Some(result));
                            }
                            Some(FromWire::Frame(McuFrame::Ack { .. })) => {
                                self.stats(|s| s.stale_acks += 1)
                            }
                            Some(FromWire::Frame(McuFrame::Event { eseq, at_us, event })) => {
                                self.on_event(eseq, at_us, event)
                            }
                        }
                    }
                    _ = sleep_until(tokio::time::Instant::from_std(wake)) => break,
                }
            }
            let now = Instant::now();
            if now >= self.silence_deadline() {
                self.stats(|s| s.timeouts += 1);
                self.die(format!(
                    "the MCU stopped answering (nothing received for {:.1} s)",
                    self.config.silence_timeout.as_secs_f64()
                ));
                return Err(self.disconnected());
            }
            // A keep-alive resend (cut short of the RTO) is not a silent try:
            // a silent MCU meets `silence_timeout` instead.
            if !damaged && wait == rto {
                self.rtt.backoff();
                silent_tries += 1;
            }
            if now >= give_up_at || silent_tries >= self.config.tries {
                self.stats(|s| s.timeouts += 1);
                return Err(LinkError::Timeout {
                    command: command.clone(),
                    tries,
                });
            }
        }
    }

    /// How long to wait for the answer to `command` before sending it again.
    ///
    /// The MCU faults if it hears no valid frame for 250 ms while a motor
    /// moves or the laser is armed, and counts a retransmission as heard. A
    /// command answered with a short `Ok` (all but `Status` and `Identify`)
    /// is therefore resent at least every quarter heartbeat interval (never
    /// sooner than two round trips): on a damaged line that puts a dozen
    /// tries into the MCU's window instead of two or three at the RTO. A
    /// long answer keeps the RTO, which a slow line's largest frame sets.
    fn retransmit_wait(&self, command: &Command, rto: Duration) -> Duration {
        if matches!(command, Command::Status | Command::Identify) {
            return rto;
        }
        let keepalive = (self.config.heartbeat_interval / 4)
            .max(2 * self.rtt.srtt().unwrap_or(self.config.initial_rto));
        rto.min(keepalive)
    }

    /// When the MCU counts as gone: `silence_timeout` after the first frame
    /// sent since anything at all was received.
    fn silence_deadline(&self) -> Instant {
        self.silent_since.unwrap_or_else(Instant::now) + self.config.silence_timeout
    }

    /// A user call: make sure the link is identified, send, interpret.
    async fn call(&mut self, mut command: Command) -> Result<Reply, LinkError> {
        if let Some(err) = self
            .shared
            .lock()
            .ok()
            .and_then(|mut s| s.pending_reset.take())
        {
            return Err(err);
        }
        if self.dead.is_some() {
            return Err(self.disconnected());
        }
        self.stats(|s| s.commands += 1);
        if !self.synced {
            self.sync().await?;
            if command == Command::Identify {
                return self.identity_reply();
            }
        }
        match command {
            Command::Identify => {
                let id = self.handshake().await?;
                if self.boot_id != Some(id.boot_id) {
                    return Err(self.recover_reset(None).await);
                }
                return Ok(Reply::Identity(id));
            }
            Command::Heartbeat { ref mut event_ack } => *event_ack = self.receiver.ack_upto(),
            Command::Reset => return self.reset().await,
            _ => {}
        }
        if self.gap_check_due {
            self.resolve_gap().await;
        }
        // Keep the MCU's bounded event queue short under a stream of commands.
        if self.receiver.ack_upto().wrapping_sub(self.acked) >= ACK_EAGER {
            self.heartbeat().await;
        }
        let mut resynced = false;
        loop {
            match self.transact(&command).await? {
                Ok(reply) => {
                    self.after_ok(&command, &reply);
                    if self.reset_seen {
                        let interrupted = has_effect(&command).then(|| command.clone());
                        return Err(self.recover_reset(interrupted).await);
                    }
                    return Ok(reply);
                }
                Err(CommandError::NotIdentified) => {
                    return Err(self.recover_reset(Some(command)).await);
                }
                // Refused, hence not executed: resend once under the number
                // the MCU expects (after a command we gave up on).
                Err(CommandError::OutOfSequence { expected }) if !resynced => {
                    self.stats(|s| s.resyncs += 1);
                    self.seq = expected.wrapping_sub(1);
                    resynced = true;
                }
                Err(error) => return Err(LinkError::Refused { command, error }),
            }
        }
    }

    fn identity_reply(&self) -> Result<Reply, LinkError> {
        self.shared
            .lock()
            .ok()
            .and_then(|s| s.identity.clone())
            .map(Reply::Identity)
            .ok_or(LinkError::UnexpectedReply {
                command: Command::Identify,
            })
    }

    /// Bookkeeping after a successful command.
    fn after_ok(&mut self, command: &Command, reply: &Reply) {
        match command {
            Command::Move { axis, .. } | Command::Home { axis } => {
                self.active_moves[axis.index()] = Some(command.clone())
            }
            Command::GalvoSweep(_) => self.active_sweep = Some(command.clone()),
            Command::Heartbeat { event_ack } | Command::AckEvents { upto: event_ack } => {
                self.acked = *event_ack
            }
            _ => {}
        }
        if let Reply::Status(status) = reply {
            self.note_status(status);
        }
    }

    fn note_status(&mut self, status: &Status) {
        if self.boot_id.is_some_and(|b| b != status.boot_id) {
            self.reset_seen = true;
        }
        if status.events_dropped != self.dropped_seen {
            let count = status.events_dropped.wrapping_sub(self.dropped_seen);
            tracing::warn!("the MCU dropped {count} events (queue full)");
            let _ = self.events.send(LinkEvent::EventsDropped {
                total: status.events_dropped,
            });
            self.dropped_seen = status.events_dropped;
        }
        if let Ok(mut s) = self.shared.lock() {
            s.status = Some(*status);
        }
    }

    /// Identify and check the peer; does not change the sync state.
    async fn handshake(&mut self) -> Result<Identity, LinkError> {
        // A stale cached answer (our sequence equals the MCU's last one from a
        // previous session) is not an Identity: the next number executes.
        for _ in 0..3 {
            match self.transact(&Command::Identify).await? {
                Ok(Reply::Identity(id)) => {
                    if id.protocol_version != PROTOCOL_VERSION {
                        return Err(LinkError::VersionMismatch {
                            mcu: id.protocol_version,
                            host: PROTOCOL_VERSION,
                        });
                    }
                    if id.schema_hash != SCHEMA_HASH {
                        return Err(LinkError::SchemaMismatch {
                            mcu: id.schema_hash,
                            host: SCHEMA_HASH,
                        });
                    }
                    if let Ok(mut s) = self.shared.lock() {
                        s.identity = Some(id.clone());
                    }
                    return Ok(id);
                }
                Ok(_) => continue,
                Err(error) => {
                    return Err(LinkError::Refused {
                        command: Command::Identify,
                        error,
                    });
                }
            }
        }
        Err(LinkError::UnexpectedReply {
            command: Command::Identify,
        })
    }

    /// Handshake, then read the status; re-base event numbering on a new boot.
    async fn sync(&mut self) -> Result<Status, LinkError> {
        self.synced = false;
        let id = self.handshake().await?;
        let status = match self.transact(&Command::Status).await? {
            Ok(Reply::Status(s)) => s,
            Ok(_) => {
                return Err(LinkError::UnexpectedReply {
                    command: Command::Status,
                });
            }
            Err(error) => {
                return Err(LinkError::Refused {
                    command: Command::Status,
                    error,
                });
            }
        };
        if self.boot_id != Some(id.boot_id) {
            // New numbering: deliver from here on. Events raised before this
            // handshake are not delivered (the status just read holds their
            // effect); acknowledge them so the MCU stops re-sending.
            if self.booted_base.take() != Some(id.boot_id) {
                self.receiver.reset(status.last_eseq);
                if let Ok(mut s) = self.shared.lock() {
                    s.delivered_upto = Some(status.last_eseq);
                }
                self.acked = status.last_eseq.wrapping_sub(1);
            }
            self.held.clear();
            self.gap_since = None;
            self.dropped_seen = status.events_dropped;
            self.boot_id = Some(id.boot_id);
        }
        self.reset_seen = false;
        self.synced = true;
        self.note_status(&status);
        Ok(status)
    }

    /// The MCU was reset: re-sync and build the report for the caller.
    async fn recover_reset(&mut self, in_flight: Option<Command>) -> LinkError {
        self.stats(|s| s.resets += 1);
        let interrupted = in_flight
            .or_else(|| self.active_sweep.take())
            .or_else(|| self.active_moves.iter_mut().find_map(Option::take));
        self.active_sweep = None;
        self.active_moves = [None, None];
        tracing::warn!("MCU reset detected (interrupted: {interrupted:?}); re-identifying");
        match self.sync().await {
            Ok(status) => {
                let _ = self.events.send(LinkEvent::DeviceReset {
                    interrupted: interrupted.clone(),
                    status: Box::new(status),
                });
                LinkError::DeviceReset {
                    interrupted,
                    status: Box::new(status),
                }
            }
            Err(e) => e,
        }
    }

    /// `Reset` on purpose: send it, then identify until the new boot answers.
    async fn reset(&mut self) -> Result<Reply, LinkError> {
        match self.transact(&Command::Reset).await? {
            Ok(_) => {}
            Err(CommandError::NotIdentified) => {
                // Already reset by itself: report, do not reset twice.
                return Err(self.recover_reset(Some(Command::Reset)).await);
            }
            Err(error) => {
                return Err(LinkError::Refused {
                    command: Command::Reset,
                    error,
                });
            }
        }
        let old = self.boot_id;
        self.synced = false;
        self.active_sweep = None;
        self.active_moves = [None, None];
        for _ in 0..self.config.tries.max(1) * 4 {
            let id = self.handshake().await?;
            if Some(id.boot_id) != old {
                self.sync().await?;
                return self.identity_reply();
            }
            sleep(self.config.min_rto).await;
        }
        Err(LinkError::Timeout {
            command: Command::Reset,
            tries: self.config.tries,
        })
    }

    async fn heartbeat(&mut self) {
        let ack = self.receiver.ack_upto();
        let mut answer = self.transact(&Command::Heartbeat { event_ack: ack }).await;
        if let Ok(Err(CommandError::OutOfSequence { expected })) = answer {
            // The command before it never arrived (a read-only one that let
            // this heartbeat go first): refused, not executed, so send it
            // again at once under the expected number.
            self.stats(|s| s.resyncs += 1);
            self.seq = expected.wrapping_sub(1);
            answer = self.transact(&Command::Heartbeat { event_ack: ack }).await;
        }
        match answer {
            Ok(Ok(_)) => self.acked = ack,
            Ok(Err(CommandError::NotIdentified)) => {
                let err = self.recover_reset(None).await;
                self.report_pending(err);
            }
            Ok(Err(CommandError::OutOfSequence { expected })) => {
                self.stats(|s| s.resyncs += 1);
                self.seq = expected.wrapping_sub(1);
            }
            Ok(Err(e)) => tracing::warn!("heartbeat refused: {e:?}"),
            // Already logged where the link died.
            Err(LinkError::Disconnected { .. }) => {}
            Err(e) => {
                self.stats(|s| s.heartbeat_failures += 1);
                tracing::warn!("heartbeat failed: {e}");
            }
        }
    }

    /// An event frame arrived: deliver in order exactly once. A frame lost
    /// on the line leaves a gap: later events wait in `held` (and are not
    /// acknowledged) until the MCU re-sends the missing one. Only when the
    /// MCU's status confirms it dropped events is the gap skipped and reported.
    fn on_event(&mut self, eseq: u16, at_us: u64, event: Event) {
        if !self.synced {
            // Not yet re-based on this boot's numbering: the MCU re-sends.
            return;
        }
        self.stats(|s| s.events += 1);
        if let Event::Booted { boot_id, .. } = event
            && self.boot_id != Some(boot_id)
        {
            // A new boot numbers from 1 again: start over at its Booted event.
            self.receiver.reset(eseq.wrapping_sub(1));
            self.held.clear();
            self.gap_since = None;
            self.booted_base = Some(boot_id);
            self.reset_seen = true;
        }
        let d = eseq.wrapping_sub(self.receiver.ack_upto());
        if d == 0 || d >= 0x8000 || self.held.iter().any(|h| h.0 == eseq) {
            self.stats(|s| s.duplicate_events += 1);
            return;
        }
        if d == 1 {
            self.deliver(eseq, at_us, event);
            self.drain_held();
        } else {
            if self.held.len() < MAX_HELD {
                self.held.push((eseq, at_us, event));
            }
            self.gap_since.get_or_insert_with(Instant::now);
        }
        self.check_gap();
    }

    /// Deliver held events that are now next in order.
    fn drain_held(&mut self) {
        let mut progressed = false;
        loop {
            let last = self.receiver.ack_upto();
            self.held.retain(|h| {
                let d = h.0.wrapping_sub(last);
                d != 0 && d < 0x8000
            });
            let next = last.wrapping_add(1);
            match self.held.iter().position(|h| h.0 == next) {
                Some(i) => {
                    let (eseq, at_us, event) = self.held.remove(i);
                    self.deliver(eseq, at_us, event);
                    progressed = true;
                }
                None => break,
            }
        }
        if self.held.is_empty() {
            self.gap_since = None;
        } else if progressed || self.gap_since.is_none() {
            self.gap_since = Some(Instant::now());
        }
    }

    /// A gap older than the timeout: ask the MCU whether it dropped events.
    fn check_gap(&mut self) {
        if self
            .gap_since
            .is_some_and(|t| t.elapsed() >= self.config.event_gap_timeout)
        {
            self.gap_check_due = true;
        }
    }

    /// The MCU confirmed dropped events: skip to the oldest held one.
    fn skip_gap(&mut self) {
        let last = self.receiver.ack_upto();
        let Some(first) = self
            .held
            .iter()
            .map(|h| h.0)
            .min_by_key(|e| e.wrapping_sub(last))
        else {
            return;
        };
        let count = first.wrapping_sub(last).wrapping_sub(1);
        tracing::warn!("{count} events lost before eseq {first} (MCU queue overflow)");
        let _ = self.events.send(LinkEvent::EventsMissed {
            before: first,
            count,
        });
        self.receiver.reset(first.wrapping_sub(1));
        self.drain_held();
    }

    /// Resolve a stale gap with a status read (idle loop and before calls).
    async fn resolve_gap(&mut self) {
        self.gap_check_due = false;
        let before = self.dropped_seen;
        if let Ok(Ok(Reply::Status(status))) = self.transact(&Command::Status).await {
            self.note_status(&status);
            if status.events_dropped != before {
                self.skip_gap();
                return;
            }
        }
        // Not dropped: the MCU will re-send; look again after another timeout.
        if !self.held.is_empty() {
            self.gap_since = Some(Instant::now());
        }
    }

    fn deliver(&mut self, eseq: u16, at_us: u64, event: Event) {
        self.receiver.accept(eseq);
        if let Ok(mut s) = self.shared.lock() {
            s.delivered_upto = Some(eseq);
        }
        match event {
            Event::MotionDone {
                axis,
                position_steps,
                homed,
            } => {
                self.active_moves[axis.index()] = None;
                if let Ok(mut s) = self.shared.lock() {
                    s.motion_done[axis.index()] = Some((eseq, position_steps, homed));
                }
            }
            Event::SweepDone { completed } => {
                self.active_sweep = None;
                if let Ok(mut s) = self.shared.lock() {
                    s.sweep_done = Some((eseq, completed));
                }
            }
            Event::Fault { cause } => {
                tracing::warn!("MCU fault: {}", crate::error::fault_name(&cause))
            }
            _ => {}
        }
        let _ = self.events.send(LinkEvent::Mcu { eseq, at_us, event });
    }
}

/// Commands whose effect a reset undoes (worth reporting as interrupted).
fn has_effect(c: &Command) -> bool {
    !matches!(
        c,
        Command::Identify | Command::Heartbeat { .. } | Command::AckEvents { .. } | Command::Status
    )
}
