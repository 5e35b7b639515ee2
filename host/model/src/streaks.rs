//! Structure along the laser sweep: how much of a map's variation lines up
//! with the direction the pass-2 stripes were swept in, against the
//! direction across it.
//!
//! The fit measures f_v from a few parallel laser stripes; an estimator
//! that depends on a texel's distance from them leaves bands parallel to
//! the stripe lines, i.e. structure *along the sweep axis*. A map of a
//! statistically isotropic material has as much structure along any axis
//! as along another, so the sweep axis is compared with the axis across it
//! (and, as a yardstick of the statistics, with the two diagonals).
//!
//! Two measures, each a share of the map's variance (so they apply alike to
//! f_v, which averages about 1, and to the LRF, which averages about 0):
//!
//! - **trend**: the variance of the profile of means along an axis (the
//!   texels binned by their coordinate on that axis, one texel wide), as a
//!   share of the variance of the texels. The sweep axis's profile is the
//!   map's row or column trend across the stripe lines.
//! - **power**: the 2D power spectrum (Hann-windowed, mean removed),
//!   whitened by its mean over each ring of frequency, averaged over the
//!   wave vectors within ±[`WEDGE_DEG`] of an axis: 1 for an isotropic map,
//!   so sweep against cross compares the power along the two axes at the
//!   same frequencies.
//!
//! [`SweepStructure::excess`] is sweep minus cross of each; both must stay
//! below [`MAX_EXCESS`] (2 % of the variance for the trend, 2 % of the
//! cross axis's power for the spectrum).

use crate::model::Texture;

/// Half-width of the spectral wedges around an axis, degrees.
pub const WEDGE_DEG: f64 = 45.0;

/// Largest allowed excess of the sweep axis over the cross axis, as a
/// share of the map's variance.
pub const MAX_EXCESS: f64 = 0.02;

/// Shares of variance along the sweep axis, across it and on the diagonals,
/// averaged over the maps and channels measured.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SweepStructure {
    pub trend_sweep: f64,
    pub trend_cross: f64,
    pub power_sweep: f64,
    pub power_cross: f64,
    /// Mean of the two diagonal wedges (the null yardstick of `power_*`).
    pub power_diagonal: f64,
    /// Map-channels measured (constant or invalid ones are skipped).
    pub fields: usize,
}

impl SweepStructure {
    /// (trend, power) excess of the sweep axis over the cross axis.
    pub fn excess(&self) -> (f64, f64) {
        (
            self.trend_sweep - self.trend_cross,
            self.power_sweep - self.power_cross,
        )
    }
    /// Both excesses within [`MAX_EXCESS`].
    pub fn passes(&self) -> bool {
        let (t, p) = self.excess();
        self.fields > 0 && t <= MAX_EXCESS && p <= MAX_EXCESS
    }
}

impl std::fmt::Display for SweepStructure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (t, p) = self.excess();
        write!(
            f,
            "trend sweep {:.4} cross {:.4} (excess {:+.4}); power sweep {:.4} cross {:.4} diagonal {:.4} (excess {:+.4}); {} fields",
            self.trend_sweep,
            self.trend_cross,
            t,
            self.power_sweep,
            self.power_cross,
            self.power_diagonal,
            p,
            self.fields
        )
    }
}

/// [`SweepStructure`] of `maps` (every channel) for stripes swept along
/// `sweep` (a direction in texel coordinates i, j; normalised here).
/// Texels that are not finite make a map-channel skipped.
pub fn sweep_structure(maps: &[&Texture], sweep: [f64; 2]) -> SweepStructure {
    let n = (sweep[0] * sweep[0] + sweep[1] * sweep[1]).sqrt();
    let s = if n > 0.0 {
        [sweep[0] / n, sweep[1] / n]
    } else {
        [0.0, 1.0]
    };
    let c = [-s[1], s[0]];
    let diag = [
        [(s[0] + c[0]) / 2f64.sqrt(), (s[1] + c[1]) / 2f64.sqrt()],
        [(s[0] - c[0]) / 2f64.sqrt(), (s[1] - c[1]) / 2f64.sqrt()],
    ];
    let mut out = SweepStructure::default();
    for t in maps {
        for ch in 0..3 {
            let z: Vec<f64> = t.data.iter().map(|p| p[ch] as f64).collect();
            if z.iter().any(|v| !v.is_finite()) {
                continue;
            }
            let mean = z.iter().sum::<f64>() / z.len() as f64;
            let z: Vec<f64> = z.iter().map(|v| v - mean).collect();
            let var = z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64;
            if !(var > 1e-30 * mean.abs().max(1e-30).powi(2)) || var == 0.0 {
                continue;
            }
            let power = power_spectrum(&z, t.width, t.height);
            let wedge = |a: [f64; 2]| wedge_share(&power, a);
            out.trend_sweep += profile_share(&z, t.width, s) / var;
            out.trend_cross += profile_share(&z, t.width, c) / var;
            out.power_sweep += wedge(s);
            out.power_cross += wedge(c);
            out.power_diagonal += 0.5 * (wedge(diag[0]) + wedge(diag[1]));
            out.fields += 1;
        }
    }
    if out.fields > 0 {
        let k = 1.0 / out.fields as f64;
        out.trend_sweep *= k;
        out.trend_cross *= k;
        out.power_sweep *= k;
        out.power_cross *= k;
        out.power_diagonal *= k;
    }
    out
}

