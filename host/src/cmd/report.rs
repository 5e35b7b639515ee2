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
    /// A column of the Fig. 6 rows: the LRF sample nearest to light
    /// THETA,PHI and view THETA,PHI in degrees, e.g. `--at 30,180:0,0`
    /// (repeat for more columns; default: four spread over the samples).
    #[arg(long = "at", value_name = "LIGHT:VIEW", value_parser = parse_at)]
    pub at: Vec<([f32; 3], [f32; 3])>,
}

/// `THETA,PHI:THETA,PHI` (degrees) as unit light and view directions.
fn parse_at(s: &str) -> Result<([f32; 3], [f32; 3]), String> {
    let dir = |p: &str| -> Result<[f32; 3], String> {
        let (t, f) = p
            .split_once(',')
            .ok_or_else(|| format!("`{p}` is not THETA,PHI in degrees"))?;
        let num = |x: &str| {
            x.trim()
                .parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("`{x}` is not an angle in degrees"))
        };
        let (t, f) = (num(t)?, num(f)?);
        if !(0.0..=90.0).contains(&t) {
            return Err(format!("theta {t} must be within 0..90 degrees"));
        }
        let (t, f) = (t.to_radians(), f.to_radians());
        Ok([t.sin() * f.cos(), t.sin() * f.sin(), t.cos()])
    };
    let (l, v) = s
        .split_once(':')
        .ok_or_else(|| format!("`{s}` is not LIGHT:VIEW (each THETA,PHI in degrees)"))?;
    Ok((dir(l)?, dir(v)?))
}

pub fn run(args: ReportArgs) -> anyhow::Result<ExitCode> {
    let model = MaterialModel::load(&args.model_dir)
        .with_context(|| format!("loading {}", args.model_dir.display()))?;
    let out = args.output.unwrap_or_else(|| args.model_dir.join("report"));
    if !args.at.is_empty() && model.lrf.samples.is_empty() {
        anyhow::bail!("--at: the model has no LRF samples to choose from");
    }
    let opts = qhm_model::report::ReportOptions {
        fig6_samples: args
            .at
            .iter()
            .filter_map(|&(l, v)| qhm_model::report::nearest_sample(&model, l, v))
            .collect(),
        ..Default::default()
    };
    let staged = StagedDir::begin(&out, OutputKind::Report, args.force)?;
    let files =
        qhm_model::report::write_report_with(&model, &args.model_dir, staged.path(), &opts)?;
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
