//! `qhm rectify CAPTURE_DIR`: HDR-merge every exposure bracket of a capture
//! with the calibrated responses, resample it onto the reference plane, fit
//! the laser stripe lines, and write CAPTURE_DIR/rectified/ (format in
//! docs/imaging.md; read by the model fitter).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use qhm_acquire::plan::{Light, Pass, Plan};
use qhm_acquire::{CaptureDir, Manifest};
use qhm_imaging::pipeline::{RectifyOptions, Shot, ShotLight, rectify_capture};
use qhm_imaging::{Calibration, hdr::MergeOptions, rectify::Grid};

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
    /// Keep stripe texels at least this far from the fitted line, mm.
    #[arg(long, default_value_t = 0.5)]
    pub d_min: f64,
    /// Keep stripe texels at most this far from the fitted line, mm.
    #[arg(long, default_value_t = 12.0)]
    pub d_max: f64,
}

/// Group a plan's steps into brackets: same pass, pose and light, differing exposure.
fn shots(plan: &Plan, root: &std::path::Path) -> Vec<Shot> {
    let mut groups: BTreeMap<String, Vec<&qhm_acquire::plan::Step>> = BTreeMap::new();
    let mut order = Vec::new();
    for s in &plan.steps {
        let key = format!(
            "{:?}|{:?}|{:.9}|{:.9}|{:?}|{:?}",
            s.pass, s.clamp_elevation, s.turntable, s.light_arc, s.light, s.cameras
        );
        if !groups.contains_key(&key) {
            order.push(key.clone());
        }
        groups.entry(key).or_default().push(s);
    }
    let power = plan.config.laser_power_permille as f64 / 1000.0;
    let mut out = Vec::new();
    for key in order {
        let steps = &groups[&key];
        let s0 = steps[0];
        for k in 0..s0.triggers() {
            for &cam in &s0.cameras {
                let light = match &s0.light {
                    Light::Laser { colour, .. } => ShotLight::Laser {
                        pass: s0.pass.number(),
                        channel: colour.index(),
                        clamp_elevation: s0.clamp_elevation.unwrap_or(std::f64::consts::FRAC_PI_2),
                        power,
                    },
                    Light::Lamp { lamp } => ShotLight::Lamp {
                        index: *lamp as usize,
                    },
                };
                debug_assert!(
                    s0.pass != Pass::Reflectance || matches!(light, ShotLight::Lamp { .. })
                );
                out.push(Shot {
                    light,
                    turntable: s0.turntable,
                    light_arc: s0.light_arc,
                    camera: cam as usize,
                    frames: steps
                        .iter()
                        .map(|s| (root.join(s.frame_path(k, cam)), s.exposure_s))
                        .collect(),
                });
            }
        }
    }
    out
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
    if !(args.width_mm > 0.0)
        || !(args.threshold > 0.0 && args.threshold < 1.0)
        || !(args.d_min >= 0.0 && args.d_max > args.d_min)
    {
        bail!("need --width-mm > 0, 0 < --threshold < 1 and 0 <= --d-min < --d-max");
    }
    let n = plan.config.rectified_size as usize;
    let opts = RectifyOptions {
        grid: Grid::centred(n, args.width_mm / n as f64),
        binning: plan.config.binning,
        sensor_gain: 10f64.powf(plan.config.gain_db / 20.0),
        threshold: args.threshold,
        d_min: args.d_min,
        d_max: args.d_max,
        merge: MergeOptions::default(),
        light_arc_azimuth0: hardware::NOMINAL_GEOMETRY.light_arc_azimuth0,
    };
    let shots = shots(&plan, root);
    let bar = indicatif::ProgressBar::new(shots.len() as u64);
    let out = root.join("rectified");
    let idx = rectify_capture(&shots, &cal, &opts, &out, &|done, _| {
        bar.set_position(done as u64)
    })
    .with_context(|| format!("rectifying {}", root.display()))?;
    bar.finish_and_clear();
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
