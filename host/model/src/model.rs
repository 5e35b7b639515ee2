//! The quasi-homogeneous material model of paper eq. 4 in memory: the global
//! dipole term, the mesostructure entrance function f(w_i), the mesostructure
//! exiting function f_v(x, w_o) and the local reflectance function
//! R(x, w_i, w_o), with the lookups a renderer needs.
//!
//! Directions are unit vectors in the local (sample) frame, z = surface normal,
//! pointing away from the surface. Texture coordinates are in [0, 1)^2 and wrap.
//! Radiance conventions (docs/model-format.md):
//! L_o(x, w_o) = ∫ R(x, w_i, w_o) E_n(w_i) dw_i  +  f_v(x, w_o) / π · Σ_i R_d(|x - x_i|) f(w_i) E(x_i) A_i,
//! where E_n is the irradiance normal to the light and E(x_i) the irradiance on the surface.

use std::collections::HashMap;
use std::f32::consts::{FRAC_PI_2, PI};
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use crate::fresnel::fresnel_transmittance_ratio;
use crate::profile::ChannelFit;
use crate::subsurface::DipoleParams;

/// An RGB f32 image stored row-major, row 0 first, sampled with wrap-around:
/// the rectified dataset's image type (qhm_formats), so the fit reads its
/// images without a copy.
pub use qhm_formats::RgbImage as Texture;

/// f(w_i) on a regular grid: θ_k = k·(π/2)/(n_theta-1), k < n_theta; φ_m = m·2π/n_phi.
/// Value 1 at the vertical by definition.
#[derive(Clone, Debug, PartialEq)]
pub struct EntranceFunction {
    pub n_theta: usize,
    pub n_phi: usize,
    /// `values[k * n_phi + m]`.
    pub values: Vec<[f32; 3]>,
}

impl EntranceFunction {
    /// Flat smooth dielectric: f = T(θ)/T(0), isotropic in φ.
    pub fn fresnel(eta: f64, n_theta: usize) -> Self {
        let values = (0..n_theta)
            .map(|k| {
                let theta = k as f64 * std::f64::consts::FRAC_PI_2 / (n_theta - 1) as f64;
                [fresnel_transmittance_ratio(theta.cos(), eta) as f32; 3]
            })
            .collect();
        EntranceFunction {
            n_theta,
            n_phi: 1,
            values,
        }
    }
    pub fn theta(&self, k: usize) -> f32 {
        k as f32 * FRAC_PI_2 / (self.n_theta - 1) as f32
    }
    pub fn phi(&self, m: usize) -> f32 {
        m as f32 * 2.0 * PI / self.n_phi as f32
    }
    /// Bilinear in (θ, φ), φ wrapping; light from below the surface gives 0
    /// (the table's θ = 90° row).
    pub fn eval(&self, wi: [f32; 3]) -> [f32; 3] {
        let n = norm(wi);
        if n == 0.0 {
            return [0.0; 3];
        }
        let z = (wi[2] / n).clamp(0.0, 1.0);
        let theta = z.acos();
        let phi = wi[1].atan2(wi[0]).rem_euclid(2.0 * PI);
        let t = theta / FRAC_PI_2 * (self.n_theta - 1) as f32;
        let k0 = (t.floor() as usize).min(self.n_theta - 1);
        let k1 = (k0 + 1).min(self.n_theta - 1);
        let ft = t - k0 as f32;
        let p = phi / (2.0 * PI) * self.n_phi as f32;
        let m0 = (p.floor() as usize) % self.n_phi;
        let m1 = (m0 + 1) % self.n_phi;
        let fp = p - p.floor();
        let v = |k: usize, m: usize| self.values[k * self.n_phi + m];
        std::array::from_fn(|c| {
            let a = v(k0, m0)[c] * (1.0 - fp) + v(k0, m1)[c] * fp;
            let b = v(k1, m0)[c] * (1.0 - fp) + v(k1, m1)[c] * fp;
            a * (1.0 - ft) + b * ft
        })
    }
}

/// f_v(x, w_o): one texture per sampled view direction.
#[derive(Clone, Debug, PartialEq)]
pub struct ExitingFunction {
    pub views: Vec<[f32; 3]>,
    pub maps: Vec<Texture>,
    index: PairIndexCache,
}

