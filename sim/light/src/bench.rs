//! `qhm sim bench`: photon paths and scattering events per second, in a
//! homogeneous and a heterogeneous medium, on 1 and 2 threads, and the CPU
//! time a stripe's profile takes to reach a given noise level. Results are
//! figures, never assertions (the machine is shared).

use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use crate::Error;
use crate::rig::RigTruth;
use crate::sample::{Coefficients, InclusionDesc, MaterialDesc, Relief, SceneDesc};
use crate::walk::{ExitGrid, Source};
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
    /// Cellular media: reflections and refractions at cell walls per path
    /// (not counted in the events above), and per CPU second.
    pub wall_events_per_path: f64,
    pub wall_events_per_cpu_s: Option<f64>,
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
    /// The stripe profile's noise against CPU time, wide and scalar walk.
    pub stripe_noise: Vec<StripeNoise>,
}

/// A laser stripe's exit profile in whole milk (green), one thread: its
/// noise after `photons`, and the CPU time to reach `target` noise.
#[derive(Debug, Clone, Serialize)]
pub struct StripeNoise {
    /// "wide" (the walk renders use) or "scalar" (one photon at a time).
    pub walk: String,
    pub photons: u64,
    pub cpu_seconds: f64,
    /// RMS over the profile's bins of their relative standard error.
    pub rel_noise: f64,
    pub target_rel_noise: f64,
    /// cpu_seconds (rel_noise / target)^2: noise falls as 1/sqrt(photons).
    pub cpu_seconds_to_target: f64,
}

/// Media the benchmark knows: (name, label, channel). Red for the sponges
/// and cellular media: the channel where foam and voids differ most.
pub const BENCH_MEDIA: [(&str, &str, usize); 5] = [
    ("whole-milk", "homogeneous whole-milk", 1),
    ("sponge-voxel", "index-matched sponge (voxel grid)", 0),
    ("sponge", "cellular sponge", 0),
    ("bread", "cellular bread", 0),
    ("rice-cake", "cellular rice-cake", 0),
];

/// Relative noise the stripe measurement extrapolates to.
pub const STRIPE_TARGET_NOISE: f64 = 0.01;

/// The stripe measurement: a 20 mm green stripe falling straight down on
/// the centre of the 200 x 200 x 100 mm whole-milk slab; its profile across
/// the stripe, |y| in [0.5, 10] mm in 0.5 mm bins (folded), over |x| < 5 mm,
/// from `batches` independent runs of photons / batches each, whose spread
/// gives each bin's standard error.
pub fn stripe_noise(photons: u64, wide: bool) -> Result<StripeNoise, Error> {
    let world = medium_world("whole-milk")?;
    let stripe = Source::Stripe {
        origin: Vec3::new(0.0, 0.0, 200.0),
        centre: Vec3::ZERO,
        dir: Vec3::X,
        length: 20.0,
    };
    let (cell, n) = (0.25f32, 96usize);
    let batches = 8u64;
    let per = (photons / batches).max(1000);
    let p1 = pool(1);
    let mut profiles = Vec::new();
    let mut cpu = 0.0;
    for b in 0..batches {
        let grid = ExitGrid::new(n, cell);
        let (_, _, c) =
            timed(|| p1.install(|| world.trace_with(&stripe, 1, per, 100 + b, Some(&grid), wide)));
        cpu += c.unwrap_or(0.0);
        let counts = grid.values();
        let mut prof = [0.0f64; 19];
        for j in 0..n {
            let y = (j as f32 + 0.5) * cell - n as f32 * cell / 2.0;
            let bin = ((y.abs() - 0.5) / 0.5).floor();
            if !(0.0..19.0).contains(&bin) {
                continue;
            }
            for i in 0..n {
                let x = (i as f32 + 0.5) * cell - n as f32 * cell / 2.0;
                if x.abs() < 5.0 {
                    prof[bin as usize] += counts[j * n + i] as f64;
                }
            }
        }
        profiles.push(prof);
    }
    let k = batches as f64;
    let mut sum_sq = 0.0;
    for bin in 0..19 {
        let vals: Vec<f64> = profiles.iter().map(|p| p[bin]).collect();
        let mean = vals.iter().sum::<f64>() / k;
        let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0);
        // standard error of the batches' mean, relative to it
        let rel = if mean > 0.0 {
            (var / k).sqrt() / mean
        } else {
            1.0
        };
        sum_sq += rel * rel;
    }
    let rel_noise = (sum_sq / 19.0).sqrt();
    Ok(StripeNoise {
        walk: if wide { "wide" } else { "scalar" }.into(),
        photons: per * batches,
        cpu_seconds: cpu,
        rel_noise,
        target_rel_noise: STRIPE_TARGET_NOISE,
        cpu_seconds_to_target: cpu * (rel_noise / STRIPE_TARGET_NOISE).powi(2),
    })
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
    run_with(photons, None, &[1, 2], full_pose)
}

/// `run` for one medium of [`BENCH_MEDIA`] (all when None) on the given
/// thread counts; the stripe measurement runs with whole milk.
pub fn run_with(
    photons: u64,
    medium: Option<&str>,
    thread_counts: &[usize],
    full_pose: bool,
) -> Result<BenchReport, Error> {
    if let Some(m) = medium
        && !BENCH_MEDIA.iter().any(|(name, ..)| *name == m)
    {
        let known: Vec<&str> = BENCH_MEDIA.iter().map(|(name, ..)| *name).collect();
        return Err(Error::InvalidField {
            field: "benchmark medium".into(),
            reason: format!("{m:?} is not one of {}", known.join(", ")),
        });
    }
    let mut rows = Vec::new();
    let pencil = pencil();
    for (preset, label, ch) in BENCH_MEDIA {
        if medium.is_some_and(|m| m != preset) {
            continue;
        }
        let world = medium_world(preset)?;
        for &threads in thread_counts {
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
                wall_events_per_path: t.wall_events as f64 / photons as f64,
                wall_events_per_cpu_s: cpu.map(|c| t.wall_events as f64 / c),
            });
        }
    }
    let speedup_1_to_2 = if thread_counts == [1, 2] {
        rows.chunks(2)
            .map(|r| (r[0].medium.clone(), r[1].events_per_s / r[0].events_per_s))
            .collect()
    } else {
        Vec::new()
    };
    let mut stripe = Vec::new();
    if medium.is_none_or(|m| m == "whole-milk") {
        for wide in [true, false] {
            stripe.push(stripe_noise(photons, wide)?);
        }
    }
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
        stripe_noise: stripe,
    })
}
