//! Benchmarks of the protocol and the emulated rig, with raw frames (the host
//! client's own round trip is measured in `host/link`).
//!
//! 1. Encode + decode time per message on the host (`encode_frame` then a
//!    streaming `FrameDecoder`), per message kind: median and p99 over
//!    batches.
//! 2. Command round trip through the in-process emulated rig in real time
//!    (`spawn_in_process`, speed 1.0): write one command frame, read until its
//!    ack decodes. With the modelled 115200-baud line and with no line delay
//!    (emulator and runtime overhead only). Median and p99.
//! 3. The same through the pseudo-terminal opened as a serial port.
//! 4. Emulator throughput on virtual time: virtual seconds per wall second
//!    while both axes move at full speed (every step is one Controller poll).
//!
//! Run: `cargo run -p sim --release --example link_bench [-- --quick]`.
//! Figures from a run are kept in `link_bench.md` beside this file.

use std::time::{Duration, Instant};

use protocol::{
    Axis, AxisStatus, Command, Event, FaultCause, FrameDecoder, HostFrame, LaserColour,
    LaserStatus, MAX_FRAME, McuFrame, MoveTarget, Reply, Status, Sweep, encode_frame,
};
use serde::{Serialize, de::DeserializeOwned};
use sim::{LinkConfig, RawHost, RigConfig, SimConfig, SimPort, spawn_in_process};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

/// Median and p99 of `samples` (sorted in place).
fn stats(samples: &mut [f64]) -> (f64, f64) {
    samples.sort_by(|a, b| a.total_cmp(b));
    (percentile(samples, 0.5), percentile(samples, 0.99))
}

/// ns per encode+decode of `msg`, one sample per batch of `batch` messages.
fn codec<T: Serialize + DeserializeOwned + PartialEq>(
    msg: &T,
    batches: usize,
    batch: usize,
) -> (f64, f64, usize) {
    let mut buf = [0u8; MAX_FRAME];
    let mut dec = FrameDecoder::new();
    let mut samples = Vec::with_capacity(batches);
    let mut len = 0;
    for _ in 0..batches {
        let t = Instant::now();
        for _ in 0..batch {
            len = encode_frame(std::hint::black_box(msg), &mut buf).expect("fits");
            let mut ok = false;
            for &b in &buf[..len] {
                if let Some(r) = dec.push::<T>(b) {
                    ok = r.as_ref().is_ok_and(|m| m == msg);
                }
            }
            assert!(ok, "round trip");
        }
        samples.push(t.elapsed().as_nanos() as f64 / batch as f64);
    }
    let (m, p) = stats(&mut samples);
    (m, p, len)
}

fn status() -> Status {
    let axis = AxisStatus {
        homed: true,
        moving: true,
        homing: false,
        position_steps: -123_456,
        target_steps: 654_321,
    };
    Status {
        uptime_us: 123_456_789_012,
        boot_id: 0xdead_beef,
        axes: [axis; 2],
        galvo_urad: -150_000,
        sweep_step: Some(17),
        laser: LaserStatus {
            selected: LaserColour::Green,
            power_permille: 750,
            armed: true,
            emitting: true,
        },
        lamps: 0b1010_1010,
        interlock_closed: true,
        estop_pressed: false,
        fault: Some(FaultCause::LimitHit(Axis::LightArc)),
        last_eseq: 4321,
        events_dropped: 0,
        last_seq: 777,
    }
}

