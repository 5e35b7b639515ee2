//! `qhm report MODEL_DIR`: plots (profile fit, entrance function), f_v and
//! LRF mosaics and an HTML page (qhm_model::report).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use host::output::{OutputKind, StagedDir};
use qhm_model::MaterialModel;

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Model directory written by `qhm fit`.
    pub model_dir: PathBuf,
    /// Output directory (default: MODEL_DIR/report); must be new, empty, or
    /// (with --force) hold an earlier qhm report.
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
    /// Replace an earlier qhm report in the output directory (nothing else is ever replaced).
    #[arg(long)]
    pub force: bool,
}

pub fn run(args: ReportArgs) -> anyhow::Result<ExitCode> {
    let model = MaterialModel::load(&args.model_dir)
        .with_context(|| format!("loading {}", args.model_dir.display()))?;
    let out = args.output.unwrap_or_else(|| args.model_dir.join("report"));
    let staged = StagedDir::begin(&out, OutputKind::Report, args.force)?;
    let files = qhm_model::report::write_report(&model, &args.model_dir, staged.path())?;
    let staging = staged.path().to_path_buf();
    let out = staged.commit()?;
    // Name the files where they are now, not in the staging directory.
    for f in files.files.iter().chain([&files.html]) {
        let f = f
            .strip_prefix(&staging)
            .map_or(f.clone(), |rel| out.join(rel));
        println!("wrote {}", f.display());
    }
    Ok(ExitCode::SUCCESS)
}
