//! Fits a rectified capture and saves the model, printing the stage times:
//! `cargo run --release -p qhm-model --example fit_dir -- CAPTURE_DIR MODEL_DIR [ETA]`
//! (what `qhm fit` does, without the CLI's output handling).

use std::path::PathBuf;

use qhm_model::fit::{FitOptions, fit_capture};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        eprintln!("usage: fit_dir CAPTURE_DIR MODEL_DIR [ETA]");
        std::process::exit(2);
    }
    let mut opts = FitOptions::default();
    if let Some(e) = args.get(2) {
        opts.eta = e.parse().unwrap_or_else(|_| {
            eprintln!("error: ETA {e:?} is not a number");
            std::process::exit(2)
        });
    }
    let t = std::time::Instant::now();
    let (model, timings) = fit_capture(&PathBuf::from(&args[0]), &opts).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(1)
    });
    let secs = t.elapsed().as_secs_f64();
    if let Err(e) = model.save(&PathBuf::from(&args[1])) {
        eprintln!("error: {e}");
        std::process::exit(1)
    }
    println!("fit {secs:.2} s: {timings:?}");
    let dir = PathBuf::from(&args[1]);
    if let Err(e) = qhm_model::report::write_report(&model, &dir, &dir.join("report")) {
        eprintln!("error: {e}");
        std::process::exit(1)
    }
    for n in model.diagnostics.iter().flat_map(|d| &d.notes) {
        println!("note: {n}");
    }
}
