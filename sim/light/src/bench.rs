//! `qhm sim bench`: photon paths and scattering events per second, in a
//! homogeneous and a heterogeneous medium, on 1 and 2 threads. Results are
//! figures, never assertions (the machine is shared).

use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use crate::Error;
use crate::rig::RigTruth;
use crate::sample::{Coefficients, InclusionDesc, MaterialDesc, Relief, SceneDesc};
use crate::walk::Source;
use crate::world::{Illumination, LaserOn, SimQuality, World};

/// One medium on one thread count.
#[derive(Debug, Clone, Serialize)]
pub struct BenchRow {
    pub medium: String,
    pub threads: usize,
    pub photons: u64,
    pub seconds: f64,
    pub paths_per_s: f64,
    /// Real collisions per second (all threads).
    pub events_per_s: f64,
    pub events_per_s_per_core: f64,
    /// CPU seconds used (all threads), when /proc is there.
    pub cpu_seconds: Option<f64>,
    /// Real collisions per CPU second: the per-core rate on a loaded machine.
    pub events_per_cpu_s: Option<f64>,
    pub null_events_per_s: f64,
    pub mean_events_per_path: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    pub rows: Vec<BenchRow>,
    /// events/s on 2 threads over events/s on 1 thread, per medium.
    pub speedup_1_to_2: Vec<(String, f64)>,
    /// Seconds to render one full-size pose (7 cameras, laser stripe) at the
    /// default photon budget, 2 threads; None when skipped.
    pub full_pose_seconds: Option<f64>,
    /// CPU seconds of that render (both threads): on a loaded machine the
    /// wall time above also counts waiting for a core.
    pub full_pose_cpu_seconds: Option<f64>,
    /// Time share of camera splatting in a laser pose (1 thread), in [0, 1].
    pub splat_share: Option<f64>,
}

/// A homogeneous or heterogeneous preset as a 200 x 200 x 100 mm slab;
/// "sponge-voxel" is the index-matched sponge (55 % air spheres r 0.4-1.2 mm
/// on the voxel grid in the sponge's wall material, pores carved in the top),
/// the cellular sponge's reference.
pub fn medium_world(name: &str) -> Result<World, Error> {
    let mut desc = SceneDesc::preset(if name == "sponge-voxel" {
        "sponge"
    } else {
        name
    })?;
    if let SceneDesc::Sample(s) = &mut desc {
        // big enough that the walls do not matter
        s.size_mm = [200.0, 200.0, 100.0];
        if name == "sponge-voxel" {
            s.volume.material = MaterialDesc::Coefficients(Coefficients {
                sigma_s: [3.6, 3.5, 2.4],
                sigma_a: [0.004, 0.008, 0.75],
            });
            s.volume.inclusions = vec![InclusionDesc::matched(
                MaterialDesc::Preset("air".into()),
                0.55,
                [0.4, 1.2],
            )];
            s.surface.relief = Relief::Pores;
            s.surface.eta = 1.3;
        }
    }
    World::new(desc, RigTruth::nominal(), SimQuality::ci())
}

/// A normal pencil beam onto the slab's centre.
pub fn pencil() -> Source {
    Source::Pencil {
        origin: Vec3::new(0.0, 0.0, 10.0),
        dir: -Vec3::Z,
    }
}

pub fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

/// The benchmark's full-size pose: whole milk under the green laser stripe,
/// seen by 7 cameras at 1024 x 768 with the default photon budget.
pub fn full_pose_scene() -> Result<(World, Illumination), Error> {
    let world = World::new(
        SceneDesc::preset("whole-milk")?,
        RigTruth::nominal(),
        SimQuality::default_scale(),
    )?;
    let illum = Illumination {
        laser: Some(LaserOn {
            channel: 1,
            power: 1.0,
        }),
        ..Illumination::default()
    };
    Ok((world, illum))
}

/// CPU seconds this process has used (user + system), from /proc; the
/// machine is shared, so per-core rates divide by CPU time, not wall time.
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // fields 14 and 15 of stat (utime, stime) are 11 and 12 after the name; 100 Hz ticks
    let ut: f64 = f.get(11)?.parse().ok()?;
    let st: f64 = f.get(12)?.parse().ok()?;
    Some((ut + st) / 100.0)
}

/// Runs `f`: its result, wall seconds and CPU seconds (None without /proc).
pub fn timed<R>(f: impl FnOnce() -> R) -> (R, f64, Option<f64>) {
    let c0 = process_cpu_seconds();
    let t0 = Instant::now();
    let r = f();
    let wall = t0.elapsed().as_secs_f64();
    (r, wall, c0.zip(process_cpu_seconds()).map(|(a, b)| b - a))
}

/// Run the benchmark; `photons` per measurement (e.g. 200_000).
pub fn run(photons: u64, full_pose: bool) -> Result<BenchReport, Error> {
    let mut rows = Vec::new();
    let pencil = pencil();
    // red: the channel where the sponge's foam and voids differ most
    for (label, preset, ch) in [
        ("homogeneous whole-milk", "whole-milk", 1),
        ("index-matched sponge (voxel grid)", "sponge-voxel", 0),
        ("cellular sponge", "sponge", 0),
        ("cellular bread", "bread", 0),
        ("cellular rice-cake", "rice-cake", 0),
    ] {
        let world = medium_world(preset)?;
        for threads in [1usize, 2] {
            let p = pool(threads);
            // warm up caches and the pool
            p.install(|| world.trace(&pencil, ch, photons / 10, 99, None));
            let (t, s, cpu) = timed(|| p.install(|| world.trace(&pencil, ch, photons, 1, None)));
            let cpu = cpu.filter(|c| *c > 0.0);
            rows.push(BenchRow {
                medium: label.to_string(),
                threads,
                photons,
                seconds: s,
                paths_per_s: photons as f64 / s,
                events_per_s: t.events as f64 / s,
                events_per_s_per_core: t.events as f64 / s / threads as f64,
                cpu_seconds: cpu,
                events_per_cpu_s: cpu.map(|c| t.events as f64 / c),
                null_events_per_s: t.null_events as f64 / s,
                mean_events_per_path: t.events as f64 / photons as f64,
            });
        }
    }
    let speedup_1_to_2 = rows
        .chunks(2)
        .map(|r| (r[0].medium.clone(), r[1].events_per_s / r[0].events_per_s))
        .collect();
    let (mut full_pose_seconds, mut full_pose_cpu_seconds, mut splat_share) = (None, None, None);
    if full_pose {
        let (world, illum) = full_pose_scene()?;
        let p2 = pool(2);
        let (r, wall, cpu) = timed(|| p2.install(|| world.render_pose(&illum, 0xFE, 1)));
        r?;
        full_pose_seconds = Some(wall);
        full_pose_cpu_seconds = cpu;
        // splat share: a small pose with and without cameras on one thread
        let small = World::new(
            SceneDesc::preset("whole-milk")?,
            RigTruth::nominal(),
            SimQuality::preview(),
        )?;
        let p1 = pool(1);
        let t0 = Instant::now();
        let r = p1.install(|| small.render_pose(&illum, 0xFE, 2))?;
        let with = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        p1.install(|| small.render_pose(&illum, 0, 2))?;
        let without = t0.elapsed().as_secs_f64();
        let _ = r;
        splat_share = Some(((with - without) / with).clamp(0.0, 1.0));
    }
    Ok(BenchReport {
        rows,
        speedup_1_to_2,
        full_pose_seconds,
        full_pose_cpu_seconds,
        splat_share,
    })
}
