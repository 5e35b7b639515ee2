//! `qhm sim`: the simulated world. `--pty` serves an emulated rig on a
//! pseudo-terminal (see `simpty.rs`); `render` draws single frames of the
//! simulated sample or calibration target as a camera of the rig sees them;
//! `bench` measures the light transport.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use host::output::check_file_output;
use sim_light::{Illumination, LaserOn, RigTruth, SceneDesc, SimQuality, World};

use crate::cmd::simpty;

#[derive(Args, Debug)]
pub struct SimArgs {
    #[command(subcommand)]
    pub action: Option<SimAction>,
    /// Serve an emulated rig on a pseudo-terminal; print its path; serve until Ctrl-C.
    #[arg(long)]
    pub pty: bool,
    #[command(flatten)]
    pub rig: simpty::PtyArgs,
}

#[derive(Subcommand, Debug)]
pub enum SimAction {
    /// Render one frame of one camera at one rig pose (PNG, and the radiance as EXR).
    Render(RenderArgs),
    /// Measure photon paths and scattering events per second (1 and 2 threads).
    Bench(BenchArgs),
    /// Ground truth for any object: a mesh filled with a sample's volume, path-traced (EXR).
    RenderObject(crate::cmd::sim_object::RenderObjectArgs),
    /// The true entrance function: f(theta)/f(0) tallied by the Monte Carlo, beside Fresnel's T(theta)/T(0).
    Entrance(EntranceArgs),
    /// List the built-in samples and calibration targets.
    Presets,
}

#[derive(Args, Debug)]
pub struct EntranceArgs {
    /// A preset (see `qhm sim presets`) or a sample TOML file.
    #[arg(long)]
    pub sample: String,
    /// Incidence angles from the normal, degrees in [0, 89] (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0])]
    pub theta: Vec<f64>,
    /// A model fitted from a capture of this sample: compare its measured f(w_i)
    /// with the truth at each of its laser directions (instead of --theta).
    #[arg(long, value_name = "MODEL_DIR", conflicts_with = "theta")]
    pub model: Option<PathBuf>,
    /// Colour channel: red, green or blue.
    #[arg(long, default_value = "green")]
    pub channel: String,
    /// Photons per angle.
    #[arg(long, default_value_t = 200_000)]
    pub photons: u64,
    /// Seed of the light transport.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// A preset (see `qhm sim presets`) or a sample/target TOML file.
    #[arg(long)]
    pub sample: String,
    /// Camera on the arc, 1 (lowest used) to 7 (straight down).
    #[arg(long, default_value_t = 4)]
    pub camera: usize,
    /// Lamps that are on, 1..=7 on the light arc (comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub light: Vec<usize>,
    /// Laser that is on: red, green or blue.
    #[arg(long)]
    pub laser: Option<String>,
    /// Laser drive, 0..=1 of full power.
    #[arg(long, default_value_t = 1.0)]
    pub laser_power: f32,
    /// Elevation at which the laser unit is clamped on the light arc, degrees.
    #[arg(long, default_value_t = 90.0)]
    pub laser_elevation: f64,
    /// Galvo beam deflection, degrees.
    #[arg(long, default_value_t = 0.0)]
    pub galvo: f64,
    /// Light-arc angle, degrees.
    #[arg(long, default_value_t = 0.0)]
    pub light_arc: f64,
    /// Turntable angle, degrees.
    #[arg(long, default_value_t = 0.0)]
    pub turntable: f64,
    /// Quality scale: ci, preview, default or final.
    #[arg(long, default_value = "preview")]
    pub quality: String,
    /// Photons per light source (overrides the quality's budget).
    #[arg(long)]
    pub photons: Option<u64>,
    /// Seed of the rig's manufacturing errors.
    #[arg(long, default_value_t = 1)]
    pub rig_seed: u64,
    /// Use the nominal rig (no errors).
    #[arg(long)]
    pub nominal: bool,
    /// Seed of the light transport and the sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Exposure time, seconds (default: the mean of the lit pixels at 30 % of full well).
    #[arg(long)]
    pub exposure: Option<f64>,
    /// Linear sensor gain.
    #[arg(long, default_value_t = 1.0)]
    pub gain: f64,
    /// The 8-bit frame as PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// The radiance before the sensor as EXR (W sr^-1 m^-2, linear RGB).
    #[arg(long)]
    pub hdr: Option<PathBuf>,
    /// Replace existing --out and --hdr files.
    #[arg(long)]
    pub force: bool,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Print the figures as JSON.
    #[arg(long)]
    pub json: bool,
    /// Photons per measurement.
    #[arg(long, default_value_t = 200_000)]
    pub photons: u64,
    /// Skip the full-size pose timing.
    #[arg(long)]
    pub no_pose: bool,
    /// Only this medium (whole-milk, sponge-voxel, sponge, bread, rice-cake).
    #[arg(long)]
    pub medium: Option<String>,
    /// Only this many threads (default: 1, then 2).
    #[arg(long)]
    pub threads: Option<usize>,
}

