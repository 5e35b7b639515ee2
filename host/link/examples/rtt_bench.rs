//! Link figures: encode+decode time per message on the host, and the command
//! round trip (median, p99) through the in-process emulated rig and through a
//! pseudo-terminal, with and without the modelled 115200 baud line.
//!
//! `cargo run -p qhm-link --release --example rtt_bench [-- ROUND_TRIPS]`
//! prints a Markdown table (kept in docs/link.md).

use std::hint::black_box;
use std::time::{Duration, Instant};

use protocol::{
    Axis, AxisStatus, Command, Event, FaultCause, FrameDecoder, HostFrame, LaserColour,
    LaserStatus, MAX_FRAME, McuFrame, MoveTarget, Reply, Status, Sweep, encode_frame,
};
use qhm_link::{Link, LinkConfig};

fn status() -> Status {
    let axis = AxisStatus {
        homed: true,
        moving: false,
        homing: false,
        position_steps: 12_345,
        target_steps: 12_345,
    };
    Status {
        uptime_us: 123_456_789,
        boot_id: 0xdead_beef,
        axes: [axis; 2],
        galvo_urad: -40_000,
        sweep_step: Some(17),
        laser: LaserStatus {
            selected: LaserColour::Green,
            power_permille: 250,
            armed: true,
            emitting: true,
        },
        lamps: 0b1010,
        interlock_closed: true,
        estop_pressed: false,
        fault: Some(FaultCause::HeartbeatLost),
        last_eseq: 4_000,
        events_dropped: 0,
        last_seq: 60_000,
    }
}

/// ns per encode+decode of `msg`, and its size on the wire.
fn codec<T>(msg: &T, iters: u32) -> (f64, usize)
where
    T: serde::Serialize + serde::de::DeserializeOwned,
{
    let mut buf = [0u8; MAX_FRAME];
    let mut dec = FrameDecoder::new();
    let n = encode_frame(msg, &mut buf).unwrap();
    let t = Instant::now();
    for _ in 0..iters {
        let n = encode_frame(black_box(msg), &mut buf).unwrap();
        for &b in &buf[..n] {
            if let Some(r) = dec.push::<T>(b) {
                black_box(r.ok());
            }
        }
    }
    (t.elapsed().as_nanos() as f64 / iters as f64, n)
}

fn percentiles(mut v: Vec<Duration>) -> (f64, f64) {
    v.sort();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    (
        ms(v[v.len() / 2]),
        ms(v[(v.len() * 99 / 100).min(v.len() - 1)]),
    )
}

async fn round_trips(link: &Link, n: usize) -> Vec<Duration> {
    // Warm up the RTT estimate and the caches.
    for _ in 0..20 {
        link.heartbeat().await.unwrap();
    }
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        link.call(Command::Lamps { mask: 0b11 }).await.unwrap();
        v.push(t.elapsed());
    }
    v
}

fn sim_config(baud: u32) -> sim::SimConfig {
    let mut cfg = sim::SimConfig::seeded(1);
    cfg.link.baud = baud;
    cfg
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(2000);

    println!("| message | wire bytes | encode+decode (ns) |");
    println!("|---|---:|---:|");
    let iters = 200_000;
    let rows: Vec<(&str, (f64, usize))> = vec![
        (
            "HostFrame Heartbeat",
            codec(
                &HostFrame {
                    seq: 1234,
                    command: Command::Heartbeat { event_ack: 77 },
                },
                iters,
            ),
        ),
        (
            "HostFrame Move",
            codec(
                &HostFrame {
                    seq: 1234,
                    command: Command::Move {
                        axis: Axis::LightArc,
                        target: MoveTarget::Absolute(1_234_567),
                        speed_urad_s: 500_000,
                        accel_urad_s2: 1_000_000,
                    },
                },
                iters,
            ),
        ),
        (
            "HostFrame GalvoSweep",
            codec(
                &HostFrame {
                    seq: 1234,
                    command: Command::GalvoSweep(Sweep {
                        start_urad: -100_000,
                        end_urad: 100_000,
                        steps: 400,
                        dwell_us: 20_000,
                        trigger_mask: 0x7f,
                        pulse_us: 5_000,
                    }),
                },
                iters,
            ),
        ),
        (
            "McuFrame Ack(Ok)",
            codec(
                &McuFrame::Ack {
                    seq: 1234,
                    result: Ok(Reply::Ok),
                },
                iters,
            ),
        ),
        (
            "McuFrame Ack(Status)",
            codec(
                &McuFrame::Ack {
                    seq: 1234,
                    result: Ok(Reply::Status(status())),
                },
                iters,
            ),
        ),
        (
            "McuFrame Event(TriggerFired)",
            codec(
                &McuFrame::Event {
                    eseq: 999,
                    at_us: 987_654_321,
                    event: Event::TriggerFired {
                        mask: 0x7f,
                        at_us: 987_654_321,
                        pulse_us: 5_000,
                    },
                },
                iters,
            ),
        ),
    ];
    for (name, (ns, bytes)) in rows {
        println!("| {name} | {bytes} | {ns:.0} |");
    }

    println!();
    println!("| link (command `Lamps`, {n} round trips) | median (ms) | p99 (ms) |");
    println!("|---|---:|---:|");
    for baud in [0u32, 115_200] {
        let line = if baud == 0 {
            "no line delay".to_string()
        } else {
            format!("{baud} baud line")
        };
        let (stream, _rig) = sim::spawn_in_process(&sim_config(baud)).unwrap();
        let link = Link::open_stream(Box::new(stream), LinkConfig::default())
            .await
            .unwrap();
        let (med, p99) = percentiles(round_trips(&link, n).await);
        println!("| in-process emulated rig, {line} | {med:.3} | {p99:.3} |");
        link.close();

        let server = sim::serve_pty(&sim_config(baud)).unwrap();
        let path = server.path().to_string_lossy().to_string();
        let link = Link::open_serial(&path, 115_200, LinkConfig::default())
            .await
            .unwrap();
        let (med, p99) = percentiles(round_trips(&link, n).await);
        println!("| pseudo-terminal ({path}), {line} | {med:.3} | {p99:.3} |");
        link.close();
        server.stop();
    }
}
