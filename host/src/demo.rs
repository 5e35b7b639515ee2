//! `qhm demo`: the whole system on the built-in simulated rig. Calibrate,
//! run the three capture passes, HDR-merge and rectify, fit the material
//! model, write it, render a teapot and a bread slice under a front light, a
//! back light and an environment map (paper Figs. 9-12), write the report,
//! and compare the recovered parameters with the simulated sample's truth.
//!
//! Output directory (each part in its documented format):
//! `calibration.toml`, `calibration-capture/` (its frames and journal),
//! `capture/` (frames, journal, `rectified/`), `model/`,
//! `renders/` (EXR + PNG), `report/`, `summary.json`.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use qhm_acquire::plan::Step;
use qhm_acquire::{
    CaptureDir, Manifest, Plan, PlanConfig, Progress, RunOptions, Scale, run_capture,
};
use qhm_imaging::Calibration;
use qhm_imaging::pipeline::rectify_capture;
use qhm_model::fit::{FitOptions, fit_capture_with_progress};
use qhm_model::{DipoleParams, MaterialModel};
use qhm_progress::Bar;
use qhm_render::RenderSettings;
use qhm_render::light::{EnvMap, Light};
use qhm_render::prepare::{Prepared, prepare};
use qhm_render::render::render_prepared;
use qhm_render::scene::Scene;
use qhm_render::settings::RenderStats;
use serde::Serialize;
use sim_devices::{SimRig, SimRigConfig};

use crate::output::{OutputKind, StagedDir};
use crate::pipeline::{StripeWindow, calibrated_shots, rectify_options, shots};

/// What to run.
#[derive(Debug, Clone)]
pub struct DemoOptions {
    /// Sample preset name or TOML file.
    pub sample: String,
    pub scale: Scale,
    pub out: PathBuf,
    /// Overwrite a non-empty output directory.
    pub force: bool,
    pub seed: u64,
    /// No progress bars (tests, logs).
    pub quiet: bool,
    /// Skip the renders (the fit and the report still run).
    pub skip_renders: bool,
    /// Use this calibration file of the same simulated rig (scale and seed,
    /// e.g. an earlier demo's `calibration.toml`) instead of taking a
    /// calibration capture; the calibrate stage then only scores it against
    /// the rig's truth.
    pub calibration: Option<PathBuf>,
}

/// Wall time of one stage.
#[derive(Debug, Clone, Serialize)]
pub struct StageTime {
    pub stage: String,
    pub seconds: f64,
}

/// The sample's dipole parameters where the simulated world defines them
/// (homogeneous presets), or the paper's recovered values for its
/// two-material sample (a reference, not a truth).
#[derive(Debug, Clone, Serialize)]
pub struct Reference {
    pub kind: &'static str,
    pub alpha_prime: [f64; 3],
    pub sigma_t_prime: [f64; 3],
}

/// The Monte Carlo behind the capture's frames: poses rendered (the
/// exposures and cameras of a pose share one), photons, scattering events,
/// and the wall time spent rendering.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct MonteCarlo {
    pub poses: u64,
    pub photons: u64,
    pub events: u64,
    pub seconds: f64,
    /// Events per wall second of rendering.
    pub events_per_s: f64,
}

impl From<sim_devices::RenderStats> for MonteCarlo {
    fn from(s: sim_devices::RenderStats) -> Self {
        MonteCarlo {
            poses: s.poses,
            photons: s.photons,
            events: s.events,
            seconds: s.seconds,
            events_per_s: s.events_per_s(),
        }
    }
}

impl std::fmt::Display for MonteCarlo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Monte Carlo: {} poses, {:.1} M photons, {:.0} M events in {:.1} s: {:.1} M events/s",
            self.poses,
            self.photons as f64 / 1e6,
            self.events as f64 / 1e6,
            self.seconds,
            self.events_per_s / 1e6
        )
    }
}