impl ExitingFunction {
    pub fn new(views: Vec<[f32; 3]>, maps: Vec<Texture>) -> Self {
        ExitingFunction {
            views,
            maps,
            index: PairIndexCache::default(),
        }
    }
    pub fn eval(&self, uv: [f32; 2], wo: [f32; 3]) -> [f32; 3] {
        self.eval_weighted(uv, &self.weights(wo))
    }
    /// The sampled views that stand for `wo`, and their weights: the same
    /// for every texel, so a lookup at several coordinates finds them once.
    pub fn weights(&self, wo: [f32; 3]) -> DirWeights {
        let pairs = || self.views.iter().map(|&v| (v, [0.0; 3]));
        self.index.nearest(self.views.len(), pairs, wo, [0.0; 3], 3)
    }
    pub fn eval_weighted(&self, uv: [f32; 2], weights: &DirWeights) -> [f32; 3] {
        weights.blend(|i| self.maps[i].sample(uv))
    }
}

/// One LRF sample: the light and view directions of a lamp image.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LrfSample {
    pub light: [f32; 3],
    pub view: [f32; 3],
}

/// R(x, w_i, w_o): one texture per (light, view) pair, in sr^-1: outgoing
/// radiance per unit irradiance measured normal to the light (cos θ_i included).
/// Negative values are kept (paper 4.2). Empty = no local reflectance.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct LocalReflectance {
    pub samples: Vec<LrfSample>,
    pub maps: Vec<Texture>,
    index: PairIndexCache,
}

impl LocalReflectance {
    pub fn new(samples: Vec<LrfSample>, maps: Vec<Texture>) -> Self {
        LocalReflectance {
            samples,
            maps,
            index: PairIndexCache::default(),
        }
    }
    pub fn eval(&self, uv: [f32; 2], wi: [f32; 3], wo: [f32; 3]) -> [f32; 3] {
        self.eval_weighted(uv, &self.weights(wi, wo))
    }
    /// The sampled (light, view) pairs that stand for (`wi`, `wo`), and
    /// their weights: the same for every texel; empty without samples.
    pub fn weights(&self, wi: [f32; 3], wo: [f32; 3]) -> DirWeights {
        let pairs = || self.samples.iter().map(|s| (s.light, s.view));
        self.index.nearest(self.samples.len(), pairs, wi, wo, 4)
    }
    /// R at `uv` with weights from [`LocalReflectance::weights`]; 0 without samples.
    pub fn eval_weighted(&self, uv: [f32; 2], weights: &DirWeights) -> [f32; 3] {
        weights.blend(|i| self.maps[i].sample(uv))
    }
}

/// Wall-clock of the fit stages ([`crate::fit`]), seconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FitTimings {
    pub dipole: f64,
    pub entrance: f64,
    pub exiting: f64,
    pub lrf: f64,
}

/// Fit diagnostics kept with the model for the report (paper Fig. 5).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FitDiagnostics {
    /// Per channel: the measured profile, range used and result.
    pub channels: Vec<ChannelFit>,
    /// Measured f at the laser directions: (direction, RGB value).
    pub entrance_samples: Vec<([f32; 3], [f32; 3])>,
    /// Free-form notes (counts, fallbacks).
    pub notes: Vec<String>,
    /// Wall time of the fit's stages (absent in models fitted before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timings: Option<FitTimings>,
    /// The calibration the capture was rectified with, from its rectified index.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<qhm_formats::rectified::CalibrationSummary>,
    /// The capture directory the model was fitted from, as the fit was given it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capture_dir: Option<String>,
    /// The texels of the rectified window the model covers, [i0, j0,
    /// width, height]: those every view's pass-2 stripes reach (model texel
    /// (i, j) is rectified texel (i0 + i, j0 + j)). Absent: the whole window.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window: Option<[u32; 4]>,
    /// What the LRF's denoising kept and removed; absent when it was off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lrf_denoise: Option<crate::denoise::DenoiseReport>,
}

/// The four-part material model.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialModel {
    pub dipole: DipoleParams,
    pub entrance: EntranceFunction,
    pub exiting: ExitingFunction,
    pub lrf: LocalReflectance,
    /// Texel size on the reference plane, mm.
    pub texel_mm: f32,
    pub width: u32,
    pub height: u32,
    pub diagnostics: Option<FitDiagnostics>,
}

