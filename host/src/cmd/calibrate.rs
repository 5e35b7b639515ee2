//! `qhm calibrate <response|colour|geometry|lamps|laser|all>`: run one
//! calibration step (or all, in dependency order) and update the versioned
//! calibration file (docs/imaging.md). With `--sim` the frames come from the
//! built-in simulated rig, and a table compares recovered with true values.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use qhm_imaging::Calibration;
use sim_devices::SimCalibrator;

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Camera response curves (Mitsunaga-Nayar) from exposure brackets.
    Response,
    /// Relative colour of the cameras from the colour pattern.
    Colour,
    /// Intrinsics, distortion, poses (Zhang) and the turntable axis from the checkerboard
    /// (on the turntable and on a spacer of known thickness, `sim_devices::cal::SPACER_MM`).
    Geometry,
    /// Lamp irradiance from the reference white.
    Lamps,
    /// Laser-plane angles (two-height target) and laser flux (reference white).
    Laser,
    /// All of the above, in order.
    All,
    /// No frames: write the calibration the simulated rig truly has (`--sim`
    /// only), to tell the fit's own errors from the calibration's.
    Truth,
}

#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// Which calibration to run.
    #[arg(value_enum)]
    pub step: Step,
    /// Calibrate the built-in simulated rig and report recovered against true values.
    #[arg(long)]
    pub sim: bool,
    /// Seed of the simulated rig's perturbations and noise.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Simulation quality: ci, preview, default or final.
    #[arg(long, default_value = "preview")]
    pub quality: String,
    /// Calibration file to update (created if missing).
    #[arg(long, short, default_value = "calibration.toml")]
    pub out: PathBuf,
}

pub fn run(args: CalibrateArgs) -> anyhow::Result<ExitCode> {
    if !args.sim {
        bail!(
            "only the simulated rig can be calibrated so far: pass --sim (real cameras need the capture backend)"
        );
    }
    let quality = sim_light::SimQuality::by_name(&args.quality)
        .map_err(|e| anyhow::anyhow!("--quality: {e}"))?;
    let mut cal = Calibration::load_or_default(&args.out)
        .with_context(|| format!("reading {}", args.out.display()))?;
    let sim = SimCalibrator::new(args.seed, quality);
    if args.step == Step::Truth {
        cal.source = format!("sim seed {} truth", args.seed);
        sim.truth(&mut cal);
        cal.save(&args.out)
            .with_context(|| format!("writing {}", args.out.display()))?;
        println!(
            "the simulated rig's true calibration written to {}",
            args.out.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    cal.source = format!("sim seed {} quality {}", args.seed, args.quality);
    let steps: &[Step] = match args.step {
        Step::All => &[
            Step::Response,
            Step::Geometry,
            Step::Colour,
            Step::Lamps,
            Step::Laser,
        ],
        _ => std::slice::from_ref(&args.step),
    };
    let mut rows = Vec::new();
    for step in steps {
        let res = match step {
            Step::Response => sim.response(&mut cal, &mut rows),
            Step::Colour => sim.colour(&mut cal, &mut rows),
            Step::Geometry => sim.geometry(&mut cal, &mut rows),
            Step::Lamps => sim.lamps(&mut cal, &mut rows),
            Step::Laser => sim.laser(&mut cal, &mut rows),
            Step::All | Step::Truth => Ok(()),
        };
        res.with_context(|| format!("calibration step {step:?}"))?;
        cal.save(&args.out)
            .with_context(|| format!("writing {}", args.out.display()))?;
    }
    println!(
        "{:<34} {:>14} {:>14} {:>12}  {:<14}",
        "quantity", "recovered", "true", "error", "target"
    );
    for r in &rows {
        println!("{r}");
    }
    let missed = rows.iter().filter(|r| !r.ok).count();
    println!(
        "{} of {} rows within target; written {}",
        rows.len() - missed,
        rows.len(),
        args.out.display()
    );
    Ok(if missed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(2)
    })
}
