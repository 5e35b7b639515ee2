//! Calibration is a capture: the simulated rig's calibration capture through
//! the link, the cameras and the operator, then the procedures on its frames,
//! within target on every row of the truth table; and a target the
//! procedures cannot find stops them with an error naming the camera and
//! the target, leaving the calibration as it was.
//!
//! About a minute of Monte Carlo in release: `cargo test --release -p tests
//! --test calibrate_capture -- --ignored`.

use host::calibrate::{cal_shots, calibrate_sim};
use qhm_acquire::{CaptureDir, Scale};
use qhm_imaging::Calibration;
use qhm_imaging::cal_compute::{self, Procedure};

#[test]
#[ignore = "a minute of Monte Carlo in release; run with --ignored"]
fn calibration_capture_recovers_the_rig() {
    let tmp = tempfile::tempdir().unwrap();
    let capture = tmp.path().join("calibration-capture");
    let out = tmp.path().join("calibration.toml");
    let rows = calibrate_sim(Scale::Default, 7, &capture, &out, true).unwrap();
    let missed: Vec<String> = rows
        .iter()
        .filter(|r| !r.ok)
        .map(|r| r.to_string())
        .collect();
    assert_eq!(rows.len(), 58);
    assert!(missed.is_empty(), "{missed:#?}");
    let cal = Calibration::load(&out).unwrap();
    assert_eq!(cal.camera.len(), 7);

    // A checkerboard camera 3 cannot see (its frames replaced by flat grey).
    let dir = CaptureDir::open_read(&capture).unwrap();
    let plan = dir.plan().unwrap();
    let grey = tmp.path().join("grey.png");
    image::RgbImage::from_pixel(256, 192, image::Rgb([128, 128, 128]))
        .save(&grey)
        .unwrap();
    let mut shots = cal_shots(&plan, &capture).unwrap();
    for s in shots
        .iter_mut()
        .filter(|s| s.camera == 3 && s.procedure == Procedure::Geometry)
    {
        for f in &mut s.frames {
            f.0 = grey.clone();
        }
    }
    let mut partial = Calibration::default();
    let err = cal_compute::compute(&shots, &mut partial, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("camera 3") && err.contains("checkerboard"),
        "{err}"
    );
    assert_eq!(partial.camera.len(), 0, "the calibration is left unchanged");
    // The untouched shots compute.
    let mut whole = Calibration::default();
    cal_compute::compute(&cal_shots(&plan, &capture).unwrap(), &mut whole, &|_| {}).unwrap();
    assert_eq!(whole.camera.len(), 7);
}
