//! Figures for issue 5, run with
//! `cargo run --release -p qhm-model --example fit_bench`:
//! the s'_t search for one channel with either profile model, and the
//! whole fit of a CI-scale synthetic capture (48×48 texels, 4 views, 9 scan
//! positions, 3 passes; synthesised with the dipole, so fitted with it).

use std::time::Instant;

use qhm_model::DipoleParams;
use qhm_model::ProfileModel;
use qhm_model::dipole::Dipole;
use qhm_model::fit::{FitOptions, fit_capture};
use qhm_model::fresnel::normal_transmittance;
use qhm_model::profile::{Norm, Profile, fit_profile};
use qhm_model::radiative_transfer::HalfSpace;
use qhm_model::synthetic_dataset::{SynthSpec, write_synthetic};

fn main() {
    // One channel: whole milk red (Jensen et al. 2001), 400 profile points
    // to 20 mm, synthesised with each model and fitted with it.
    let p = DipoleParams::from_coefficients([2.55, 3.21, 3.77], [0.0011, 0.0024, 0.014], 1.3);
    let (a, st) = (p.alpha_prime[0], p.sigma_t_prime[0]);
    let t = Instant::now();
    let _ = HalfSpace::shared_for_line_profiles(1.3);
    println!(
        "transport kernel tables for eta 1.3 (once per process): {:.2} s",
        t.elapsed().as_secs_f64()
    );
    let ds: Vec<f64> = (0..400).map(|k| k as f64 * 0.05).collect();
    let xs: Vec<f64> = ds.iter().map(|d| d * st).collect();
    let dp = Dipole::new(a, st, 1.3);
    for model in [ProfileModel::Dipole, ProfileModel::Transport] {
        let values: Vec<f64> = match model {
            ProfileModel::Dipole => ds.iter().map(|&d| dp.stripe(d)).collect(),
            // A separate solver, so the fit below finds nothing of this
            // albedo in the shared one's cache.
            ProfileModel::Transport => HalfSpace::new(1.3)
                .line_profile(a, &xs)
                .iter()
                .map(|g| st * g)
                .collect(),
        };
        let profile = Profile::new(ds.iter().copied().zip(values), 0.0);
        let r = normal_transmittance(1.3) * model.total_reflectance(a, 1.3);
        let profile = Profile {
            intensity: profile
                .intensity
                .iter()
                .map(|i| i * normal_transmittance(1.3))
                .collect(),
            ..profile
        };
        let t = Instant::now();
        let fixed =
            fit_profile(&profile, r, 1.3, model, Some((1.0, 15.0)), Norm::Poisson).expect("fit");
        let search = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let auto = fit_profile(&profile, r, 1.3, model, None, Norm::Poisson).expect("fit");
        let with_range = t.elapsed().as_secs_f64();
        println!(
            "{}: a' and the s'_t search, one channel, {} points: {:.3} s (a' {:.6} true {a:.6}; s'_t {:.4} true {st:.4})",
            model.name(),
            fixed.points,
            search,
            fixed.alpha_prime,
            fixed.sigma_t_prime
        );
        println!(
            "  with automatic range {:.2}:{:.2} mm: {:.3} s (fitted {:.4})",
            auto.range_mm[0], auto.range_mm[1], with_range, auto.sigma_t_prime
        );
    }

    let truth = DipoleParams {
        alpha_prime: [0.995, 0.98, 0.9],
        sigma_t_prime: [1.2, 1.8, 2.6],
        eta: 1.3,
        model: ProfileModel::Dipole,
    };
    let dir = tempfile_dir();
    let spec = SynthSpec::small(truth);
    let t = Instant::now();
    write_synthetic(&dir, &spec).expect("synthesise");
    let synth = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let opts = FitOptions {
        model: ProfileModel::Dipole,
        ..FitOptions::default()
    };
    let (model, timings) = fit_capture(&dir, &opts).expect("fit");
    let whole = t.elapsed().as_secs_f64();
    println!("synthetic CI-scale capture written in {synth:.2} s");
    println!("whole fit: {whole:.2} s ({timings:?})");
    for c in 0..3 {
        println!(
            "  channel {c}: a' {:.5} (true {:.5}), s'_t {:.4} (true {:.4})",
            model.dipole.alpha_prime[c],
            truth.alpha_prime[c],
            model.dipole.sigma_t_prime[c],
            truth.sigma_t_prime[c]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("qhm-fit-bench-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}
