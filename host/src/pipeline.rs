//! Glue between a capture directory (qhm-acquire's plan and frames) and the
//! rectification pipeline (qhm-imaging): which frames form one exposure
//! bracket of one shot, and the rectification settings a plan implies.
//! Used by `qhm rectify` and `qhm demo`. Also where a capture's
//! calibration file is: the one capture.toml records, or beside the capture.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use qhm_acquire::Manifest;
use qhm_acquire::dir::sha256_hex;
use qhm_acquire::plan::{Light, Plan, Step};
use qhm_imaging::Calibration;
use qhm_imaging::hdr::MergeOptions;
use qhm_imaging::pipeline::{RectifyOptions, Shot, ShotLight};
use qhm_imaging::rectify::Grid;

/// Where stripe texels are kept and how they are found (paper section 4.2).
#[derive(Debug, Clone, Copy)]
pub struct StripeWindow {
    /// Width of the rectified area on the sample, mm.
    pub width_mm: f64,
    /// Stripe texels: intensity threshold as a fraction of the brightest texel.
    pub threshold: f64,
    /// Keep stripe texels within [d_min, d_max] mm of the fitted line.
    pub d_min: f64,
    pub d_max: f64,
}

impl Default for StripeWindow {
    fn default() -> Self {
        StripeWindow {
            width_mm: 32.0,
            threshold: 0.3,
            d_min: 0.0,
            d_max: 12.0,
        }
    }
}

impl StripeWindow {
    /// Checks the ranges; the message names the offending value.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.width_mm.is_finite() && self.width_mm > 0.0) {
            return Err(format!("rectified width {} mm must be > 0", self.width_mm));
        }
        if !(self.threshold > 0.0 && self.threshold < 1.0) {
            return Err(format!(
                "stripe threshold {} must be in (0, 1)",
                self.threshold
            ));
        }
        if !(self.d_min >= 0.0 && self.d_max > self.d_min) {
            return Err(format!(
                "distance interval [{}, {}] mm must satisfy 0 <= min < max",
                self.d_min, self.d_max
            ));
        }
        Ok(())
    }
}

/// Rectification settings for a capture made with `plan`.
pub fn rectify_options(plan: &Plan, window: &StripeWindow) -> RectifyOptions {
    let n = plan.config.rectified_size as usize;
    RectifyOptions {
        grid: Grid::centred(n, window.width_mm / n as f64),
        binning: plan.config.binning,
        sensor_gain: 10f64.powf(plan.config.gain_db / 20.0),
        threshold: window.threshold,
        d_min: window.d_min,
        d_max: window.d_max,
        merge: MergeOptions::default(),
        light_arc_azimuth0: hardware::NOMINAL_GEOMETRY.light_arc_azimuth0,
    }
}

/// Groups a plan's steps into shots: same pass, pose, light and cameras,
/// differing only in exposure, become one bracket per trigger and camera.
pub fn shots(plan: &Plan, capture_root: &Path) -> Vec<Shot> {
    let mut groups: BTreeMap<String, Vec<&Step>> = BTreeMap::new();
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
        for k in 0..s0.triggers() {
            for &cam in &s0.cameras {
                out.push(Shot {
                    light: light.clone(),
                    turntable: s0.turntable,
                    light_arc: s0.light_arc,
                    camera: cam as usize,
                    frames: steps
                        .iter()
                        .map(|s| (capture_root.join(s.frame_path(k, cam)), s.exposure_s))
                        .collect(),
                });
            }
        }
    }
    out
}

/// Keeps the shots of cameras with a geometric calibration; returns them and
/// the cameras left out (their frames stay in the capture, unrectified).
pub fn calibrated_shots(shots: Vec<Shot>, cal: &Calibration) -> (Vec<Shot>, Vec<usize>) {
    let ok = |k: usize| cal.camera(k).is_some_and(|c| c.geometry.is_some());
    let mut skipped: Vec<usize> = shots.iter().map(|s| s.camera).filter(|&k| !ok(k)).collect();
    skipped.sort_unstable();
    skipped.dedup();
    (
        shots.into_iter().filter(|s| ok(s.camera)).collect(),
        skipped,
    )
}

/// The calibration file's name where qhm looks for it beside a capture
/// directory: `DIR/calibration.toml` next to `DIR/capture/` (the layout of
/// `qhm demo` and of the walkthrough).
pub const CALIBRATION_FILE: &str = "calibration.toml";

/// `capture_dir/../calibration.toml`, taken apart by name (the capture
/// directory need not exist yet).
pub fn calibration_beside(capture_dir: &Path) -> PathBuf {
    match (capture_dir.file_name(), capture_dir.parent()) {
        (Some(_), Some(parent)) => parent.join(CALIBRATION_FILE),
        _ => capture_dir.join("..").join(CALIBRATION_FILE),
    }
}

/// The calibration `qhm capture run` records for a capture into `out`: the
/// one `given`, else the one beside `out` if there is one. Refused if it
/// does not load, before any frame is taken.
pub fn capture_calibration(out: &Path, given: Option<&Path>) -> anyhow::Result<Option<PathBuf>> {
    let beside = calibration_beside(out);
    let file = match given {
        Some(f) => f.to_path_buf(),
        None if beside.is_file() => beside,
        None => return Ok(None),
    };
    Calibration::load(&file).with_context(|| {
        format!(
            "the calibration {} does not load; pass --calibration FILE",
            file.display()
        )
    })?;
    Ok(Some(file))
}

/// The calibration file `qhm rectify` uses for the capture in `root`, in
/// this order: the one `given`; the one its capture.toml records (which
/// must be unchanged since); `root/calibration.toml`; the one beside `root`.
pub fn find_calibration(
    root: &Path,
    manifest: &Manifest,
    given: Option<&Path>,
) -> anyhow::Result<PathBuf> {
    if let Some(f) = given {
        return Ok(f.to_path_buf());
    }
    if let Some((file, sha)) = manifest.calibration_file(root) {
        let data = std::fs::read(&file).with_context(|| {
            format!(
                "{} was taken with the calibration {}, which cannot be read; pass --calibration FILE",
                root.display(),
                file.display()
            )
        })?;
        if sha256_hex(&data) != sha {
            bail!(
                "the calibration {} has changed since {} was taken with it; pass --calibration {} to rectify with it as it is now",
                file.display(),
                root.display(),
                file.display()
            );
        }
        return Ok(file);
    }
    let inside = root.join(CALIBRATION_FILE);
    let beside = calibration_beside(root);
    for f in [inside, beside] {
        if f.is_file() {
            return Ok(f);
        }
    }
    bail!(
        "{} names no calibration and there is none at {} or {}; pass --calibration FILE (from `qhm calibrate all`)",
        root.display(),
        root.join(CALIBRATION_FILE).display(),
        calibration_beside(root).display()
    )
}
