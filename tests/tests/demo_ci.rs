//! The `ci`-scale demo end to end (issue 7): the simulated rig is calibrated,
//! captured, rectified, fitted, rendered and reported, and the recovered
//! global-term parameters are checked against the homogeneous sample's truth.

use host::demo::{DemoOptions, reference, reload_model, run};
use qhm_acquire::Scale;

#[test]
fn ci_demo_recovers_the_homogeneous_sample() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let sample = "marble";
    let opts = DemoOptions {
        sample: sample.into(),
        scale: Scale::Ci,
        out: out.clone(),
        force: false,
        seed: 3,
        quiet: true,
        skip_renders: false,
        calibration: None,
    };
    let summary = run(&opts).expect("the ci demo runs");
    let truth = reference(sample).expect("homogeneous presets have a truth");

    // Every documented part is there and loads.
    for part in [
        "calibration.toml",
        "capture/rectified/index.toml",
        "model/manifest.toml",
        "report/index.html",
        "summary.json",
    ] {
        assert!(out.join(part).is_file(), "{part} missing");
    }
    // The calibration capture through the link and the cameras, every row
    // of the simulated rig's truth table within target (seed 3).
    assert_eq!(
        (
            summary.calibration_rows_within_target,
            summary.calibration_rows
        ),
        (58, 58)
    );
    assert!(out.join("calibration-capture/capture.toml").is_file());
    assert_eq!(summary.renders.len(), 6);
    for r in &summary.renders {
        assert!(out.join(r).is_file(), "{r} missing");
    }
    let model = reload_model(&out).unwrap();
    assert_eq!(model.dipole, summary.recovered);

    // Issue 5's targets. Measured at this seed: a' within 0.0001; s'_t
    // -0.8, -0.2, +0.1 % (seed 1: -1.6, -1.4, -0.5 %).
    assert_meets_issue_5(sample, &summary.recovered, &truth);
    // The polished top is a flat, smooth surface: f(w_i) is the Fresnel
    // ratio T(theta_i)/T(0) within 3 % (measured: 0.5 % at most).
    let diagnostics = model
        .diagnostics
        .as_ref()
        .expect("qhm fit keeps its diagnostics");
    let oblique: Vec<_> = diagnostics
        .entrance_samples
        .iter()
        .filter(|(dir, _)| dir[2] < 0.99)
        .collect();
    assert!(
        !oblique.is_empty(),
        "no oblique laser direction was measured"
    );
    for (dir, f) in oblique {
        let t = qhm_model::fresnel::fresnel_transmittance_ratio(dir[2] as f64, model.dipole.eta);
        for c in 0..3 {
            let err = f[c] as f64 / t - 1.0;
            assert!(
                err.abs() < 0.03,
                "f({dir:?})[{c}] = {} vs Fresnel {t}",
                f[c]
            );
        }
    }

    // A homogeneous slab's lamp response has no texture: the denoising
    // keeps at most one component and takes the noise per texel away
    // (measured: none kept, 0.047 /sr of noise to 0).
    let denoised = diagnostics
        .lrf_denoise
        .as_ref()
        .expect("the fit denoises the LRF by default");
    assert!(denoised.components <= 1, "{}", denoised.summary());
    for c in 0..3 {
        assert!(
            denoised.noise_after[c] < 0.2 * denoised.noise_before[c],
            "{}",
            denoised.summary()
        );
    }

    // Against the simulator's own tally of the exitance ratio (the marble's
    // top is smooth and its albedo high, so the entering share and the
    // Fresnel ratio are within 0.5 % of it; measured: 0.6 % at most), and a
    // fit 5 % low fails the same bound.
    let world = sim_light::World::new(
        sim_light::SceneDesc::preset(sample).unwrap(),
        sim_light::RigTruth::nominal(),
        sim_light::SimQuality::ci(),
    )
    .unwrap();
    let checks = host::entrance_check::check_entrance(&world, &model, 100_000, 1).unwrap();
    let worst = host::entrance_check::worst_error(&checks);
    assert!(worst < 0.03, "f against the true entrance: {worst}");
    let low: Vec<_> = checks
        .into_iter()
        .map(|mut c| {
            c.fitted = c.fitted.map(|f| 0.95 * f);
            c
        })
        .collect();
    assert!(host::entrance_check::worst_error(&low) > 0.03);

    // A second run into the same, now non-empty, directory is refused.
    let err = run(&opts).unwrap_err();
    assert!(format!("{err:#}").contains("--force"), "{err:#}");
}

