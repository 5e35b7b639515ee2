//! The output rule on the real `qhm` binary, one test per command: an
//! existing output is refused with a message naming it and `--force`, and
//! left untouched; `--force` replaces it and keeps no stale files; a
//! directory that holds something else is refused even with `--force`.

mod cli_util;
use cli_util::{run as qhm, snapshot};

use std::path::{Path, PathBuf};

use qhm_model::synthetic_dataset::{SynthSpec, write_synthetic};
use qhm_model::{DipoleParams, MaterialModel};

fn ok(args: &[impl AsRef<std::ffi::OsStr> + std::fmt::Debug]) -> String {
    let (ok, text) = qhm(args);
    assert!(ok, "qhm {args:?} failed: {text}");
    text
}

fn refused(args: &[impl AsRef<std::ffi::OsStr> + std::fmt::Debug], want: &[&str]) -> String {
    let (ok, text) = qhm(args);
    assert!(!ok, "qhm {args:?} should have been refused: {text}");
    for w in want {
        assert!(
            text.contains(w),
            "qhm {args:?}: message lacks {w:?}: {text}"
        );
    }
    assert_eq!(text.trim().lines().count(), 1, "one-line message: {text}");
    text
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

const TRUTH: DipoleParams = DipoleParams {
    alpha_prime: [0.99, 0.97, 0.9],
    sigma_t_prime: [1.0, 1.5, 2.0],
    eta: 1.3,
    model: qhm_model::ProfileModel::Dipole,
};

/// A small synthetic rectified capture (a tenth of a second's fit with `--model dipole`).
fn synthetic_capture(root: &Path) -> PathBuf {
    let cap = root.join("cap");
    let mut spec = SynthSpec::small(TRUTH);
    spec.width = 16;
    spec.height = 16;
    spec.scan_offsets_mm = vec![-3.0, -1.1, 0.7, 2.3];
    write_synthetic(&cap, &spec).unwrap();
    cap
}

#[test]
fn fit_refuses_models_and_foreign_dirs_and_force_replaces_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = synthetic_capture(tmp.path());
    let model = tmp.path().join("model");
    ok(&["fit", "--model", "dipole", s(&cap), "-o", s(&model)]);
    let raw = snapshot(&model);
    assert!(
        raw.keys()
            .any(|p| p.starts_with("lrf") && s(p).contains("sample_"))
    );

    // Onto the model: refused, untouched.
    refused(
        &[
            "fit",
            "--model",
            "dipole",
            s(&cap),
            "-o",
            s(&model),
            "--lrf-components",
            "2",
        ],
        &[s(&model), "already holds a material model", "--force"],
    );
    assert_eq!(snapshot(&model), raw);

    // With --force: the PCA model alone, no raw LRF samples left over.
    ok(&[
        "fit",
        "--model",
        "dipole",
        s(&cap),
        "-o",
        s(&model),
        "--lrf-components",
        "2",
        "--force",
    ]);
    let pca = snapshot(&model);
    assert!(pca.keys().any(|p| s(p).contains("pca_basis")));
    assert!(
        !pca.keys().any(|p| s(p).contains("sample_")),
        "stale files: {:?}",
        pca.keys().collect::<Vec<_>>()
    );
    assert!(MaterialModel::load(&model).is_ok());
    // No staging directory is left beside it.
    let siblings: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(siblings.len(), 2, "{siblings:?}");

    // A foreign non-empty directory: refused even with --force.
    let foreign = tmp.path().join("photos");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("holiday.jpg"), b"jpeg").unwrap();
    for force in [false, true] {
        let mut args = vec!["fit", "--model", "dipole", s(&cap), "-o", s(&foreign)];
        if force {
            args.push("--force");
        }
        refused(&args, &[s(&foreign), "refusing"]);
    }
    assert_eq!(snapshot(&foreign).len(), 1);

    // An empty directory is fine.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    ok(&["fit", "--model", "dipole", s(&cap), "-o", s(&empty)]);
    assert!(empty.join("manifest.toml").exists());
}

#[test]
fn report_refuses_foreign_index_and_force_replaces_a_report() {
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("model");
    MaterialModel::homogeneous(TRUTH).save(&model).unwrap();

    // A directory with someone's own index.html: refused, with or without --force.
    let site = tmp.path().join("site");
    std::fs::create_dir(&site).unwrap();
    std::fs::write(site.join("index.html"), b"<p>my page</p>").unwrap();
    for extra in [None, Some("--force")] {
        let mut args = vec!["report", s(&model), "-o", s(&site)];
        args.extend(extra);
        refused(&args, &[s(&site), "refusing"]);
    }
    assert_eq!(
        std::fs::read(site.join("index.html")).unwrap(),
        b"<p>my page</p>"
    );
    assert_eq!(snapshot(&site).len(), 1);

    // The default output (MODEL/report), then again: refused without --force.
    let text = ok(&["report", s(&model)]);
    let report = model.join("report");
    assert!(text.contains(s(&report.join("index.html"))), "{text}");
    assert!(!text.contains(".tmp-"), "names the staging dir: {text}");
    std::fs::write(report.join("stale.png"), b"old").unwrap();
    let before = snapshot(&report);
    refused(
        &["report", s(&model)],
        &[s(&report), "already holds a qhm report", "--force"],
    );
    assert_eq!(snapshot(&report), before);
    ok(&["report", s(&model), "--force"]);
    assert!(report.join("index.html").exists());
    assert!(!report.join("stale.png").exists(), "stale file kept");
}

