//! `qhm capture plan|run`: the capture plan of paper Fig. 4 (frames, disk,
//! rig time against a mechanical lower bound) and its execution on the
//! built-in simulated rig (`--sim`) or a real rig (`--port` + GenICam cameras),
//! into a crash-safe, resumable capture directory. A simulated capture can
//! be taken in shares (`--shard K/N`, one process or machine each, e.g. a
//! Slurm job array) and joined with `--merge` into the directory an
//! unsharded run writes (qhm_acquire::dir).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use qhm_acquire::dir::{merge_shards, shard_dir, shell_word};
use qhm_acquire::plan::Step;
use qhm_acquire::qhm_link::{DEFAULT_BAUD, Link};
use qhm_acquire::{
    Camera, CaptureDir, ConsoleOperator, DirError, Manifest, Operator, Plan, PlanConfig, Progress,
    RunOptions, Scale, run_capture, safe_off,
};
use qhm_imaging::shards::Shard;
use qhm_progress::Bar;
use sim_devices::{SimRig, SimRigConfig};

#[derive(Args, Debug)]
pub struct CaptureArgs {
    #[command(subcommand)]
    pub action: CaptureAction,
}

#[derive(Subcommand, Debug)]
pub enum CaptureAction {
    /// Print the plan: frames per pass, disk, estimated rig time and its lower bound.
    Plan {
        /// Sampling density: ci, default or paper (Table 1).
        #[arg(long, default_value = "default")]
        scale: String,
        /// Machine-readable JSON.
        #[arg(long)]
        json: bool,
    },
    /// Execute the plan into a capture directory.
    Run(RunArgs),
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// Use the built-in simulated rig and cameras.
    #[arg(long, conflicts_with = "port")]
    pub sim: bool,
    /// Serial device of the rig's MCU (real rig; cameras through Aravis).
    #[arg(long)]
    pub port: Option<PathBuf>,
    #[arg(long, default_value_t = DEFAULT_BAUD)]
    pub baud: u32,
    /// Real rig: camera on arc position N is GenICam device ID (repeat: 1=ID1 2=ID2 ...);
    /// `N=DEVICE,trigger=software` fires a camera not wired to the MCU's trigger
    /// lines by software on the MCU's trigger event (`trigger=Line2`: another input line).
    #[arg(long = "camera", value_name = "N=DEVICE[,trigger=software]")]
    pub cameras: Vec<String>,
    /// Sampling density: ci, default or paper.
    #[arg(long, default_value = "default")]
    pub scale: String,
    /// Sample preset or TOML file (what the simulated rig measures; recorded in capture.toml).
    #[arg(long, default_value = "two-material")]
    pub sample: String,
    /// Seed of the simulated world (rig errors, Monte Carlo, sensor noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated rig: at most this many rig seconds per wall second (default 200;
    /// the rig also waits for a late host, so its clock never outruns the link).
    #[arg(long)]
    pub sim_speed: Option<f64>,
    /// Capture directory.
    #[arg(short = 'o', long = "out")]
    pub out: PathBuf,
    /// The calibration file of the rig (from `qhm calibrate`), recorded in
    /// capture.toml for `qhm rectify` [default: OUT/../calibration.toml if
    /// there].
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Continue the capture in OUT (after Ctrl-C, a crash, a disconnect).
    #[arg(long)]
    pub resume: bool,
    /// Longest wait for one frame, seconds.
    #[arg(long, default_value_t = 120.0)]
    pub frame_timeout: f64,
    /// No progress bars (logs and CI).
    #[arg(long)]
    pub quiet: bool,
    /// Real rig, unattended: report each operator step (the laser clamp) and
    /// carry on without waiting for Enter.
    #[arg(long)]
    pub yes: bool,
    /// Simulated rig: take only share K of N of the plan's steps (1 <= K <= N),
    /// into OUT/shards/K-of-N/; join the N shares with `--merge`.
    #[arg(long, value_name = "K/N", requires = "sim")]
    pub shard: Option<Shard>,
    /// Join the N finished shares in OUT/shards/ into the capture OUT, as
    /// one unsharded run writes it (no rig needed).
    #[arg(long, conflicts_with_all = ["sim", "port", "shard", "resume"])]
    pub merge: bool,
}

