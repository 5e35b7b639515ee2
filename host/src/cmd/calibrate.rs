//! `qhm calibrate plan|capture|compute|all|truth`: calibration is a capture.
//! `capture` runs the calibration plan (qhm_acquire::cal_plan) through the
//! same machinery as `qhm capture run` (link, cameras, operator prompts for
//! each target and the laser clamp, a capture directory with its journal,
//! `--resume`, progress); `compute` runs the procedures
//! (qhm_imaging::cal_compute) on the frames a calibration capture holds,
//! whatever rig took them, and writes the calibration file; `all` does both.
//! `--sim` takes the frames on the built-in simulated rig; after the compute
//! step of a simulated capture, and only there, a table compares the
//! recovered values with the simulated rig's true ones.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use host::calibrate::{RigSpec, capture, compute};
use qhm_acquire::Plan;
use qhm_acquire::Scale;
use qhm_acquire::cal_plan::{self, CalPlanConfig};
use qhm_acquire::qhm_link::DEFAULT_BAUD;
use qhm_imaging::Calibration;
use sim_devices::SimTruth;

use crate::cmd::capture::hms;

#[derive(Args, Debug)]
pub struct CalibrateArgs {
    #[command(subcommand)]
    pub action: CalibrateAction,
}

#[derive(Subcommand, Debug)]
pub enum CalibrateAction {
    /// Print the calibration plan: targets, frames, rig time and its lower bound.
    Plan {
        /// Frame binning: ci and default bin 4 (2 for the checkerboard and
        /// colour pattern), paper takes full resolution.
        #[arg(long, default_value = "default")]
        scale: String,
        /// Machine-readable JSON.
        #[arg(long)]
        json: bool,
    },
    /// Take the calibration capture into a capture directory.
    Capture(CaptureArgs),
    /// Compute the calibration from a calibration capture's frames.
    Compute {
        /// The calibration capture directory.
        capture: PathBuf,
        /// Calibration file to write (replaced only when every step succeeds).
        #[arg(long, short, default_value = "calibration.toml")]
        out: PathBuf,
    },
    /// Capture and compute.
    All {
        #[command(flatten)]
        rig: RigArgs,
        /// Calibration file to write.
        #[arg(long, short, default_value = "calibration.toml")]
        out: PathBuf,
        /// Calibration capture directory (default: OUT without `.toml`, plus `-capture`).
        #[arg(long)]
        capture: Option<PathBuf>,
    },
    /// No frames: write the calibration the simulated rig truly has (`--sim`
    /// only), to tell the fit's own errors from the calibration's.
    Truth {
        /// The simulated rig (required: only it has a known truth).
        #[arg(long)]
        sim: bool,
        /// Seed of the simulated rig's perturbations.
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Calibration file to update (created if missing).
        #[arg(long, short, default_value = "calibration.toml")]
        out: PathBuf,
    },
}

/// Where the calibration frames come from, and how the capture runs.
#[derive(Args, Debug, Clone)]
pub struct RigArgs {
    /// Use the built-in simulated rig, cameras and operator.
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
    /// Frame binning of the calibration plan: ci, default or paper.
    #[arg(long, default_value = "default")]
    pub scale: String,
    /// Seed of the simulated rig (the same seed as a capture's is the same rig).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Continue the calibration capture (after Ctrl-C, a crash, a disconnect).
    #[arg(long)]
    pub resume: bool,
    /// Unattended: report each operator step and carry on without waiting
    /// for Enter (a rig whose targets and clamp are handled otherwise).
    #[arg(long)]
    pub yes: bool,
    /// Longest wait for one frame, seconds.
    #[arg(long, default_value_t = 120.0)]
    pub frame_timeout: f64,
    /// No progress bars (logs and CI).
    #[arg(long)]
    pub quiet: bool,
}

impl RigArgs {
    fn spec(&self) -> Result<RigSpec> {
        if !(self.frame_timeout.is_finite() && self.frame_timeout > 0.0) {
            bail!("--frame-timeout must be a positive number of seconds");
        }
        Ok(RigSpec {
            sim: self.sim,
            port: self.port.clone(),
            baud: self.baud,
            cameras: self.cameras.clone(),
            scale: self.scale.parse()?,
            seed: self.seed,
            resume: self.resume,
            yes: self.yes,
            frame_timeout: Duration::from_secs_f64(self.frame_timeout),
            quiet: self.quiet,
        })
    }
}

#[derive(Args, Debug)]
pub struct CaptureArgs {
    #[command(flatten)]
    pub rig: RigArgs,
    /// Calibration capture directory.
    #[arg(short = 'o', long = "out")]
    pub out: PathBuf,
}

pub fn run(args: CalibrateArgs) -> Result<ExitCode> {
    match args.action {
        CalibrateAction::Plan { scale, json } => plan(&scale, json),
        CalibrateAction::Capture(a) => Ok(if capture(&a.rig.spec()?, &a.out)? {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(130)
        }),
        CalibrateAction::Compute { capture, out } => compute_cmd(&capture, &out),
        CalibrateAction::All {
            rig,
            out,
            capture: dir,
        } => {
            let dir = dir.unwrap_or_else(|| default_capture_dir(&out));
            if !capture(&rig.spec()?, &dir)? {
                return Ok(ExitCode::from(130));
            }
            compute_cmd(&dir, &out)
        }
        CalibrateAction::Truth { sim, seed, out } => truth(sim, seed, &out),
    }
}

