//! The transport benchmark as a release binary:
//! `cargo run --release -p sim-light --example bench [photons] [--pose]
//! [--medium NAME] [--threads N]` (one medium of `bench::BENCH_MEDIA`, or
//! one thread count, for profiling; all media on 1 and 2 threads by default).
fn main() -> Result<(), sim_light::Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let photons = args.first().and_then(|s| s.parse().ok()).unwrap_or(200_000);
    let pose = args.iter().any(|a| a == "--pose");
    let medium = value("--medium");
    let threads: Vec<usize> = match value("--threads").and_then(|s| s.parse().ok()) {
        Some(n) => vec![n],
        None => vec![1, 2],
    };
    let r = sim_light::bench::run_with(photons, medium.as_deref(), &threads, pose)?;
    for row in &r.rows {
        println!(
            "{:28} {} thr: {:8.0} paths/s, {:6.1} M events/s wall ({:5.1} M/s/thread), {:6.2} events/path, {:5.1} M null/s, {:6.2} M events per CPU s, {:6.1} wall events/path",
            row.medium,
            row.threads,
            row.paths_per_s,
            row.events_per_s / 1e6,
            row.events_per_s_per_core / 1e6,
            row.mean_events_per_path,
            row.null_events_per_s / 1e6,
            row.events_per_cpu_s.unwrap_or(0.0) / 1e6,
            row.wall_events_per_path,
        );
    }
    println!(
        "speed-up 1->2: {:?}  full pose: {:?} s ({:?} CPU s)  splat share: {:?}",
        r.speedup_1_to_2, r.full_pose_seconds, r.full_pose_cpu_seconds, r.splat_share
    );
    Ok(())
}
