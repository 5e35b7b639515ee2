//! `qhm rectify CAPTURE_DIR`: HDR-merge every exposure bracket of a capture
//! with the calibrated responses, resample it onto the reference plane, fit
//! the laser stripe lines, and write CAPTURE_DIR/rectified/ (format in
//! docs/imaging.md; read by the model fitter).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use host::pipeline::{StripeWindow, calibrated_shots, rectify_options, shots};
use qhm_acquire::{CaptureDir, Manifest};
use qhm_imaging::Calibration;
use qhm_imaging::pipeline::rectify_capture;

#[derive(clap::Args, Debug)]
pub struct RectifyArgs {
    /// Capture directory written by `qhm capture run`.
    pub capture_dir: PathBuf,
    /// Calibration file from `qhm calibrate` [default: CAPTURE_DIR/calibration.toml].
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Width of the rectified area on the sample, mm (texel = width / the plan's rectified size).
    #[arg(long, default_value_t = 32.0)]
    pub width_mm: f64,
    /// Stripe texels: intensity threshold as a fraction of the brightest texel.
    #[arg(long, default_value_t = 0.3)]
    pub threshold: f64,
    /// Keep stripe texels at least this far from the fitted line, mm (0 keeps
    /// the core, which the fit needs for R).
    #[arg(long, default_value_t = 0.0)]
    pub d_min: f64,
    /// Keep stripe texels at most this far from the fitted line, mm.
    #[arg(long, default_value_t = 12.0)]
    pub d_max: f64,
}

pub fn run(args: RectifyArgs) -> anyhow::Result<ExitCode> {
    let root = &args.capture_dir;
    let dir = CaptureDir::open(root, None)
        .with_context(|| format!("opening capture {}", root.display()))?;
    if !dir.is_complete() {
        bail!(
            "{}: the capture is not complete; finish it with `qhm capture run --resume`",
            root.display()
        );
    }
    let manifest: &Manifest = dir.manifest();
    let plan = dir.plan()?;
    let cal_path = args
        .calibration
        .clone()
        .unwrap_or_else(|| root.join("calibration.toml"));
    let cal = Calibration::load(&cal_path)
        .with_context(|| "run `qhm calibrate all` first, or pass --calibration")?;
    let window = StripeWindow {
        width_mm: args.width_mm,
        threshold: args.threshold,
        d_min: args.d_min,
        d_max: args.d_max,
    };
    window.validate().map_err(|e| anyhow::anyhow!("{e}"))?;
    let n = plan.config.rectified_size as usize;
    let opts = rectify_options(&plan, &window);
    let (shots, skipped) = calibrated_shots(shots(&plan, root), &cal);
    if !skipped.is_empty() {
        eprintln!(
            "note: cameras {skipped:?} have no geometric calibration; their frames are left out"
        );
    }
    if shots.is_empty() {
        bail!("no camera of the capture has a geometric calibration");
    }
    let bar = qhm_progress::Bar::new("rectify", shots.len() as u64, false);
    let out = root.join("rectified");
    let idx = rectify_capture(&shots, &cal, &opts, &out, &|done, _| {
        bar.set_position(done as u64)
    })
    .with_context(|| format!("rectifying {}", root.display()))?;
    bar.finish();
    println!(
        "{}: {} stripe and {} lamp images, {}x{} texels of {:.3} mm (sample {:?}) -> {}",
        root.display(),
        idx.stripe.len(),
        idx.lamp.len(),
        n,
        n,
        opts.grid.texel_mm,
        manifest.sample,
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}
