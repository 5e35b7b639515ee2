//! Running the emulated rig in real time (or a multiple of it) behind an
//! in-process byte stream.
//!
//! A [`SimPort`] lives behind a [`RigHandle`] (shared, locked). A
//! [`VirtualClock`] maps wall time to virtual time: `virtual = wall * speed`,
//! so `speed = 1.0` is real time and `speed = 20.0` runs the rig 20 times
//! faster (the host must then heartbeat 20 times as often in wall time: the
//! MCU's 250 ms heartbeat timeout is virtual time).
//!
//! Two things hold the clock back, so that what the rig sees is what a
//! real rig next to a real host would: a stall of the emulator itself
//! ([`MAX_CATCH_UP_WALL`], [`MAX_CATCH_UP_VIRTUAL_US`]), and, in lockstep
//! (`SimConfig::host_lead_us`), a host that has not written for longer than
//! its lead: a simulated host PC is never descheduled for a quarter second,
//! a host process on a loaded 2-core machine running the rig 50 times
//! faster than real time may be. Motion profiles, dwells and the MCU's own
//! timeouts are untouched: a move takes the rig time it would on the rig,
//! only its wall time shrinks.
//!
//! [`spawn_in_process`] returns the host's end of a `tokio::io::duplex` pair
//! (`AsyncRead + AsyncWrite`) and spawns a tokio task that serves the other
//! end: bytes the host writes go onto the modelled line, bytes the MCU sends
//! come back at the baud rate, with the configured faults. The task ends when
//! the host drops its end, on [`RigHandle::shutdown`], or on a disconnect
//! fault (the host then reads EOF).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::sync::Notify;
use tokio::sync::mpsc::UnboundedReceiver;

use crate::peripherals::{RigState, TriggerEvent};
use crate::port::SimPort;
use crate::{SimConfig, SimError};

/// Longest wall time a driver sleeps without looking at the rig: bounds how
/// late a timed MCU reply (motion done, sweep step) leaves the emulator.
pub const MAX_IDLE_WALL: Duration = Duration::from_millis(1);

/// Longest wall time one catch-up of the rig may cover. The drivers look
/// every millisecond, so a longer gap means the emulator itself was not
/// running (descheduled on a loaded machine, stopped): that is not rig time.
/// A real MCU would have received the bytes that waited meanwhile on time,
/// so the clock resumes where it stood instead of jumping past the
/// heartbeat timeout before it sees them.
pub const MAX_CATCH_UP_WALL: Duration = Duration::from_millis(50);
/// Longest virtual time one catch-up of a free-running rig may cover,
/// whatever the speed: a fifth of the MCU's 250 ms heartbeat timeout (in
/// lockstep the host's lead bounds it instead). At speed 8 a 50 ms stall of the
/// whole process (host and emulated MCU alike) would otherwise be 400 ms of
/// rig time, and the MCU would fault on a host that only paused with it.
pub const MAX_CATCH_UP_VIRTUAL_US: u64 = 50_000;

/// Wall time to virtual time.
#[derive(Debug, Clone, Copy)]
pub struct VirtualClock {
    start: Instant,
    start_us: u64,
    speed: f64,
}

impl VirtualClock {
    /// A clock that reads `start_us` now and runs `speed` times faster than the wall.
    pub fn new(start_us: u64, speed: f64) -> Self {
        Self {
            start: Instant::now(),
            start_us,
            speed,
        }
    }

    pub fn now_us(&self) -> u64 {
        self.start_us + (self.start.elapsed().as_secs_f64() * 1e6 * self.speed) as u64
    }

    pub fn speed(&self) -> f64 {
        self.speed
    }

    /// Wall time until the virtual clock reads `t_us` (zero if past).
    pub fn wall_until(&self, t_us: u64) -> Duration {
        let now = self.now_us();
        let s = t_us.saturating_sub(now) as f64 * 1e-6 / self.speed;
        // A speed of 0 (or NaN) would stop the clock: wait "forever".
        Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX)
    }
}

struct Shared {
    port: Mutex<SimPort>,
    clock: VirtualClock,
    /// Virtual µs the clock was held back (emulator stalls, a late host).
    paused_us: AtomicU64,
    /// Lockstep lead (see `SimConfig::host_lead_us`).
    host_lead_us: Option<u64>,
    /// Virtual time the host last wrote, µs.
    host_wrote_us: AtomicU64,
    stop: AtomicBool,
    wake: Notify,
}

/// Shared access to a rig that a driver runs in real time. Cheap to clone.
#[derive(Clone)]
pub struct RigHandle {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for RigHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RigHandle")
            .field("speed", &self.shared.clock.speed)
            .finish_non_exhaustive()
    }
}

