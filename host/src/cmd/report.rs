//! `qhm report MODEL_DIR`: plots (profile fit, entrance function), f_v and
//! LRF mosaics and an HTML page (qhm_model::report).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use qhm_model::MaterialModel;

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Model directory written by `qhm fit`.
    pub model_dir: PathBuf,
    /// Output directory (default: MODEL_DIR/report).
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
}

pub fn run(args: ReportArgs) -> anyhow::Result<ExitCode> {
    let model = MaterialModel::load(&args.model_dir)
        .with_context(|| format!("loading {}", args.model_dir.display()))?;
    let out = args.output.unwrap_or_else(|| args.model_dir.join("report"));
    let files = qhm_model::report::write_report(&model, &args.model_dir, &out)?;
    for f in &files.files {
        println!("wrote {}", f.display());
    }
    println!("wrote {}", files.html.display());
    Ok(ExitCode::SUCCESS)
}