impl MaterialModel {
    /// The texels of the rectified window the fit covered, [i0, j0, width,
    /// height] ([`FitDiagnostics::window`]); None for a model without one.
    pub fn window(&self) -> Option<[u32; 4]> {
        self.diagnostics.as_ref().and_then(|d| d.window)
    }

    /// A homogeneous material with a flat smooth surface: f = T(θ)/T(0),
    /// f_v = 1, LRF = 0, a 1×1 texture of 1 mm.
    pub fn homogeneous(dipole: DipoleParams) -> Self {
        MaterialModel {
            dipole,
            entrance: EntranceFunction::fresnel(dipole.eta, 19),
            exiting: ExitingFunction::new(
                vec![[0.0, 0.0, 1.0]],
                vec![Texture::filled(1, 1, [1.0; 3])],
            ),
            lrf: LocalReflectance::default(),
            texel_mm: 1.0,
            width: 1,
            height: 1,
            diagnostics: None,
        }
    }
    /// f(w_i), `wi` in the local frame.
    pub fn entrance(&self, wi: [f32; 3]) -> [f32; 3] {
        self.entrance.eval(wi)
    }
    /// f_v(x, w_o) at texture coordinate `uv` (wrapping).
    pub fn exiting(&self, uv: [f32; 2], wo: [f32; 3]) -> [f32; 3] {
        self.exiting.eval(uv, wo)
    }
    /// R(x, w_i, w_o) in sr^-1 (see [`LocalReflectance`]).
    pub fn lrf(&self, uv: [f32; 2], wi: [f32; 3], wo: [f32; 3]) -> [f32; 3] {
        self.lrf.eval(uv, wi, wo)
    }
    pub fn texture_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    pub fn texel_mm(&self) -> f32 {
        self.texel_mm
    }
}

pub(crate) fn norm(v: [f32; 3]) -> f32 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn angle(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (na, nb) = (norm(a), norm(b));
    if na == 0.0 || nb == 0.0 {
        return 0.0;
    }
    ((a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (na * nb))
        .clamp(-1.0, 1.0)
        .acos()
}

/// At most this many sampled directions blend into one lookup.
const MAX_BLEND: usize = 4;

/// Sampled directions and their blending weights for one lookup direction
/// (summing to 1; empty when nothing is sampled).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DirWeights {
    len: usize,
    index: [usize; MAX_BLEND],
    weight: [f32; MAX_BLEND],
}

impl DirWeights {
    fn blend(&self, f: impl Fn(usize) -> [f32; 3]) -> [f32; 3] {
        let mut out = [0.0; 3];
        for (&i, &w) in self.index.iter().zip(&self.weight).take(self.len) {
            let v = f(i);
            for c in 0..3 {
                out[c] += w * v[c];
            }
        }
        out
    }
}

/// A set of direction pairs with each distinct direction listed once: a
/// capture's LRF holds each lamp direction at several views and each view
/// under many lamps (784 pairs of 112 lights and 28 views at the default
/// scale), so the angles to a lookup are taken once per distinct direction.
#[derive(Debug, Default)]
struct PairIndex {
    firsts: Vec<[f32; 3]>,
    seconds: Vec<[f32; 3]>,
    /// Per pair, its first and second direction's place in the lists.
    pairs: Vec<(u32, u32)>,
}

impl PairIndex {
    fn new(pairs: impl Iterator<Item = ([f32; 3], [f32; 3])>) -> Self {
        fn place(list: &mut Vec<[f32; 3]>, seen: &mut HashMap<[u32; 3], u32>, d: [f32; 3]) -> u32 {
            *seen.entry(d.map(f32::to_bits)).or_insert_with(|| {
                list.push(d);
                (list.len() - 1) as u32
            })
        }
        let (mut seen_a, mut seen_b) = (HashMap::new(), HashMap::new());
        let mut index = PairIndex::default();
        for (a, b) in pairs {
            let pa = place(&mut index.firsts, &mut seen_a, a);
            let pb = place(&mut index.seconds, &mut seen_b, b);
            index.pairs.push((pa, pb));
        }
        index
    }

