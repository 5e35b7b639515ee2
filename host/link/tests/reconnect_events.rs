//! `reconnect()` on the same handle, against the emulated MCU in-process:
//! events the MCU raises after the reconnect reach the subscribers the
//! caller already holds (and new ones), each exactly once and in order.
//!
//! The emulator's stream is served through a small proxy so the connector
//! can hand out a fresh host end to the same rig (same boot, same event
//! queue) each time, as a serial device reopened would.

use std::sync::Arc;
use std::time::Duration;

use protocol::Event;
use qhm_link::{BoxStream, Connector, EventStream, Link, LinkConfig, LinkEvent};
use sim::{RigHandle, SimConfig, spawn_in_process};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};
use tokio::sync::Mutex;

const SPEED: f64 = 10.0;

/// A connector to one emulated rig: each call proxies a new stream onto the
/// rig's stream once the previous proxy has seen its host end close.
fn reconnectable(rig_end: DuplexStream) -> Connector {
    let rig_end = Arc::new(Mutex::new(rig_end));
    Arc::new(move || {
        let rig_end = rig_end.clone();
        Box::pin(async move {
            let (host, mut mine) = tokio::io::duplex(64 * 1024);
            tokio::spawn(async move {
                let mut rig = rig_end.lock().await;
                let (mut a, mut b) = ([0u8; 1024], [0u8; 1024]);
                loop {
                    tokio::select! {
                        r = mine.read(&mut a) => match r {
                            Ok(0) | Err(_) => return,
                            Ok(n) => if rig.write_all(&a[..n]).await.is_err() { return },
                        },
                        r = rig.read(&mut b) => match r {
                            Ok(0) | Err(_) => return,
                            // The host end is gone: bytes in flight are lost, as on a line.
                            Ok(n) => if mine.write_all(&b[..n]).await.is_err() { return },
                        },
                    }
                }
            });
            Ok(Box::new(host) as BoxStream)
        })
    })
}

async fn open(seed: u64) -> (Link, RigHandle) {
    let mut cfg = SimConfig::seeded(seed);
    cfg.speed = SPEED;
    let (stream, rig) = spawn_in_process(&cfg).expect("emulator starts");
    let link = Link::open_with(reconnectable(stream), LinkConfig::scaled(SPEED))
        .await
        .expect("handshake");
    (link, rig)
}

/// The next `n` TriggerFired events as (eseq, pulse_us); fails on anything
/// that says events were lost, or after 10 s.
async fn triggers(events: &mut EventStream, n: usize, what: &str) -> Vec<(u16, u32)> {
    let mut got = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), async {
        while got.len() < n {
            match events.recv().await.expect("event stream") {
                LinkEvent::Mcu {
                    eseq,
                    event: Event::TriggerFired { pulse_us, .. },
                    ..
                } => got.push((eseq, pulse_us)),
                LinkEvent::Mcu { .. } => {}
                other => panic!("{what}: unexpected {other:?}"),
            }
        }
    })
    .await
    .unwrap_or_else(|_| {
        panic!(
            "{what}: {} of {n} TriggerFired events in 10 s: {got:?}",
            got.len()
        )
    });
    got
}

/// Nothing more arrives for a while (no duplicates re-delivered).
async fn quiet(events: &mut EventStream, what: &str) {
    tokio::time::sleep(Duration::from_millis(300)).await;
    while let Some(e) = events.try_recv() {
        if let Ok(LinkEvent::Mcu {
            event: Event::TriggerFired { .. },
            ..
        }) = &e
        {
            panic!("{what}: extra {e:?}");
        }
    }
}

fn assert_in_order(got: &[(u16, u32)], pulses: std::ops::RangeInclusive<u32>, what: &str) {
    let want: Vec<u32> = pulses.collect();
    let pulses: Vec<u32> = got.iter().map(|g| g.1).collect();
    assert_eq!(pulses, want, "{what}: each trigger once, in order");
    assert!(
        got.windows(2)
            .all(|w| protocol::seq::seq_after(w[1].0, w[0].0)),
        "{what}: event numbers increase: {got:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn events_after_reconnect_reach_existing_and_new_subscribers_once_in_order() {
    let (link, _rig) = open(21).await;
    let mut held = link.subscribe();
    let mut pulse = 100u32;
    for round in 0..4 {
        let what = format!("round {round}");
        // A subscriber taken after the reconnect sees the same events.
        let mut fresh = link.subscribe();
        let first = pulse + 1;
        for _ in 0..5 {
            pulse += 1;
            link.trigger(1, pulse).await.unwrap();
        }
        let got = triggers(&mut held, 5, &what).await;
        assert_in_order(&got, first..=pulse, &what);
        assert_eq!(triggers(&mut fresh, 5, &what).await, got, "{what}");
        quiet(&mut held, &what).await;
        let id = link.reconnect().await.expect("reconnect");
        assert_eq!(Some(id.boot_id), link.identity().map(|i| i.boot_id));
    }
    assert_eq!(link.stats().resets, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn events_raised_just_before_a_reconnect_are_delivered_once_after_it() {
    let (link, _rig) = open(22).await;
    let mut held = link.subscribe();
    let mut pulse = 200u32;
    let mut all = Vec::new();
    for _ in 0..3 {
        // Reconnect at once: these events may still be unsent, unacknowledged
        // or in flight when the old stream goes.
        for _ in 0..3 {
            pulse += 1;
            link.trigger(1, pulse).await.unwrap();
        }
        link.reconnect().await.expect("reconnect");
    }
    all.extend(triggers(&mut held, 9, "before the reconnects").await);
    for _ in 0..3 {
        pulse += 1;
        link.trigger(1, pulse).await.unwrap();
    }
    all.extend(triggers(&mut held, 3, "after the reconnects").await);
    assert_in_order(&all, 201..=pulse, "across reconnects");
    quiet(&mut held, "after the last").await;
}
