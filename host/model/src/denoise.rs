//! LRF noise: a per-texel measure of it, and denoising by projecting every
//! texel's values over the LRF's samples (all lamp images and channels)
//! onto the leading principal components the texels share ([`crate::pca`]).
//! The fit denoises the lamp response, the lamp images per unit irradiance,
//! before it takes the global term away.
//!
//! Each texel's values are a vector of D = 3·samples. The texels of a
//! quasi-homogeneous sample vary along a few directions of that space (the
//! mesostructure's few kinds of local response), while the noise of the lamp
//! images is independent from image to image. How many components carry
//! the material rather than the noise is chosen by bi-cross-validation
//! (Owen and Perry 2009): the texels are split into the window's left and
//! right halves and the samples into two halves by light (every view of a
//! light on the same side: the views of one lamp share its noise, in the
//! simulator the very photons, in a real rig the lamp's flicker); components
//! fitted on one half of the texels and samples predict the other half of
//! the samples on the other half of the texels, whose noise the prediction
//! never saw.
//! The rank with the least held-out error, averaged over the four ways to
//! choose the halves, is kept. A component of noise predicts nothing, so it
//! only adds error; a component of the material lowers it.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::model::{LrfSample, Texture};
use crate::pca::{TexelMatrix, principal_components, to_f32};

/// How many principal components the fit keeps of the LRF.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LrfDenoise {
    /// Keep the LRF as measured.
    Off,
    /// The rank with the least cross-validated error (at most
    /// [`MAX_COMPONENTS`]).
    #[default]
    Auto,
    /// Exactly this many components (at most D and N).
    Components(usize),
}

/// The most components [`LrfDenoise::Auto`] keeps.
pub const MAX_COMPONENTS: usize = 32;

/// What [`denoise_lrf`] did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DenoiseReport {
    /// Components kept.
    pub components: usize,
    /// Values per texel (D = 3·samples) and texels (N).
    pub dims: usize,
    pub texels: usize,
    /// Variance along each computed component, largest first (1/sr²).
    pub spectrum: Vec<f64>,
    /// Held-out mean squared error of k = 0, 1, ... components (1/sr²;
    /// empty unless the rank was chosen by cross-validation).
    pub cross_validation: Vec<f64>,
    /// [`texel_noise`] per channel before and after (1/sr).
    pub noise_before: [f64; 3],
    pub noise_after: [f64; 3],
    /// RMS of what was taken away, per channel (1/sr).
    pub removed_rms: [f64; 3],
}

impl DenoiseReport {
    /// One line for the fit's output and the report.
    pub fn summary(&self) -> String {
        let [a, b, c] = self.noise_before;
        let [d, e, f] = self.noise_after;
        let how = if self.cross_validation.is_empty() {
            "as asked".to_string()
        } else {
            format!(
                "cross-validated error {:.3e} /sr against {:.3e} for the mean alone",
                self.cross_validation[self.components].sqrt(),
                self.cross_validation[0].sqrt()
            )
        };
        format!(
            "Denoised: {} of {} principal components of the lamp response kept ({how}); noise per texel {a:.3e}, {b:.3e}, {c:.3e} -> {d:.3e}, {e:.3e}, {f:.3e} /sr",
            self.components,
            self.dims.min(self.texels),
        )
    }
}

/// Which light each sample was taken under: ids in order of first
/// appearance (samples of one lamp position share its light direction).
pub fn light_ids(samples: &[LrfSample]) -> Vec<usize> {
    let mut lights: Vec<[f32; 3]> = Vec::new();
    samples
        .iter()
        .map(|s| match lights.iter().position(|l| *l == s.light) {
            Some(i) => i,
            None => {
                lights.push(s.light);
                lights.len() - 1
            }
        })
        .collect()
}