    /// The `k` (at most [`MAX_BLEND`]) pairs nearest to (a, b) in summed
    /// angle, ties to the earlier pair, with inverse-square distance
    /// weights (an exact hit takes all the weight).
    fn nearest(&self, a: [f32; 3], b: [f32; 3], k: usize) -> DirWeights {
        let k = k.min(MAX_BLEND).min(self.pairs.len());
        let mut out = DirWeights::default();
        if k == 0 {
            return out;
        }
        let to_a: Vec<f32> = self.firsts.iter().map(|&x| angle(x, a)).collect();
        let to_b: Vec<f32> = self.seconds.iter().map(|&y| angle(y, b)).collect();
        let mut dist = [0.0f32; MAX_BLEND];
        for (i, &(pa, pb)) in self.pairs.iter().enumerate() {
            let d = to_a[pa as usize] + to_b[pb as usize];
            if out.len == k && d.total_cmp(&dist[k - 1]).is_ge() {
                continue;
            }
            // After every kept pair at most as far: ties stay in pair order.
            let at = dist[..out.len]
                .iter()
                .take_while(|x| x.total_cmp(&d).is_le())
                .count();
            let end = (out.len + 1).min(k);
            dist.copy_within(at..end - 1, at + 1);
            out.index.copy_within(at..end - 1, at + 1);
            dist[at] = d;
            out.index[at] = i;
            out.len = end;
        }
        if dist[0] < 1e-5 {
            out.len = 1;
            out.weight[0] = 1.0;
            return out;
        }
        for (w, d) in out.weight.iter_mut().zip(dist).take(out.len) {
            *w = 1.0 / (d * d);
        }
        let sum: f32 = out.weight[..out.len].iter().sum();
        for w in &mut out.weight[..out.len] {
            *w /= sum;
        }
        out
    }
}

/// A [`PairIndex`] built at the first lookup. The function's pairs are not
/// to change after that; if their number does, the lookup indexes them
/// afresh each time.
#[derive(Default)]
struct PairIndexCache(OnceLock<PairIndex>);

impl PairIndexCache {
    fn nearest<I: Iterator<Item = ([f32; 3], [f32; 3])>>(
        &self,
        len: usize,
        pairs: impl Fn() -> I,
        a: [f32; 3],
        b: [f32; 3],
        k: usize,
    ) -> DirWeights {
        let index = self.0.get_or_init(|| PairIndex::new(pairs()));
        if index.pairs.len() == len {
            index.nearest(a, b, k)
        } else {
            PairIndex::new(pairs()).nearest(a, b, k)
        }
    }
}

impl Clone for PairIndexCache {
    fn clone(&self) -> Self {
        PairIndexCache::default()
    }
}