/// What the demo produced.
#[derive(Debug, Clone, Serialize)]
pub struct DemoSummary {
    pub sample: String,
    pub scale: String,
    pub seed: u64,
    pub recovered: DipoleParams,
    pub reference: Option<Reference>,
    pub calibration_rows_within_target: usize,
    pub calibration_rows: usize,
    pub frames: usize,
    /// The simulated cameras' Monte Carlo during the capture.
    pub monte_carlo: MonteCarlo,
    pub renders: Vec<String>,
    pub stages: Vec<StageTime>,
}

/// The paper's recovered values for its synthetic two-material volume (section 6).
const PAPER_TWO_MATERIAL: Reference = Reference {
    kind: "paper's recovered values (section 6)",
    alpha_prime: [0.8224, 0.8125, 0.9853],
    sigma_t_prime: [1.1701, 1.29605, 1.53456],
};

/// The reference for a sample name, if there is one.
pub fn reference(sample: &str) -> Option<Reference> {
    if sample == "two-material" {
        return Some(PAPER_TWO_MATERIAL);
    }
    let (c, _eta) = sim_light::material_preset(sample)?;
    let sigma_t_prime: [f64; 3] = std::array::from_fn(|i| c.sigma_s[i] + c.sigma_a[i]);
    Some(Reference {
        kind: "true (homogeneous preset)",
        alpha_prime: std::array::from_fn(|i| c.sigma_s[i] / sigma_t_prime[i]),
        sigma_t_prime,
    })
}

/// What a demo writes into its output directory; `--force` removes these
/// (whole, with anything inside them) and nothing else.
pub const DEMO_PARTS: [&str; 7] = [
    "calibration.toml",
    "calibration-capture",
    "capture",
    "model",
    "renders",
    "report",
    "summary.json",
];