pub fn run(args: SimArgs) -> Result<ExitCode> {
    if args.pty {
        return simpty::serve(&args.rig);
    }
    match args.action {
        Some(SimAction::Render(r)) => render(r),
        Some(SimAction::Bench(b)) => bench(b),
        Some(SimAction::RenderObject(r)) => crate::cmd::sim_object::run(r),
        Some(SimAction::Entrance(e)) => entrance(e),
        Some(SimAction::Presets) => {
            let mut out = std::io::stdout().lock();
            for p in sim_light::SCENE_PRESETS {
                writeln!(out, "{p}")?;
            }
            Ok(ExitCode::SUCCESS)
        }
        None => bail!(
            "say what to simulate: `render`, `bench`, `presets`, or --pty to serve an emulated rig"
        ),
    }
}

fn laser_channel(name: &str) -> Result<usize> {
    match name.to_ascii_lowercase().as_str() {
        "red" | "r" | "650" => Ok(0),
        "green" | "g" | "532" => Ok(1),
        "blue" | "b" | "473" => Ok(2),
        other => bail!("--laser {other:?}: expected red, green or blue"),
    }
}

fn degrees(name: &str, v: f64) -> Result<f64> {
    if !v.is_finite() || v.abs() > 720.0 {
        bail!("--{name} {v}: expected degrees in [-720, 720]");
    }
    Ok(v.to_radians())
}

fn render(a: RenderArgs) -> Result<ExitCode> {
    if a.camera == 0 || a.camera > 7 {
        bail!(
            "--camera {}: the cameras in use are 1..=7 (0, the lowest, is unused; 7 looks straight down)",
            a.camera
        );
    }
    let mut lamps = 0u8;
    for &l in &a.light {
        if l == 0 || l > 7 {
            bail!("--light {l}: the lamps in use are 1..=7 (lamp 0, the lowest, is not used)");
        }
        lamps |= 1 << l;
    }
    let laser = match &a.laser {
        Some(name) => {
            if !(a.laser_power.is_finite() && (0.0..=1.0).contains(&a.laser_power)) {
                bail!("--laser-power {}: expected 0..=1", a.laser_power);
            }
            Some(LaserOn {
                channel: laser_channel(name)?,
                power: a.laser_power,
            })
        }
        None => None,
    };
    if laser.is_none() && lamps == 0 {
        bail!("nothing lights the sample: give --laser and/or --light");
    }
    for p in std::iter::once(&a.out).chain(&a.hdr) {
        check_file_output(p, a.force)?;
    }
    // Refused before the Monte Carlo, not after it.
    let ends_in = |p: &Path, ext: &str| p.extension().is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if !ends_in(&a.out, "png") {
        bail!("--out {} must end in .png", a.out.display());
    }
    if let Some(h) = a.hdr.as_deref().filter(|h| !ends_in(h, "exr")) {
        bail!("--hdr {} must end in .exr", h.display());
    }
    if !(a.gain.is_finite() && a.gain > 0.0 && a.gain <= 64.0) {
        bail!("--gain {}: expected (0, 64]", a.gain);
    }
    if let Some(e) = a.exposure {
        if !(e.is_finite() && e > 0.0 && e <= 60.0) {
            bail!("--exposure {e}: expected (0, 60] seconds");
        }
    }
    let mut quality = SimQuality::by_name(&a.quality)?;
    if let Some(p) = a.photons {
        if p == 0 || p > 10_000_000_000 {
            bail!("--photons {p}: expected 1..=1e10");
        }
        quality.laser_photons = p;
        quality.lamp_photons = p;
    }
    let desc = SceneDesc::load(&a.sample)?;
    let rig = if a.nominal {
        RigTruth::nominal()
    } else {
        RigTruth::perturbed(a.rig_seed)
    };
    let t0 = Instant::now();
    let mut world = World::new(desc, rig, quality)?;
    world.set_laser_mount(degrees("laser-elevation", a.laser_elevation)?);
    let illum = Illumination {
        turntable_rad: degrees("turntable", a.turntable)?,
        light_arc_rad: degrees("light-arc", a.light_arc)?,
        galvo_rad: degrees("galvo", a.galvo)?,
        laser,
        lamps,
    };
    let pose = world.render_pose(&illum, 1 << a.camera, a.seed)?;
    let radiance = pose.image(a.camera).context("camera produced no image")?;
    let sensor = world.sensor(a.camera);
    let exposure = match a.exposure {
        Some(e) => e,
        None => auto_exposure(radiance, &sensor, a.gain),
    };
    let frame = sensor.expose(radiance, exposure, a.gain, a.seed ^ 0x5EED);
    write_png(&a.out, frame.width, frame.height, &frame.rgb)?;
    if let Some(h) = &a.hdr {
        write_exr(h, radiance)?;
    }
    let t = pose.tally;
    eprintln!(
        "camera {}: {}x{}, exposure {:.3} ms, gain {}, {} saturated px; {} photons ({} exited, {} reflected, {} absorbed, {} missed) in {:.2} s",
        a.camera,
        frame.width,
        frame.height,
        exposure * 1e3,
        a.gain,
        frame.meta.saturated_pixels,
        t.launched,
        t.exited,
        t.reflected,
        t.absorbed,
        t.missed,
        t0.elapsed().as_secs_f64()
    );
    Ok(ExitCode::SUCCESS)
}

