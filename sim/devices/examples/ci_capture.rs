//! Runs a whole capture on the built-in simulated rig and prints how long it
//! took: `cargo run --release -p sim-devices --example ci_capture -- [scale] [dir]`.

use std::time::Instant;

use qhm_acquire::{
    CaptureDir, Manifest, Plan, PlanConfig, Progress, RunOptions, Scale, run_capture,
};
use sim_devices::SimRig;

struct Notes;
impl Progress for Notes {
    fn note(&mut self, m: &str) {
        eprintln!("note: {m}");
    }
    fn frame(&mut self, step: &qhm_acquire::plan::Step, done: usize) {
        if done % 20 == 0 {
            eprintln!("{done} frames (step {})", step.index);
        }
    }
}

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let scale: Scale = args.get(1).map_or("ci", |s| s.as_str()).parse()?;
    let out = args
        .get(2)
        .cloned()
        .unwrap_or_else(|| format!("/tmp/qhm-capture-{}", scale.name()));
    let plan = Plan::new(PlanConfig::for_scale(scale))?;
    let t0 = Instant::now();
    let mut rig = SimRig::start("two-material", scale, 1).await?;
    let speed = rig.handle.rig().speed();
    let mut dir = CaptureDir::create(
        std::path::Path::new(&out),
        Manifest::new("sim", "two-material", 1, &plan),
    )?;
    let mut op = rig.handle.operator();
    let opts = RunOptions {
        time_scale: speed,
        ..RunOptions::default()
    };
    let report = run_capture(
        &rig.link,
        &mut rig.cameras,
        &mut op,
        &mut dir,
        &opts,
        &mut Notes,
    )
    .await?;
    println!(
        "{}: {} frames in {:.1} s wall ({:.1} s rig time at speed {speed}); {report:?}",
        scale.name(),
        dir.frame_count(),
        t0.elapsed().as_secs_f64(),
        rig.handle.rig().now_us() as f64 * 1e-6,
    );
    Ok(())
}
