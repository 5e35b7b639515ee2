//! The bench's full-size pose alone, for profiling and before/after timings:
//! `cargo run --release -p sim-light --example pose_bench [repeats] [threads]`.
//! Whole milk, green laser stripe, 7 cameras at 1024 x 768, the default
//! photon budget (`SimQuality::default_scale`); prints wall and CPU seconds
//! of each render (the world is built before the clock starts).
use sim_light::bench::{full_pose_scene, process_cpu_seconds};

fn main() -> Result<(), sim_light::Error> {
    let args: Vec<String> = std::env::args().collect();
    let repeats: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(3);
    let threads: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(2);
    let (world, illum) = full_pose_scene()?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    for _ in 0..repeats {
        let c0 = process_cpu_seconds().unwrap_or(0.0);
        let t0 = std::time::Instant::now();
        let r = pool.install(|| world.render_pose(&illum, 0xFE, 1))?;
        let wall = t0.elapsed().as_secs_f64();
        let cpu = process_cpu_seconds().unwrap_or(0.0) - c0;
        println!(
            "full pose, {threads} threads: {wall:.2} s wall, {cpu:.2} CPU s; {} photons, {} events",
            r.tally.launched, r.tally.events
        );
    }
    Ok(())
}
