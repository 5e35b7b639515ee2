//! One walk alone, for profiling (`perf record`) and before/after timings:
//! `cargo run --release -p sim-light --example walk_bench [photons] [preset] [channel]`
//! (default 400 k photons, whole milk, green: the bench's homogeneous row).
//! A pencil beam into a 200 x 200 x 100 mm slab, one thread, no cameras;
//! prints real collisions per CPU second and the tally.
use sim_light::bench::{medium_world, pencil, pool, timed};

fn main() -> Result<(), sim_light::Error> {
    let args: Vec<String> = std::env::args().collect();
    let photons: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(400_000);
    let preset = args.get(2).map(String::as_str).unwrap_or("whole-milk");
    let ch: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    let world = medium_world(preset)?;
    let (pencil, pool) = (pencil(), pool(1));
    pool.install(|| world.trace(&pencil, ch, photons / 10, 99, None));
    let (t, _, cpu) = timed(|| pool.install(|| world.trace(&pencil, ch, photons, 1, None)));
    let c = cpu.expect("CPU time from /proc");
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
