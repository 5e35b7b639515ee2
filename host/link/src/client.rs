//! The cloneable link handle: opening, typed calls, event subscription and the
//! event-driven wait helpers.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use protocol::seq::seq_after;
use protocol::{
    Axis, Command, Event, FrameDecoder, Identity, LaserColour, McuFrame, MoveTarget, Reply, Status,
    Sweep,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::task::JoinHandle;

use crate::engine::{Engine, FromWire, Request, Shared};

/// A heartbeat tick this late (wall time) is reported as a stall of the process.
const STALL_WARNING: std::time::Duration = std::time::Duration::from_millis(100);
use crate::rto::RttEstimator;
use crate::transport::{BoxStream, Connector, serial_connector};
use crate::{LinkConfig, LinkError};

/// What subscribers receive.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkEvent {
    /// An MCU event, delivered once, in order.
    Mcu { eseq: u16, at_us: u64, event: Event },
    /// Events before `before` never arrived: the MCU's queue overflowed.
    EventsMissed { before: u16, count: u16 },
    /// The MCU's status reports this many events dropped since boot.
    EventsDropped { total: u16 },
    /// The MCU was reset; the link re-identified. See `LinkError::DeviceReset`.
    DeviceReset {
        interrupted: Option<Command>,
        status: Box<Status>,
    },
    /// The byte stream ended.
    Disconnected { reason: String },
}

/// Counters of the link's life, for tests, benchmarks and `rig status`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkStats {
    pub commands: u64,
    pub transmissions: u64,
    pub retransmissions: u64,
    pub timeouts: u64,
    pub bad_frames: u64,
    pub stale_acks: u64,
    pub events: u64,
    pub duplicate_events: u64,
    pub resyncs: u64,
    pub resets: u64,
    pub heartbeat_failures: u64,
    /// Read-only commands that let a due heartbeat go first while retrying.
    pub heartbeats_first: u64,
}

/// Where a move or homing ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotionDone {
    pub position_steps: i32,
    pub homed: bool,
}

/// A subscription to link events.
pub struct EventStream {
    rx: broadcast::Receiver<LinkEvent>,
}

impl EventStream {
    /// The next event; `LinkError::Lagged` if this subscriber fell behind the
    /// broadcast capacity (the events themselves were delivered to the link).
    pub async fn recv(&mut self) -> Result<LinkEvent, LinkError> {
        match self.rx.recv().await {
            Ok(e) => Ok(e),
            Err(broadcast::error::RecvError::Lagged(n)) => Err(LinkError::Lagged(n)),
            Err(broadcast::error::RecvError::Closed) => Err(LinkError::Disconnected {
                reason: "link closed".into(),
            }),
        }
    }

    /// The next event if one is waiting.
    pub fn try_recv(&mut self) -> Option<Result<LinkEvent, LinkError>> {
        match self.rx.try_recv() {
            Ok(e) => Some(Ok(e)),
            Err(broadcast::error::TryRecvError::Lagged(n)) => Some(Err(LinkError::Lagged(n))),
            Err(_) => None,
        }
    }
}

struct Session {
    requests: mpsc::Sender<Request>,
    /// Engine first: it goes before the reader and writer it watches.
    tasks: Vec<JoinHandle<()>>,
    /// Set before the tasks stop, so the engine does not report its stream's
    /// end to the subscribers as a lost link (they outlive the session).
    retired: Arc<AtomicBool>,
}

impl Drop for Session {
    fn drop(&mut self) {
        self.retired.store(true, Ordering::SeqCst);
        for t in &self.tasks {
            t.abort();
        }
    }
}

struct Inner {
    config: LinkConfig,
    shared: Arc<Mutex<Shared>>,
    events: broadcast::Sender<LinkEvent>,
    connector: Option<Connector>,
    session: Mutex<Option<Session>>,
    /// Sequence to continue from on reconnect.
    seq: Mutex<u16>,
}

/// Handle to the rig MCU. Clone it freely; calls from several clones are
/// queued and sent one at a time.
#[derive(Clone)]
pub struct Link {
    inner: Arc<Inner>,
}

impl Link {
    /// Open a serial device (or the emulator's pseudo-terminal) and handshake.
    pub async fn open_serial(path: &str, baud: u32, config: LinkConfig) -> Result<Link, LinkError> {
        Self::open_with(serial_connector(path, baud), config).await
    }

    /// Run over an already open stream (e.g. the emulator's in-process link).
    /// Such a link cannot `reconnect()`.
    pub async fn open_stream(stream: BoxStream, config: LinkConfig) -> Result<Link, LinkError> {
        let link = Self::new(None, config);
        link.start(stream);
        link.identify().await?;
        Ok(link)
    }

