//! `qhm compare RENDER.exr TRUTH.exr`: a render against a ground truth in
//! statistics (qhm_render::compare): means, the low-pass block RMSE (with
//! the truth's noise taken out given a second truth) and the local-contrast
//! histogram distance.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::anyhow;
use clap::Args;
use qhm_formats::exr::read_rgb;

#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The render (linear EXR, e.g. from `qhm render -o R.exr`).
    pub render: PathBuf,
    /// The ground truth (linear EXR, e.g. from `qhm sim render-object -o T.exr`).
    pub truth: PathBuf,
    /// A second, independent truth (another `--seed`): its difference from
    /// the first is the truth's noise, taken out of the block RMSE.
    #[arg(long)]
    pub truth2: Option<PathBuf>,
    /// Block edge in pixels for the low-pass comparison.
    #[arg(long, default_value_t = 8)]
    pub block: usize,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: CompareArgs) -> anyhow::Result<ExitCode> {
    // The reader's errors name the file already.
    let read = |p: &PathBuf| read_rgb(p).map_err(|e| anyhow!("{e}"));
    let render = read(&args.render)?;
    let truth = read(&args.truth)?;
    let truth2 = args.truth2.as_ref().map(read).transpose()?;
    let c = qhm_render::compare::compare(&render, &truth, truth2.as_ref(), args.block)
        .map_err(|e| anyhow!(e))?;
    if args.json {
        println!("{}", serde_json::to_string(&c)?);
    } else {
        let [r, g, b] = c.mean_ratio;
        println!("pixels compared        {}", c.pixels);
        println!(
            "mean, render / truth   R {r:.4}  G {g:.4}  B {b:.4}  luminance {:.4}",
            c.luminance_ratio
        );
        println!(
            "low-pass {0}x{0} blocks   {1} blocks, RMSE {2:.2} % of the truth's mean luminance",
            args.block,
            c.blocks,
            100.0 * c.block_rmse
        );
        if let (Some(n), Some(d)) = (c.truth_noise, c.block_rmse_denoised) {
            println!(
                "truth's own noise      {:.2} %; RMSE without it {:.2} %",
                100.0 * n,
                100.0 * d
            );
        }
        println!(
            "local contrast         histogram distance {:.3} (0 alike, 1 disjoint)",
            c.contrast_distance
        );
    }
    Ok(ExitCode::SUCCESS)
}
