//! 10,000 commands over a faulty line: 1% of bytes lost, 0.1% corrupted
//! (both directions, the emulator's seeded wire), and 1% of whole frames
//! duplicated (both directions, by a wrapper around the host's stream). Each
//! command must complete exactly once and in order, counted on the emulator
//! side (its trigger lines and motor steps), and the rig must end in the
//! state the last commands asked for.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::task::{Context, Poll};
use std::time::Duration;

use protocol::{Axis, Command, Event, FaultCause, LaserColour, MoveTarget};
use qhm_link::{Link, LinkConfig, LinkEvent};
use sim::{ByteFaults, FaultConfig, SimConfig, spawn_in_process};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

const SPEED: f64 = 10.0;
const COMMANDS: usize = 10_000;
const MOVE_EVERY: usize = 250;

/// Duplicates whole frames: each write of the host (one frame per write) and
/// each frame read from the MCU is repeated with probability `p`.
struct Duplicator<S> {
    inner: S,
    p: f64,
    rng: u64,
    /// Bytes of the MCU frame being read, and extra bytes queued for the host.
    partial: Vec<u8>,
    pending: Vec<u8>,
    /// A write to repeat once the original completed.
    repeat: Option<Vec<u8>>,
    duplicated: Arc<AtomicU64>,
}

impl<S> Duplicator<S> {
    fn new(inner: S, p: f64, seed: u64, duplicated: Arc<AtomicU64>) -> Self {
        Self {
            inner,
            p,
            rng: seed | 1,
            partial: Vec::new(),
            pending: Vec::new(),
            repeat: None,
            duplicated,
        }
    }

