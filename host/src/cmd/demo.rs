//! `qhm demo`: the whole pipeline on the built-in simulated rig (see
//! `host::demo`); prints the recovered-against-reference table and the time
//! of every stage.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use host::demo::{DemoOptions, run as run_demo, summary_table};
use qhm_acquire::Scale;

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Sample: a preset (two-material, sponge, bread, whole-milk, marble, ...) or a TOML file.
    #[arg(long, default_value = "two-material")]
    pub sample: String,
    /// Capture scale: ci (about a minute), default (minutes), paper (hours; see README).
    #[arg(long, default_value = "default")]
    pub scale: String,
    /// Output directory: new, empty, or (with --force) one an earlier demo wrote.
    #[arg(short = 'o', long = "out", default_value = "qhm-out")]
    pub out: PathBuf,
    /// Replace an earlier demo's output: deletes OUT's calibration.toml,
    /// calibration-capture/, capture/, model/, renders/, report/ and summary.json, with everything
    /// inside them (your own files there too); other files in OUT are kept.
    #[arg(long)]
    pub force: bool,
    /// Seed of the simulated rig's perturbations, sample and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    /// Use this calibration of the same simulated rig (same --scale and
    /// --seed, e.g. an earlier demo's calibration.toml) instead of calibrating.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

pub fn run(args: DemoArgs) -> Result<ExitCode> {
    let scale: Scale = args.scale.parse()?;
    let opts = DemoOptions {
        sample: args.sample,
        scale,
        out: args.out,
        force: args.force,
        seed: args.seed,
        quiet: args.quiet,
        skip_renders: false,
        calibration: args.calibration,
    };
    let summary = run_demo(&opts)?;
    println!("{}", summary_table(&summary));
    println!("everything is in {}", opts.out.display());
    Ok(ExitCode::SUCCESS)
}