/// Exposure that puts the mean of the lit pixels (brightest channel) at
/// 30 % of full well; sparse bright splats would fool a percentile.
fn auto_exposure(
    radiance: &sim_light::RadianceImage,
    sensor: &sim_light::Sensor,
    gain: f64,
) -> f64 {
    let lit: Vec<f64> = radiance
        .data
        .iter()
        .map(|p| {
            (0..3)
                .map(|c| p[c] as f64 * sensor.colour_gain[c])
                .fold(0.0, f64::max)
        })
        .filter(|&v| v > 0.0)
        .collect();
    if lit.is_empty() {
        return 0.01;
    }
    let l = lit.iter().sum::<f64>() / lit.len() as f64;
    (0.3 * sim_light::sensor::FULL_WELL_E / (l * sim_light::sensor::SENSITIVITY * gain))
        .clamp(1e-6, 10.0)
}

fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    image::save_buffer(path, rgb, w, h, image::ColorType::Rgb8)
        .with_context(|| format!("writing {}", path.display()))
}

fn write_exr(path: &Path, img: &sim_light::RadianceImage) -> Result<()> {
    let (w, h) = (img.width as usize, img.height as usize);
    qhm_formats::exr::write_rgb_pixels(path, w, h, &img.data)
        .with_context(|| format!("writing {}", path.display()))
}