    fn chance(&mut self) -> bool {
        // xorshift64*: a seeded, dependency-free stream.
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        let x = self.rng.wrapping_mul(0x2545_f491_4f6c_dd1d);
        ((x >> 11) as f64 / (1u64 << 53) as f64) < self.p
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Duplicator<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = &mut *self;
        if !this.pending.is_empty() {
            let n = this.pending.len().min(buf.remaining());
            buf.put_slice(&this.pending[..n]);
            this.pending.drain(..n);
            return Poll::Ready(Ok(()));
        }
        let mut tmp = [0u8; 512];
        let mut rb = ReadBuf::new(&mut tmp);
        match Pin::new(&mut this.inner).poll_read(cx, &mut rb) {
            Poll::Ready(Ok(())) => {
                let got = rb.filled().to_vec();
                for &b in &got {
                    this.partial.push(b);
                    if b == 0 {
                        let frame = std::mem::take(&mut this.partial);
                        this.pending.extend_from_slice(&frame);
                        if frame.len() > 1 && this.chance() {
                            this.pending.extend_from_slice(&frame);
                            this.duplicated.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                }
                if got.is_empty() {
                    // End of stream: hand over what is left.
                    this.pending.append(&mut this.partial);
                    if this.pending.is_empty() {
                        return Poll::Ready(Ok(()));
                    }
                }
                let n = this.pending.len().min(buf.remaining());
                buf.put_slice(&this.pending[..n]);
                this.pending.drain(..n);
                if n == 0 {
                    cx.waker().wake_by_ref();
                    return Poll::Pending;
                }
                Poll::Ready(Ok(()))
            }
            other => other,
        }
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Duplicator<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let this = &mut *self;
        while let Some(rep) = this.repeat.take() {
            match Pin::new(&mut this.inner).poll_write(cx, &rep) {
                Poll::Ready(Ok(n)) if n < rep.len() => this.repeat = Some(rep[n..].to_vec()),
                Poll::Ready(Ok(_)) => {}
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => {
                    this.repeat = Some(rep);
                    return Poll::Pending;
                }
            }
        }
        let r = Pin::new(&mut this.inner).poll_write(cx, buf);
        if let Poll::Ready(Ok(n)) = r
            && n == buf.len()
            && this.chance()
        {
            this.repeat = Some(buf.to_vec());
            this.duplicated.fetch_add(1, Ordering::Relaxed);
        }
        r
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let this = &mut *self;
        if let Some(rep) = this.repeat.take() {
            match Pin::new(&mut this.inner).poll_write(cx, &rep) {
                Poll::Ready(Ok(n)) if n < rep.len() => {
                    this.repeat = Some(rep[n..].to_vec());
                    cx.waker().wake_by_ref();
                    return Poll::Pending;
                }
                Poll::Ready(Ok(_)) => {}
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => {
                    this.repeat = Some(rep);
                    return Poll::Pending;
                }
            }
        }
        Pin::new(&mut this.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// The i-th command of the run (moves are handled by the caller).
fn command(i: usize, triggers: &mut Vec<(u8, u32)>) -> Command {
    match i % 5 {
        0 => {
            let k = triggers.len();
            let (mask, pulse_us) = (1 + (k % 255) as u8, 10 + (k % 40) as u32);
            triggers.push((mask, pulse_us));
            Command::Trigger { mask, pulse_us }
        }
        1 => Command::Lamps { mask: i as u8 },
        2 => Command::GalvoSet {
            angle_urad: ((i * 37) % 200_001) as i32 - 100_000,
        },
        3 => Command::LaserPower {
            permille: (i % 1001) as u16,
        },
        _ => Command::LaserSelect {
            colour: LaserColour::ALL[(i / 5) % 3],
        },
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ten_thousand_commands_exactly_once_over_a_faulty_line() {
    let mut cfg = SimConfig::seeded(2026);
    cfg.speed = SPEED;
    cfg.rig.physical.start_rad = [Some(0.3), Some(0.3)];
    let faults = ByteFaults {
        drop: 0.01,
        corrupt: 0.001,
        ..ByteFaults::NONE
    };
    cfg.link.faults = FaultConfig::symmetric(77, faults);
    // No line delay: the run is about loss, not about the UART rate.
    cfg.link.baud = 0;
    let (stream, rig) = spawn_in_process(&cfg).unwrap();
    let mut triggers_seen = rig.subscribe_triggers();
    let duplicated = Arc::new(AtomicU64::new(0));
    let stream = Duplicator::new(stream, 0.01, 99, duplicated.clone());
    let config = LinkConfig {
        tries: 30,
        ..LinkConfig::scaled(SPEED)
    };
    let link = Link::open_stream(Box::new(stream), config).await.unwrap();

    // Count TriggerFired events as the link delivers them.
    let mut events = link.subscribe();
    let counter = tokio::spawn(async move {
        let mut fired = Vec::new();
        let mut problems = Vec::new();
        loop {
            match events.recv().await {
                Ok(LinkEvent::Mcu {
                    event: Event::TriggerFired { mask, pulse_us, .. },
                    ..
                }) => fired.push((mask, pulse_us)),
                Ok(LinkEvent::Disconnected { .. }) | Err(_) => break,
                Ok(e @ (LinkEvent::EventsMissed { .. } | LinkEvent::EventsDropped { .. })) => {
                    problems.push(e)
                }
                Ok(_) => {}
            }
        }
        (fired, problems)
    });

    let start_steps = link.status().await.unwrap().axes[0].position_steps;
    let mut triggers = Vec::new();
    let mut last = std::collections::HashMap::new();
    let mut moves = 0;
    let t0 = std::time::Instant::now();
    for i in 0..COMMANDS {
        if i % MOVE_EVERY == MOVE_EVERY - 1 {
            // 1000 urad relative: a few steps, executed exactly once each.
            link.move_axis(Axis::Turntable, MoveTarget::Relative(1_000), 0, 0)
                .await
                .unwrap_or_else(|e| panic!("move at command {i}: {e}"));
            tokio::time::timeout(
                Duration::from_secs(10),
                link.wait_motion_done(Axis::Turntable),
            )
            .await
            .expect("move finishes")
            .unwrap();
            moves += 1;
            continue;
        }
        let c = command(i, &mut triggers);
        last.insert(std::mem::discriminant(&c), c.clone());
        link.call(c.clone())
            .await
            .unwrap_or_else(|e| panic!("command {i} ({c:?}): {e}"));
    }
    let elapsed = t0.elapsed();
    let status = link.status().await.unwrap();
    let stats = link.stats();
    let (wire_up, wire_down) = rig.with(|p| p.wire_stats());
    eprintln!(
        "{COMMANDS} commands in {:.1} s; {} frames duplicated; link {stats:?}; wire up {wire_up:?} down {wire_down:?}",
        elapsed.as_secs_f64(),
        duplicated.load(Ordering::Relaxed)
    );

    // The faults really happened, and were survived.
    assert!(stats.retransmissions > 100, "{stats:?}");
    assert!(stats.bad_frames > 10, "{stats:?}");
    assert_eq!(stats.timeouts, 0);
    let duplicated = duplicated.load(Ordering::Relaxed);
    assert!(duplicated > 100, "{duplicated} frames duplicated");
    assert_eq!(status.fault, None::<FaultCause>, "no fault latched");

    // Final state = the last command of each kind.
    let Some(Command::Lamps { mask }) = last.values().find(|c| matches!(c, Command::Lamps { .. }))
    else {
        unreachable!()
    };
    assert_eq!(status.lamps, *mask);
    assert_eq!(rig.rig_state().lamps, *mask);
    for c in last.values() {
        match *c {
            Command::GalvoSet { angle_urad } => assert_eq!(status.galvo_urad, angle_urad),
            Command::LaserPower { permille } => assert_eq!(status.laser.power_permille, permille),
            Command::LaserSelect { colour } => assert_eq!(status.laser.selected, colour),
            _ => {}
        }
    }

    // Each move executed once: the turntable moved moves * (steps of 1000 urad).
    let spr = link.identity().unwrap().limits.steps_per_rev[0] as f64;
    let per_move = (1e-3 * spr / std::f64::consts::TAU).round() as i32;
    assert_eq!(
        status.axes[0].position_steps - start_steps,
        moves * per_move,
        "{moves} moves of {per_move} steps"
    );

    // Each trigger fired once and in order, as the emulator's lines saw them.
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut seen = Vec::new();
    while let Ok(t) = triggers_seen.try_recv() {
        seen.push(t.mask);
    }
    let expected: Vec<u8> = triggers.iter().map(|t| t.0).collect();
    assert_eq!(seen.len(), expected.len(), "trigger pulses on the lines");
    assert_eq!(seen, expected, "trigger pulses in order");

    // And the link delivered each TriggerFired event exactly once, in order.
    drop(link);
    rig.shutdown();
    let (fired, problems) = tokio::time::timeout(Duration::from_secs(5), counter)
        .await
        .expect("event counter ends")
        .unwrap();
    assert!(problems.is_empty(), "{problems:?}");
    assert_eq!(fired, triggers);
}
