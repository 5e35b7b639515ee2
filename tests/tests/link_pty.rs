//! The link client over a real serial device path: the emulator serves its
//! MCU on a pseudo-terminal and the client opens it with `serialport`, as it
//! would a USB serial adapter. (The two-process version, `qhm sim --pty` and
//! `qhm rig --port`, is in host/tests/link_pty.rs.)

use std::time::Duration;

use protocol::{Event, LaserColour};
use qhm_link::{Link, LinkConfig, LinkError, LinkEvent};
use sim::{SimConfig, serve_pty};

const SPEED: f64 = 10.0;

fn config(seed: u64) -> SimConfig {
    let mut cfg = SimConfig::seeded(seed);
    cfg.speed = SPEED;
    cfg
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_and_events_through_a_pseudo_terminal() {
    let server = serve_pty(&config(21)).expect("pty server");
    let path = server.path().to_string_lossy().to_string();
    let link = Link::open_serial(&path, 115_200, LinkConfig::scaled(SPEED))
        .await
        .expect("open the pty as a serial port");
    let id = link.identity().unwrap();
    assert_eq!(id.protocol_version, protocol::PROTOCOL_VERSION);
    assert_eq!(id.boot_id, server.handle().with(|p| p.rig().boot_id()));

    let mut events = link.subscribe();
    link.lamps(0b0110).await.unwrap();
    link.laser_select(LaserColour::Blue).await.unwrap();
    link.galvo_set(-30_000).await.unwrap();
    link.trigger(0b100, 300).await.unwrap();
    let fired = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            if let LinkEvent::Mcu {
                event: Event::TriggerFired { mask, .. },
                ..
            } = events.recv().await.unwrap()
            {
                return mask;
            }
        }
    })
    .await
    .expect("TriggerFired arrives");
    assert_eq!(fired, 0b100);
    let s = link.status().await.unwrap();
    assert_eq!(s.lamps, 0b0110);
    assert_eq!(s.galvo_urad, -30_000);
    assert_eq!(s.laser.selected, LaserColour::Blue);
    assert_eq!(server.handle().rig_state().lamps, 0b0110);

    // Reopen the device without rebuilding the handle: same boot, state kept.
    let again = link.reconnect().await.unwrap();
    assert_eq!(again.boot_id, id.boot_id);
    assert_eq!(link.status().await.unwrap().lamps, 0b0110);
    link.lamps(0).await.unwrap();
    assert_eq!(server.handle().rig_state().lamps, 0);

    // The server goes away: a clear disconnect, and reopening fails cleanly.
    server.stop();
    let r = tokio::time::timeout(Duration::from_secs(5), link.status())
        .await
        .expect("fails promptly");
    assert!(
        matches!(
            r,
            Err(LinkError::Disconnected { .. } | LinkError::Timeout { .. })
        ),
        "{r:?}"
    );
    let r = link.reconnect().await;
    assert!(r.is_err(), "{r:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_device_is_one_clear_error() {
    let r = Link::open_serial("/dev/qhm-no-such-port", 115_200, LinkConfig::default()).await;
    match r {
        Err(e @ LinkError::Open { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("/dev/qhm-no-such-port"), "{msg}");
            assert!(!msg.contains('\n'), "{msg}");
        }
        Err(e) => panic!("expected an Open error, got {e}"),
        Ok(_) => panic!("opened a missing device"),
    }
}
