//! The transport benchmark as a release binary:
//! `cargo run --release -p sim-light --example bench [photons] [--pose]`.
fn main() -> Result<(), sim_light::Error> {
    let photons = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(200_000);
    let pose = std::env::args().any(|a| a == "--pose");
    let r = sim_light::bench::run(photons, pose)?;
    for row in &r.rows {
        println!(
            "{:28} {} thr: {:8.0} paths/s, {:6.1} M events/s wall ({:5.1} M/s/thread), {:6.1} events/path, {:5.1} M null/s, {:6.1} M events per CPU s",
            row.medium,
            row.threads,
            row.paths_per_s,
            row.events_per_s / 1e6,
            row.events_per_s_per_core / 1e6,
            row.mean_events_per_path,
            row.null_events_per_s / 1e6,
            row.events_per_cpu_s.unwrap_or(0.0) / 1e6
        );
    }
    println!(
        "speed-up 1->2: {:?}  full pose: {:?} s ({:?} CPU s)  splat share: {:?}",
        r.speedup_1_to_2, r.full_pose_seconds, r.full_pose_cpu_seconds, r.splat_share
    );
    Ok(())
}