pub fn run(args: CaptureArgs) -> Result<ExitCode> {
    match args.action {
        CaptureAction::Plan { scale, json } => plan(&scale, json),
        CaptureAction::Run(a) => {
            let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
            rt.block_on(run_cmd(a))
        }
    }
}

pub(crate) fn hms(s: f64) -> String {
    let s = s.round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

fn plan(scale: &str, json: bool) -> Result<ExitCode> {
    let scale: Scale = scale.parse()?;
    let plan = Plan::new(PlanConfig::for_scale(scale))?;
    let s = plan.summary();
    if json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(ExitCode::SUCCESS);
    }
    let c = &plan.config;
    let deg = |v: &[f64]| {
        v.iter()
            .map(|e| format!("{:.0}", e.to_degrees()))
            .collect::<Vec<_>>()
            .join(",")
    };
    let ms = |v: &[f64]| {
        v.iter()
            .map(|e| format!("{}", e * 1e3))
            .collect::<Vec<_>>()
            .join(",")
    };
    println!("capture plan, scale {}", scale.name());
    println!(
        "  pass 1 (entrance):    (clamp at {} deg x {} arc rotations x {} turntable + {} vertical reference rows) x {} lasers x {} scan x {} exposures, cameras {:?}: {} frames",
        deg(&c.oblique_elevations()),
        c.entrance_arc_rotations,
        c.entrance_turntable,
        c.entrance_vertical_rows().len(),
        c.laser_colours.len(),
        c.entrance_positions(),
        c.laser_exposures.len(),
        c.entrance_cameras,
        s.frames_per_pass[0]
    );
    println!(
        "  pass 2 (exiting):     {} turntable (arc follows) x {} lasers x {} scan x {} exposures, cameras {:?}: {} frames",
        c.exiting_turntable,
        c.laser_colours.len(),
        c.scan_positions,
        c.laser_exposures.len(),
        c.cameras,
        s.frames_per_pass[1]
    );
    println!(
        "  pass 3 (reflectance): {} arc rotations x {} turntable x lamps {:?} x {} exposures, cameras {:?}: {} frames",
        c.reflectance_arc_rotations,
        c.reflectance_turntable,
        c.lamps,
        c.lamp_exposures.len(),
        c.cameras,
        s.frames_per_pass[2]
    );
    println!(
        "  exposures: laser {} ms, lamp {} ms; gain {} dB; frames {}x{} (binning {}); rectified {}^2",
        ms(&c.laser_exposures),
        ms(&c.lamp_exposures),
        c.gain_db,
        s.frame_size.0,
        s.frame_size.1,
        c.binning,
        c.rectified_size
    );
    println!(
        "  {} steps, {} triggers, {} frames, disk at most {:.2} GB",
        s.steps,
        s.triggers,
        s.frames,
        s.disk_bytes as f64 / 1e9
    );
    let t = &s.timing;
    println!(
        "  rig time estimate {} (homing {:.0} s, {} moves {:.0} s, exposures {:.0} s, switching {:.0} s, operator {:.0} s)",
        hms(s.estimate_s),
        t.homing_s,
        t.moves,
        t.motion_s,
        t.exposure_s,
        t.switching_s,
        t.operator_s
    );
    println!(
        "  lower bound       {} (exposures at {} Hz {:.0} s, unavoidable travel {:.1} s, operator {:.0} s); ratio {:.3}",
        hms(s.lower_bound_s),
        s.frame_rate_hz,
        t.lower_exposure_s,
        t.lower_motion_s,
        t.lower_operator_s,
        s.ratio
    );
    Ok(ExitCode::SUCCESS)
}

/// Progress: frames done, with the ETA (a bar on a terminal, a plain line
/// every few seconds otherwise).
struct Bars {
    bar: Bar,
}

impl Progress for Bars {
    fn start(&mut self, total: usize, done: usize) {
        self.bar.start(total as u64, done as u64);
    }
    fn frame(&mut self, step: &Step, done: usize) {
        self.bar
            .set_message(&format!("pass {} step {}", step.pass.number(), step.index));
        self.bar.set_position(done as u64);
    }
    fn note(&mut self, message: &str) {
        self.bar.println(message);
    }
}