/// A cache: equal whatever it holds.
impl PartialEq for PairIndexCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for PairIndexCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PairIndexCache")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> DipoleParams {
        DipoleParams {
            alpha_prime: [0.99, 0.98, 0.9],
            sigma_t_prime: [1.0, 1.5, 2.0],
            eta: 1.3,
            model: crate::subsurface::ProfileModel::Dipole,
        }
    }

    #[test]
    fn homogeneous_model_lookups() {
        let m = MaterialModel::homogeneous(params());
        assert_eq!(m.entrance([0.0, 0.0, 1.0]), [1.0; 3]);
        let t60 = fresnel_transmittance_ratio(0.5, 1.3) as f32;
        let w60 = [(60f32).to_radians().sin(), 0.0, 0.5];
        let f = m.entrance(w60);
        // 19-row table: 60° is a node, so exact.
        assert!((f[0] - t60).abs() < 1e-5, "{f:?} vs {t60}");
        assert_eq!(m.entrance([0.0, 0.0, -1.0])[1], m.entrance.values[18][1]);
        assert_eq!(m.exiting([0.3, 0.7], [0.5, 0.5, 0.7]), [1.0; 3]);
        assert_eq!(
            m.lrf([0.1, 0.1], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
            [0.0; 3]
        );
        assert_eq!(m.texture_size(), (1, 1));
    }

    #[test]
    fn texture_wraps_and_interpolates() {
        let mut t = Texture::filled(2, 1, [0.0; 3]);
        t.data[1] = [1.0; 3];
        // Texel centres at u = 0.25 (0) and 0.75 (1); u = 0.5 halfway; u = 0 halfway by wrap.
        assert_eq!(t.sample([0.25, 0.5])[0], 0.0);
        assert_eq!(t.sample([0.75, 0.5])[0], 1.0);
        assert!((t.sample([0.5, 0.5])[0] - 0.5).abs() < 1e-6);
        assert!((t.sample([0.0, 0.5])[0] - 0.5).abs() < 1e-6);
        assert!((t.sample([1.0, 0.5])[0] - 0.5).abs() < 1e-6);
    }

    /// The k nearest by a full sort of every pair's summed angle, the
    /// plain way: what [`PairIndex::nearest`] must give.
    fn nearest_by_sorting(
        dirs: &[([f32; 3], [f32; 3])],
        a: [f32; 3],
        b: [f32; 3],
        k: usize,
    ) -> Vec<(usize, f32)> {
        let mut d: Vec<(usize, f32)> = dirs
            .iter()
            .enumerate()
            .map(|(i, &(x, y))| (i, angle(x, a) + angle(y, b)))
            .collect();
        d.sort_by(|x, y| x.1.total_cmp(&y.1));
        d.truncate(k);
        if d[0].1 < 1e-5 {
            return vec![(d[0].0, 1.0)];
        }
        let w: Vec<(usize, f32)> = d.iter().map(|&(i, x)| (i, 1.0 / (x * x))).collect();
        let sum: f32 = w.iter().map(|x| x.1).sum();
        w.into_iter().map(|(i, x)| (i, x / sum)).collect()
    }

    #[test]
    fn indexed_nearest_pairs_equal_a_full_sort() {
        // Lights and views on a coarse grid, repeated as a capture repeats
        // them, with ties (the same pair twice) and the query on a sample.
        let dir = |t: f32, p: f32| [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
        let lights: Vec<[f32; 3]> = (0..12)
            .map(|k| dir(0.1 * k as f32, 0.7 * k as f32))
            .collect();
        let views: Vec<[f32; 3]> = (0..5)
            .map(|k| dir(0.15 * k as f32, 1.3 * k as f32))
            .collect();
        let mut pairs: Vec<([f32; 3], [f32; 3])> = lights
            .iter()
            .flat_map(|&l| views.iter().map(move |&v| (l, v)))
            .collect();
        pairs.push(pairs[7]);
        let index = PairIndex::new(pairs.iter().copied());
        assert_eq!((index.firsts.len(), index.seconds.len()), (12, 5));
        let mut queries: Vec<([f32; 3], [f32; 3])> = (0..200)
            .map(|k| {
                (
                    dir(0.007 * k as f32, 0.37 * k as f32),
                    dir(0.004 * k as f32, 1.1 * k as f32),
                )
            })
            .collect();
        queries.push(pairs[7]);
        for (a, b) in queries {
            for k in [1, 3, 4] {
                let got = index.nearest(a, b, k);
                let want = nearest_by_sorting(&pairs, a, b, k);
                let got: Vec<(usize, f32)> = (0..got.len)
                    .map(|j| (got.index[j], got.weight[j]))
                    .collect();
                assert_eq!(got, want, "query {a:?} {b:?}, k {k}");
            }
        }
        // The comparison can fail: ties broken the other way (the repeated
        // pair 7 taken for its later copy) differ from the full sort.
        let (a, b) = pairs[7];
        let mut later = index.nearest(a, b, 1);
        later.index[0] = pairs.len() - 1;
        assert_ne!(later.index[0], nearest_by_sorting(&pairs, a, b, 1)[0].0);
    }

    #[test]
    fn exiting_picks_the_exact_view_and_blends_between() {
        let views = vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
        let maps = vec![
            Texture::filled(1, 1, [1.0; 3]),
            Texture::filled(1, 1, [3.0; 3]),
        ];
        let e = ExitingFunction::new(views, maps);
        assert_eq!(e.eval([0.0, 0.0], [0.0, 0.0, 1.0])[0], 1.0);
        assert_eq!(e.eval([0.0, 0.0], [1.0, 0.0, 0.0])[0], 3.0);
        let mid = e.eval([0.0, 0.0], [1.0, 0.0, 1.0])[0];
        assert!((mid - 2.0).abs() < 1e-4, "{mid}");
    }
}
