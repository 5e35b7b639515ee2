//! Step 6 of the fit: the local reflectance function, each lamp image less
//! the global term the model already explains, per unit irradiance.

use std::f64::consts::PI;

use rayon::prelude::*;

use super::stripes::f32v;
use crate::ModelError;
use crate::fresnel::normal_transmittance;
use crate::model::{EntranceFunction, ExitingFunction, LocalReflectance, LrfSample, Texture};
use crate::rectified::Rectified;
use crate::subsurface::DipoleParams;

/// The LRF of every lamp image of `data` over `window` ([i0, j0, width,
/// height] of the rectified grid), given the fitted global term, f(w_i) and
/// f_v. `step` is called once per lamp image.
pub(super) fn fit_lrf(
    data: &Rectified,
    dipole: &DipoleParams,
    entrance: &EntranceFunction,
    exiting: &ExitingFunction,
    window: [u32; 4],
    notes: &mut Vec<String>,
    step: &(dyn Fn() + Sync),
) -> Result<LocalReflectance, ModelError> {
    let grid = data.index.grid;
    let [i0, j0, ww, wh] = window.map(|x| x as usize);
    // Light entering per incident flux at normal incidence (f(w_i) is relative to it).
    let t_in = normal_transmittance(dipole.eta);
    // The texel's own area as an equal-area disc: the paper's x_i != x_o.
    let r0 = grid.texel_mm / PI.sqrt();
    let subsurface = dipole.subsurface();
    let global: [f64; 3] =
        std::array::from_fn(|c| t_in * (subsurface.total(c) - subsurface.disc_integral(c, r0)));
    let lrf: Vec<(LrfSample, Texture, usize)> = data
        .index
        .lamp
        .par_iter()
        .map(|lamp| -> Result<_, ModelError> {
            let img = data.read_image(&lamp.file)?;
            let f = entrance.eval(f32v(lamp.light_dir));
            let cos_i = lamp.light_dir[2].max(0.0);
            let wo = f32v(lamp.view_dir);
            let mut nan = 0;
            let out = (0..ww * wh)
                .map(|p| {
                    let uv = [
                        ((p % ww) as f32 + 0.5) / ww as f32,
                        ((p / ww) as f32 + 0.5) / wh as f32,
                    ];
                    let fv = exiting.eval(uv, wo);
                    let l = img.get(i0 + p % ww, j0 + p / ww);
                    std::array::from_fn(|c| {
                        if !l[c].is_finite() {
                            nan += 1;
                            return 0.0;
                        }
                        let e = lamp.irradiance[c];
                        let g = fv[c] as f64 * f[c] as f64 * e * cos_i * global[c] / PI;
                        ((l[c] as f64 - g) / e) as f32
                    })
                })
                .collect();
            step();
            let sample = LrfSample {
                light: f32v(lamp.light_dir),
                view: wo,
            };
            Ok((
                sample,
                Texture {
                    width: ww,
                    height: wh,
                    data: out,
                },
                nan,
            ))
        })
        .collect::<Result<_, _>>()?;
    let nan: usize = lrf.iter().map(|x| x.2).sum();
    if nan > 0 {
        notes.push(format!(
            "LRF: {nan} texel-channels were not valid in the lamp images; set to 0"
        ));
    }
    let (samples, maps) = lrf.into_iter().map(|x| (x.0, x.1)).unzip();
    Ok(LocalReflectance { samples, maps })
}
