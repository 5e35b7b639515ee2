//! Glue between a capture directory (qhm-acquire's plan and frames) and the
//! rectification pipeline (qhm-imaging): which frames form one exposure
//! bracket of one shot, and the rectification settings a plan implies.
//! Used by `qhm rectify` and `qhm demo`.

use std::collections::BTreeMap;
use std::path::Path;

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