fn entrance(e: EntranceArgs) -> Result<ExitCode> {
    let channel = match e.channel.as_str() {
        "red" => 0,
        "green" => 1,
        "blue" => 2,
        other => bail!("--channel {other:?}: expected red, green or blue"),
    };
    if e.photons < 1000 || e.photons > 1_000_000_000 {
        bail!("--photons {}: expected 1000..=1e9", e.photons);
    }
    let world = World::new(
        SceneDesc::load(&e.sample)?,
        RigTruth::nominal(),
        SimQuality::ci(),
    )?;
    if let Some(dir) = &e.model {
        return entrance_against_model(&world, dir, &e);
    }
    let points =
        sim_light::entrance::entrance_function(&world, &e.theta, channel, e.photons, e.seed)?;
    let mut out = std::io::stdout().lock();
    if e.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&points)?)?;
    } else {
        writeln!(
            out,
            "theta_deg  f            f/f(0)            T/T(0)   (f/f(0)) / (T/T(0))  exitance  its ratio"
        )?;
        for p in &points {
            writeln!(
                out,
                "{:9.1}  {:.5}  {:.5} +- {:.5}  {:.5}  {:.4}               {:.5}   {:.5} +- {:.5}",
                p.theta_deg,
                p.f,
                p.ratio,
                p.ratio_err,
                p.fresnel_ratio,
                p.ratio / p.fresnel_ratio,
                p.exitance,
                p.exitance_ratio,
                p.exitance_ratio_err
            )?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn entrance_against_model(world: &World, dir: &Path, e: &EntranceArgs) -> Result<ExitCode> {
    let model = qhm_model::MaterialModel::load(dir)
        .with_context(|| format!("loading the model {}", dir.display()))?;
    let checks = host::entrance_check::check_entrance(world, &model, e.photons, e.seed)?;
    let worst = host::entrance_check::worst_error(&checks);
    let mut out = std::io::stdout().lock();
    if e.json {
        let v = serde_json::json!({ "directions": checks, "worst_error": worst });
        writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
        return Ok(ExitCode::SUCCESS);
    }
    writeln!(
        out,
        "theta_deg  phi_deg  fitted R / G / B          true exitance ratio R / G / B  error R / G / B         entering f/f(0)   T/T(0)"
    )?;
    for c in &checks {
        let [er, eg, eb] = c.errors().map(|x| 100.0 * x);
        let [xr, xg, xb] = c.exitance;
        writeln!(
            out,
            "{:9.1}  {:7.1}  {:.4} / {:.4} / {:.4}  {xr:.4} / {xg:.4} / {xb:.4}       {er:+5.1} / {eg:+5.1} / {eb:+5.1} %  {:.4} +- {:.4}  {:.4}",
            c.theta_deg,
            c.phi_deg,
            c.fitted[0],
            c.fitted[1],
            c.fitted[2],
            c.truth,
            c.truth_err,
            c.fresnel
        )?;
    }
    writeln!(
        out,
        "worst |fitted / true exitance ratio - 1|: {:.1} %",
        100.0 * worst
    )?;
    Ok(ExitCode::SUCCESS)
}

fn bench(b: BenchArgs) -> Result<ExitCode> {
    if b.photons < 1000 || b.photons > 1_000_000_000 {
        bail!("--photons {}: expected 1000..=1e9", b.photons);
    }
    if let Some(m) = &b.medium
        && !sim_light::bench::BENCH_MEDIA
            .iter()
            .any(|(name, ..)| name == m)
    {
        let known: Vec<&str> = sim_light::bench::BENCH_MEDIA
            .iter()
            .map(|(n, ..)| *n)
            .collect();
        bail!("--medium {m:?}: expected one of {}", known.join(", "));
    }
    let threads = match b.threads {
        Some(n @ 1..=256) => vec![n],
        Some(n) => bail!("--threads {n}: expected 1..=256"),
        None => vec![1, 2],
    };
    let report = sim_light::bench::run_with(b.photons, b.medium.as_deref(), &threads, !b.no_pose)?;
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let mut out = std::io::stdout().lock();
    if b.json {
        let v = serde_json::json!({
            "report": report,
            "machine": { "cores": cores, "loadavg": load.trim() },
            "target_events_per_s_per_core_homogeneous": 45.0e6,
        });
        writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
    } else {
        for r in &report.rows {
            writeln!(
                out,
                "{:28} {} thread(s): {:9.0} paths/s, {:6.2} M events/s/core, {:6.1} events/path{}{}",
                r.medium,
                r.threads,
                r.paths_per_s,
                r.events_per_s_per_core / 1e6,
                r.mean_events_per_path,
                r.events_per_cpu_s
                    .map(|e| format!(", {:6.1} M events per CPU s", e / 1e6))
                    .unwrap_or_default(),
                match r.wall_events_per_cpu_s {
                    Some(w) if r.wall_events_per_path > 0.0 => format!(
                        "; cell walls {:.1} per path, {:.1} M per CPU s",
                        r.wall_events_per_path,
                        w / 1e6
                    ),
                    _ => String::new(),
                }
            )?;
        }
        for n in &report.stripe_noise {
            writeln!(
                out,
                "stripe profile, whole milk, {} walk, 1 thread: {:.2} % noise after {} photons in {:.2} CPU s; {:.1} CPU s to {:.1} %",
                n.walk,
                n.rel_noise * 100.0,
                n.photons,
                n.cpu_seconds,
                n.cpu_seconds_to_target,
                n.target_rel_noise * 100.0
            )?;
        }
        for (m, s) in &report.speedup_1_to_2 {
            writeln!(out, "speed-up 1 -> 2 threads, {m}: {s:.2}")?;
        }
        if let Some(s) = report.full_pose_seconds {
            let cpu = report
                .full_pose_cpu_seconds
                .map(|c| format!(" ({c:.2} CPU s)"))
                .unwrap_or_default();
            writeln!(
                out,
                "full-size pose (7 cameras, laser, default budget): {s:.2} s{cpu}"
            )?;
        }
        writeln!(out, "machine: {cores} cores, load average {}", load.trim())?;
    }
    Ok(ExitCode::SUCCESS)
}