/// Between-bin variance of the mean-free field `z` binned one texel wide by
/// the coordinate along `axis`.
fn profile_share(z: &[f64], w: usize, axis: [f64; 2]) -> f64 {
    let coord = |p: usize| ((p % w) as f64 + 0.5) * axis[0] + ((p / w) as f64 + 0.5) * axis[1];
    let lo = (0..z.len()).map(coord).fold(f64::INFINITY, f64::min);
    let hi = (0..z.len()).map(coord).fold(f64::NEG_INFINITY, f64::max);
    let nb = (hi - lo).floor() as usize + 1;
    let mut sum = vec![0.0; nb];
    let mut cnt = vec![0.0; nb];
    for (p, v) in z.iter().enumerate() {
        let b = ((coord(p) - lo).floor() as usize).min(nb - 1);
        sum[b] += v;
        cnt[b] += 1.0;
    }
    sum.iter()
        .zip(&cnt)
        .filter(|(_, n)| **n > 0.0)
        .map(|(s, n)| s * s / n)
        .sum::<f64>()
        / z.len() as f64
}

/// (fx, fy, |F|²) of the Hann-windowed field, DC left out; frequencies in
/// cycles per texel, in [-1/2, 1/2).
fn power_spectrum(z: &[f64], w: usize, h: usize) -> Vec<(f64, f64, f64)> {
    let hann = |k: usize, n: usize| {
        if n < 2 {
            1.0
        } else {
            0.5 - 0.5 * (2.0 * std::f64::consts::PI * (k as f64 + 0.5) / n as f64).cos()
        }
    };
    let zw: Vec<f64> = z
        .iter()
        .enumerate()
        .map(|(p, v)| v * hann(p % w, w) * hann(p / w, h))
        .collect();
    // Rows first, then columns: O(w h (w + h)).
    let dft = |n: usize| -> Vec<(f64, f64)> {
        (0..n * n)
            .map(|q| {
                let a = -2.0 * std::f64::consts::PI * ((q / n) * (q % n) % n) as f64 / n as f64;
                (a.cos(), a.sin())
            })
            .collect()
    };
    let (tw, th) = (dft(w), dft(h));
    let mut rows = vec![(0.0, 0.0); w * h];
    for j in 0..h {
        for k in 0..w {
            let (mut re, mut im) = (0.0, 0.0);
            for i in 0..w {
                let (c, s) = tw[k * w + i];
                re += zw[j * w + i] * c;
                im += zw[j * w + i] * s;
            }
            rows[j * w + k] = (re, im);
        }
    }
    let mut out = Vec::with_capacity(w * h);
    for k in 0..w {
        for l in 0..h {
            if k == 0 && l == 0 {
                continue;
            }
            let (mut re, mut im) = (0.0, 0.0);
            for j in 0..h {
                let (c, s) = th[l * h + j];
                let (a, b) = rows[j * w + k];
                re += a * c - b * s;
                im += a * s + b * c;
            }
            let f = |k: usize, n: usize| {
                let k = if 2 * k >= n {
                    k as f64 - n as f64
                } else {
                    k as f64
                };
                k / n as f64
            };
            out.push((f(k, w), f(l, h), re * re + im * im));
        }
    }
    out
}