/// Refuses a non-empty output directory unless `force`, and a non-empty one
/// holding none of a demo's parts even then; with `force` removes only what a
/// previous demo wrote there.
fn prepare_out(out: &Path, force: bool) -> Result<()> {
    if out.exists() {
        if !out.is_dir() {
            bail!("{} exists and is not a directory", out.display());
        }
        let non_empty = std::fs::read_dir(out)
            .with_context(|| format!("reading {}", out.display()))?
            .next()
            .is_some();
        if non_empty && !DEMO_PARTS.iter().any(|p| out.join(p).exists()) {
            bail!(
                "{} is not empty and holds no qhm demo output; refusing to write into it (choose an empty or new directory)",
                out.display()
            );
        }
        if non_empty && !force {
            bail!(
                "{} holds an earlier demo; pass --force to replace it",
                out.display()
            );
        }
        for part in DEMO_PARTS {
            let p = out.join(part);
            if p.is_dir() {
                std::fs::remove_dir_all(&p).with_context(|| format!("removing {}", p.display()))?;
            } else if p.exists() {
                std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
            }
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    Ok(())
}

/// A stage timer that prints as it goes.
struct Stages {
    quiet: bool,
    times: Vec<StageTime>,
}

impl Stages {
    fn run<T>(&mut self, name: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
        if !self.quiet {
            eprintln!("== {name}");
        }
        let t = Instant::now();
        let r = f().with_context(|| format!("stage `{name}`"))?;
        let seconds = t.elapsed().as_secs_f64();
        if !self.quiet {
            eprintln!("   {name}: {seconds:.1} s");
        }
        self.times.push(StageTime {
            stage: name.to_string(),
            seconds,
        });
        Ok(r)
    }
}

/// The capture's progress on a [`Bar`] (a plain line every few seconds when
/// stderr is not a terminal).
struct CaptureBar(Bar);

impl Progress for CaptureBar {
    fn start(&mut self, total: usize, done: usize) {
        self.0.start(total as u64, done as u64);
    }
    fn frame(&mut self, step: &Step, done: usize) {
        self.0.set_message(&format!("pass {}", step.pass.number()));
        self.0.set_position(done as u64);
    }
    fn note(&mut self, message: &str) {
        self.0.println(&format!("   {message}"));
    }
}

/// Render size and dipole sample budget per scale.
fn render_settings(scale: Scale) -> RenderSettings {
    let (size, spp, surface_samples) = match scale {
        Scale::Ci => (96, 1, 4_000),
        Scale::Default => (320, 2, 20_000),
        Scale::Paper => (512, 4, 30_000),
    };
    RenderSettings {
        width: size,
        height: size,
        spp,
        surface_samples,
        ..RenderSettings::default()
    }
}

/// The three lightings of the renders: a key light from the camera's side,
/// a back light behind the object, and an environment map alone.
fn lightings(scene: &Scene) -> [(&'static str, Vec<Light>, Option<EnvMap>); 3] {
    let to_camera = (scene.camera.eye - scene.camera.target).normalize();
    let front = (to_camera + Vec3::Z * 0.6).normalize();
    let back = (-to_camera + Vec3::Z * 0.3).normalize();
    [
        (
            "front",
            vec![Light::Directional {
                to_light: front,
                irradiance: Vec3::splat(3.0),
            }],
            None,
        ),
        (
            "back",
            vec![Light::Directional {
                to_light: back,
                irradiance: Vec3::splat(3.0),
            }],
            None,
        ),
        ("env", Vec::new(), Some(EnvMap::studio(1.0))),
    ]
}

/// Runs the demo; returns the summary also written to `out/summary.json`.
pub fn run(opts: &DemoOptions) -> Result<DemoSummary> {
    let out = opts.out.as_path();
    let rig_cfg = SimRigConfig::new(&opts.sample, opts.scale, opts.seed);
    // Validate the sample before anything long starts.
    let desc = sim_light::SceneDesc::load(&opts.sample)
        .with_context(|| format!("sample {:?}", opts.sample))?;
    // The fit assumes the sample's refractive index, as a user would pass
    // `qhm fit --eta` for a known material.
    let eta = match &desc {
        sim_light::SceneDesc::Sample(s) => s.surface.eta,
        sim_light::SceneDesc::Target { .. } => {
            bail!("{:?} is a calibration target, not a sample", opts.sample)
        }
    };
    // Only a demo that can start makes its output directory.
    prepare_out(&opts.out, opts.force)?;
    // The fit's radiative-transfer tables for eta (some CPU seconds), built
    // while the captures leave cores idle; the fit then finds them made.
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    crate::idle::in_idle_time(threads, move || {
        qhm_model::radiative_transfer::HalfSpace::shared_for_line_profiles(eta);
    })?;
    let mut stages = Stages {
        quiet: opts.quiet,
        times: Vec::new(),
    };

    // 1. Calibration of the simulated rig (the same seed as the capture's
    // rig), a calibration capture through the link and the cameras like any
    // other, then the procedures on its frames.
    let cal_path = out.join("calibration.toml");
    let (cal_ok, cal_rows) = stages.run("calibrate", || {
        let rows = match &opts.calibration {
            None => crate::calibrate::calibrate_sim(
                opts.scale,
                opts.seed,
                &out.join("calibration-capture"),
                &cal_path,
                opts.quiet,
            )?,
            Some(given) => {
                let cal = Calibration::load(given)
                    .with_context(|| format!("calibration {}", given.display()))?;
                cal.save(&cal_path)
                    .with_context(|| format!("writing {}", cal_path.display()))?;
                let plane_arc =
                    qhm_acquire::cal_plan::CalPlanConfig::for_scale(opts.scale).plane_arc;
                sim_devices::SimTruth::new(opts.seed).rows(&cal, plane_arc)
            }
        };
        if !opts.quiet {
            for r in &rows {
                eprintln!("   {r}");
            }
        }
        Ok((rows.iter().filter(|r| r.ok).count(), rows.len()))
    })?;

    // 2. The three capture passes through the link and the cameras.
    let capture = out.join("capture");
    let plan = Plan::new(PlanConfig::for_scale(opts.scale))?;
    let (frames, monte_carlo) = stages.run("capture", || {
        let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
        rt.block_on(async {
            let mut manifest = Manifest::new("sim", &opts.sample, opts.seed, &plan);
            // As `qhm capture run --calibration` does, for `qhm rectify`.
            manifest.record_calibration(&capture, &cal_path)?;
            let mut dir = CaptureDir::create(&capture, manifest)?;
            let run_opts = RunOptions {
                time_scale: rig_cfg.speed,
                frame_timeout: Duration::from_secs(600),
                ..RunOptions::default()
            };
            let mut rig = SimRig::start_with(rig_cfg.clone())
                .await
                .context("starting the simulated rig")?;
            let mut operator = rig.handle.operator();
            let mut progress = CaptureBar(Bar::new("capture", 0, opts.quiet));
            let report = run_capture(
                &rig.link,
                &mut rig.cameras,
                &mut operator,
                &mut dir,
                &run_opts,
                &mut progress,
            )
            .await?;
            progress.0.finish();
            if !report.complete {
                bail!("the capture stopped before the end of the plan");
            }
            let mc = MonteCarlo::from(rig.handle.render_stats());
            if !opts.quiet {
                eprintln!("   {mc}");
            }
            Ok((dir.frame_count(), mc))
        })
    })?;

    // 3. HDR merge and rectification onto the reference plane.
    stages.run("hdr + rectify", || {
        let cal = Calibration::load(&cal_path)?;
        let window = StripeWindow::default();
        let (shots, skipped) = calibrated_shots(shots(&plan, &capture), &cal);
        if !skipped.is_empty() && !opts.quiet {
            eprintln!(
                "   note: cameras {skipped:?} were not found in calibration; their frames are left out"
            );
        }
        let b = Bar::new("rectify", shots.len() as u64, opts.quiet);
        rectify_capture(
            &shots,
            &cal,
            &rectify_options(&plan, &window),
            &capture.join("rectified"),
            &|done, _| b.set_position(done as u64),
        )?;
        b.finish();
        Ok(())
    })?;

    // 4. The four-part material model.
    let model_dir = out.join("model");
    let model = stages.run("fit", || {
        let fit_opts = FitOptions {
            eta,
            ..FitOptions::default()
        };
        let b = Bar::new("fit", 0, opts.quiet);
        let (model, _timings) = fit_capture_with_progress(&capture, &fit_opts, &|done, total| {
            b.set_total(total as u64);
            b.set_position(done as u64)
        })?;
        b.finish();
        model.save(&model_dir)?;
        Ok(model)
    })?;

    // 5. Renders of objects made of the material.
    let mut renders = Vec::new();
    if !opts.skip_renders {
        stages.run("render", || {
            let renders_dir = out.join("renders");
            std::fs::create_dir_all(&renders_dir)?;
            let settings = render_settings(opts.scale);
            let b = Bar::new("render", 6, opts.quiet);
            // One scene per object: the lightings change only its lights.
            let light = |scene: &mut Scene, lights: Vec<Light>, env: Option<EnvMap>| {
                scene.lights = lights;
                scene.env_visible = env.is_some();
                scene.env = env;
            };
            // One pass 1 per object (surface samples, R_d table, texture),
            // under its first lighting, both objects side by side: the
            // texture synthesis grows one point at a time, on one core. Each
            // lighting then redoes only its irradiance.
            let t = Instant::now();
            type Lit = [(&'static str, Vec<Light>, Option<EnvMap>); 3];
            let first = |object: &str| -> Result<(Scene, Lit, Prepared)> {
                let mut scene = Scene::builtin(object)?;
                let lit = lightings(&scene);
                light(&mut scene, lit[0].1.clone(), lit[0].2.clone());
                let stats = &mut RenderStats::default();
                let prepared = prepare(&scene, &model, &settings, stats)?;
                Ok((scene, lit, prepared))
            };
            let (teapot, bread) = rayon::join(|| first("teapot"), || first("bread"));
            b.println(&format!(
                "   teapot and bread, surface samples and textures: {:.1} s",
                t.elapsed().as_secs_f64()
            ));
            for (object, first) in [("teapot", teapot), ("bread", bread)] {
                let (mut scene, lit, mut prep) = first?;
                for (k, (light_name, lights, env)) in lit.into_iter().enumerate() {
                    let t = Instant::now();
                    if k > 0 {
                        light(&mut scene, lights, env);
                        prep.relight(&scene, &model, &settings, &mut RenderStats::default())?;
                    }
                    let (img, _) =
                        render_prepared(&scene, &model, &settings, &prep, &AtomicBool::new(false))
                            .context("render cancelled")?;
                    let stem = format!("{object}-{light_name}");
                    img.write_exr(&renders_dir.join(format!("{stem}.exr")))?;
                    img.write_png(&renders_dir.join(format!("{stem}.png")), None)?;
                    b.println(&format!("   {stem}: {:.1} s", t.elapsed().as_secs_f64()));
                    b.inc(1);
                    renders.push(format!("renders/{stem}.png"));
                }
            }
            b.finish();
            Ok(())
        })?;
    }

    // 6. The report: fit plot, f(w_i), f_v and LRF mosaics, the stage times so far.
    let report_opts = qhm_model::report::ReportOptions {
        stages: stages
            .times
            .iter()
            .map(|t| (t.stage.clone(), t.seconds))
            .collect(),
        ..Default::default()
    };
    stages.run("report", || {
        // From the files on disk, as `qhm report` would: checks they are whole.
        let saved = reload_model(out)?;
        // Staged, so the report carries the marker `qhm report --force` recognises.
        let staged = StagedDir::begin(&out.join("report"), OutputKind::Report, true)?;
        qhm_model::report::write_report_with(&saved, &model_dir, staged.path(), &report_opts)?;
        staged.commit()?;
        Ok(())
    })?;

    let summary = DemoSummary {
        sample: opts.sample.clone(),
        scale: opts.scale.name().to_string(),
        seed: opts.seed,
        recovered: model.dipole,
        reference: reference(&opts.sample),
        calibration_rows_within_target: cal_ok,
        calibration_rows: cal_rows,
        frames,
        monte_carlo,
        renders,
        stages: stages.times,
    };
    let json = serde_json::to_string_pretty(&summary)?;
    std::fs::write(out.join("summary.json"), json + "\n")
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(summary)
}

/// The closing table: recovered against reference parameters, stage times.
pub fn summary_table(s: &DemoSummary) -> String {
    use std::fmt::Write;
    let mut t = String::new();
    let d = &s.recovered;
    let _ = writeln!(
        t,
        "sample {} at scale {} (seed {}), {} frames",
        s.sample, s.scale, s.seed, s.frames
    );
    let _ = writeln!(
        t,
        "{:<12} {:>9} {:>10} {:>10}",
        "parameter", "channel", "recovered", "reference"
    );
    for (c, name) in ["R", "G", "B"].iter().enumerate() {
        let (ra, rs) = match &s.reference {
            Some(r) => (
                format!("{:.4}", r.alpha_prime[c]),
                format!("{:.4}", r.sigma_t_prime[c]),
            ),
            None => ("-".into(), "-".into()),
        };
        let _ = writeln!(
            t,
            "{:<12} {:>9} {:>10.4} {:>10}",
            "a'", name, d.alpha_prime[c], ra
        );
        let _ = writeln!(
            t,
            "{:<12} {:>9} {:>10.4} {:>10}",
            "s'_t (1/mm)", name, d.sigma_t_prime[c], rs
        );
    }
    if let Some(r) = &s.reference {
        let _ = writeln!(t, "reference: {}", r.kind);
    }
    let _ = writeln!(
        t,
        "calibration: {} of {} quantities within target",
        s.calibration_rows_within_target, s.calibration_rows
    );
    let _ = writeln!(t, "capture {}", s.monte_carlo);
    let total: f64 = s.stages.iter().map(|x| x.seconds).sum();
    for st in &s.stages {
        let _ = writeln!(t, "{:<14} {:>8.1} s", st.stage, st.seconds);
    }
    let _ = writeln!(t, "{:<14} {:>8.1} s", "total", total);
    t
}

/// Loads a written model back, as a user would (checks the files are whole).
pub fn reload_model(out: &Path) -> Result<MaterialModel> {
    MaterialModel::load(&out.join("model"))
        .with_context(|| format!("loading {}", out.join("model").display()))
}