/// Issue 5's targets: a' within 0.002 absolute and s'_t within 5 %.
fn assert_meets_issue_5(
    sample: &str,
    recovered: &qhm_model::DipoleParams,
    truth: &host::demo::Reference,
) {
    for c in 0..3 {
        let (a, a_true) = (recovered.alpha_prime[c], truth.alpha_prime[c]);
        let (s, s_true) = (recovered.sigma_t_prime[c], truth.sigma_t_prime[c]);
        assert!(
            (a - a_true).abs() < 0.002,
            "{sample} channel {c}: a' {a} vs true {a_true}"
        );
        assert!(
            (s - s_true).abs() / s_true < 0.05,
            "{sample} channel {c}: s'_t {s} vs true {s_true}"
        );
    }
}

/// The same targets on a milk (a' up to 0.9996, light spreading over
/// centimetres) and on skin (a' down to 0.92, most light near the line).
/// Measured (seed 1): whole milk a' within 0.0001, s'_t -2.1, -1.8, -1.1 %;
/// skin2 a' within 0.0010, s'_t -0.4, +0.1, +0.9 %. Other seeds and
/// presets: README "Status". Both captures are of the same rig (seed 1),
/// so the skin's demo takes the milk's calibration instead of calibrating
/// again, and scores it against the rig's truth all the same.
#[test]
fn ci_demo_recovers_milk_and_skin() {
    let tmp = tempfile::tempdir().unwrap();
    let milk_cal = tmp.path().join("whole-milk/calibration.toml");
    for (sample, calibration) in [("whole-milk", None), ("skin2", Some(milk_cal.clone()))] {
        let opts = DemoOptions {
            sample: sample.into(),
            scale: Scale::Ci,
            out: tmp.path().join(sample),
            force: false,
            seed: 1,
            quiet: true,
            skip_renders: true,
            calibration,
        };
        let summary = run(&opts).expect("the ci demo runs");
        assert_eq!(
            (
                summary.calibration_rows_within_target,
                summary.calibration_rows
            ),
            (58, 58),
            "{sample}"
        );
        let truth = reference(sample).expect("homogeneous presets have a truth");
        assert_meets_issue_5(sample, &summary.recovered, &truth);
    }
    assert!(!tmp.path().join("skin2/calibration-capture").exists());
}

/// A calibration of another rig (seed) is scored against this rig's truth:
/// the demo does not take it for its own.
#[test]
fn a_calibration_of_another_rig_scores_badly() {
    let tmp = tempfile::tempdir().unwrap();
    let plane_arc = qhm_acquire::cal_plan::CalPlanConfig::for_scale(Scale::Ci).plane_arc;
    let truth = sim_devices::SimTruth::new(2);
    let mut other = qhm_imaging::Calibration::default();
    truth.truth(&mut other, plane_arc);
    let path = tmp.path().join("seed2.toml");
    other.save(&path).unwrap();
    let own = sim_devices::SimTruth::new(1);
    let ok = |t: &sim_devices::SimTruth| {
        let cal = qhm_imaging::Calibration::load(&path).unwrap();
        t.rows(&cal, plane_arc).iter().filter(|r| r.ok).count()
    };
    assert_eq!(ok(&truth), 58);
    assert!(ok(&own) < 58, "seed 2's calibration passes for seed 1");
}