/// Projects the texels of `maps` (one texture per LRF sample, all of one
/// size) onto their leading principal components, as `how` says; `light[s]`
/// tells which light sample s was taken under (any ids). Returns None and
/// changes nothing for [`LrfDenoise::Off`], no maps, or an automatic rank
/// that cannot be cross-validated (fewer than two lights or two texel
/// columns).
pub fn denoise_lrf(
    maps: &mut [Texture],
    light: &[usize],
    how: LrfDenoise,
) -> Option<DenoiseReport> {
    if how == LrfDenoise::Off || maps.is_empty() || maps[0].data.is_empty() {
        return None;
    }
    let noise_before = texel_noise(maps);
    let (k, cross_validation) = match how {
        LrfDenoise::Components(k) => (k, Vec::new()),
        _ => {
            let cv = cross_validated_error(maps, light, MAX_COMPONENTS)?;
            let best = (0..cv.len())
                .min_by(|&a, &b| cv[a].total_cmp(&cv[b]))
                .unwrap_or(0);
            (best, cv)
        }
    };
    let x = TexelMatrix::new(maps);
    let pc = principal_components(&x, k);
    let k = pc.basis.len();
    let mut removed = [0.0f64; 3];
    for (s, map) in maps.iter_mut().enumerate() {
        for (p, texel) in map.data.iter_mut().enumerate() {
            let c = &pc.coeffs[p * k..(p + 1) * k];
            for ch in 0..3 {
                let i = 3 * s + ch;
                let v = x.mean[i]
                    + c.iter()
                        .zip(&pc.basis)
                        .map(|(a, b)| *a as f64 * b[i])
                        .sum::<f64>();
                removed[ch] += (texel[ch] as f64 - v).powi(2);
                texel[ch] = v as f32;
            }
        }
    }
    let values = (x.n * maps.len()).max(1) as f64;
    Some(DenoiseReport {
        components: k,
        dims: x.d,
        texels: x.n,
        spectrum: pc.variance,
        cross_validation,
        noise_before,
        noise_after: texel_noise(maps),
        removed_rms: removed.map(|e| (e / values).sqrt()),
    })
}

/// Held-out mean squared error per value of 0, 1, ..., up to `r`
/// components (see the module docs), averaged over the four folds; None
/// with fewer than two lights or two texel columns.
pub fn cross_validated_error(maps: &[Texture], light: &[usize], r: usize) -> Option<Vec<f64>> {
    let (w, h) = (maps[0].width, maps[0].height);
    let half =
        |left: bool| -> Vec<usize> { (0..w * h).filter(|p| (p % w < w / 2) == left).collect() };
    // Lights in order of first appearance, alternately to the two halves.
    let mut order: Vec<usize> = Vec::new();
    for &l in light {
        if !order.contains(&l) {
            order.push(l);
        }
    }
    let side = |s: usize| order.iter().position(|&l| l == light[s]).unwrap_or(0) % 2 == 0;
    let parity =
        |even: bool| -> Vec<usize> { (0..maps.len()).filter(|&s| side(s) == even).collect() };
    let (texels, samples) = ([half(true), half(false)], [parity(true), parity(false)]);
    if texels.iter().any(|t| t.is_empty()) || samples.iter().any(|s| s.is_empty()) {
        return None;
    }
    let folds: Vec<Vec<f64>> = [(0, 0), (0, 1), (1, 0), (1, 1)]
        .par_iter()
        .map(|&(t, s)| {
            held_out_error(
                maps,
                &texels[t],
                &samples[s],
                &texels[1 - t],
                &samples[1 - s],
                r,
            )
        })
        .collect();
    let kmax = folds.iter().map(|f| f.len()).min().unwrap_or(1);
    let values: f64 = folds.len() as f64;
    Some(
        (0..kmax)
            .map(|k| folds.iter().map(|f| f[k]).sum::<f64>() / values)
            .collect(),
    )
}

