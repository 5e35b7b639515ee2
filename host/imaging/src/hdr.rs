//! HDR merge: exposure brackets + calibrated response -> linear radiance.
//!
//! X_q = linear(Z_q) / t_q per exposure q, averaged with a hat weight that
//! vanishes near black (read noise) and near saturation (clipping):
//! E = sum_q w(Z_q) X_q / sum_q w(Z_q). A pixel saturated in every exposure
//! carries no measurement and is NaN (the flag), never an average of clipped
//! values. A pixel dark in every exposure takes the longest exposure's value.

use rayon::prelude::*;

use crate::image::{Image8, ImageF};
use crate::response::ResponseCurve;
use crate::{Error, Result};

/// Merge options, in 8-bit pixel values.
#[derive(Debug, Clone, Copy)]
pub struct MergeOptions {
    /// Values at or above this are clipped.
    pub saturation: u8,
    /// Values at or below this are noise.
    pub dark: u8,
}

impl Default for MergeOptions {
    fn default() -> Self {
        Self {
            saturation: 250,
            dark: 2,
        }
    }
}

/// Hat weight on (dark, saturation), zero outside.
fn weight(z: u8, o: &MergeOptions) -> f32 {
    if z <= o.dark || z >= o.saturation {
        return 0.0;
    }
    let mid = 0.5 * (o.dark as f32 + o.saturation as f32);
    let half = 0.5 * (o.saturation as f32 - o.dark as f32);
    1.0 - ((z as f32 - mid) / half).abs() + 1e-3
}

/// Merge one bracket. `responses` has one curve per channel (or one for all).
/// Output: one f32 per channel, exposure per second in the curve's units; NaN
/// where every exposure is saturated.
pub fn merge(
    frames: &[&Image8],
    exposures: &[f64],
    responses: &[ResponseCurve],
    opts: MergeOptions,
) -> Result<ImageF> {
    let f0 = *frames
        .first()
        .ok_or_else(|| Error::Input("empty bracket".into()))?;
    if frames.len() != exposures.len() {
        return Err(Error::Input(format!(
            "{} frames but {} exposure times",
            frames.len(),
            exposures.len()
        )));
    }
    if frames
        .iter()
        .any(|f| f.width != f0.width || f.height != f0.height || f.channels != f0.channels)
    {
        return Err(Error::Input("bracket frames differ in size".into()));
    }
    if exposures.iter().any(|&t| !(t > 0.0 && t.is_finite())) {
        return Err(Error::Input("exposure times must be positive".into()));
    }
    if responses.is_empty() || (responses.len() != 1 && responses.len() != f0.channels) {
        return Err(Error::Input(format!(
            "{} response curves for {} channels",
            responses.len(),
            f0.channels
        )));
    }
    let ch = f0.channels;
    let luts: Vec<[f32; 256]> = (0..ch)
        .map(|c| responses[c.min(responses.len() - 1)].lut())
        .collect();
    let wts: [f32; 256] = std::array::from_fn(|z| weight(z as u8, &opts));
    let inv_t: Vec<f32> = exposures.iter().map(|&t| (1.0 / t) as f32).collect();
    let longest = (0..exposures.len())
        .max_by(|&a, &b| exposures[a].total_cmp(&exposures[b]))
        .unwrap_or(0);
    let mut out = ImageF::zeros(f0.width, f0.height, ch);
    let row_len = f0.width * ch;
    out.data
        .par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(y, row)| {
            let base = y * row_len;
            for (i, o) in row.iter_mut().enumerate() {
                let c = i % ch;
                let lut = &luts[c];
                let (mut num, mut den) = (0f32, 0f32);
                let mut all_saturated = true;
                for (f, &it) in frames.iter().zip(&inv_t) {
                    let z = f.data[base + i];
                    all_saturated &= z >= opts.saturation;
                    let w = wts[z as usize];
                    num += w * lut[z as usize] * it;
                    den += w;
                }
                *o = if den > 0.0 {
                    num / den
                } else if all_saturated {
                    f32::NAN
                } else {
                    // Dark everywhere (or a mix of dark and clipped: take the longest unclipped).
                    let z = frames[longest].data[base + i];
                    if z >= opts.saturation {
                        f32::NAN
                    } else {
                        lut[z as usize] * inv_t[longest]
                    }
                };
            }
        });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::response::{MnOptions, fit_mitsunaga_nayar};
    use crate::synthetic_calibration;

    #[test]
    fn merged_radiance_is_linear_and_saturation_is_flagged() {
        let resp = synthetic_calibration::Response::gamma_s_curve(2.2, 0.08);
        let times = [1.0 / 64.0, 1.0 / 16.0, 1.0 / 4.0, 1.0, 4.0];
        let b = synthetic_calibration::bracket_of_ramp(160, 120, &times, &resp, 0.5, 3);
        let curves: Vec<_> = (0..3)
            .map(|c| {
                fit_mitsunaga_nayar(&b, c, MnOptions::default())
                    .unwrap()
                    .curve
            })
            .collect();
        let frames: Vec<&Image8> = b.frames.iter().collect();
        let hdr = merge(&frames, &b.exposures, &curves, MergeOptions::default()).unwrap();
        // Linear up to one scale per channel: compare ratios to the truth.
        let (w, h) = (160, 120);
        let refv =
            hdr.get(80, 60, 1) as f64 / synthetic_calibration::ramp_irradiance(80, 60, w, h, 1);
        // Per pixel, 8-bit quantisation through a gamma-2.2 curve is worth several
        // percent at Z ~ 20-40; 6x6 blocks average it out (the read noise dithers).
        let mut worst = 0.0f64;
        for y0 in (20..h - 6).step_by(13) {
            // From x = 40 on, the longest exposure reaches Z >= 20 (the valid range).
            for x0 in (40..w - 16).step_by(9) {
                let (mut got, mut want) = (0.0, 0.0);
                for y in y0..y0 + 6 {
                    for x in x0..x0 + 6 {
                        got += hdr.get(x, y, 1) as f64;
                        want += synthetic_calibration::ramp_irradiance(x, y, w, h, 1) * refv;
                    }
                }
                worst = worst.max((got / want - 1.0).abs());
            }
        }
        assert!(worst < 0.03, "worst relative error {worst}");
        assert!(
            hdr.get(w - 2, 2, 0).is_nan(),
            "saturated everywhere must be NaN"
        );
        assert!(hdr.data.iter().filter(|v| v.is_nan()).count() < w * h * 3 / 50);
    }

    #[test]
    fn mismatched_inputs_are_errors() {
        let a = Image8::new(2, 2, 1, vec![0; 4]).unwrap();
        let b = Image8::new(2, 3, 1, vec![0; 6]).unwrap();
        let r = [ResponseCurve::linear_camera()];
        assert!(merge(&[&a, &b], &[1.0, 2.0], &r, MergeOptions::default()).is_err());
        assert!(merge(&[&a], &[1.0, 2.0], &r, MergeOptions::default()).is_err());
        assert!(merge(&[&a], &[0.0], &r, MergeOptions::default()).is_err());
        assert!(merge(&[], &[], &r, MergeOptions::default()).is_err());
    }
}