fn bench_codec(quick: bool) {
    let (batches, batch) = if quick { (50, 200) } else { (300, 2000) };
    println!("## Encode + decode per message (host, {batches} batches of {batch})\n");
    println!("| message | wire bytes | median ns | p99 ns |");
    println!("|---|---|---|---|");
    let row = |name: &str, (m, p, len): (f64, f64, usize)| {
        println!("| {name} | {len} | {m:.0} | {p:.0} |");
    };
    let hf = |command| HostFrame { seq: 4242, command };
    row(
        "HostFrame Heartbeat",
        codec(&hf(Command::Heartbeat { event_ack: 999 }), batches, batch),
    );
    row(
        "HostFrame Move",
        codec(
            &hf(Command::Move {
                axis: Axis::LightArc,
                target: MoveTarget::Absolute(-1_234_567),
                speed_urad_s: 500_000,
                accel_urad_s2: 1_000_000,
            }),
            batches,
            batch,
        ),
    );
    row(
        "HostFrame GalvoSweep",
        codec(
            &hf(Command::GalvoSweep(Sweep {
                start_urad: -300_000,
                end_urad: 300_000,
                steps: 600,
                dwell_us: 40_000,
                trigger_mask: 0xfe,
                pulse_us: 20_000,
            })),
            batches,
            batch,
        ),
    );
    row(
        "McuFrame Ack(Ok)",
        codec(
            &McuFrame::Ack {
                seq: 4242,
                result: Ok(Reply::Ok),
            },
            batches,
            batch,
        ),
    );
    row(
        "McuFrame Ack(Status)",
        codec(
            &McuFrame::Ack {
                seq: 4242,
                result: Ok(Reply::Status(status())),
            },
            batches,
            batch,
        ),
    );
    row(
        "McuFrame Event TriggerFired",
        codec(
            &McuFrame::Event {
                eseq: 31_000,
                at_us: 98_765_432_100,
                event: Event::TriggerFired {
                    mask: 0xfe,
                    at_us: 98_765_432_100,
                    pulse_us: 20_000,
                },
            },
            batches,
            batch,
        ),
    );
    println!();
}

async fn round_trip(
    stream: &mut DuplexStream,
    dec: &mut FrameDecoder,
    seq: u16,
    command: Command,
) -> Duration {
    let mut frame = [0u8; MAX_FRAME];
    let n = encode_frame(&HostFrame { seq, command }, &mut frame).expect("fits");
    let mut buf = [0u8; 512];
    let t = Instant::now();
    stream.write_all(&frame[..n]).await.expect("write");
    loop {
        let got = stream.read(&mut buf).await.expect("read");
        assert!(got > 0, "rig closed the stream");
        let mut done = false;
        dec.push_slice::<McuFrame>(&buf[..got], |f| {
            if let Ok(McuFrame::Ack { seq: s, .. }) = f
                && s == seq
            {
                done = true;
            }
        });
        if done {
            return t.elapsed();
        }
    }
}

async fn bench_rtt_case(baud: u32, n: usize) -> ((f64, f64), (f64, f64)) {
    let mut cfg = SimConfig::seeded(77);
    cfg.link.baud = baud;
    let (mut stream, rig) = spawn_in_process(&cfg).expect("emulator");
    let mut dec = FrameDecoder::new();
    round_trip(&mut stream, &mut dec, 1, Command::Identify).await;
    let mut seq = 1u16;
    let mut hb = Vec::with_capacity(n);
    let mut st = Vec::with_capacity(n);
    for i in 0..2 * n {
        seq = seq.wrapping_add(1);
        // Heartbeats also acknowledge the Booted event, so the MCU stays quiet.
        let (cmd, out) = if i % 2 == 0 {
            (Command::Heartbeat { event_ack: 1 }, &mut hb)
        } else {
            (Command::Status, &mut st)
        };
        out.push(
            round_trip(&mut stream, &mut dec, seq, cmd)
                .await
                .as_secs_f64()
                * 1e6,
        );
    }
    rig.shutdown();
    (stats(&mut hb), stats(&mut st))
}

fn bench_rtt(quick: bool) {
    let n = if quick { 200 } else { 2000 };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    println!(
        "## Command round trip through the in-process emulated rig (real time, raw frames, {n} each)\n"
    );
    println!("| line | command | median µs | p99 µs |");
    println!("|---|---|---|---|");
    for (baud, name) in [(115_200, "115200 baud modelled"), (0, "no line delay")] {
        let ((hm, hp), (sm, sp)) = rt.block_on(bench_rtt_case(baud, n));
        println!("| {name} | Heartbeat | {hm:.0} | {hp:.0} |");
        println!("| {name} | Status | {sm:.0} | {sp:.0} |");
    }
    println!();
}

