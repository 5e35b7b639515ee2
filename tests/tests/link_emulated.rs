//! The link client against the emulated MCU (the firmware's Controller on
//! virtual time) through the in-process stream: handshake, every command and
//! every event, faults and interlock, reset in the middle of a sweep,
//! disconnect. The rig runs 10 times faster than real time.

use std::time::Duration;

use protocol::{Axis, Command, CommandError, Event, FaultCause, LaserColour, Sweep};
use qhm_link::{Link, LinkConfig, LinkError, LinkEvent};
use sim::{RigHandle, SimConfig, spawn_in_process};

const SPEED: f64 = 10.0;

fn sim_config(seed: u64) -> SimConfig {
    let mut cfg = SimConfig::seeded(seed);
    cfg.speed = SPEED;
    // Start near the home cams so homing takes a fraction of a second.
    cfg.rig.physical.start_rad = [Some(0.3), Some(0.3)];
    cfg
}

async fn open(cfg: &SimConfig) -> (Link, RigHandle) {
    let (stream, rig) = spawn_in_process(cfg).expect("emulator starts");
    let link = Link::open_stream(Box::new(stream), LinkConfig::scaled(SPEED))
        .await
        .expect("handshake");
    (link, rig)
}

/// Wait (bounded) for the first event matching `pred`.
async fn next_matching(
    events: &mut qhm_link::EventStream,
    what: &str,
    pred: impl Fn(&LinkEvent) -> bool,
) -> LinkEvent {
    tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            let e = events.recv().await.expect("event stream");
            if pred(&e) {
                return e;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no {what} event within 10 s"))
}

fn is_mcu(e: &LinkEvent, f: impl Fn(&Event) -> bool) -> bool {
    matches!(e, LinkEvent::Mcu { event, .. } if f(event))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn handshake_reports_the_emulated_mcu() {
    let cfg = sim_config(11);
    let (link, rig) = open(&cfg).await;
    let id = link.identity().expect("identity after open");
    assert_eq!(id.protocol_version, protocol::PROTOCOL_VERSION);
    assert_eq!(id.schema_hash, protocol::SCHEMA_HASH);
    assert_eq!(id.boot_id, rig.with(|p| p.rig().boot_id()));
    assert!(id.limits.steps_per_rev[0] > 0);
    let again = link.identify().await.unwrap();
    assert_eq!(again.boot_id, id.boot_id);
    let status = link.status().await.unwrap();
    assert_eq!(status.boot_id, id.boot_id);
    assert_eq!(status.fault, None);
    link.heartbeat().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_command_and_event() {
    let cfg = sim_config(12);
    let (link, rig) = open(&cfg).await;
    let mut events = link.subscribe();
    let id = link.identity().unwrap();

    // Absolute moves need homing first.
    let refused = link
        .move_deg(Axis::Turntable, 10.0, false, 30.0, 60.0)
        .await;
    assert!(
        matches!(
            refused,
            Err(LinkError::Refused {
                error: CommandError::NotHomed(Axis::Turntable),
                ..
            })
        ),
        "{refused:?}"
    );

    // Home both axes: MotionDone events, homed.
    for axis in Axis::ALL {
        link.home(axis).await.unwrap();
        let done = tokio::time::timeout(Duration::from_secs(20), link.wait_motion_done(axis))
            .await
            .expect("homing finishes")
            .unwrap();
        assert!(done.homed, "{axis:?} homed");
    }
    next_matching(&mut events, "MotionDone", |e| {
        is_mcu(e, |ev| matches!(ev, Event::MotionDone { homed: true, .. }))
    })
    .await;

    // Absolute move in degrees: the physical turntable ends there.
    link.move_deg(Axis::Turntable, 20.0, false, 60.0, 120.0)
        .await
        .unwrap();
    let done = link.wait_motion_done(Axis::Turntable).await.unwrap();
    let spr = id.limits.steps_per_rev[0] as f64;
    let rad = done.position_steps as f64 * std::f64::consts::TAU / spr;
    assert!((rad - 20f64.to_radians()).abs() < 1e-3, "{rad}");
    let phys = rig.rig_state().turntable_rad;
    assert!((phys - 20f64.to_radians()).abs() < 1e-3, "physical {phys}");
    // Relative move of the light arc, then abort of a long one.
    link.move_deg(Axis::LightArc, 5.0, true, 0.0, 0.0)
        .await
        .unwrap();
    link.wait_motion_done(Axis::LightArc).await.unwrap();
    link.move_deg(Axis::LightArc, 90.0, true, 5.0, 10.0)
        .await
        .unwrap();
    let busy = link.move_deg(Axis::LightArc, 1.0, true, 5.0, 10.0).await;
    assert!(
        matches!(
            busy,
            Err(LinkError::Refused {
                error: CommandError::Busy(Axis::LightArc),
                ..
            })
        ),
        "{busy:?}"
    );
    link.abort().await.unwrap();
    let stopped = link.wait_motion_done(Axis::LightArc).await.unwrap();
    let arc_deg = stopped.position_steps as f64 * 360.0 / id.limits.steps_per_rev[1] as f64;
    assert!(
        arc_deg < 60.0,
        "abort stopped the arc early, at {arc_deg} deg"
    );

    // Galvo, lamps, laser.
    link.galvo_set_rad(0.05).await.unwrap();
    link.lamps(0b1010_0101).await.unwrap();
    link.laser_select(LaserColour::Green).await.unwrap();
    link.laser_power(500).await.unwrap();
    link.laser_arm(true).await.unwrap();
    let s = link.status().await.unwrap();
    assert_eq!(s.galvo_urad, 50_000);
    assert_eq!(s.lamps, 0b1010_0101);
    assert_eq!(s.laser.selected, LaserColour::Green);
    assert!(s.laser.armed && s.laser.emitting, "{:?}", s.laser);
    let state = rig.rig_state();
    assert!((state.galvo_rad - 0.05).abs() < 1e-3, "{state:?}");
    assert_eq!(state.lamps, 0b1010_0101);
    assert_eq!(state.laser.map(|l| l.0), Some(LaserColour::Green));

    // The interlock opens: event, laser dark; closes: event.
    rig.set_interlock(false);
    next_matching(&mut events, "Interlock open", |e| {
        is_mcu(e, |ev| matches!(ev, Event::Interlock { closed: false }))
    })
    .await;
    assert!(!link.status().await.unwrap().laser.emitting);
    assert_eq!(rig.rig_state().laser, None);
    rig.set_interlock(true);
    next_matching(&mut events, "Interlock closed", |e| {
        is_mcu(e, |ev| matches!(ev, Event::Interlock { closed: true }))
    })
    .await;
    link.laser_arm(false).await.unwrap();

    // Trigger: TriggerFired with the mask.
    link.trigger(0b11, 200).await.unwrap();
    next_matching(&mut events, "TriggerFired", |e| {
        is_mcu(e, |ev| {
            matches!(
                ev,
                Event::TriggerFired {
                    mask: 0b11,
                    pulse_us: 200,
                    ..
                }
            )
        })
    })
    .await;

    // A sweep: a step event and a trigger per step, then SweepDone.
    let sweep = Sweep {
        start_urad: -20_000,
        end_urad: 20_000,
        steps: 5,
        dwell_us: 3_000,
        trigger_mask: 0b1,
        pulse_us: 500,
    };
    let mut sweep_events = link.subscribe();
    link.galvo_sweep(sweep).await.unwrap();
    let completed = tokio::time::timeout(Duration::from_secs(10), link.wait_sweep_done())
        .await
        .expect("sweep ends")
        .unwrap();
    assert!(completed);
    let mut steps = Vec::new();
    let mut fired = 0;
    while let Some(e) = sweep_events.try_recv() {
        match e.unwrap() {
            LinkEvent::Mcu {
                event: Event::SweepStepDone { step, .. },
                ..
            } => steps.push(step),
            LinkEvent::Mcu {
                event: Event::TriggerFired { mask: 1, .. },
                ..
            } => fired += 1,
            _ => {}
        }
    }
    assert_eq!(steps, [0, 1, 2, 3, 4]);
    assert_eq!(fired, 5);

    // E-stop latches a fault: event, refusals, clear.
    link.estop().await.unwrap();
    next_matching(&mut events, "Fault", |e| {
        is_mcu(e, |ev| {
            matches!(
                ev,
                Event::Fault {
                    cause: FaultCause::EStop
                }
            )
        })
    })
    .await;
    let s = link.status().await.unwrap();
    assert_eq!(s.fault, Some(FaultCause::EStop));
    assert_eq!(s.lamps, 0);
    let refused = link.lamps(1).await;
    assert!(
        matches!(
            refused,
            Err(LinkError::Refused {
                error: CommandError::Faulted(FaultCause::EStop),
                ..
            })
        ),
        "{refused:?}"
    );
    link.clear_fault().await.unwrap();
    assert_eq!(link.status().await.unwrap().fault, None);

    // Bad arguments are refused by the MCU, never executed.
    let bad = link.laser_power(1001).await;
    assert!(matches!(
        bad,
        Err(LinkError::Refused {
            error: CommandError::BadArgument,
            ..
        })
    ));

    // Reset on purpose: a new boot, identified before reset() returns.
    let old = id.boot_id;
    let new = link.reset().await.unwrap();
    assert_ne!(new.boot_id, old);
    assert_eq!(new.boot_id, rig.with(|p| p.rig().boot_id()));
    // An intentional reset is not reported as an interruption.
    let s = link.status().await.unwrap();
    assert_eq!(s.boot_id, new.boot_id);
    assert!(!s.axes[0].homed);

    let stats = link.stats();
    assert_eq!(stats.timeouts, 0, "{stats:?}");
    assert!(stats.events > 10, "{stats:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reset_in_the_middle_of_a_sweep_is_reported_with_the_laser_off() {
    let cfg = sim_config(13);
    let (link, rig) = open(&cfg).await;
    let mut events = link.subscribe();
    link.laser_select(LaserColour::Red).await.unwrap();
    link.laser_power(300).await.unwrap();
    link.laser_arm(true).await.unwrap();
    let sweep = Sweep {
        start_urad: -100_000,
        end_urad: 100_000,
        steps: 200,
        dwell_us: 5_000,
        trigger_mask: 0b10,
        pulse_us: 1_000,
    };
    link.galvo_sweep(sweep).await.unwrap();
    let waiter = {
        let link = link.clone();
        tokio::spawn(async move { link.wait_sweep_done().await })
    };
    // Let a few steps run, then reset the MCU behind the host's back.
    next_matching(&mut events, "SweepStepDone 3", |e| {
        is_mcu(e, |ev| matches!(ev, Event::SweepStepDone { step: 3, .. }))
    })
    .await;
    assert!(rig.rig_state().laser.is_some(), "laser on during the sweep");
    rig.reset_mcu();

    let outcome = tokio::time::timeout(Duration::from_secs(10), waiter)
        .await
        .expect("waiter wakes")
        .unwrap();
    match outcome {
        Err(LinkError::DeviceReset {
            interrupted,
            status,
        }) => {
            assert_eq!(interrupted, Some(Command::GalvoSweep(sweep)));
            assert!(!status.laser.emitting && !status.laser.armed, "{status:?}");
            assert_eq!(status.sweep_step, None);
            assert_eq!(status.boot_id, rig.with(|p| p.rig().boot_id()));
        }
        other => panic!("expected DeviceReset, got {other:?}"),
    }
    assert_eq!(rig.rig_state().laser, None, "laser physically off");
    // Reported once: the next call goes through on the new boot, nothing was re-issued.
    let s = link.status().await.unwrap();
    assert_eq!(s.sweep_step, None);
    assert!(!s.laser.armed);
    assert_eq!(link.stats().resets, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reset_while_a_command_is_in_flight_names_that_command() {
    let cfg = sim_config(14);
    let (link, rig) = open(&cfg).await;
    link.home(Axis::Turntable).await.unwrap();
    link.wait_motion_done(Axis::Turntable).await.unwrap();
    rig.reset_mcu();
    // The next command meets a rebooted MCU (NotIdentified).
    let r = link.move_deg(Axis::Turntable, 10.0, false, 0.0, 0.0).await;
    match r {
        Err(LinkError::DeviceReset {
            interrupted: Some(Command::Move { axis, .. }),
            status,
        }) => {
            assert_eq!(axis, Axis::Turntable);
            assert!(!status.axes[0].homed);
            assert!(!status.axes[0].moving, "the move was not re-issued");
        }
        // The Booted event may beat the command to the host: then the reset
        // is reported to this call before sending it.
        Err(LinkError::DeviceReset { status, .. }) => assert!(!status.axes[0].moving),
        other => panic!("expected DeviceReset, got {other:?}"),
    }
    let s = link.status().await.unwrap();
    assert!(!s.axes[0].moving && !s.axes[0].homed);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disconnect_is_a_clear_error() {
    let cfg = sim_config(15);
    let (link, rig) = open(&cfg).await;
    let mut events = link.subscribe();
    rig.disconnect();
    next_matching(&mut events, "Disconnected", |e| {
        matches!(e, LinkEvent::Disconnected { .. })
    })
    .await;
    let r = link.status().await;
    assert!(matches!(r, Err(LinkError::Disconnected { .. })), "{r:?}");
    assert!(matches!(
        link.reconnect().await,
        Err(LinkError::ReconnectUnsupported)
    ));
}

/// A fake MCU that answers every `Identify` with `identity` and ignores
/// everything else: enough to test the handshake checks.
fn fake_mcu(identity: protocol::Identity) -> tokio::io::DuplexStream {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let (host, mut mcu) = tokio::io::duplex(4096);
    tokio::spawn(async move {
        let mut dec = protocol::FrameDecoder::new();
        let mut buf = [0u8; 256];
        loop {
            let n = match mcu.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            };
            let mut replies = Vec::new();
            dec.push_slice::<protocol::HostFrame>(&buf[..n], |r| {
                if let Ok(f) = r
                    && f.command == Command::Identify
                {
                    replies.push(protocol::McuFrame::Ack {
                        seq: f.seq,
                        result: Ok(protocol::Reply::Identity(identity.clone())),
                    });
                }
            });
            for r in replies {
                let mut out = [0u8; protocol::MAX_FRAME];
                let n = protocol::encode_frame(&r, &mut out).unwrap();
                if mcu.write_all(&out[..n]).await.is_err() {
                    return;
                }
            }
        }
    });
    host
}

fn identity(protocol_version: u16, schema_hash: u32) -> protocol::Identity {
    protocol::Identity {
        protocol_version,
        schema_hash,
        firmware_version: [0, 1, 0],
        board: "fake".try_into().unwrap(),
        boot_id: 42,
        limits: firmware::Controller::limits(),
    }
}

#[tokio::test]
async fn handshake_refuses_another_protocol_version_or_schema() {
    let cfg = LinkConfig::scaled(10.0);
    let stream = fake_mcu(identity(
        protocol::PROTOCOL_VERSION + 1,
        protocol::SCHEMA_HASH,
    ));
    match Link::open_stream(Box::new(stream), cfg.clone()).await {
        Err(e @ LinkError::VersionMismatch { .. }) => {
            assert!(e.to_string().contains("protocol version"), "{e}")
        }
        Err(e) => panic!("expected VersionMismatch, got {e}"),
        Ok(_) => panic!("accepted a peer with another protocol version"),
    }
    let stream = fake_mcu(identity(
        protocol::PROTOCOL_VERSION,
        protocol::SCHEMA_HASH ^ 1,
    ));
    assert!(matches!(
        Link::open_stream(Box::new(stream), cfg).await,
        Err(LinkError::SchemaMismatch { .. })
    ));
}

#[tokio::test]
async fn a_silent_peer_times_out_after_the_configured_tries() {
    let (host, _mcu) = tokio::io::duplex(4096);
    let cfg = LinkConfig {
        tries: 4,
        ..LinkConfig::scaled(100.0)
    };
    let t = std::time::Instant::now();
    match Link::open_stream(Box::new(host), cfg).await {
        Err(LinkError::Timeout { command, tries }) => {
            assert_eq!(command, Command::Identify);
            assert_eq!(tries, 4);
        }
        Err(e) => panic!("expected Timeout, got {e}"),
        Ok(_) => panic!("handshake with nobody"),
    }
    // 2 + 4 + 8 + 16 ms of back-off, far below a second.
    assert!(t.elapsed() < Duration::from_secs(2));
}
