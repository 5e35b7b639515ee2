//! The bench's full-size pose alone, for profiling and before/after timings:
//! `cargo run --release -p sim-light --example pose_bench [repeats] [threads]`.
//! Whole milk, green laser stripe, 7 cameras at 1024 x 768, the default
//! photon budget (`SimQuality::default_scale`); prints wall and CPU seconds
//! of each render (the world is built before the clock starts).
use sim_light::bench::{full_pose_scene, pool, timed};

fn main() -> Result<(), sim_light::Error> {
    let args: Vec<String> = std::env::args().collect();
    let repeats: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(3);
    let threads: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(2);
    let (world, illum) = full_pose_scene()?;
    let pool = pool(threads);
    for _ in 0..repeats {
        let (r, wall, cpu) = timed(|| pool.install(|| world.render_pose(&illum, 0xFE, 1)));
        let (r, cpu) = (r?, cpu.unwrap_or(0.0));
        println!(
            "full pose, {threads} threads: {wall:.2} s wall, {cpu:.2} CPU s; {} photons, {} events",
            r.tally.launched, r.tally.events
        );
    }
    Ok(())
}
