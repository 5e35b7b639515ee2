//! `qhm rectify --shard K/N` and `--merge` on the real binary: N = 1, 2 and
//! 3 shares, run at once by GNU parallel and merged, give a rectified
//! dataset byte-identical to the unsharded run, file for file; a merge with
//! a share missing, a share already done, and malformed K/N are refused in
//! one line. The capture is a small synthetic one (the `ci` plan at 8x
//! binning, frames drawn here rather than simulated, so it takes a second).

mod cli_util;
use cli_util::{run as qhm, snapshot};

use std::path::{Path, PathBuf};
use std::process::Command;

use qhm_acquire::plan::Light;
use qhm_acquire::{CaptureDir, Manifest, Plan, PlanConfig, Scale};

fn ok(args: &[&str]) -> String {
    let (ok, text) = qhm(args);
    assert!(ok, "qhm {args:?} failed: {text}");
    text
}

/// The one `qhm:` line of a refused run, checked to name each of `want`.
fn refused(args: &[&str], want: &[&str]) -> String {
    let (ok, text) = qhm(args);
    assert!(!ok, "qhm {args:?} should have been refused: {text}");
    assert_eq!(text.trim().lines().count(), 1, "one line: {text}");
    for w in want {
        assert!(text.contains(w), "qhm {args:?}: lacks {w:?}: {text}");
    }
    text
}