    /// Open with a connector that `reconnect()` calls again.
    pub async fn open_with(connector: Connector, config: LinkConfig) -> Result<Link, LinkError> {
        let stream = connector().await?;
        let link = Self::new(Some(connector), config);
        link.start(stream);
        link.identify().await?;
        Ok(link)
    }

    fn new(connector: Option<Connector>, config: LinkConfig) -> Link {
        let (events, _) = broadcast::channel(config.event_capacity.max(16));
        // Start from a number unlikely to equal the MCU's last one from an
        // earlier session (the handshake copes if it does).
        let seed = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.subsec_nanos() ^ std::process::id())
            .unwrap_or(0) as u16;
        Link {
            inner: Arc::new(Inner {
                config,
                shared: Arc::new(Mutex::new(Shared::default())),
                events,
                connector,
                session: Mutex::new(None),
                seq: Mutex::new(seed),
            }),
        }
    }

    /// Spawn reader, writer, heartbeat and engine tasks over `stream`.
    fn start(&self, stream: BoxStream) {
        let config = self.inner.config.clone();
        let (mut rd, mut wr) = tokio::io::split(stream);
        let (wire_tx, wire_rx) = mpsc::channel::<FromWire>(1024);
        let (out_tx, mut out_rx) = mpsc::unbounded_channel::<Vec<u8>>();
        let (req_tx, req_rx) = mpsc::channel::<Request>(64);
        let (beat_tx, beat_rx) = mpsc::channel::<()>(1);

        let reader_tx = wire_tx.clone();
        let reader = tokio::spawn(async move {
            let mut decoder = FrameDecoder::new();
            let mut buf = [0u8; 512];
            loop {
                let n = match rd.read(&mut buf).await {
                    Ok(0) => {
                        let _ = reader_tx
                            .send(FromWire::Closed("end of stream".into()))
                            .await;
                        return;
                    }
                    Ok(n) => n,
                    Err(e) => {
                        let _ = reader_tx.send(FromWire::Closed(e.to_string())).await;
                        return;
                    }
                };
                for &b in &buf[..n] {
                    let msg = match decoder.push::<McuFrame>(b) {
                        None => continue,
                        Some(Ok(frame)) => FromWire::Frame(frame),
                        Some(Err(e)) => FromWire::Bad(e),
                    };
                    if reader_tx.send(msg).await.is_err() {
                        return;
                    }
                }
            }
        });
        let writer_err = wire_tx;
        let writer = tokio::spawn(async move {
            while let Some(bytes) = out_rx.recv().await {
                let r = async {
                    wr.write_all(&bytes).await?;
                    wr.flush().await
                }
                .await;
                if let Err(e) = r {
                    let _ = writer_err.send(FromWire::Closed(e.to_string())).await;
                    return;
                }
            }
        });
        let interval = config.heartbeat_interval;
        let heart = tokio::spawn(async move {
            let mut tick = tokio::time::interval(interval);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                let due = tick.tick().await;
                // A tick this late means the process itself was not running
                // (an overloaded machine): the MCU heard nothing meanwhile and
                // may fault for it. Say so, so the fault has its cause.
                let late = due.elapsed();
                if late >= STALL_WARNING {
                    tracing::warn!(
                        "this process did not run for {:.2} s (machine overloaded?): the MCU \
                         faults when it hears nothing for 250 ms while a motor moves or the laser is armed",
                        late.as_secs_f64() + interval.as_secs_f64()
                    );
                }
                if let Err(mpsc::error::TrySendError::Closed(_)) = beat_tx.try_send(()) {
                    return;
                }
            }
        });
        let seq = *self.inner.seq.lock().unwrap_or_else(|p| p.into_inner());
        // A reconnect to the same boot goes on delivering after the last
        // event delivered (the MCU re-sends the unacknowledged ones).
        let delivered = self.inner.shared.lock().ok().and_then(|s| s.delivered_upto);
        let mut receiver = protocol::seq::EventReceiver::default();
        if let Some(upto) = delivered {
            receiver.reset(upto);
        }
        let retired = Arc::new(AtomicBool::new(false));
        let engine = Engine {
            retired: retired.clone(),
            rtt: RttEstimator::new(config.initial_rto, config.min_rto, config.max_rto),
            config,
            shared: self.inner.shared.clone(),
            events: self.inner.events.clone(),
            out: out_tx,
            wire: wire_rx,
            requests: req_rx,
            beats: beat_rx,
            seq,
            receiver,
            acked: delivered.unwrap_or(0),
            synced: false,
            held: Vec::new(),
            gap_since: None,
            gap_check_due: false,
            booted_base: None,
            boot_id: self
                .inner
                .shared
                .lock()
                .ok()
                .and_then(|s| s.identity.as_ref().map(|i| i.boot_id)),
            dropped_seen: 0,
            active_moves: [None, None],
            active_sweep: None,
            reset_seen: false,
            dead: None,
            silent_since: None,
            last_beat: None,
        };
        let engine = tokio::spawn(engine.run());
        let session = Session {
            requests: req_tx,
            tasks: vec![engine, reader, writer, heart],
            retired,
        };
        *self.inner.session.lock().unwrap_or_else(|p| p.into_inner()) = Some(session);
    }

    /// Drop the current stream and open it again through the connector; the
    /// handle (and its subscribers) stay valid. A reset that happened while
    /// disconnected is reported as `DeviceReset` by this call.
    pub async fn reconnect(&self) -> Result<Identity, LinkError> {
        let connector = self
            .inner
            .connector
            .clone()
            .ok_or(LinkError::ReconnectUnsupported)?;
        // Continue the numbering so the MCU does not mistake our first command
        // for a retransmission.
        let old = self
            .inner
            .session
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        // Wait until the old tasks are gone: they own the device, and a
        // serial port is opened exclusively.
        if let Some(mut old) = old {
            let tasks = std::mem::take(&mut old.tasks);
            // Retired before anything stops: the subscribers stay with the
            // handle and must not read this stream's end as a lost link.
            drop(old);
            for t in tasks {
                t.abort();
                let _ = t.await;
            }
        }
        *self.inner.seq.lock().unwrap_or_else(|p| p.into_inner()) = self.inner.seq_hint();
        let stream = connector().await?;
        self.start(stream);
        self.identify().await
    }

    /// Stop the link's tasks and close the stream; later calls fail with
    /// `Disconnected` until `reconnect()`.
    pub fn close(&self) {
        let session = self
            .inner
            .session
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        drop(session);
    }

    /// Send one command and wait for the MCU's answer.
    pub async fn call(&self, command: Command) -> Result<Reply, LinkError> {
        let requests = {
            let session = self.inner.session.lock().unwrap_or_else(|p| p.into_inner());
            match session.as_ref() {
                Some(s) => s.requests.clone(),
                None => {
                    return Err(LinkError::Disconnected {
                        reason: "not connected".into(),
                    });
                }
            }
        };
        let (tx, rx) = oneshot::channel();
        let gone = || LinkError::Disconnected {
            reason: "link engine stopped".into(),
        };
        requests
            .send(Request { command, reply: tx })
            .await
            .map_err(|_| gone())?;
        rx.await.map_err(|_| gone())?
    }

    async fn call_ok(&self, command: Command) -> Result<(), LinkError> {
        match self.call(command.clone()).await? {
            Reply::Ok => Ok(()),
            _ => Err(LinkError::UnexpectedReply { command }),
        }
    }

    /// Subscribe to link events from now on.
    pub fn subscribe(&self) -> EventStream {
        EventStream {
            rx: self.inner.events.subscribe(),
        }
    }

    /// The identity read at the last handshake.
    pub fn identity(&self) -> Option<Identity> {
        self.inner
            .shared
            .lock()
            .ok()
            .and_then(|s| s.identity.clone())
    }

    /// The status read most recently (by any call).
    pub fn last_status(&self) -> Option<Status> {
        self.inner.shared.lock().ok().and_then(|s| s.status)
    }

    pub fn stats(&self) -> LinkStats {
        self.inner
            .shared
            .lock()
            .map(|s| s.stats)
            .unwrap_or_default()
    }

    pub fn config(&self) -> &LinkConfig {
        &self.inner.config
    }

    // ---- typed calls, one per command ----

    /// Handshake again (checks protocol version and schema hash).
    pub async fn identify(&self) -> Result<Identity, LinkError> {
        match self.call(Command::Identify).await? {
            Reply::Identity(id) => Ok(id),
            _ => Err(LinkError::UnexpectedReply {
                command: Command::Identify,
            }),
        }
    }

    /// An explicit heartbeat (the heartbeat task sends them anyway); it
    /// acknowledges every event delivered so far.
    pub async fn heartbeat(&self) -> Result<(), LinkError> {
        self.call_ok(Command::Heartbeat { event_ack: 0 }).await
    }

    pub async fn status(&self) -> Result<Status, LinkError> {
        match self.call(Command::Status).await? {
            Reply::Status(s) => Ok(s),
            _ => Err(LinkError::UnexpectedReply {
                command: Command::Status,
            }),
        }
    }

    pub async fn home(&self, axis: Axis) -> Result<(), LinkError> {
        self.call_ok(Command::Home { axis }).await
    }

    /// Move with wire units (urad, urad/s, urad/s^2).
    pub async fn move_axis(
        &self,
        axis: Axis,
        target: MoveTarget,
        speed_urad_s: u32,
        accel_urad_s2: u32,
    ) -> Result<(), LinkError> {
        self.call_ok(Command::Move {
            axis,
            target,
            speed_urad_s,
            accel_urad_s2,
        })
        .await
    }

    /// Move in radians (rad/s, rad/s^2; 0 = the axis maximum); `relative`
    /// moves from the current position.
    pub async fn move_rad(
        &self,
        axis: Axis,
        angle: f64,
        relative: bool,
        speed: f64,
        accel: f64,
    ) -> Result<(), LinkError> {
        let a = urad(angle, "angle")?;
        let target = if relative {
            MoveTarget::Relative(a)
        } else {
            MoveTarget::Absolute(a)
        };
        self.move_axis(
            axis,
            target,
            urad_u32(speed, "speed")?,
            urad_u32(accel, "acceleration")?,
        )
        .await
    }

    /// Move in degrees (deg/s, deg/s^2).
    pub async fn move_deg(
        &self,
        axis: Axis,
        angle: f64,
        relative: bool,
        speed: f64,
        accel: f64,
    ) -> Result<(), LinkError> {
        self.move_rad(
            axis,
            angle.to_radians(),
            relative,
            speed.to_radians(),
            accel.to_radians(),
        )
        .await
    }

    pub async fn galvo_set(&self, angle_urad: i32) -> Result<(), LinkError> {
        self.call_ok(Command::GalvoSet { angle_urad }).await
    }

    pub async fn galvo_set_rad(&self, angle: f64) -> Result<(), LinkError> {
        self.galvo_set(urad(angle, "galvo angle")?).await
    }

    pub async fn galvo_sweep(&self, sweep: Sweep) -> Result<(), LinkError> {
        self.call_ok(Command::GalvoSweep(sweep)).await
    }

    pub async fn laser_select(&self, colour: LaserColour) -> Result<(), LinkError> {
        self.call_ok(Command::LaserSelect { colour }).await
    }

    pub async fn laser_power(&self, permille: u16) -> Result<(), LinkError> {
        self.call_ok(Command::LaserPower { permille }).await
    }

    pub async fn laser_arm(&self, armed: bool) -> Result<(), LinkError> {
        self.call_ok(Command::LaserArm { armed }).await
    }

    pub async fn lamps(&self, mask: u8) -> Result<(), LinkError> {
        self.call_ok(Command::Lamps { mask }).await
    }

    pub async fn trigger(&self, mask: u8, pulse_us: u32) -> Result<(), LinkError> {
        self.call_ok(Command::Trigger { mask, pulse_us }).await
    }

    pub async fn abort(&self) -> Result<(), LinkError> {
        self.call_ok(Command::Abort).await
    }

    pub async fn estop(&self) -> Result<(), LinkError> {
        self.call_ok(Command::EStop).await
    }

    pub async fn clear_fault(&self) -> Result<(), LinkError> {
        self.call_ok(Command::ClearFault).await
    }

    /// Reset the MCU on purpose and wait until its new boot is identified.
    pub async fn reset(&self) -> Result<Identity, LinkError> {
        match self.call(Command::Reset).await? {
            Reply::Identity(id) => Ok(id),
            _ => Err(LinkError::UnexpectedReply {
                command: Command::Reset,
            }),
        }
    }

    // ---- waits driven by events ----

    /// Wait until `axis` stops (move or homing finished or aborted). Returns
    /// at once if it is not moving. Fails with `DeviceReset` if the MCU resets.
    pub async fn wait_motion_done(&self, axis: Axis) -> Result<MotionDone, LinkError> {
        let mut events = self.subscribe();
        // The status read closes the race with a MotionDone that came before
        // the subscription: later events are newer than its last_eseq.
        let mut status = self.status().await?;
        loop {
            let a = status.axes[axis.index()];
            if !a.moving && !a.homing {
                return Ok(MotionDone {
                    position_steps: a.position_steps,
                    homed: a.homed,
                });
            }
            let since = status.last_eseq;
            loop {
                match events.recv().await {
                    Ok(LinkEvent::Mcu {
                        eseq,
                        event:
                            Event::MotionDone {
                                axis: done,
                                position_steps,
                                homed,
                            },
                        ..
                    }) if done == axis && seq_after(eseq, since) => {
                        return Ok(MotionDone {
                            position_steps,
                            homed,
                        });
                    }
                    Ok(LinkEvent::DeviceReset {
                        interrupted,
                        status,
                    }) => return Err(self.take_reset(interrupted, status)),
                    Ok(LinkEvent::Disconnected { reason }) => {
                        return Err(LinkError::Disconnected { reason });
                    }
                    // Missed something: ask instead of waiting forever.
                    Ok(LinkEvent::EventsMissed { .. }) | Err(LinkError::Lagged(_)) => break,
                    Ok(_) => {}
                    Err(e) => return Err(e),
                }
            }
            status = self.status().await?;
        }
    }

    /// Wait until the running sweep ends; returns whether it completed (false
    /// if aborted). Returns the last known outcome if no sweep runs.
    pub async fn wait_sweep_done(&self) -> Result<bool, LinkError> {
        let mut events = self.subscribe();
        let mut status = self.status().await?;
        loop {
            if status.sweep_step.is_none() {
                let last = self.inner.shared.lock().ok().and_then(|s| s.sweep_done);
                return Ok(last.is_none_or(|(_, completed)| completed));
            }
            let since = status.last_eseq;
            loop {
                match events.recv().await {
                    Ok(LinkEvent::Mcu {
                        eseq,
                        event: Event::SweepDone { completed },
                        ..
                    }) if seq_after(eseq, since) => return Ok(completed),
                    Ok(LinkEvent::DeviceReset {
                        interrupted,
                        status,
                    }) => return Err(self.take_reset(interrupted, status)),
                    Ok(LinkEvent::Disconnected { reason }) => {
                        return Err(LinkError::Disconnected { reason });
                    }
                    Ok(LinkEvent::EventsMissed { .. }) | Err(LinkError::Lagged(_)) => break,
                    Ok(_) => {}
                    Err(e) => return Err(e),
                }
            }
            status = self.status().await?;
        }
    }

    /// A reset seen by a waiter is reported to it, not again to the next call.
    fn take_reset(&self, interrupted: Option<Command>, status: Box<Status>) -> LinkError {
        if let Ok(mut s) = self.inner.shared.lock() {
            s.pending_reset = None;
        }
        LinkError::DeviceReset {
            interrupted,
            status,
        }
    }

    /// Axis position in radians, from a status and the MCU's advertised steps/rev.
    pub fn position_rad(&self, status: &Status, axis: Axis) -> Option<f64> {
        let id = self.identity()?;
        let spr = id.limits.steps_per_rev[axis.index()];
        (spr > 0).then(|| {
            status.axes[axis.index()].position_steps as f64 * std::f64::consts::TAU / spr as f64
        })
    }
}

