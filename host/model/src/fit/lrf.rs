//! Steps 6 and 7 of the fit: the local reflectance function, each lamp
//! image less the global term the model already explains, per unit
//! irradiance; denoised on the lamp images' own values, before the global
//! term is taken away.

use std::f64::consts::PI;

use rayon::prelude::*;

use super::stripes::f32v;
use crate::ModelError;
use crate::denoise::{DenoiseReport, LrfDenoise, denoise_lrf, light_ids};
use crate::fresnel::normal_transmittance;
use crate::model::{EntranceFunction, ExitingFunction, LocalReflectance, LrfSample, Texture};
use crate::rectified::Rectified;
use crate::subsurface::DipoleParams;

/// The LRF of every lamp image of `data` over `window` ([i0, j0, width,
/// height] of the rectified grid), given the fitted global term, f(w_i) and
/// f_v, with the lamp images denoised as `denoise` says. `step` is called
/// once per lamp image.
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_lrf(
    data: &Rectified,
    dipole: &DipoleParams,
    entrance: &EntranceFunction,
    exiting: &ExitingFunction,
    window: [u32; 4],
    denoise: LrfDenoise,
    notes: &mut Vec<String>,
    step: &(dyn Fn() + Sync),
) -> Result<(LocalReflectance, Option<DenoiseReport>), ModelError> {
    let [i0, j0, ww, wh] = window.map(|x| x as usize);
    // The lamp images per unit irradiance over the window.
    let (samples, mut maps): (Vec<LrfSample>, Vec<Texture>) = data
        .index
        .lamp
        .par_iter()
        .map(|lamp| -> Result<_, ModelError> {
            let img = data.read_image(&lamp.file)?;
            let out = (0..ww * wh)
                .map(|p| {
                    let l = img.get(i0 + p % ww, j0 + p / ww);
                    std::array::from_fn(|c| (l[c] as f64 / lamp.irradiance[c]) as f32)
                })
                .collect();
            step();
            let sample = LrfSample {
                light: f32v(lamp.light_dir),
                view: f32v(lamp.view_dir),
            };
            let texture = Texture {
                width: ww,
                height: wh,
                data: out,
            };
            Ok((sample, texture))
        })
        .collect::<Result<Vec<_>, _>>()?
        .into_iter()
        .unzip();
    // An invalid texel-channel takes the sample's mean over the valid ones
    // for the denoising (a neutral value for the components), and 0 in the
    // LRF afterwards.
    let invalid: Vec<Vec<[bool; 3]>> = maps
        .iter()
        .map(|m| m.data.iter().map(|v| v.map(|x| !x.is_finite())).collect())
        .collect();
    let nan: usize = invalid.iter().flatten().flatten().filter(|&&b| b).count();
    if nan > 0 {
        for m in &mut maps {
            let mean: [f32; 3] = std::array::from_fn(|c| {
                let (s, n) = m
                    .data
                    .iter()
                    .filter(|v| v[c].is_finite())
                    .fold((0.0f64, 0usize), |(s, n), v| (s + v[c] as f64, n + 1));
                (s / n.max(1) as f64) as f32
            });
            for v in &mut m.data {
                for c in 0..3 {
                    if !v[c].is_finite() {
                        v[c] = mean[c];
                    }
                }
            }
        }
        let total = maps.len() * ww * wh * 3;
        notes.push(format!(
            "LRF: {nan} of {total} texel-channels ({:.1} %) were not valid in the lamp images \
             (saturated in every exposure: the plan's lamp_exposures need a shorter one); set to 0",
            100.0 * nan as f64 / total.max(1) as f64
        ));
    }
    let light = light_ids(&samples);
    let report = denoise_lrf(&mut maps, &light, denoise);
    if report.is_none() && denoise != LrfDenoise::Off && !maps.is_empty() {
        notes.push(format!(
            "LRF not denoised: the automatic rank needs two lights and two texel columns ({} lights, {ww} columns)",
            light.iter().max().map_or(0, |m| m + 1)
        ));
    }
    let global = LampGlobalTerm::new(dipole, entrance, exiting, data.index.grid.texel_mm);
    maps.par_iter_mut()
        .zip(&samples)
        .zip(&invalid)
        .for_each(|((m, s), bad)| {
            let g = global.eval(ww, wh, s);
            for ((v, gv), b) in m.data.iter_mut().zip(&g.data).zip(bad) {
                for c in 0..3 {
                    v[c] = if b[c] { 0.0 } else { v[c] - gv[c] };
                }
            }
        });
    Ok((LocalReflectance::new(samples, maps), report))
}

/// The global term of a lamp image per unit irradiance, at each texel for
/// the light and view of a sample: f_v(x, w_o) T(0) f(w_i) cos θ_i
/// (R_total - R_texel) / π, R_texel the model's R_d integrated over the
/// texel's own area (an equal-area disc: the paper's Σ over x_i ≠ x_o for
/// uniform lamp light).
pub struct LampGlobalTerm<'a> {
    entrance: &'a EntranceFunction,
    exiting: &'a ExitingFunction,
    /// T(0) (R_total - R_texel) / π per channel.
    per_cos: [f64; 3],
}

impl<'a> LampGlobalTerm<'a> {
    /// For texels of `texel_mm`.
    pub fn new(
        dipole: &DipoleParams,
        entrance: &'a EntranceFunction,
        exiting: &'a ExitingFunction,
        texel_mm: f64,
    ) -> Self {
        // Light entering per incident flux at normal incidence (f(w_i) is relative to it).
        let t_in = normal_transmittance(dipole.eta);
        let r0 = texel_mm / PI.sqrt();
        let subsurface = dipole.subsurface();
        LampGlobalTerm {
            entrance,
            exiting,
            per_cos: std::array::from_fn(|c| {
                t_in * (subsurface.total(c) - subsurface.disc_integral(c, r0)) / PI
            }),
        }
    }

    /// The term over a `width` x `height` window (f_v's whole texture).
    pub fn eval(&self, width: usize, height: usize, sample: &LrfSample) -> Texture {
        let f = self.entrance.eval(sample.light);
        let cos_i = sample.light[2].max(0.0) as f64;
        let data = (0..width * height)
            .map(|p| {
                let uv = [
                    ((p % width) as f32 + 0.5) / width as f32,
                    ((p / width) as f32 + 0.5) / height as f32,
                ];
                let fv = self.exiting.eval(uv, sample.view);
                std::array::from_fn(|c| {
                    (fv[c] as f64 * f[c] as f64 * cos_i * self.per_cos[c]) as f32
                })
            })
            .collect();
        Texture {
            width,
            height,
            data,
        }
    }
}