/// The exact command that continues the capture in `a.out`: rig, scale,
/// sample and seed from its capture.toml, a real rig's cameras and baud rate
/// from this run.
fn resume_command(m: &Manifest, a: &RunArgs) -> String {
    let mut cmd = format!("qhm capture run {}", m.run_args());
    if m.rig.starts_with("serial:") {
        for c in &a.cameras {
            cmd += &format!(" --camera {}", shell_word(c));
        }
        if a.baud != DEFAULT_BAUD {
            cmd += &format!(" --baud {}", a.baud);
        }
        if a.yes {
            cmd += " --yes";
        }
    }
    cmd + &format!(" --resume -o {}", shell_word(&a.out.to_string_lossy()))
}

/// A capture directory's refusal, with the command that resumes it where
/// there is one to resume.
fn dir_error(e: DirError, out: &std::path::Path, a: &RunArgs) -> anyhow::Error {
    let hint = match &e {
        DirError::Exists(_) | DirError::Mismatch { .. } => Manifest::read(out)
            .ok()
            .map(|m| format!("; to continue it: `{}`", resume_command(&m, a))),
        _ => None,
    };
    match hint {
        Some(h) => anyhow::anyhow!("{e}{h}"),
        None => anyhow::Error::new(e),
    }
}

/// A real rig needs `--camera N=DEVICE` for every camera the plan fires.
fn check_cameras_given(plan: &Plan, specs: &[String]) -> Result<()> {
    let mut given = std::collections::BTreeSet::new();
    for spec in specs {
        let n = spec
            .split_once('=')
            .filter(|(_, dev)| !dev.trim().is_empty())
            .and_then(|(n, _)| n.trim().parse::<u8>().ok())
            .filter(|&n| n < 8);
        match n {
            Some(n) => given.insert(n),
            None => bail!("--camera {spec:?}: expected N=DEVICE, N in 0..8"),
        };
    }
    let needed: std::collections::BTreeSet<u8> = plan
        .steps
        .iter()
        .flat_map(|s| s.cameras.iter().copied())
        .collect();
    let missing: Vec<String> = needed.difference(&given).map(|c| c.to_string()).collect();
    if !missing.is_empty() {
        bail!(
            "the plan fires cameras {}; give --camera N=DEVICE for each (missing: {})",
            needed
                .iter()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            missing.join(", ")
        );
    }
    Ok(())
}