/// Copies the capture (frames, journal, manifest, calibration), not its rectified/.
fn copy_capture(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for (rel, bytes) in snapshot(from) {
        if rel.starts_with("rectified") {
            continue;
        }
        let p = to.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
}

/// A complete capture of the `ci` plan at 8x binning (128 x 96 frames,
/// 16^2 texels), its frames a texture plus, for laser steps, a bright band
/// that moves with the scan position; and the simulated rig's true
/// calibration beside it.
fn synthetic_capture(root: &Path) -> PathBuf {
    let cap = root.join("cap");
    let mut config = PlanConfig::for_scale(Scale::Ci);
    config.binning = 8;
    config.rectified_size = 16;
    config.laser_exposures = vec![0.0005, 0.004];
    let plan = Plan::new(config).unwrap();
    let (w, h) = plan.config.frame_size();
    let mut dir = CaptureDir::create(&cap, Manifest::new("sim", "marble", 1, &plan)).unwrap();
    for step in &plan.steps {
        for k in 0..step.triggers() {
            for &c in &step.cameras {
                let band = (w as i64 / 2 + (k as i64 - 1) * 6, step.light.clone());
                let mut rgb = Vec::with_capacity((w * h * 3) as usize);
                for y in 0..h as i64 {
                    for x in 0..w as i64 {
                        let texture =
                            1.0 + ((x * 7 + y * 3 + step.index as i64 + c as i64) % 23) as f64;
                        for ch in 0..3 {
                            let radiance = match &band.1 {
                                Light::Laser { colour, .. } if colour.index() == ch => {
                                    texture + if (x - band.0).abs() < 3 { 400.0 } else { 0.0 }
                                }
                                Light::Laser { .. } => 0.0,
                                Light::Lamp { .. } => texture * 0.2,
                            };
                            rgb.push((radiance * step.exposure_s * 500.0).clamp(0.0, 255.0) as u8);
                        }
                    }
                }
                let mut png = Vec::new();
                image::codecs::png::PngEncoder::new(&mut png)
                    .write_image(&rgb, w, h, image::ExtendedColorType::Rgb8)
                    .map(drop)
                    .unwrap();
                dir.write_frame((step.index, k as u32, c), &step.frame_path(k, c), &png)
                    .unwrap();
            }
        }
        dir.step_done(step.index).unwrap();
    }
    dir.finish().unwrap();
    drop(dir);
    let cal = cap.join("calibration.toml");
    ok(&[
        "calibrate",
        "truth",
        "--sim",
        "--seed",
        "1",
        "-o",
        cal.to_str().unwrap(),
    ]);
    cap
}

use image::ImageEncoder;

/// GNU parallel, not moreutils' command of the same name.
fn has_parallel() -> bool {
    Command::new("parallel")
        .arg("--version")
        .output()
        .is_ok_and(|o| {
            o.status.success() && String::from_utf8_lossy(&o.stdout).contains("GNU parallel")
        })
}

#[test]
fn shards_run_by_gnu_parallel_and_merged_equal_the_unsharded_run() {
    if !has_parallel() {
        eprintln!("SKIPPED: GNU parallel is not installed (Debian: apt-get install parallel)");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cap = synthetic_capture(tmp.path());
    let whole = tmp.path().join("whole");
    copy_capture(&cap, &whole);
    ok(&["rectify", whole.to_str().unwrap()]);
    let want = snapshot(&whole.join("rectified"));
    assert!(want.contains_key(Path::new("index.toml")));
    assert!(want.len() > 40, "{} files", want.len());
    for n in 1..=3usize {
        let dir = tmp.path().join(format!("split{n}"));
        copy_capture(&cap, &dir);
        let ks: Vec<String> = (1..=n).map(|k| k.to_string()).collect();
        let out = Command::new("parallel")
            .arg("--halt")
            .arg("now,fail=1")
            .arg(env!("CARGO_BIN_EXE_qhm"))
            .arg("rectify")
            .arg(&dir)
            .arg("--shard")
            .arg(format!("{{}}/{n}"))
            .arg(":::")
            .args(&ks)
            .output()
            .expect("parallel runs");
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "parallel, N = {n}: {text}");
        for k in 1..=n {
            assert!(text.contains(&format!("shard {k}/{n}:")), "{text}");
        }
        ok(&["rectify", dir.to_str().unwrap(), "--merge"]);
        let got = snapshot(&dir.join("rectified"));
        assert_eq!(
            got.keys().collect::<Vec<_>>(),
            want.keys().collect::<Vec<_>>(),
            "N = {n}: the same files"
        );
        for (f, bytes) in &want {
            assert!(got[f] == *bytes, "N = {n}: {} differs", f.display());
        }
    }
}

#[test]
fn merge_refuses_missing_shards_and_shards_refuse_redo_and_bad_values() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = synthetic_capture(tmp.path());
    let c = cap.to_str().unwrap();
    refused(
        &["rectify", c, "--merge"],
        &["no shards to merge", "--shard K/N"],
    );
    ok(&["rectify", c, "--shard", "2/3"]);
    let before = snapshot(&cap.join("rectified"));
    refused(
        &["rectify", c, "--merge"],
        &["missing shards 1/3, 3/3 of 3", "--shard K/3"],
    );
    refused(
        &["rectify", c, "--shard", "2/3"],
        &["shard 2/3 is already rectified", "--force"],
    );
    refused(
        &["rectify", c, "--shard", "1/2"],
        &["2-of-3.toml", "another split", "--force"],
    );
    refused(
        &["rectify", c, "--shard", "1/3", "--width-mm", "30"],
        &["2-of-3.toml", "other settings"],
    );
    refused(&["rectify", c], &["holds shards", "--merge", "--force"]);
    assert_eq!(
        snapshot(&cap.join("rectified")),
        before,
        "refusals change nothing"
    );
    for bad in ["0/2", "3/2", "1/0", "a/b", "2", "1/2/3"] {
        refused(&["rectify", c, "--shard", bad], &["--shard", "K/N"]);
    }
    refused(&["rectify", c, "--shard", "1/2", "--merge"], &["--merge"]);
    ok(&["rectify", c, "--shard", "2/3", "--force"]);
    ok(&["rectify", c, "--shard", "1/3"]);
    ok(&["rectify", c, "--shard", "3/3"]);
    ok(&["rectify", c, "--merge"]);
    refused(&["rectify", c, "--merge"], &["already complete", "--force"]);
    refused(
        &["rectify", c, "--shard", "1/3"],
        &["is complete", "--force"],
    );
    refused(&["rectify", c], &["already there", "--force"]);
    // --force replaces the merged dataset whole, as an unsharded run writes it.
    let merged = snapshot(&cap.join("rectified"));
    ok(&["rectify", c, "--force"]);
    assert_eq!(snapshot(&cap.join("rectified")), merged);
}