/// One fold: components of texels `ta` over samples `sa` predict samples
/// `sb` of texels `tb`. Mean squared error per value for k = 0..=r.
fn held_out_error(
    maps: &[Texture],
    ta: &[usize],
    sa: &[usize],
    tb: &[usize],
    sb: &[usize],
    r: usize,
) -> Vec<f64> {
    let xa = TexelMatrix::select(maps, ta, sa);
    let pc = principal_components(&xa, r);
    let k = pc.basis.len();
    // Each component's response over the held-out samples: the regression
    // of those samples on its coefficients over the same texels (the
    // coefficients of a PCA are uncorrelated, so one component at a time).
    let ya = TexelMatrix::select(maps, ta, sb);
    let response: Vec<Vec<f64>> = (0..k)
        .map(|j| {
            let mut v = vec![0.0f64; ya.d];
            let mut norm = 0.0f64;
            for p in 0..ya.n {
                let c = pc.coeffs[p * k + j] as f64;
                norm += c * c;
                for (a, y) in v.iter_mut().zip(ya.row(p)) {
                    *a += c * *y as f64;
                }
            }
            v.iter_mut().for_each(|a| *a /= norm.max(f64::MIN_POSITIVE));
            v
        })
        .collect();
    // The held-out texels' coefficients, from their values on `sa` less
    // the fitting texels' mean.
    let xb = TexelMatrix::select(maps, tb, sa);
    let offset: Vec<f64> = pc
        .basis
        .iter()
        .map(|b| {
            b.iter()
                .zip(xb.mean.iter().zip(&xa.mean))
                .map(|(v, (mb, ma))| v * (mb - ma))
                .sum()
        })
        .collect();
    let cb = xb.project(&to_f32(&pc.basis));
    let yb = TexelMatrix::select(maps, tb, sb);
    let mut err = vec![0.0f64; k + 1];
    for p in 0..yb.n {
        // Residual of the prediction from the fitting texels' mean alone.
        let mut res: Vec<f64> = yb
            .row(p)
            .iter()
            .zip(yb.mean.iter().zip(&ya.mean))
            .map(|(y, (mb, ma))| *y as f64 + mb - ma)
            .collect();
        err[0] += res.iter().map(|v| v * v).sum::<f64>();
        for j in 0..k {
            let c = cb[p * k + j] as f64 + offset[j];
            for (e, a) in res.iter_mut().zip(&response[j]) {
                *e -= c * a;
            }
            err[j + 1] += res.iter().map(|v| v * v).sum::<f64>();
        }
    }
    let values = (yb.n * yb.d).max(1) as f64;
    err.iter().map(|e| e / values).collect()
}