impl RigHandle {
    pub(crate) fn new(port: SimPort, speed: f64, host_lead_us: Option<u64>) -> Self {
        let clock = VirtualClock::new(port.now_us(), speed);
        Self {
            shared: Arc::new(Shared {
                host_wrote_us: AtomicU64::new(port.now_us()),
                port: Mutex::new(port),
                clock,
                paused_us: AtomicU64::new(0),
                host_lead_us,
                stop: AtomicBool::new(false),
                wake: Notify::new(),
            }),
        }
    }

    /// Lock the port after catching it up with the clock.
    fn lock(&self) -> MutexGuard<'_, SimPort> {
        // A panic while locked leaves a consistent SimPort (every method
        // finishes its state change before it can panic), so go on.
        let mut port = self.shared.port.lock().unwrap_or_else(|e| e.into_inner());
        let at = port.now_us();
        let wall = self.wall_us();
        let mut target = wall;
        let mut max_step = (MAX_CATCH_UP_WALL.as_secs_f64() * 1e6 * self.speed()) as u64;
        if let Some(lead) = self.shared.host_lead_us {
            let wrote = self.shared.host_wrote_us.load(Ordering::SeqCst);
            target = target.min(wrote.saturating_add(lead));
        } else {
            max_step = max_step.min(MAX_CATCH_UP_VIRTUAL_US);
        }
        target = target.min(at.saturating_add(max_step));
        let target = target.max(at);
        if wall > target {
            // Held back: the clock resumes from here, not from the wall.
            self.shared
                .paused_us
                .fetch_add(wall - target, Ordering::SeqCst);
        }
        port.advance_to(target);
        port
    }

    /// Wall time times speed, less the time held back so far, µs.
    fn wall_us(&self) -> u64 {
        self.shared
            .clock
            .now_us()
            .saturating_sub(self.shared.paused_us.load(Ordering::SeqCst))
    }

    /// Run `f` on the port at the current virtual time (tests: inspect the
    /// rig, change inputs, clear history). Keep it short: the rig is paused.
    pub fn with<R>(&self, f: impl FnOnce(&mut SimPort) -> R) -> R {
        let r = f(&mut self.lock());
        self.shared.wake.notify_one();
        r
    }

    /// The physical rig state now.
    pub fn rig_state(&self) -> RigState {
        self.with(|p| p.rig().rig_state())
    }

    /// Subscribe to camera trigger pulses (see [`TriggerEvent`];
    /// `recv().await` from async code, `blocking_recv()` from threads).
    pub fn subscribe_triggers(&self) -> UnboundedReceiver<TriggerEvent> {
        self.with(|p| p.rig_mut().subscribe_triggers())
    }

    pub fn set_interlock(&self, closed: bool) {
        self.with(|p| p.rig_mut().set_interlock(closed));
    }

    pub fn set_estop(&self, pressed: bool) {
        self.with(|p| p.rig_mut().set_estop(pressed));
    }

    /// Reset the MCU now (fault injection).
    pub fn reset_mcu(&self) {
        self.with(|p| {
            p.rig_mut().reset_mcu(false);
        });
    }

    /// Reset the MCU now as its watchdog would (the new boot latches
    /// `FaultCause::Watchdog`).
    pub fn watchdog_reset(&self) {
        self.with(|p| {
            p.rig_mut().reset_mcu(true);
        });
    }

    /// Close the link now: the host reads EOF (in-process) or a hangup (pty).
    pub fn disconnect(&self) {
        self.with(|p| p.disconnect());
    }

    /// Virtual time now, µs: the rig caught up with the clock (wall time
    /// times speed, less the time it was held back). Never decreases, and
    /// every later trigger edge is at or after it.
    pub fn now_us(&self) -> u64 {
        self.with(|p| p.now_us())
    }

    pub fn speed(&self) -> f64 {
        self.shared.clock.speed()
    }

    /// Stop the driver (the host's end then reads EOF or hangs up).
    pub fn shutdown(&self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        self.shared.wake.notify_one();
    }

    pub(crate) fn stopped(&self) -> bool {
        self.shared.stop.load(Ordering::SeqCst)
    }

    /// Advance to now; return what reached the host, when to look again
    /// (wall), and whether the link is closed.
    pub(crate) fn service(&self) -> (Vec<u8>, Duration, bool) {
        let mut port = self.lock();
        let out = port.host_read();
        let next = port.next_event_us();
        let closed = port.is_disconnected();
        let now = port.now_us();
        drop(port);
        let wait = next
            .map(|t| {
                let ahead = t.saturating_sub(now) as f64 * 1e-6 / self.speed();
                Duration::try_from_secs_f64(ahead).unwrap_or(Duration::MAX)
            })
            .unwrap_or(MAX_IDLE_WALL)
            .min(MAX_IDLE_WALL);
        (out, wait, closed)
    }

    /// The host wrote these bytes now.
    pub(crate) fn host_wrote(&self, bytes: &[u8]) {
        let mut port = self.lock();
        port.host_write(bytes);
        self.shared
            .host_wrote_us
            .store(port.now_us(), Ordering::SeqCst);
    }

    pub(crate) async fn woken(&self) {
        self.shared.wake.notified().await
    }
}