/// `calibration.toml` -> `calibration-capture` beside it.
pub fn default_capture_dir(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map_or("calibration".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}-capture"))
}

fn plan(scale: &str, json: bool) -> Result<ExitCode> {
    let scale: Scale = scale.parse()?;
    let plan = Plan::new(CalPlanConfig::plan_config(scale))?;
    let t = cal_plan::timing(&plan);
    if json {
        let v = serde_json::json!({
            "scale": scale.name(),
            "targets": cal_plan::targets(&plan),
            "steps": plan.steps.len(),
            "frames": plan.frames(),
            "triggers": plan.triggers(),
            "timing": t,
            "estimate_s": t.estimate_s(),
            "lower_bound_s": t.lower_bound_s(),
            "ratio": t.ratio(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(ExitCode::SUCCESS);
    }
    let c = plan
        .config
        .calibration
        .as_ref()
        .expect("a calibration plan");
    println!("calibration plan, scale {}", scale.name());
    let frames = |p: cal_plan::Procedure| -> usize {
        (plan.steps.iter())
            .filter(|s| s.calibration.as_ref().is_some_and(|x| x.procedure == p))
            .map(|s| s.frames())
            .sum()
    };
    use cal_plan::Procedure as P;
    println!(
        "  1. colour pattern, lamp {}: response {} exposures x cameras {:?} ({} frames, binning {}); colour {} exposures ({} frames, binning {})",
        c.target_lamp,
        c.response_exposures.len(),
        c.cameras,
        frames(P::Response),
        c.binning,
        c.colour_exposures.len(),
        frames(P::Colour),
        c.fine_binning
    );
    println!(
        "  2. checkerboard on the turntable, then on the {} mm spacer: {} angles each ({} frames, binning {})",
        c.spacer_mm,
        c.board_turntable.len(),
        frames(P::Geometry),
        c.fine_binning
    );
    println!(
        "  3. reference white: lamps {:?} x {} exposures, then each laser with the clamp vertical x {} exposures, camera {} ({} frames)",
        c.lamps,
        c.lamp_exposures.len(),
        c.laser_exposures.len(),
        c.reference_camera,
        frames(P::Lamp) + frames(P::LaserFlux)
    );
    println!(
        "  4. two-height target under the laser at {} deg, light arc and turntable at {:.0} deg, camera {} ({} frames)",
        c.plane_elevations
            .iter()
            .map(|e| format!("{:.0}", e.to_degrees()))
            .collect::<Vec<_>>()
            .join(","),
        c.plane_arc.to_degrees(),
        c.plane_camera,
        frames(P::LaserPlane)
    );
    println!(
        "  {} steps, {} triggers, {} frames; the operator places {} targets and moves the clamp {} times",
        plan.steps.len(),
        plan.triggers(),
        plan.frames(),
        cal_plan::targets(&plan).len(),
        (t.operator_s - cal_plan::targets(&plan).len() as f64 * cal_plan::OPERATOR_TARGET_S)
            / qhm_acquire::plan::OPERATOR_CLAMP_S
    );
    println!(
        "  rig time estimate {} (homing {:.0} s, {} moves {:.0} s, exposures {:.0} s, switching {:.0} s, operator {:.0} s)",
        hms(t.estimate_s()),
        t.homing_s,
        t.moves,
        t.motion_s,
        t.exposure_s,
        t.switching_s,
        t.operator_s
    );
    println!(
        "  lower bound       {} (exposures {:.0} s, unavoidable travel {:.1} s, operator {:.0} s); ratio {:.3}",
        hms(t.lower_bound_s()),
        t.lower_exposure_s,
        t.lower_motion_s,
        t.lower_operator_s,
        t.ratio()
    );
    Ok(ExitCode::SUCCESS)
}

fn compute_cmd(dir: &Path, out: &Path) -> Result<ExitCode> {
    let (cal, rows) = compute(dir, false)?;
    cal.save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    let Some(rows) = rows else {
        println!("calibration written to {}", out.display());
        return Ok(ExitCode::SUCCESS);
    };
    println!("{}", sim_devices::cal::header());
    for r in &rows {
        println!("{r}");
    }
    let missed = rows.iter().filter(|r| !r.ok).count();
    println!(
        "simulated rig: {} of {} rows within target; written {}",
        rows.len() - missed,
        rows.len(),
        out.display()
    );
    Ok(if missed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(2)
    })
}

fn truth(sim: bool, seed: u64, out: &Path) -> Result<ExitCode> {
    if !sim {
        bail!("only the simulated rig has a known true calibration: pass --sim");
    }
    let mut cal =
        Calibration::load_or_default(out).with_context(|| format!("reading {}", out.display()))?;
    cal.source = format!("sim seed {seed} truth");
    let plane_arc = CalPlanConfig::for_scale(Scale::Default).plane_arc;
    SimTruth::new(seed).truth(&mut cal, plane_arc);
    cal.save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    println!(
        "the simulated rig's true calibration written to {}",
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}