impl Inner {
    /// Where the next session's numbering should start: past anything sent.
    fn seq_hint(&self) -> u16 {
        let s = self
            .shared
            .lock()
            .map(|s| s.stats.transmissions)
            .unwrap_or(0);
        (*self.seq.lock().unwrap_or_else(|p| p.into_inner()))
            .wrapping_add(s as u16)
            .wrapping_add(7)
    }
}

fn urad(rad: f64, what: &str) -> Result<i32, LinkError> {
    let u = (rad * 1e6).round();
    if !u.is_finite() || u < i32::MIN as f64 || u > i32::MAX as f64 {
        return Err(LinkError::BadArgument(format!(
            "{what} {rad} rad out of range"
        )));
    }
    Ok(u as i32)
}

fn urad_u32(rad: f64, what: &str) -> Result<u32, LinkError> {
    let u = (rad * 1e6).round();
    if !u.is_finite() || u < 0.0 || u > u32::MAX as f64 {
        return Err(LinkError::BadArgument(format!(
            "{what} {rad} must be in 0..{} (0 = the axis maximum)",
            u32::MAX as f64 / 1e6
        )));
    }
    Ok(u as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_conversion_rejects_bad_values() {
        assert_eq!(urad(1.0, "a").unwrap(), 1_000_000);
        assert_eq!(urad(-0.5e-6, "a").unwrap(), -1);
        assert!(urad(f64::NAN, "a").is_err());
        assert!(urad(3000.0, "a").is_err());
        assert_eq!(urad_u32(0.0, "s").unwrap(), 0);
        assert!(urad_u32(-1.0, "s").is_err());
        assert_eq!(urad_u32(0.25, "s").unwrap(), 250_000);
    }
}
