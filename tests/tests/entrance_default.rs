//! The mesostructure entrance function of a heterogeneous sample, acquired
//! at the default scale, against the simulator's tally: at every measured
//! direction and channel, the fitted f(w_i) within 3 % of the true ratio of
//! diffuse exitance (docs/model-format.md, "f(w_i) on quasi-homogeneous
//! samples"). Minutes of Monte Carlo: run with `--ignored`.

use host::demo::{DemoOptions, reload_model, run};
use host::entrance_check::{check_entrance, worst_error};
use qhm_acquire::Scale;

#[test]
#[ignore = "minutes: a default-scale capture (about 4 min on 2 cores)"]
fn default_scale_entrance_function_of_the_two_material_sample() {
    // Measured (seed 1): 1.6 %.
    entrance_within_3_percent("two-material");
}

#[test]
#[ignore = "minutes: a default-scale capture of the cellular bread (about 13 min on 2 cores)"]
fn default_scale_entrance_function_of_the_cellular_bread() {
    // Measured (seed 1): 1.2 %; each direction on its own, before the fit
    // pools the azimuths at one elevation, 3.9 %.
    entrance_within_3_percent("bread");
}

fn entrance_within_3_percent(sample: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let opts = DemoOptions {
        sample: sample.into(),
        scale: Scale::Default,
        out: out.clone(),
        force: false,
        seed: 1,
        quiet: true,
        skip_renders: true,
        calibration: None,
    };
    run(&opts).expect("the default-scale demo runs");
    let model = reload_model(&out).unwrap();
    let world = sim_light::World::new(
        sim_light::SceneDesc::preset(sample).unwrap(),
        sim_light::RigTruth::nominal(),
        sim_light::SimQuality::ci(),
    )
    .unwrap();
    let checks = check_entrance(&world, &model, 100_000, 1).unwrap();
    // The vertical, and two elevations (30 and 60 degrees from the normal)
    // on four azimuths.
    assert_eq!(checks.len(), 9);
    let worst = worst_error(&checks);
    eprintln!("{sample}: worst |fitted f / true exitance ratio - 1|: {worst:.4}");
    assert!(worst < 0.03, "f against the true exitance ratio: {worst}");
    // A fit 5 % off at one direction fails the same bound.
    let mut off = checks.clone();
    off[3].fitted[0] *= 1.05;
    assert!(worst_error(&off) > 0.03);
}
