//! The emulated rig behind its links: raw frames through the in-process
//! stream and through a pseudo-terminal opened as a serial port, the clock's
//! speed factor, trigger subscription from async code, disconnects, and
//! exactly-once execution over a faulty line (virtual time).

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use protocol::{
    Command, CommandError, Event, FrameDecoder, HostFrame, MAX_FRAME, McuFrame, Reply, encode_frame,
};
use sim::{
    ByteFaults, FaultConfig, LinkConfig, RawError, RawHost, ResetFault, RigConfig, SimConfig,
    SimPort, spawn_in_process,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn frame(seq: u16, command: Command) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    let n = encode_frame(&HostFrame { seq, command }, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// Read from `read` until the ack of `seq` decodes; events are skipped.
fn ack_from(dec: &mut FrameDecoder, bytes: &[u8], seq: u16) -> Option<Result<Reply, CommandError>> {
    let mut found = None;
    dec.push_slice::<McuFrame>(bytes, |f| {
        if let Ok(McuFrame::Ack { seq: s, result }) = f
            && s == seq
        {
            found = Some(result);
        }
    });
    found
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn in_process_stream_answers_and_closes_on_disconnect() {
    let (mut stream, rig) = spawn_in_process(&SimConfig::seeded(21)).unwrap();
    stream
        .write_all(&frame(1, Command::Identify))
        .await
        .unwrap();
    let mut dec = FrameDecoder::new();
    let mut buf = [0u8; 512];
    let reply = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let n = stream.read(&mut buf).await.unwrap();
            assert!(n > 0, "EOF before the ack");
            if let Some(r) = ack_from(&mut dec, &buf[..n], 1) {
                return r;
            }
        }
    })
    .await
    .expect("ack within 5 s");
    match reply {
        Ok(Reply::Identity(id)) => assert_eq!(id.boot_id, rig.with(|p| p.rig().boot_id())),
        other => panic!("{other:?}"),
    }
    rig.disconnect();
    let eof = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            match stream.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
        }
    })
    .await;
    assert!(eof.is_ok(), "host end reads EOF after a disconnect");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn speed_factor_runs_virtual_time_faster_and_triggers_reach_async_subscribers() {
    let mut cfg = SimConfig::seeded(22);
    // A window of 100 ms of wall time (the longest pulse the MCU takes at
    // speed 10), so a few ms of scheduling delay stay within the 5 % bound.
    cfg.speed = 10.0;
    let (mut stream, rig) = spawn_in_process(&cfg).unwrap();
    let mut triggers = rig.subscribe_triggers();
    let (t0, w0) = (rig.now_us(), Instant::now());
    stream
        .write_all(&frame(1, Command::Identify))
        .await
        .unwrap();
    stream
        .write_all(&frame(
            2,
            Command::Trigger {
                mask: 0b1000_0001,
                pulse_us: 1_000_000,
            },
        ))
        .await
        .unwrap();
    // Keep reading so the MCU's output never backs up.
    let reader = tokio::spawn(async move {
        let mut buf = [0u8; 512];
        while let Ok(n) = stream.read(&mut buf).await {
            if n == 0 {
                break;
            }
        }
    });
    let ev = tokio::time::timeout(Duration::from_secs(5), triggers.recv())
        .await
        .expect("a trigger within 5 s")
        .expect("subscription open");
    let (virt, wall) = (rig.now_us() - t0, w0.elapsed());
    assert_eq!(ev.mask, 0b1000_0001);
    // The pulse is measured in virtual time: 1 s, i.e. 100 ms of wall time.
    assert!(
        (1_000_000..=1_002_000).contains(&ev.pulse_us),
        "{}",
        ev.pulse_us
    );
    let ratio = virt as f64 / (wall.as_secs_f64() * 1e6);
    assert!((ratio - 10.0).abs() < 0.5, "virtual/wall = {ratio}");
    rig.shutdown();
    let _ = tokio::time::timeout(Duration::from_secs(5), reader).await;
}

