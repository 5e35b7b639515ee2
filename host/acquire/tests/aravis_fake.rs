//! The Aravis backend against Aravis's fake GigE Vision camera on loopback
//! (`arv-fake-gv-camera-0.8 -i 127.0.0.1`, Debian's aravis-tools).
//!
//! Ignored by default (it needs the tools and a free GVCP port); `ci-aravis.sh`
//! runs it with `--ignored`. With `QHM_ARAVIS_FAKE=running` the test uses a
//! fake camera someone else started; otherwise it starts and stops its own.
#![cfg(feature = "aravis")]

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use qhm_acquire::aravis_camera::{AravisCamera, AravisConfig};
use qhm_acquire::{Camera, CameraSettings};

struct Fake(Option<Child>);

impl Drop for Fake {
    fn drop(&mut self) {
        if let Some(c) = self.0.as_mut() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn start_fake() -> Fake {
    if std::env::var("QHM_ARAVIS_FAKE").as_deref() == Ok("running") {
        return Fake(None);
    }
    let child = Command::new("arv-fake-gv-camera-0.8")
        .args(["-i", "127.0.0.1"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("arv-fake-gv-camera-0.8 (apt install aravis-tools)");
    Fake(Some(child))
}

/// Opens the camera at 127.0.0.1, retrying while the fake camera starts.
fn open(trigger: &str) -> AravisCamera {
    let t0 = Instant::now();
    loop {
        let mut cfg = AravisConfig::new(3, Some("127.0.0.1".into()));
        cfg.trigger_source = trigger.into();
        match AravisCamera::open(cfg) {
            Ok(c) => return c,
            Err(e) if t0.elapsed() < Duration::from_secs(10) => {
                eprintln!("waiting for the fake camera: {e}");
                std::thread::sleep(Duration::from_millis(300));
            }
            Err(e) => panic!("fake camera not reachable: {e}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs arv-fake-gv-camera-0.8; run by host/acquire/ci-aravis.sh"]
async fn fake_gv_camera_software_trigger() {
    let _fake = start_fake();
    let mut cam = open("Software");
    let info = cam.info();
    assert_eq!(info.index, 3);
    assert!(info.width > 0 && info.height > 0, "{info:?}");
    eprintln!("opened {info:?}");

    cam.configure(CameraSettings {
        exposure_s: 0.005,
        gain_db: 1.0,
        binning: 1,
    })
    .await
    .expect("set exposure and gain");
    // An exposure far outside the camera's range is refused, not clamped.
    assert!(
        cam.configure(CameraSettings {
            exposure_s: 1e6,
            gain_db: 0.0,
            binning: 1,
        })
        .await
        .is_err()
    );
    cam.configure(CameraSettings {
        exposure_s: 0.005,
        gain_db: 1.0,
        binning: 1,
    })
    .await
    .unwrap();

    cam.arm(vec![0xA1, 0xA2]).await.unwrap();
    for tag in [0xA1u64, 0xA2] {
        cam.software_trigger().await.expect("software trigger");
        let f = cam
            .next_frame(Duration::from_secs(5))
            .await
            .expect("a frame after the trigger");
        assert_eq!(f.meta.tag, tag);
        assert_eq!(f.meta.camera, 3);
        // The fake camera's default region is 512 x 512 of its 2048 x 2048 sensor.
        assert!(f.width > 0 && f.width <= info.width && f.height <= info.height);
        assert_eq!((f.width, f.height), (512, 512));
        assert_eq!(
            f.data.len(),
            (f.width * f.height) as usize * f.format.channels()
        );
        assert!((f.meta.exposure_s - 0.005).abs() < 1e-12);
        // The fake camera draws a non-constant test pattern.
        assert!(f.data.iter().any(|&b| b != f.data[0]));
        let png = f.to_png().unwrap();
        assert!(png.starts_with(b"\x89PNG"));
    }
    // Not armed: no frame is invented.
    assert!(cam.next_frame(Duration::from_millis(100)).await.is_err());
}

/// Triggers that come faster than the camera takes frames (the fake camera
/// looks for one every 40 ms and merges the rest) are queued, one frame each,
/// tags in order: what the MCU's trigger-fired events need.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs arv-fake-gv-camera-0.8; run by host/acquire/ci-aravis.sh"]
async fn fake_gv_camera_queued_software_triggers() {
    use qhm_acquire::soft_trigger::SoftwareTrigger;
    let _fake = start_fake();
    let mut cam = open("Software");
    cam.configure(CameraSettings {
        exposure_s: 0.001,
        gain_db: 0.0,
        binning: 1,
    })
    .await
    .unwrap();
    let tags = vec![0xB1u64, 0xB2, 0xB3, 0xB4];
    cam.arm(tags.clone()).await.unwrap();
    let handle = cam.trigger_handle();
    for k in 0..tags.len() as u64 {
        handle.fire(1000 + k);
    }
    for (k, &tag) in tags.iter().enumerate() {
        let f = cam
            .next_frame(Duration::from_secs(5))
            .await
            .expect("one frame per queued trigger");
        assert_eq!(f.meta.tag, tag);
        assert_eq!(f.meta.trigger_us, 1000 + k as u64, "the MCU's trigger time");
    }
    // No trigger, no frame: nothing beyond the four is delivered.
    cam.arm(vec![0xC1]).await.unwrap();
    assert!(cam.next_frame(Duration::from_millis(300)).await.is_err());
}

/// A camera on a hardware line refuses a software trigger instead of
/// pretending (so a missing `,trigger=software` shows at once).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs arv-fake-gv-camera-0.8; run by host/acquire/ci-aravis.sh"]
async fn fake_gv_camera_on_a_line_refuses_software_triggers() {
    let _fake = start_fake();
    let mut cam = open("Line0");
    let e = cam.software_trigger().await.unwrap_err().to_string();
    assert!(e.contains("hardware line"), "{e}");
}
