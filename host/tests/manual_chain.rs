//! The manual chain on a demo's directories gives the demo's model: after
//! `qhm demo --scale ci`, `qhm capture run --sim`, `qhm rectify`, `qhm fit`
//! and `qhm render` run by hand in the same directory (the calibration found
//! beside the capture, as the demo leaves it) write the same model, file for
//! file and byte for byte (fit.json's wall-clock `timings` aside), and
//! render it to the same image. The same model with its index of refraction
//! or one texel changed is shown to differ, so the comparison can fail.

mod cli_util;
use cli_util::{run as qhm, snapshot};

use std::path::{Path, PathBuf};

use host::demo::{DemoOptions, run};
use qhm_acquire::Scale;

fn ok(args: &[&str]) -> String {
    let (ok, text) = qhm(args);
    assert!(ok, "qhm {args:?} failed: {text}");
    text
}

/// How the model in `got` differs from the one in `want`: files missing or
/// extra, files whose bytes differ; fit.json compared without `timings`.
fn model_differences(want: &Path, got: &Path) -> Vec<String> {
    let (a, b) = (snapshot(want), snapshot(got));
    let mut out = Vec::new();
    let names: std::collections::BTreeSet<&PathBuf> = a.keys().chain(b.keys()).collect();
    for name in names {
        match (a.get(name), b.get(name)) {
            (Some(x), Some(y)) if name == Path::new("fit.json") => {
                let untimed = |bytes: &[u8]| {
                    let mut v: serde_json::Value = serde_json::from_slice(bytes).unwrap();
                    v.as_object_mut().unwrap().remove("timings");
                    v
                };
                if untimed(x) != untimed(y) {
                    out.push(format!("{} differs", name.display()));
                }
            }
            (Some(x), Some(y)) if x != y => out.push(format!("{} differs", name.display())),
            (Some(_), None) => out.push(format!("{} missing", name.display())),
            (None, Some(_)) => out.push(format!("{} extra", name.display())),
            _ => {}
        }
    }
    out
}

fn render(model: &Path, out: &Path) -> Vec<u8> {
    let (m, o) = (model.to_str().unwrap(), out.to_str().unwrap());
    ok(&[
        "render",
        "--model",
        m,
        "--builtin",
        "sphere",
        "--width",
        "48",
        "--height",
        "48",
        "--spp",
        "1",
        "--samples",
        "2000",
        "--quiet",
        "-o",
        o,
    ]);
    std::fs::read(out).unwrap()
}

#[test]
fn the_manual_chain_on_a_demos_directories_gives_the_demos_model() {
    let tmp = tempfile::tempdir().unwrap();
    let demo = tmp.path().join("demo");
    let (sample, seed) = ("two-material", 2);
    // The simulated rig's true calibration (no frames: a second) stands in
    // for the demo's calibration capture, which this test does not check.
    let truth = tmp.path().join("truth.toml");
    ok(&[
        "calibrate",
        "truth",
        "--sim",
        "--seed",
        &seed.to_string(),
        "-o",
        truth.to_str().unwrap(),
    ]);
    let summary = run(&DemoOptions {
        sample: sample.into(),
        scale: Scale::Ci,
        out: demo.clone(),
        force: false,
        seed,
        quiet: true,
        skip_renders: true,
        calibration: Some(truth),
    })
    .expect("the ci demo runs");
    // The demo's model and capture step aside; the manual chain writes
    // capture/ and model/ where the demo did, beside its calibration.toml.
    let demo_model = tmp.path().join("demo-model");
    std::fs::rename(demo.join("model"), &demo_model).unwrap();
    std::fs::rename(demo.join("capture"), tmp.path().join("demo-capture")).unwrap();
    let capture = demo.join("capture");
    let (cap, model) = (capture.to_str().unwrap(), demo.join("model"));
    let seed = seed.to_string();
    ok(&[
        "capture", "run", "--sim", "--scale", "ci", "--sample", sample, "--seed", &seed, "--quiet",
        "-o", cap,
    ]);
    let manifest = std::fs::read_to_string(capture.join("capture.toml")).unwrap();
    assert!(
        manifest.contains("calibration = \"../calibration.toml\""),
        "the capture records the calibration beside it:\n{manifest}"
    );
    // No --calibration: rectify finds the one the capture was taken with.
    ok(&["rectify", cap]);
    let eta = summary.recovered.eta.to_string();
    ok(&["fit", cap, "-o", model.to_str().unwrap(), "--eta", &eta]);
    let differences = model_differences(&demo_model, &model);
    assert!(
        differences.is_empty(),
        "the manual chain's model is not the demo's: {differences:?}"
    );
    let snap = snapshot(&model);
    assert!(
        snap.contains_key(Path::new("manifest.toml")) && snap.len() > 4,
        "a whole model: {:?}",
        snap.keys().collect::<Vec<_>>()
    );
    assert_eq!(
        render(&demo_model, &tmp.path().join("demo.exr")),
        render(&model, &tmp.path().join("manual.exr")),
        "the two models render differently"
    );

    // The comparison sees a model that differs: the manual chain's model
    // with its index of refraction changed, and with one texel changed.
    let other = tmp.path().join("other-model");
    cli_util::copy_tree(&model, &other);
    let manifest = std::fs::read_to_string(other.join("manifest.toml")).unwrap();
    let eta_line = format!("eta = {eta}\n");
    assert!(
        manifest.contains(&eta_line),
        "no {eta_line:?} in:\n{manifest}"
    );
    std::fs::write(
        other.join("manifest.toml"),
        manifest.replacen(&eta_line, "eta = 1.35\n", 1),
    )
    .unwrap();
    let differences = model_differences(&demo_model, &other);
    assert_eq!(differences, ["manifest.toml differs"]);
    cli_util::copy_tree(&model, &other);
    let exr = other.join("fv/view_000.exr");
    let mut bytes = std::fs::read(&exr).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&exr, bytes).unwrap();
    assert_eq!(
        model_differences(&demo_model, &other),
        ["fv/view_000.exr differs"]
    );
}