#[test]
fn pty_serves_a_real_serial_device_and_hangs_up_on_disconnect() {
    let server = sim::serve_pty(&SimConfig::seeded(23)).unwrap();
    let path = server.path().to_str().unwrap().to_owned();
    assert!(path.starts_with("/dev/pts/"), "{path}");
    let mut port = serialport::new(&path, 115_200)
        .timeout(Duration::from_millis(50))
        .open()
        .expect("open the pty as a serial port");
    // A plain thread (no async runtime) consumes trigger events.
    let mut triggers = server.handle().subscribe_triggers();
    let camera = std::thread::spawn(move || triggers.blocking_recv());
    let mut dec = FrameDecoder::new();
    let mut buf = [0u8; 512];
    for (seq, cmd) in [
        (7u16, Command::Identify),
        (8, Command::Lamps { mask: 0x5a }),
        (
            9,
            Command::Trigger {
                mask: 0x40,
                pulse_us: 3_000,
            },
        ),
    ] {
        port.write_all(&frame(seq, cmd)).unwrap();
        let end = Instant::now() + Duration::from_secs(5);
        let reply = loop {
            assert!(Instant::now() < end, "no ack for {seq}");
            match port.read(&mut buf) {
                Ok(n) => {
                    if let Some(r) = ack_from(&mut dec, &buf[..n], seq) {
                        break r;
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) => panic!("read: {e}"),
            }
        };
        assert!(reply.is_ok(), "{reply:?}");
    }
    assert_eq!(server.handle().rig_state().lamps, 0x5a);
    let ev = camera.join().unwrap().expect("a trigger event");
    assert_eq!(ev.mask, 0x40);
    assert!((3_000..3_500).contains(&ev.pulse_us), "{}", ev.pulse_us);
    assert_eq!(ev.state.lamps, 0x5a);
    server.handle().disconnect();
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        assert!(Instant::now() < end, "no hangup");
        match port.read(&mut buf) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => break,
        }
    }
    // The port sees the hangup before the server thread has noticed it.
    let end = Instant::now() + Duration::from_secs(5);
    while !server.finished() {
        assert!(
            Instant::now() < end,
            "the pty server did not finish after the disconnect"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn every_command_runs_exactly_once_over_a_faulty_line() {
    let faults = ByteFaults {
        drop: 0.01,
        corrupt: 0.001,
        duplicate: 0.01,
        delay: 0.01,
        delay_max_us: 2_000,
    };
    let link = LinkConfig {
        faults: FaultConfig::symmetric(31, faults),
        ..LinkConfig::default()
    };
    let mut h = RawHost::new(SimPort::new(RigConfig::seeded(31), link).unwrap());
    let mut identified = false;
    for _ in 0..20 {
        if let Ok(Ok(Reply::Identity(_))) = h.identify() {
            identified = true;
            break;
        }
    }
    assert!(identified);
    h.port.rig_mut().peripherals_mut().clear_history();
    // Each executed Trigger makes one physical pulse: count them.
    let n = 400;
    for i in 0..n {
        let mask = 1u8 << (i % 8);
        let r = h.call_with(
            Command::Trigger {
                mask,
                pulse_us: 100,
            },
            30_000,
            30,
        );
        assert_eq!(r, Ok(Ok(Reply::Ok)), "command {i}");
    }
    h.run_for(10_000);
    let log = h.port.rig().peripherals().trigger_log();
    assert_eq!(log.len(), n, "every command executed exactly once");
    for (i, t) in log.iter().enumerate() {
        assert_eq!(t.mask, 1 << (i % 8), "in order");
    }
    let (up, down) = h.port.wire_stats();
    assert!(up.dropped > 0 && up.duplicated > 0 && down.dropped > 0 && down.corrupted > 0);
    assert!(h.retransmissions > 0 && h.bad_frames > 0);
}

#[test]
fn reset_right_after_a_command_loses_its_reply() {
    let link = LinkConfig {
        faults: FaultConfig {
            // Identify is frame 1; the Lamps command is frame 2.
            reset: Some(ResetFault::AfterFrames {
                frames: 2,
                delay_us: 0,
            }),
            ..FaultConfig::none()
        },
        ..LinkConfig::default()
    };
    let mut h = RawHost::new(SimPort::new(RigConfig::seeded(32), link).unwrap());
    assert!(matches!(h.identify(), Ok(Ok(Reply::Identity(_)))));
    // Executed, then the MCU reset before answering: the retransmission
    // reaches a new boot that wants a handshake, and the lamps are dark.
    assert_eq!(
        h.call_with(Command::Lamps { mask: 0xff }, 20_000, 3),
        Ok(Err(CommandError::NotIdentified))
    );
    assert!(h.port.reset_fired());
    assert_eq!(h.port.rig().rig_state().lamps, 0);
    h.run_for(100_000);
    assert!(
        h.events
            .iter()
            .any(|e| matches!(e.event, Event::Booted { .. })
                && e.eseq == 1
                && h.port.rig().boots() == 2)
    );
}

#[test]
fn disconnect_fault_closes_the_line_at_its_time() {
    let link = LinkConfig {
        faults: FaultConfig {
            disconnect_at_us: Some(50_000),
            ..FaultConfig::none()
        },
        ..LinkConfig::default()
    };
    let mut h = RawHost::new(SimPort::new(RigConfig::seeded(33), link).unwrap());
    assert!(matches!(h.identify(), Ok(Ok(Reply::Identity(_)))));
    h.run_for(40_000);
    assert!(!h.port.is_disconnected());
    // A call in flight when the line closes learns it at once.
    let t = h.now_us();
    assert_eq!(
        h.call_with(Command::Status, 1_000_000, 3),
        Err(RawError::Disconnected)
    );
    assert!(h.port.is_disconnected());
    assert!(
        h.now_us() - t < 20_000,
        "noticed at the disconnect, not after the timeouts"
    );
    assert!(h.port.host_read().is_empty());
}

#[test]
fn bad_configs_are_refused_with_a_message() {
    let mut cfg = SimConfig::seeded(1);
    cfg.speed = 0.0;
    assert!(spawn_err(&cfg).contains("speed"));
    let mut cfg = SimConfig::seeded(1);
    cfg.link.faults.host_to_mcu.corrupt = 2.0;
    assert!(spawn_err(&cfg).contains("corrupt"));
    let mut cfg = SimConfig::seeded(1);
    cfg.rig.physical.start_rad = [Some(f64::NAN), None];
    assert!(spawn_err(&cfg).contains("start_rad"));
    // And from JSON, with defaults for what is missing.
    let cfg: SimConfig = serde_json::from_str(r#"{"speed": 5.0, "link": {"baud": 9600}}"#).unwrap();
    assert_eq!((cfg.speed, cfg.link.baud), (5.0, 9600));
    assert!(cfg.validate().is_ok());
}

fn spawn_err(cfg: &SimConfig) -> String {
    match sim::serve_pty(cfg) {
        Ok(_) => panic!("accepted {cfg:?}"),
        Err(e) => e.to_string(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cli_server_prints_the_path_and_ends_with_the_link() {
    // `qhm sim --pty` serves until Ctrl-C; a disconnect fault ends it too.
    let mut cfg = SimConfig::seeded(24);
    cfg.link.faults.disconnect_at_us = Some(200_000);
    let mut out = Vec::new();
    let t = Instant::now();
    tokio::time::timeout(
        Duration::from_secs(10),
        sim::serve_pty_until_ctrl_c(&cfg, &mut out),
    )
    .await
    .expect("ends after the disconnect")
    .expect("serves");
    let printed = String::from_utf8(out).unwrap();
    assert!(
        printed.starts_with("/dev/pts/") && printed.ends_with('\n'),
        "{printed:?}"
    );
    assert!(t.elapsed() >= Duration::from_millis(200));
}