/// Noise per texel of `maps`, per channel: the RMS over texels and maps of
/// a texel minus the mean of its four neighbours, divided by sqrt(1.25)
/// (the factor for white noise), interior texels only. Texture finer than a
/// texel counts too, so this is an upper bound on the noise.
pub fn texel_noise(maps: &[Texture]) -> [f64; 3] {
    let mut sum = [0.0f64; 3];
    let mut n = 0usize;
    for t in maps {
        let (w, h) = (t.width, t.height);
        for j in 1..h.saturating_sub(1) {
            for i in 1..w.saturating_sub(1) {
                let c = t.get(i, j);
                let nb = [
                    t.get(i - 1, j),
                    t.get(i + 1, j),
                    t.get(i, j - 1),
                    t.get(i, j + 1),
                ];
                let d: [f64; 3] = std::array::from_fn(|ch| {
                    c[ch] as f64 - nb.iter().map(|p| p[ch] as f64).sum::<f64>() / 4.0
                });
                if d.iter().all(|x| x.is_finite()) {
                    for ch in 0..3 {
                        sum[ch] += d[ch] * d[ch];
                    }
                    n += 1;
                }
            }
        }
    }
    sum.map(|s| (s / (1.25 * n.max(1) as f64)).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rank-3 LRF (three smooth spatial patterns, each with its own
    /// response over samples and channels) and the same with white noise.
    fn low_rank_lrf(
        samples: usize,
        w: usize,
        h: usize,
        signal: f64,
        noise: f64,
    ) -> (Vec<Texture>, Vec<Texture>) {
        let mut gauss = crate::pca::tests::gaussian(99u64 ^ noise.to_bits());
        let pattern = |k: usize, i: usize, j: usize| -> f64 {
            let (x, y) = (i as f64, j as f64);
            match k {
                0 => (0.31 * x + 0.17 * y).sin(),
                1 => (0.23 * x - 0.29 * y).cos(),
                _ => (0.41 * x).sin() * (0.37 * y).cos(),
            }
        };
        let response = |k: usize, s: usize, ch: usize| -> f64 {
            signal * ((s * (k + 1) + 3 * ch) as f64 * 0.9 + k as f64).cos()
        };
        let truth: Vec<Texture> = (0..samples)
            .map(|s| Texture {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|p| {
                        std::array::from_fn(|ch| {
                            (0.02
                                + (0..3)
                                    .map(|k| pattern(k, p % w, p / w) * response(k, s, ch))
                                    .sum::<f64>()) as f32
                        })
                    })
                    .collect(),
            })
            .collect();
        let noisy = truth
            .iter()
            .map(|t| Texture {
                width: w,
                height: h,
                data: t
                    .data
                    .iter()
                    .map(|v| std::array::from_fn(|ch| v[ch] + (noise * gauss()) as f32))
                    .collect(),
            })
            .collect();
        (truth, noisy)
    }

    fn rms_error(a: &[Texture], b: &[Texture]) -> f64 {
        let (mut e, mut n) = (0.0f64, 0usize);
        for (x, y) in a.iter().zip(b) {
            for (p, q) in x.data.iter().zip(&y.data) {
                for ch in 0..3 {
                    e += (p[ch] as f64 - q[ch] as f64).powi(2);
                    n += 1;
                }
            }
        }
        (e / n as f64).sqrt()
    }

    /// Each sample its own light.
    fn own_lights(n: usize) -> Vec<usize> {
        (0..n).collect()
    }

    #[test]
    fn the_automatic_rule_keeps_the_signal_and_drops_the_noise() {
        let noise = 0.02;
        let (truth, noisy) = low_rank_lrf(40, 48, 40, 0.05, noise);
        let raw = rms_error(&noisy, &truth);
        let mut maps = noisy.clone();
        let r = denoise_lrf(&mut maps, &own_lights(40), LrfDenoise::Auto).unwrap();
        assert_eq!(r.components, 3, "held-out errors {:?}", r.cross_validation);
        let after = rms_error(&maps, &truth);
        // Three of 120 dimensions keep their noise: about sqrt(3/120) of it.
        assert!(after < 0.25 * raw, "error {after} against {raw} raw");
        assert!(
            r.noise_after
                .iter()
                .zip(&r.noise_before)
                .all(|(a, b)| a < &(0.3 * b))
        );
        assert!(r.removed_rms.iter().all(|e| (e / noise - 1.0).abs() < 0.1));
    }

    /// The same check fails on a deliberately wrong choice: one component
    /// loses two of the three patterns, and the error exceeds the noise's.
    #[test]
    fn too_few_components_lose_the_signal() {
        let noise = 0.02;
        let (truth, noisy) = low_rank_lrf(40, 48, 40, 0.05, noise);
        let raw = rms_error(&noisy, &truth);
        let mut maps = noisy.clone();
        let r = denoise_lrf(&mut maps, &own_lights(40), LrfDenoise::Components(1)).unwrap();
        assert_eq!(r.components, 1);
        assert!(rms_error(&maps, &truth) > raw);
    }

    #[test]
    fn pure_noise_keeps_no_component_and_off_changes_nothing() {
        let (_, pure) = low_rank_lrf(20, 40, 40, 0.0, 0.01);
        let mut maps = pure.clone();
        let r = denoise_lrf(&mut maps, &own_lights(20), LrfDenoise::Auto).unwrap();
        assert_eq!(r.components, 0, "held-out errors {:?}", r.cross_validation);
        let mut same = pure.clone();
        assert!(denoise_lrf(&mut same, &own_lights(20), LrfDenoise::Off).is_none());
        assert_eq!(same, pure);
        // One light: nothing to cross-validate against, nothing changed.
        assert!(denoise_lrf(&mut same, &[0; 20], LrfDenoise::Auto).is_none());
        assert_eq!(same, pure);
    }
}