/// Capacity of each direction of the in-process stream, bytes.
const DUPLEX_CAPACITY: usize = 64 * 1024;

/// Start an emulated rig behind an in-process stream. Must be called within
/// a tokio runtime (it spawns the serving task). Returns the host's end and
/// a handle on the rig.
pub fn spawn_in_process(cfg: &SimConfig) -> Result<(DuplexStream, RigHandle), SimError> {
    cfg.validate()?;
    let port = SimPort::new(cfg.rig.clone(), cfg.link)?;
    let handle = RigHandle::new(port, cfg.speed, cfg.host_lead_us);
    let (host_end, sim_end) = tokio::io::duplex(DUPLEX_CAPACITY);
    let runtime = tokio::runtime::Handle::try_current().map_err(|_| SimError::NoRuntime)?;
    runtime.spawn(serve_stream(sim_end, handle.clone()));
    Ok((host_end, handle))
}

/// Serve the rig on one end of a byte stream until it closes.
async fn serve_stream(stream: DuplexStream, handle: RigHandle) {
    let (mut rd, mut wr) = tokio::io::split(stream);
    let mut buf = [0u8; 1024];
    while !handle.stopped() {
        let (out, wait, closed) = handle.service();
        if !out.is_empty() && wr.write_all(&out).await.is_err() {
            break;
        }
        if closed {
            break;
        }
        tokio::select! {
            r = rd.read(&mut buf) => match r {
                Ok(0) | Err(_) => break,
                Ok(n) => handle.host_wrote(&buf[..n]),
            },
            _ = tokio::time::sleep(wait) => {}
            _ = handle.woken() => {}
        }
    }
    // Dropping both halves closes the host's end: it reads EOF.
    let _ = wr.shutdown().await;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(speed: f64, host_lead_us: Option<u64>) -> SimConfig {
        SimConfig {
            speed,
            host_lead_us,
            ..SimConfig::seeded(9)
        }
    }

    /// Wall time `wall` with the host writing one byte every `every` (never if None).
    async fn run_for(cfg: &SimConfig, wall: Duration, every: Option<Duration>) -> u64 {
        let (mut host, rig) = spawn_in_process(cfg).unwrap();
        let end = tokio::time::Instant::now() + wall;
        while tokio::time::Instant::now() < end {
            match every {
                Some(d) => {
                    host.write_all(&[0]).await.unwrap();
                    tokio::time::sleep(d).await;
                }
                None => tokio::time::sleep(wall).await,
            }
        }
        let t = rig.now_us();
        rig.shutdown();
        t
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn lockstep_holds_the_rig_at_its_lead_past_a_silent_host() {
        let wall = Duration::from_millis(300);
        // Free: 300 ms at 50x is seconds of rig time.
        let free = run_for(&config(50.0, None), wall, None).await;
        assert!(free > 2_000_000, "free clock at {free} µs");
        // Lockstep: the clock waits 100 ms past the last byte (the start).
        let held = run_for(&config(50.0, Some(100_000)), wall, None).await;
        assert!(held <= 100_000, "held clock at {held} µs");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn lockstep_runs_while_the_host_writes() {
        let wall = Duration::from_millis(300);
        let every = Some(Duration::from_millis(2));
        let t = run_for(&config(50.0, Some(100_000)), wall, every).await;
        assert!(t > 2_000_000, "clock at {t} µs after 300 ms of a live host");
    }

    /// One catch-up after 5 ms of wall time at 1000x (5 s of rig time): a
    /// free-running rig moves at most MAX_CATCH_UP_VIRTUAL_US; in lockstep
    /// the lead alone bounds it, so a fast rig is not held to 50 ms per look.
    #[test]
    fn in_lockstep_one_catch_up_covers_the_whole_lead() {
        let catch_up = |lead: Option<u64>| {
            let cfg = config(1000.0, lead);
            let port = SimPort::new(cfg.rig.clone(), cfg.link).unwrap();
            let start = port.now_us();
            let rig = RigHandle::new(port, cfg.speed, cfg.host_lead_us);
            std::thread::sleep(Duration::from_millis(5));
            rig.now_us() - start
        };
        assert_eq!(catch_up(None), MAX_CATCH_UP_VIRTUAL_US);
        assert_eq!(catch_up(Some(200_000)), 200_000);
    }

    #[test]
    fn a_lead_at_or_past_the_heartbeat_timeout_is_refused() {
        let lead = firmware::controller::HEARTBEAT_TIMEOUT_US;
        let err = config(1.0, Some(lead)).validate().unwrap_err();
        assert!(err.to_string().contains("host_lead_us"), "{err}");
        assert!(config(1.0, Some(lead - 1)).validate().is_ok());
        assert!(config(1.0, Some(0)).validate().is_err());
    }
}