async fn run_cmd(a: RunArgs) -> Result<ExitCode> {
    if a.merge {
        let d = merge_shards(&a.out)
            .with_context(|| format!("merging the shares of {}", a.out.display()))?;
        eprintln!(
            "{}: shares merged: {} frames, capture complete",
            a.out.display(),
            d.frame_count()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let scale: Scale = a.scale.parse()?;
    if !(a.frame_timeout.is_finite() && a.frame_timeout > 0.0) {
        bail!("--frame-timeout must be a positive number of seconds");
    }
    let plan = Plan::new(PlanConfig::for_scale(scale))?;
    let rig_name = match (&a.port, a.sim) {
        (_, true) => "sim".to_string(),
        (Some(p), false) => format!("serial:{}", p.display()),
        (None, false) => bail!("say where the rig is: --sim or --port DEVICE"),
    };
    if a.port.is_some() {
        check_cameras_given(&plan, &a.cameras)?;
    }
    let mut manifest = Manifest::new(&rig_name, &a.sample, a.seed, &plan);
    if let Some(cal) = host::pipeline::capture_calibration(&a.out, a.calibration.as_deref())? {
        manifest
            .record_calibration(&a.out, &cal)
            .with_context(|| format!("recording the calibration {}", cal.display()))?;
    }
    // A share is a capture directory of its own inside OUT/shards/.
    let out = match a.shard {
        Some(s) => {
            if a.out.join("capture.toml").exists() {
                bail!(
                    "{} already holds a whole capture; shares go into a directory of their own",
                    a.out.display()
                );
            }
            if let Ok(entries) = std::fs::read_dir(&a.out)
                && let Some(other) = entries
                    .flatten()
                    .find(|e| e.file_name() != qhm_acquire::dir::SHARDS)
            {
                bail!(
                    "{} holds {} and is not a capture taken in shares; refusing to write into it",
                    a.out.display(),
                    other.file_name().to_string_lossy()
                );
            }
            manifest.shard = Some([s.k as u32, s.n as u32]);
            shard_dir(&a.out, s.k as u32, s.n as u32)
        }
        None => a.out.clone(),
    };
    // Refuse foreign, corrupt or mismatching directories before touching the
    // rig. A new capture's directory is made only once the rig and cameras
    // are up, so a failed start leaves nothing; a capture that never took a
    // frame is started anew, whatever it was asked to measure.
    let resuming = a.resume && !CaptureDir::is_unstarted(&out).unwrap_or(false);
    let opened = if resuming {
        let d = CaptureDir::open(&out, Some(&manifest))
            .map_err(|e| dir_error(e, &out, &a))
            .with_context(|| format!("cannot resume {}", out.display()))?;
        if d.is_complete() {
            eprintln!(
                "{}: capture already complete ({} frames)",
                out.display(),
                d.frame_count()
            );
            return Ok(ExitCode::SUCCESS);
        }
        Some(d)
    } else {
        CaptureDir::check_new(&out).map_err(|e| dir_error(e, &out, &a))?;
        None
    };
    let mut opts = RunOptions {
        frame_timeout: Duration::from_secs_f64(a.frame_timeout),
        ..RunOptions::default()
    };
    // The simulated rig owns its world and cameras for the whole run.
    let mut sim_rig: Option<SimRig> = None;
    let mut real_cameras: Vec<Box<dyn Camera>> = Vec::new();
    let (link, mut operator): (Link, Box<dyn Operator>) = if a.sim {
        let mut cfg = SimRigConfig::new(&a.sample, scale, a.seed);
        if let Some(s) = a.sim_speed {
            if !(s.is_finite() && s > 0.0 && s <= 1000.0) {
                bail!("--sim-speed must be in (0, 1000]");
            }
            cfg.speed = s;
        }
        opts.time_scale = cfg.speed;
        let rig = SimRig::start_with(cfg)
            .await
            .context("starting the simulated rig")?;
        let out = (
            rig.link.clone(),
            Box::new(rig.handle.operator()) as Box<dyn Operator>,
        );
        sim_rig = Some(rig);
        out
    } else {
        let link;
        (link, real_cameras) = host::real_rig::open(a.port.as_deref(), a.baud, &a.cameras).await?;
        let op: Box<dyn Operator> = if a.yes {
            Box::new(host::calibrate::Unattended)
        } else {
            Box::new(ConsoleOperator)
        };
        (link, op)
    };
    let made_out = !out.exists();
    let mut dir = match opened {
        Some(d) => d,
        None => CaptureDir::create(&out, manifest).map_err(|e| dir_error(e, &out, &a))?,
    };
    let cameras: &mut [Box<dyn Camera>] = match sim_rig.as_mut() {
        Some(r) => &mut r.cameras,
        None => &mut real_cameras,
    };
    let mut bars = Bars {
        bar: Bar::new("capture", 0, a.quiet),
    };
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
    bars.bar.finish();
    let resume = resume_command(dir.manifest(), &a);
    let planned = dir.planned_frames(&plan);
    let stopped = |dir: CaptureDir| -> Result<String> {
        let n = dir.frame_count();
        Ok(if dir.discard_if_unstarted()? {
            if made_out {
                let _ = std::fs::remove_dir(&out);
                if a.shard.is_some() {
                    // The shards folder and OUT, if this share made them and they are empty.
                    let _ = std::fs::remove_dir(a.out.join(qhm_acquire::dir::SHARDS));
                    let _ = std::fs::remove_dir(&a.out);
                }
            }
            format!(
                "no frame was taken; {} is left as it was before",
                out.display()
            )
        } else {
            format!("{n} of {planned} frames are safely on disk; continue with `{resume}`")
        })
    };
    match outcome {
        None => {
            safe_off(&link).await;
            eprintln!("interrupted: {}", stopped(dir)?);
            Ok(ExitCode::from(130))
        }
        Some(Err(e)) => {
            let why = stopped(dir)?;
            Err(anyhow::Error::new(e).context(format!("capture stopped: {why}")))
        }
        Some(Ok(report)) => {
            eprintln!(
                "capture {}: {} frames written now, {} total, {} MCU resets recovered, {} steps retaken for damaged frames",
                if report.complete {
                    "complete"
                } else {
                    "paused"
                },
                report.frames_written,
                dir.frame_count(),
                report.resets_recovered,
                report.retakes
            );
            if let Some(s) = a.shard.filter(|_| report.complete) {
                eprintln!(
                    "share {s} done; once all {} are, join them with `qhm capture run --merge -o {}`",
                    s.n,
                    shell_word(&a.out.to_string_lossy())
                );
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
