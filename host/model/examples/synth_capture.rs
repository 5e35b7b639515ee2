//! Writes a small synthetic rectified capture (the acquisition contract) and a
//! stripe-profile CSV, for trying `qhm fit`, `qhm report` and `qhm fit-profile`:
//! `cargo run --release -p qhm-model --example synth_capture -- OUT_DIR`.

use qhm_model::DipoleParams;
use qhm_model::dipole::{Dipole, total_reflectance};
use qhm_model::profile::Profile;
use qhm_model::synthetic_dataset::{SynthSpec, write_synthetic};

fn main() {
    let Some(out) = std::env::args().nth(1) else {
        eprintln!("usage: synth_capture OUT_DIR");
        std::process::exit(2);
    };
    let out = std::path::PathBuf::from(out);
    let truth = DipoleParams {
        alpha_prime: [0.995, 0.98, 0.9],
        sigma_t_prime: [1.2, 1.8, 2.6],
        eta: 1.3,
        model: qhm_model::ProfileModel::Dipole,
    };
    write_synthetic(&out.join("capture"), &SynthSpec::small(truth)).expect("synthesise");
    let dp = Dipole::new(truth.alpha_prime[1], truth.sigma_t_prime[1], 1.3);
    let p = Profile::new(
        (0..300).map(|k| (k as f64 * 0.05, dp.stripe(k as f64 * 0.05))),
        0.0,
    );
    std::fs::write(out.join("profile.csv"), p.to_csv()).expect("write csv");
    println!(
        "wrote {}/capture and {}/profile.csv (green: a' {}, s'_t {}, R {:.6})",
        out.display(),
        out.display(),
        truth.alpha_prime[1],
        truth.sigma_t_prime[1],
        total_reflectance(truth.alpha_prime[1], 1.3)
    );
}
