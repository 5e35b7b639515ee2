//! One walk alone, for profiling (`perf record`) and before/after timings:
//! `cargo run --release -p sim-light --example walk_bench [photons] [preset] [channel]`
//! (default 400 k photons, whole milk, green: the bench's homogeneous row).
//! A pencil beam into a 200 x 200 x 100 mm slab, one thread, no cameras;
//! prints real collisions per CPU second and the tally.
use glam::Vec3;
use sim_light::RigTruth;
use sim_light::SceneDesc;
use sim_light::Source;
use sim_light::{SimQuality, World};

fn main() -> Result<(), sim_light::Error> {
    let args: Vec<String> = std::env::args().collect();
    let photons: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(400_000);
    let preset = args.get(2).map(String::as_str).unwrap_or("whole-milk");
    let ch: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    let mut desc = SceneDesc::preset(preset)?;
    if let SceneDesc::Sample(s) = &mut desc {
        s.size_mm = [200.0, 200.0, 100.0];
    }
    let world = World::new(desc, RigTruth::nominal(), SimQuality::ci())?;
    let pencil = Source::Pencil {
        origin: Vec3::new(0.0, 0.0, 10.0),
        dir: -Vec3::Z,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| world.trace(&pencil, ch, photons / 10, 99, None));
    let c0 = sim_light::bench::process_cpu_seconds().unwrap();
    let t = pool.install(|| world.trace(&pencil, ch, photons, 1, None));
    let c = sim_light::bench::process_cpu_seconds().unwrap() - c0;
    println!(
        "{preset} ch{ch}: {:.2} M events per CPU s ({} events, {:.2} CPU s, {:.1} events/path, exited {}, absorbed {}, escaped {})",
        t.events as f64 / c / 1e6,
        t.events,
        c,
        t.events as f64 / photons as f64,
        t.exited,
        t.absorbed,
        t.escaped
    );
    Ok(())
}
