//! Calibration is a capture (the library side of `qhm calibrate` and the
//! demo's calibration stage): the calibration plan (qhm_acquire::cal_plan)
//! runs through `run_capture` like any capture, on a real rig or the
//! simulated one, into a capture directory; the procedures
//! (qhm_imaging::cal_compute) then read its frames. After the compute step
//! of a simulated capture, and only there, the simulated rig's truth table
//! is made (sim_devices::cal).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use qhm_acquire::cal_plan::{self, CalPlanConfig};
use qhm_acquire::dir::shell_word;
use qhm_acquire::plan::{Light, Step};
use qhm_acquire::qhm_link::{DEFAULT_BAUD, Link};
use qhm_acquire::{
    BoxFuture, Camera, CaptureDir, ConsoleOperator, Manifest, Operator, OperatorError, Plan,
    Progress, RunOptions, Scale, run_capture, safe_off,
};
use qhm_imaging::Calibration;
use qhm_imaging::cal_compute::{self, CalShot, Procedure, ShotLight};
use qhm_progress::Bar;
use sim_devices::{Row, SimRig, SimRigConfig, SimTruth};

/// Where the calibration frames come from, and how the capture runs.
#[derive(Debug, Clone)]
pub struct RigSpec {
    /// The built-in simulated rig, cameras and operator.
    pub sim: bool,
    /// Serial device of a real rig's MCU (cameras through Aravis).
    pub port: Option<PathBuf>,
    pub baud: u32,
    /// Real rig: `N=DEVICE` per camera.
    pub cameras: Vec<String>,
    pub scale: Scale,
    /// Seed of the simulated rig.
    pub seed: u64,
    /// Continue the capture in the directory.
    pub resume: bool,
    /// Report operator steps and carry on without waiting.
    pub yes: bool,
    pub frame_timeout: Duration,
    pub quiet: bool,
}

impl RigSpec {
    /// The simulated rig of `seed` at `scale`.
    pub fn sim(scale: Scale, seed: u64, quiet: bool) -> RigSpec {
        RigSpec {
            sim: true,
            port: None,
            baud: DEFAULT_BAUD,
            cameras: Vec::new(),
            scale,
            seed,
            resume: false,
            yes: false,
            frame_timeout: Duration::from_secs(600),
            quiet,
        }
    }
}

/// The capture's progress on a [`Bar`], with the ETA.
struct CalBar(Bar);

impl Progress for CalBar {
    fn start(&mut self, total: usize, done: usize) {
        self.0.start(total as u64, done as u64);
    }
    fn frame(&mut self, step: &Step, done: usize) {
        self.0.set_message(&format!("step {}", step.index));
        self.0.set_position(done as u64);
    }
    fn note(&mut self, message: &str) {
        self.0.println(message);
    }
}

/// Reports each manual step and carries on (`--yes`).
pub struct Unattended;

impl Operator for Unattended {
    fn move_laser_clamp(&mut self, elevation: f64) -> BoxFuture<'_, Result<(), OperatorError>> {
        eprintln!(
            "operator (--yes): laser clamp at {:.1} deg",
            elevation.to_degrees()
        );
        Box::pin(async { Ok(()) })
    }
    fn place_on_turntable(&mut self, what: &str) -> BoxFuture<'_, Result<(), OperatorError>> {
        eprintln!("operator (--yes): the {what} on the turntable");
        Box::pin(async { Ok(()) })
    }
}

/// Takes (or continues) the calibration capture in `out`; false if Ctrl-C stopped it.
pub fn capture(a: &RigSpec, out: &Path) -> Result<bool> {
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    rt.block_on(capture_async(a, out))
}

pub fn resume_command(a: &RigSpec, out: &Path) -> String {
    let mut cmd = match &a.port {
        Some(p) => format!(
            "qhm calibrate capture --port {}",
            shell_word(&p.to_string_lossy())
        ),
        None => format!("qhm calibrate capture --sim --seed {}", a.seed),
    };
    if a.port.is_some() {
        for c in &a.cameras {
            cmd += &format!(" --camera {}", shell_word(c));
        }
        if a.baud != DEFAULT_BAUD {
            cmd += &format!(" --baud {}", a.baud);
        }
    }
    cmd + &format!(
        " --scale {} --resume -o {}",
        a.scale.name(),
        shell_word(&out.to_string_lossy())
    )
}