/// The mean whitened power within ±[`WEDGE_DEG`] of `axis` (either sign
/// of the wave vector): each bin's power over the mean power of its ring
/// of frequency (rings 1/max(w, h) cycles per texel wide), so every
/// frequency counts alike and an isotropic map gives 1 in every wedge.
fn wedge_share(power: &[(f64, f64, f64)], axis: [f64; 2]) -> f64 {
    let cos_max = WEDGE_DEG.to_radians().cos();
    let fmax = power
        .iter()
        .map(|p| p.0.abs().max(p.1.abs()))
        .fold(0.0, f64::max);
    let step = if fmax > 0.0 { fmax / 24.0 } else { 1.0 };
    let ring = |p: &(f64, f64, f64)| ((p.0 * p.0 + p.1 * p.1).sqrt() / step) as usize;
    let nr = power.iter().map(ring).max().unwrap_or(0) + 1;
    let (mut sum, mut cnt) = (vec![0.0; nr], vec![0.0; nr]);
    for p in power {
        sum[ring(p)] += p.2;
        cnt[ring(p)] += 1.0;
    }
    let (mut acc, mut n) = (0.0, 0.0);
    for p in power {
        let f = (p.0 * p.0 + p.1 * p.1).sqrt();
        let r = ring(p);
        if f > 0.0 && ((p.0 * axis[0] + p.1 * axis[1]) / f).abs() >= cos_max && sum[r] > 0.0 {
            acc += p.2 / (sum[r] / cnt[r]);
            n += 1.0;
        }
    }
    if n > 0.0 { acc / n } else { 0.0 }
}

/// The sweep axis of a set of stripes in texel coordinates: the normal of
/// their mean line direction (`line_dir`, sample frame, whose x and y are
/// the texel axes i and j).
pub fn sweep_axis(line_dirs: impl IntoIterator<Item = [f64; 2]>) -> [f64; 2] {
    // Lines have no sign: average the doubled angle.
    let (mut c, mut s) = (0.0, 0.0);
    for d in line_dirs {
        let a = d[1].atan2(d[0]);
        c += (2.0 * a).cos();
        s += (2.0 * a).sin();
    }
    let a = 0.5 * s.atan2(c);
    [-a.sin(), a.cos()]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth isotropic texture: a sum of blobs at pseudo-random places.
    fn blobs(w: usize, h: usize, seed: u64) -> Texture {
        let mut x = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let mut rnd = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let centres: Vec<(f64, f64, f64)> = (0..150)
            .map(|_| (rnd() * w as f64, rnd() * h as f64, rnd() - 0.5))
            .collect();
        let data = (0..w * h)
            .map(|p| {
                let (i, j) = ((p % w) as f64, (p / w) as f64);
                let v: f64 = centres
                    .iter()
                    .map(|(cx, cy, a)| a * (-((i - cx).powi(2) + (j - cy).powi(2)) / 4.0).exp())
                    .sum();
                [(1.0 + 0.2 * v) as f32; 3]
            })
            .collect();
        Texture {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn isotropic_maps_pass_and_bands_across_the_sweep_fail() {
        let maps: Vec<Texture> = (0..12).map(|s| blobs(64, 64, s)).collect();
        let refs: Vec<&Texture> = maps.iter().collect();
        let m = sweep_structure(&refs, [0.0, 1.0]);
        assert!(m.passes(), "{m}");
        // Bands parallel to stripe lines along i (rows), 6 texels apart,
        // 5 % of f_v: structure along the sweep axis j.
        let streaked: Vec<Texture> = maps
            .iter()
            .map(|t| {
                let mut t = t.clone();
                for (p, v) in t.data.iter_mut().enumerate() {
                    let j = (p / t.width) as f32;
                    let k = 1.0 + 0.05 * (2.0 * std::f32::consts::PI * j / 9.0).sin();
                    v.iter_mut().for_each(|x| *x *= k);
                }
                t
            })
            .collect();
        let refs: Vec<&Texture> = streaked.iter().collect();
        let bad = sweep_structure(&refs, [0.0, 1.0]);
        assert!(!bad.passes(), "{bad}");
        // The same bands are across the axis when the sweep runs along i.
        assert!(sweep_structure(&refs, [1.0, 0.0]).excess().0 < 0.0);
    }

    #[test]
    fn sweep_axis_is_the_normal_of_the_lines() {
        let a = sweep_axis([[1.0, 0.001], [-1.0, 0.002], [1.0, -0.003]]);
        assert!(
            a[0].abs() < 0.01 && (a[1].abs() - 1.0).abs() < 1e-4,
            "{a:?}"
        );
    }
}
