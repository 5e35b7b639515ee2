//! Tally and time of a pencil beam into a large slab of a preset, one
//! thread: `cargo run --release -p sim-light --example cell_probe -- sponge 0 100000`.
use sim_light::bench::{medium_world, pencil, pool, timed};

fn main() -> Result<(), sim_light::Error> {
    let mut a = std::env::args().skip(1);
    let name = a.next().unwrap_or("sponge".into());
    let ch: usize = a.next().and_then(|s| s.parse().ok()).unwrap_or(0);
    let n: u64 = a.next().and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let (w, s) = {
        let (w, s, _) = timed(|| medium_world(&name));
        (w?, s)
    };
    println!("build {s:.2} s");
    let p = pool(1);
    let (t, s, cpu) = timed(|| p.install(|| w.trace(&pencil(), ch, n, 1, None)));
    println!("{t:?}\nbalanced {}", t.balanced());
    println!(
        "{s:.2} s ({cpu:?} CPU s): {:.2} M events/s, {:.1} events/path, R {:.4}",
        t.events as f64 / s / 1e6,
        t.events as f64 / n as f64,
        t.exited as f64 / n as f64
    );
    Ok(())
}