async fn capture_async(a: &RigSpec, out: &Path) -> Result<bool> {
    let scale = a.scale;
    let plan = Plan::new(CalPlanConfig::plan_config(scale))?;
    let rig_name = match (&a.port, a.sim) {
        (_, true) => "sim".to_string(),
        (Some(p), false) => format!("serial:{}", p.display()),
        (None, false) => bail!("say where the rig is: --sim or --port DEVICE"),
    };
    let seed = if a.sim { a.seed } else { 0 };
    let manifest = Manifest::new(&rig_name, "calibration targets", seed, &plan);
    let resuming = a.resume && !CaptureDir::is_unstarted(out).unwrap_or(false);
    let opened = if resuming {
        let d = CaptureDir::open(out, Some(&manifest))
            .with_context(|| format!("cannot resume {}", out.display()))?;
        if d.is_complete() {
            eprintln!(
                "{}: calibration capture already complete ({} frames)",
                out.display(),
                d.frame_count()
            );
            return Ok(true);
        }
        Some(d)
    } else {
        CaptureDir::check_new(out).map_err(|e| match e {
            qhm_acquire::DirError::Exists(_) => {
                anyhow::anyhow!("{e}; to continue it: `{}`", resume_command(a, out))
            }
            e => e.into(),
        })?;
        None
    };
    let mut opts = RunOptions {
        frame_timeout: a.frame_timeout,
        ..RunOptions::default()
    };
    // The simulated rig owns its world and cameras for the whole run.
    let mut sim_rig: Option<SimRig> = None;
    let mut real_cameras: Vec<Box<dyn Camera>> = Vec::new();
    let (link, mut operator): (Link, Box<dyn Operator>) = if a.sim {
        let cfg = SimRigConfig::calibration(scale, a.seed);
        opts.time_scale = cfg.speed;
        let rig = SimRig::start_with(cfg)
            .await
            .context("starting the simulated rig")?;
        let op = (
            rig.link.clone(),
            Box::new(rig.handle.operator()) as Box<dyn Operator>,
        );
        sim_rig = Some(rig);
        op
    } else {
        let link;
        (link, real_cameras) = crate::real_rig::open(a.port.as_deref(), a.baud, &a.cameras).await?;
        let op: Box<dyn Operator> = if a.yes {
            Box::new(Unattended)
        } else {
            Box::new(ConsoleOperator)
        };
        (link, op)
    };
    let mut dir = match opened {
        Some(d) => d,
        None => CaptureDir::create(out, manifest)?,
    };
    let cameras: &mut [Box<dyn Camera>] = match sim_rig.as_mut() {
        Some(r) => &mut r.cameras,
        None => &mut real_cameras,
    };
    let mut bars = CalBar(Bar::new("calibration capture", 0, a.quiet));
    let run = run_capture(
        &link,
        cameras,
        operator.as_mut(),
        &mut dir,
        &opts,
        &mut bars,
    );
    let outcome = tokio::select! {
        r = run => Some(r),
        _ = tokio::signal::ctrl_c() => None,
    };
    bars.0.finish();
    let resume = resume_command(a, out);
    match outcome {
        None => {
            safe_off(&link).await;
            eprintln!(
                "interrupted: {} frames are safely on disk; continue with `{resume}`",
                dir.frame_count()
            );
            Ok(false)
        }
        Some(Err(e)) => Err(anyhow::Error::new(e).context(format!(
            "calibration capture stopped: {} frames are safely on disk; continue with `{resume}`",
            dir.frame_count()
        ))),
        Some(Ok(report)) => {
            if !report.complete {
                bail!(
                    "the calibration capture stopped before the end of its plan; continue with `{resume}`"
                );
            }
            bars.note(&format!(
                "calibration capture complete: {} frames ({} written now), {} MCU resets recovered, {} steps retaken for damaged frames",
                dir.frame_count(),
                report.frames_written,
                report.resets_recovered,
                report.retakes
            ));
            Ok(true)
        }
    }
}