/// Round trips through a pseudo-terminal opened as a serial port (the
/// server thread and this client in one process; the device path is the
/// same one another process would open).
fn bench_pty(quick: bool) {
    use std::io::{Read, Write};
    let n = if quick { 200 } else { 2000 };
    println!(
        "## Command round trip through the pseudo-terminal (real time, raw frames, {n} each)\n"
    );
    println!("| line | command | median µs | p99 µs |");
    println!("|---|---|---|---|");
    for (baud, name) in [(115_200, "115200 baud modelled"), (0, "no line delay")] {
        let mut cfg = SimConfig::seeded(78);
        cfg.link.baud = baud;
        let server = sim::serve_pty(&cfg).expect("pty");
        let mut port = serialport::new(server.path().to_string_lossy(), 115_200)
            .timeout(Duration::from_millis(100))
            .open()
            .expect("open pty");
        let mut dec = FrameDecoder::new();
        let mut rtt = |seq: u16, command: Command| -> f64 {
            let mut frame = [0u8; MAX_FRAME];
            let len = encode_frame(&HostFrame { seq, command }, &mut frame).expect("fits");
            let mut buf = [0u8; 512];
            let t = Instant::now();
            port.write_all(&frame[..len]).expect("write");
            loop {
                let got = match port.read(&mut buf) {
                    Ok(k) => k,
                    Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
                    Err(e) => panic!("read: {e}"),
                };
                let mut done = false;
                dec.push_slice::<McuFrame>(&buf[..got], |f| {
                    done |= matches!(f, Ok(McuFrame::Ack { seq: s, .. }) if s == seq);
                });
                if done {
                    return t.elapsed().as_secs_f64() * 1e6;
                }
                assert!(t.elapsed() < Duration::from_secs(5), "no ack");
            }
        };
        rtt(1, Command::Identify);
        let (mut hb, mut st) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut seq = 1u16;
        for i in 0..2 * n {
            seq = seq.wrapping_add(1);
            if i % 2 == 0 {
                hb.push(rtt(seq, Command::Heartbeat { event_ack: 1 }));
            } else {
                st.push(rtt(seq, Command::Status));
            }
        }
        let ((hm, hp), (sm, sp)) = (stats(&mut hb), stats(&mut st));
        println!("| {name} | Heartbeat | {hm:.0} | {hp:.0} |");
        println!("| {name} | Status | {sm:.0} | {sp:.0} |");
        server.stop();
    }
    println!();
}

/// One timed run: home, then move both axes to `target` µrad at full speed;
/// returns (virtual s, wall s, steps) of the move.
fn virtual_run(seed: u64, target: i32) -> (f64, f64, u64) {
    let mut cfg = RigConfig::seeded(seed);
    cfg.physical.start_rad = [Some(0.2), Some(0.2)];
    let mut h = RawHost::new(SimPort::new(cfg, LinkConfig::default()).expect("rig"));
    h.heartbeat_us = Some(100_000);
    let _ = h.identify();
    for axis in Axis::ALL {
        let _ = h.call(Command::Home { axis });
    }
    h.run_for(30_000_000);
    h.port.rig_mut().peripherals_mut().clear_history();
    let t = Instant::now();
    let v0 = h.now_us();
    for axis in Axis::ALL {
        let r = h.call(Command::Move {
            axis,
            target: MoveTarget::Absolute(target),
            speed_urad_s: 0,
            accel_urad_s2: 0,
        });
        assert!(matches!(r, Ok(Ok(Reply::Ok))), "{r:?}");
    }
    let mut done = 0;
    while done < 2 {
        if h.run_until_event(60_000_000, |e| matches!(e, Event::MotionDone { .. }))
            .is_none()
        {
            break;
        }
        done += 1;
    }
    assert_eq!(done, 2, "both moves finish");
    let steps: u64 = h
        .port
        .rig()
        .snapshot()
        .axes
        .iter()
        .map(|a| a.step_count)
        .sum();
    (
        (h.now_us() - v0) as f64 * 1e-6,
        t.elapsed().as_secs_f64(),
        steps,
    )
}

fn bench_virtual(quick: bool) {
    let runs = if quick { 5 } else { 25 };
    let target = 3_000_000;
    let mut ratios = Vec::with_capacity(runs);
    let (mut virt, mut steps) = (0.0, 0);
    for r in 0..runs {
        let (v, w, s) = virtual_run(5 + r as u64, target);
        ratios.push(v / w);
        (virt, steps) = (v, s);
    }
    let (median, _) = stats(&mut ratios);
    println!("## Emulator on virtual time ({runs} runs)\n");
    println!(
        "both axes to {:.1} rad at full speed ({virt:.2} virtual s, {steps} steps, one Controller poll each, \
         plus the raw host's 0.5 ms receive ticks): median {median:.0}x real time, slowest run {:.0}x\n",
        target as f64 * 1e-6,
        ratios[0]
    );
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    println!("# link_bench{}\n", if quick { " (quick)" } else { "" });
    println!("machine: {cores} cores, load average {}\n", load.trim());
    bench_codec(quick);
    bench_rtt(quick);
    bench_pty(quick);
    bench_virtual(quick);
}