#[test]
fn render_and_exports_refuse_existing_files() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("out.png");
    let pbrt = tmp.path().join("m.pbrt");
    let xml = tmp.path().join("m.xml");
    for p in [&png, &pbrt, &xml] {
        std::fs::write(p, b"mine").unwrap();
    }
    let small = [
        "--model",
        "builtin:marble",
        "--builtin",
        "slab",
        "--width",
        "8",
        "--height",
        "8",
        "--spp",
        "1",
        "--samples",
        "200",
        "--quiet",
    ];
    let with = |extra: &[&str]| -> Vec<String> {
        ["render"]
            .iter()
            .chain(&small)
            .chain(extra)
            .map(|a| a.to_string())
            .collect()
    };
    refused(&with(&["-o", s(&png)]), &[s(&png), "--force"]);
    refused(&with(&["--export-pbrt", s(&pbrt)]), &[s(&pbrt), "--force"]);
    refused(&with(&["--export-mitsuba", s(&xml)]), &[s(&xml), "--force"]);
    // One existing output refuses the whole command: nothing else is written.
    let fresh = tmp.path().join("fresh.pbrt");
    refused(
        &with(&["--export-pbrt", s(&fresh), "-o", s(&png)]),
        &[s(&png)],
    );
    assert!(!fresh.exists());
    for p in [&png, &pbrt, &xml] {
        assert_eq!(std::fs::read(p).unwrap(), b"mine");
    }
    ok(&with(&[
        "-o",
        s(&png),
        "--export-pbrt",
        s(&pbrt),
        "--export-mitsuba",
        s(&xml),
        "--force",
    ]));
    assert!(image::open(&png).is_ok());
    assert!(std::fs::read_to_string(&pbrt).unwrap().contains("Material"));
    assert!(std::fs::read_to_string(&xml).unwrap().contains("<bsdf"));
    // `-` is stdout, never a file.
    let text = ok(&["render", "--model", "builtin:marble", "--export-pbrt", "-"]);
    assert!(text.contains("Material"), "{text}");
}

#[test]
fn sim_render_refuses_existing_files() {
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("frame.png");
    let exr = tmp.path().join("frame.exr");
    std::fs::write(&png, b"mine").unwrap();
    let args = |out: &Path, hdr: &Path| {
        vec![
            "sim".to_string(),
            "render".into(),
            "--sample".into(),
            "marble".into(),
            "--light".into(),
            "4".into(),
            "--quality".into(),
            "ci".into(),
            "--photons".into(),
            "2000".into(),
            "--out".into(),
            s(out).into(),
            "--hdr".into(),
            s(hdr).into(),
        ]
    };
    let a = args(&png, &exr);
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    refused(&a, &[s(&png), "--force"]);
    assert_eq!(std::fs::read(&png).unwrap(), b"mine");
    assert!(!exr.exists());
    let mut forced = a.clone();
    forced.push("--force");
    ok(&forced);
    assert!(image::open(&png).is_ok());
    assert!(exr.exists());
}

#[test]
fn demo_refuses_foreign_and_earlier_output_and_says_what_force_deletes() {
    let tmp = tempfile::tempdir().unwrap();
    let foreign = tmp.path().join("photos");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("holiday.jpg"), b"jpeg").unwrap();
    let demo = |out: &Path, force: bool| {
        let mut a = vec!["demo", "--scale", "ci", "--quiet", "-o", s(out)];
        if force {
            a.push("--force");
        }
        a.iter().map(|x| x.to_string()).collect::<Vec<_>>()
    };
    for force in [false, true] {
        let a = demo(&foreign, force);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        refused(&a, &[s(&foreign), "refusing"]);
    }
    assert_eq!(snapshot(&foreign).len(), 1);
    // An earlier demo's output: refused without --force (no demo runs here).
    let earlier = tmp.path().join("qhm-out");
    std::fs::create_dir_all(earlier.join("model")).unwrap();
    std::fs::write(earlier.join("summary.json"), b"{}").unwrap();
    let a = demo(&earlier, false);
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    refused(&a, &[s(&earlier), "--force"]);
    assert!(earlier.join("summary.json").exists());
    let help = ok(&["demo", "--help"]);
    for part in ["capture/", "model/", "report/", "summary.json"] {
        assert!(
            help.contains(part),
            "--help does not say --force deletes {part}"
        );
    }
}