/// The brackets of a calibration capture, one per camera and rig pose.
pub fn cal_shots(plan: &Plan, root: &Path) -> Result<Vec<CalShot>> {
    let gain = 10f64.powf(plan.config.gain_db / 20.0);
    let mut shots: Vec<CalShot> = Vec::new();
    for step in &plan.steps {
        let Some(cal) = &step.calibration else {
            bail!(
                "step {} is not a calibration step: not a calibration capture",
                step.index
            );
        };
        let procedure = match cal.procedure {
            cal_plan::Procedure::Response => Procedure::Response,
            cal_plan::Procedure::Geometry => Procedure::Geometry,
            cal_plan::Procedure::Colour => Procedure::Colour,
            cal_plan::Procedure::Lamp => Procedure::Lamp,
            cal_plan::Procedure::LaserPlane => Procedure::LaserPlane,
            cal_plan::Procedure::LaserFlux => Procedure::LaserFlux,
        };
        let light = match &step.light {
            Light::Lamp { lamp } => ShotLight::Lamp(*lamp as usize),
            Light::Laser { colour, .. } => ShotLight::Laser(colour.index()),
        };
        for &camera in &step.cameras {
            for k in 0..step.triggers() {
                let frame = (
                    root.join(step.frame_path(k, camera)),
                    step.exposure_s * gain,
                );
                let same = |s: &CalShot| {
                    s.procedure == procedure
                        && s.target == cal.target
                        && s.camera == camera as usize
                        && s.turntable == step.turntable
                        && s.light_arc == step.light_arc
                        && s.clamp == step.clamp_elevation
                        && s.light == light
                        && s.binning == cal.binning
                };
                match shots.iter_mut().find(|s| same(s)) {
                    Some(s) => s.frames.push(frame),
                    None => shots.push(CalShot {
                        procedure,
                        target: cal.target.clone(),
                        height_mm: cal.height_mm,
                        camera: camera as usize,
                        turntable: step.turntable,
                        light_arc: step.light_arc,
                        clamp: step.clamp_elevation,
                        light,
                        binning: cal.binning,
                        frames: vec![frame],
                    }),
                }
            }
        }
    }
    for s in &mut shots {
        s.frames.sort_by(|a, b| a.1.total_cmp(&b.1));
    }
    Ok(shots)
}

/// Computes the calibration from the capture in `dir`: the calibration and,
/// for a simulated capture, its table against the truth.
pub fn compute(dir: &Path, quiet: bool) -> Result<(Calibration, Option<Vec<Row>>)> {
    let d = CaptureDir::open_read(dir).with_context(|| format!("reading {}", dir.display()))?;
    let plan = d.plan()?;
    let Some(config) = plan.config.calibration.clone() else {
        bail!(
            "{} is a capture of a sample, not a calibration capture (take one with `qhm calibrate capture`)",
            dir.display()
        );
    };
    if !d.is_complete() {
        bail!(
            "{}: the calibration capture is not complete ({} frames of {}); continue it with `qhm calibrate capture ... --resume -o {}`",
            dir.display(),
            d.frame_count(),
            d.planned_frames(&plan),
            shell_word(&dir.to_string_lossy())
        );
    }
    let shots = cal_shots(&plan, dir)?;
    let mut cal = Calibration {
        source: format!(
            "calibration capture {} (rig {})",
            dir.display(),
            d.manifest().rig
        ),
        ..Calibration::default()
    };
    let bar = qhm_progress::Bar::new("calibrate", 6, quiet);
    cal_compute::compute(&shots, &mut cal, &|name| {
        bar.set_message(name);
        bar.inc(1);
    })
    .with_context(|| format!("computing the calibration from {}", dir.display()))?;
    bar.finish();
    let rows = (d.manifest().rig == "sim")
        .then(|| SimTruth::new(d.manifest().seed).rows(&cal, config.plane_arc));
    Ok((cal, rows))
}

/// The simulated calibration `qhm demo` runs: capture into `capture_dir`,
/// compute, write `out`; the rows against the truth.
pub fn calibrate_sim(
    scale: Scale,
    seed: u64,
    capture_dir: &Path,
    out: &Path,
    quiet: bool,
) -> Result<Vec<Row>> {
    if !capture(&RigSpec::sim(scale, seed, quiet), capture_dir)? {
        bail!("interrupted");
    }
    let (cal, rows) = compute(capture_dir, quiet)?;
    cal.save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(rows.unwrap_or_default())
}
