//! The whole fit (paper section 4.2): from a rectified capture to a
//! [`MaterialModel`]. Per colour channel:
//!
//! 1. I(d) from the vertical (pass-2) stripe images: exitance per incident
//!    flux per mm, binned by distance d from each stripe's line and averaged
//!    over views. Each view's radiance becomes exitance through the angular
//!    distribution of the light under the boundary and its Fresnel
//!    transmittance ([`ProfileModel::exitance_per_radiance`]), not Lambert's
//!    π L: isotropic for the dipole, exact for transport (at a' 0.8 the
//!    isotropic guess puts R 3 % low and a' 0.007 low).
//! 2. R = 2 ∫ I(d) dd, per view that sees the stripe's whole core (far
//!    enough from the laser's mirror direction), averaged over those views:
//!    near-field bins the capture lacks (masked as NaN) are filled from the
//!    model by iterating R -> a' -> s'_t; beyond the data the measured tail
//!    is continued at its own exponential decay.
//! 3. a' by inverting R = T(0) R_total (T(0) = 1 - F(0): the share of the
//!    stripe that enters), s'_t by the profile fit ([`crate::profile`]).
//! 4. f(w_i) from pass-1 band fluxes over views, relative to the vertical.
//! 5. f_v(p, v) = Σ_l L(p, v, l) / Σ_l T(0) I_D(d(p, l)) flux_l / π (the
//!    formula after eq. 6 with I(p, l) from the dipole of eq. 5).
//! 6. LRF = (L - f_v T(0) f(w_i) E cos θ_i (R_total - R_texel) / π) / E,
//!    negatives kept.

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;

use crate::ModelError;
use crate::dipole::{self, DipoleParams, ScaledStripe};
use crate::model::{
    EntranceFunction, ExitingFunction, FitDiagnostics, LocalReflectance, LrfSample, MaterialModel,
    Texture,
};
use crate::profile::{ChannelFit, Norm, Profile, ProfileFit, ProfileModel, fit_profile};
use crate::rectified::{Rectified, StripeEntry};

/// Options of [`fit_capture`].
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub eta: f64,
    /// Distance range for the s'_t fit (None: automatic per channel).
    pub range: Option<(f64, f64)>,
    /// Misfit of the s'_t search.
    pub norm: Norm,
    /// Light transport of the stripe profile and R_total(a').
    pub model: ProfileModel,
    /// Entrance table resolution.
    pub n_theta: usize,
    pub n_phi: usize,
    /// Width of the distance bins of I(d), mm (None: an eighth of a texel).
    pub bin_mm: Option<f64>,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            eta: dipole::DEFAULT_ETA,
            range: None,
            norm: Norm::default(),
            model: ProfileModel::default(),
            n_theta: 10,
            n_phi: 24,
            bin_mm: None,
        }
    }
}

/// Wall-clock of the fit stages, seconds.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitTimings {
    pub dipole: f64,
    pub entrance: f64,
    pub exiting: f64,
    pub lrf: f64,
}

/// Light directions within 5 degrees of the normal count as vertical.
const NEAR_VERTICAL_COS: f64 = 0.996_194_698_091_745_5;

/// Pass-1 light directions closer than this (radians) are one direction.
const SAME_LIGHT_DIR: f64 = 0.02;

/// Directions are grouped when closer than this (radians).
const SAME_DIR: f64 = 1e-3;

/// The group key of every near-vertical light (`dir_key` of the normal).
const VERTICAL_KEY: [i64; 3] = [0, 0, (1.0 / SAME_DIR) as i64];

/// Views within 30 degrees of a stripe's mirror direction see the laser's
/// specular reflection on its core, which is surface, not subsurface,
/// light: their core is left out of I(d), they do not count for R, and the
/// entrance function leaves them out. The polished presets (GGX alpha 0.02)
/// put 10 % into a 13-degree view's R of skin1 blue (default scale) and
/// 1e-3 of R into a 26-degree view's at ci (green and blue alike, so a
/// glint's, not the material's); an oblique laser's glint is stronger still
/// (Fresnel 3.5 times at 60 degrees, BRDF over cos theta_i). With 30 degrees
/// whole milk's worst f(w_i) at the default scale went from 3.6 to 2.2 %.
const SPECULAR_VIEW_COS: f64 = 0.866_025_403_784_438_6;

/// The stripe's core: the laser line blurred by a camera pixel and the
/// rectification's interpolation, a texel and a half either side.
fn core_mm(grid: &crate::rectified::Grid) -> f64 {
    1.5 * grid.texel_mm
}

/// Cosine between `s`'s view and the laser's mirror direction.
fn cos_to_mirror(s: &StripeEntry) -> f64 {
    let (l, v) = (s.light_dir, s.view_dir);
    -l[0] * v[0] - l[1] * v[1] + l[2] * v[2]
}

fn dir_key(v: [f64; 3]) -> [i64; 3] {
    v.map(|x| (x / SAME_DIR).round() as i64)
}

fn f32v(v: [f64; 3]) -> [f32; 3] {
    v.map(|x| x as f32)
}

/// A channel's I_D(d) as the capture sees it: per incident flux of a
/// normal stripe, T(0) times the per-entered profile of the fit's model
/// (see [`crate::profile`]), tabulated out to `d_max`.
struct EnteringStripe {
    table: ScaledStripe,
    sigma_t_prime: f64,
    t_in: f64,
}

impl EnteringStripe {
    fn new(
        model: ProfileModel,
        alpha_prime: f64,
        sigma_t_prime: f64,
        eta: f64,
        d_max: f64,
    ) -> Self {
        EnteringStripe {
            table: model.stripe_table(alpha_prime, eta, sigma_t_prime * d_max),
            sigma_t_prime,
            t_in: dipole::normal_transmittance(eta),
        }
    }
    fn stripe(&self, d: f64) -> f64 {
        self.t_in * self.table.eval(d, self.sigma_t_prime)
    }
    /// The mean of [`Self::stripe`] across a texel `w` wide centred at `d`:
    /// what an area-mean texel measures.
    fn texel_mean(&self, d: f64, w: f64) -> f64 {
        self.t_in * self.table.bin_mean(d, w, self.sigma_t_prime)
    }
    /// ∫_{d0}^∞ of [`Self::stripe`] (d = d0 + L t/(1 - t), L = 1/s'_t).
    fn tail(&self, d0: f64) -> f64 {
        let l = 1.0 / self.sigma_t_prime;
        let f = |t: f64| {
            if t >= 1.0 {
                return 0.0;
            }
            let u = 1.0 - t;
            self.stripe(d0 + l * t / u) * l / (u * u)
        };
        crate::quad::integrate(f, 0.0, 1.0, 1e-6, 1e-300, 200)
    }
}

/// One view's pass-2 bins: fine ones for the profile, texel-wide ones for R.
struct ViewBins {
    cos: f64,
    /// No image of this view left the stripe's core out.
    whole_core: bool,
    fine: DistanceBins,
    coarse: DistanceBins,
}

/// Radiance summed by distance from a stripe's line in bins of `width` mm,
/// with the summed distances (each bin's mean distance) and texel weights.
#[derive(Clone)]
struct DistanceBins {
    width: f64,
    sum: Vec<f64>,
    dsum: Vec<f64>,
    count: Vec<f64>,
}

impl DistanceBins {
    fn new(width: f64, d_max: f64) -> Self {
        let n = (d_max / width).ceil() as usize + 1;
        DistanceBins {
            width,
            sum: vec![0.0; n],
            dsum: vec![0.0; n],
            count: vec![0.0; n],
        }
    }
    fn add_weighted(&mut self, b: usize, d: f64, value: f64, weight: f64) {
        if b < self.sum.len() {
            self.sum[b] += weight * value;
            self.dsum[b] += weight * d;
            self.count[b] += weight;
        }
    }
    /// Adds a texel to its bin unless the bin starts below `from`: a bin a
    /// view covers only in part would average its outer texels alone,
    /// biased low next to the stripe where the profile falls steeply (with
    /// the specular view's core skipped, R came out 1.3 % low and s'_t 6 %
    /// low).
    fn add_from(&mut self, from: f64, d: f64, value: f64) {
        if (d / self.width).floor() * self.width >= from {
            self.add_weighted((d / self.width) as usize, d, value, 1.0);
        }
    }
    /// Adds a texel to the two bins whose centres straddle its distance, in
    /// proportion to its nearness to each (bin -1 is bin 0 mirrored across
    /// the line), so that the bin means times the width sum to the texel
    /// rows' sum across the line wherever the line falls on the texel grid.
    /// Counted whole, a row on a bin edge went to either side on a rounding
    /// of the fitted line: a narrow stripe's centroid lands on a texel
    /// centre, its neighbours on the edges, and skin1's blue R moved 5 %
    /// with a tenth of a code of dark offset. A bin counts only where every
    /// texel it gathers lies at `from` or beyond.
    fn add_spread(&mut self, from: f64, d: f64, value: f64) {
        let u = d / self.width - 0.5;
        let k0 = u.floor();
        let frac = u - k0;
        for (k, weight) in [(k0, 1.0 - frac), (k0 + 1.0, frac)] {
            let k = if k < 0.0 { -k - 1.0 } else { k };
            if from <= 0.0 || (k - 0.5) * self.width >= from {
                self.add_weighted(k as usize, d, value, weight);
            }
        }
    }
    /// The same bins with every value times `k`.
    fn scaled(&self, k: f64) -> Self {
        DistanceBins {
            sum: self.sum.iter().map(|s| s * k).collect(),
            ..self.clone()
        }
    }
    fn merged(mut self, other: DistanceBins) -> Self {
        for b in 0..self.sum.len() {
            self.sum[b] += other.sum[b];
            self.dsum[b] += other.dsum[b];
            self.count[b] += other.count[b];
        }
        self
    }
    /// Mean radiance per bin (None: no texel).
    fn means(&self) -> Vec<Option<f64>> {
        (0..self.sum.len())
            .map(|b| (self.count[b] > 0.0).then(|| self.sum[b] / self.count[b]))
            .collect()
    }
    /// (mean distance, mean radiance) of the bins that hold texels.
    fn points(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        (0..self.sum.len())
            .filter(|&b| self.count[b] > 0.0)
            .map(|b| {
                let n = self.count[b];
                (self.dsum[b] / n, self.sum[b] / n)
            })
    }
}

/// R = 2 ∫ I(d) dd from I(d) binned at `bin` mm (None: no valid texel).
/// Measured bins count as they are; unmeasured bins below the last measured
/// one (the stripe's near field, masked) come from the dipole `dp` when
/// given; beyond the last bin the measured tail goes on at its own
/// exponential decay, fitted over the outer third of the measured distances.
/// The sample's edges and depth shape that far tail, and the dipole's
/// semi-infinite tail would overstate it (and feed back through a' into a
/// still longer tail).
fn reflectance_from_profile(means: &[Option<f64>], bin: f64, dp: Option<&EnteringStripe>) -> f64 {
    let centre = |k: usize| (k as f64 + 0.5) * bin;
    let measured: Vec<usize> = (0..means.len()).filter(|&k| means[k].is_some()).collect();
    let (Some(&first), Some(&last)) = (measured.first(), measured.last()) else {
        return 0.0;
    };
    let inside: f64 = (0..=last)
        .map(|k| match means[k] {
            Some(i) => i,
            None => dp.map_or(0.0, |dp| dp.stripe(centre(k))),
        })
        .sum::<f64>()
        * bin;
    // ln I = a - κ d over the outer third, least squares.
    let from = centre(last) - (centre(last) - centre(first)) / 3.0;
    let pts: Vec<(f64, f64)> = measured
        .iter()
        .filter(|&&k| centre(k) >= from)
        .filter_map(|&k| means[k].filter(|&i| i > 0.0).map(|i| (centre(k), i.ln())))
        .collect();
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let kappa = -sxy / sxx;
    let d_end = (last + 1) as f64 * bin;
    let tail = if pts.len() >= 4 && kappa > 1e-3 {
        (my - kappa * (d_end - mx)).exp() / kappa
    } else if let Some(dp) = dp {
        // No usable decay (too few or noisy points): the model's own tail.
        dp.tail(d_end)
    } else {
        0.0
    };
    2.0 * (inside + tail)
}

/// Fits the material model of the capture in `capture_dir`.
pub fn fit_capture(
    capture_dir: &Path,
    opts: &FitOptions,
) -> Result<(MaterialModel, FitTimings), ModelError> {
    fit_capture_with_progress(capture_dir, opts, &|_, _| {})
}

/// [`fit_capture`], calling `progress(done, total)` as its steps finish: one
/// per channel's dipole, one for f(w_i), one per f_v view, one per lamp image.
pub fn fit_capture_with_progress(
    capture_dir: &Path,
    opts: &FitOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(MaterialModel, FitTimings), ModelError> {
    let data = Rectified::open(capture_dir)?;
    let total_steps = 4
        + data.index.lamp.len()
        + data
            .index
            .stripe
            .iter()
            .filter(|s| s.pass == 2)
            .map(|s| dir_key(s.view_dir))
            .collect::<std::collections::BTreeSet<_>>()
            .len();
    let steps_done = std::sync::atomic::AtomicUsize::new(0);
    let step = || {
        let done = steps_done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(done, total_steps);
    };
    let grid = data.index.grid.clone();
    let (w, h) = (grid.width as usize, grid.height as usize);
    let bin = opts.bin_mm.unwrap_or(grid.texel_mm / 8.0);
    if !(bin.is_finite() && bin > 0.0) {
        return Err(ModelError::Domain(format!(
            "distance bin {bin} mm must be > 0"
        )));
    }
    let diag_max = grid.texel_mm * ((w * w + h * h) as f64).sqrt();
    let mut timings = FitTimings::default();
    let mut notes = Vec::new();

    // 1-3: the global dipole per channel from the vertical stripes.
    let t0 = Instant::now();
    let mut channels = Vec::new();
    let mut stripes: [Option<EnteringStripe>; 3] = [None, None, None];
    for c in 0..3u8 {
        let entries: Vec<&StripeEntry> = data
            .index
            .stripe
            .iter()
            .filter(|s| s.pass == 2 && s.channel == c)
            .collect();
        if entries.is_empty() {
            return Err(ModelError::Fit(format!(
                "no pass-2 (vertical stripe) images for channel {c}"
            )));
        }
        // Per view, merged: radiance per incident flux per mm in fine bins
        // for the s'_t fit, and in texel-wide bins for R. A texel is an area
        // mean, so the texels of a texel-wide bin sum to the flux across the
        // line; finer bins leave gaps between texel distances that only the
        // model could fill. Views stay apart because turning radiance into
        // exitance depends on the view and, through the light's angular
        // distribution, on a'.
        let per_image = entries
            .par_iter()
            .map(|s| -> Result<_, ModelError> {
                let img = data.read_image(&s.file)?;
                let k = 1.0 / s.flux_per_mm;
                let skip = if cos_to_mirror(s) > SPECULAR_VIEW_COS {
                    core_mm(&grid)
                } else {
                    0.0
                };
                let mut fine = DistanceBins::new(bin, diag_max);
                let mut coarse = DistanceBins::new(grid.texel_mm, diag_max);
                for j in 0..h {
                    for i in 0..w {
                        let l = img.get(i, j)[c as usize] as f64;
                        let d = s.distance(grid.centre(i, j));
                        if l.is_finite() {
                            fine.add_from(skip, d, k * l);
                            coarse.add_spread(skip, d, k * l);
                        }
                    }
                }
                Ok((
                    dir_key(s.view_dir),
                    s.view_dir[2],
                    skip == 0.0,
                    fine,
                    coarse,
                ))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut views: BTreeMap<[i64; 3], ViewBins> = BTreeMap::new();
        for (key, cos, whole_core, fine, coarse) in per_image {
            let merged = match views.remove(&key) {
                Some(v) => ViewBins {
                    cos,
                    whole_core: v.whole_core && whole_core,
                    fine: v.fine.merged(fine),
                    coarse: v.coarse.merged(coarse),
                },
                None => ViewBins {
                    cos,
                    whole_core,
                    fine,
                    coarse,
                },
            };
            views.insert(key, merged);
        }
        let cos_views: Vec<f64> = views.values().map(|v| v.cos).collect();
        // I(d) with each view's radiance turned into exitance: points at the
        // mean distance of their texels (uneven coverage inside a bin does
        // not bias the fit), over all views. Each texel is an area mean, so
        // the model is averaged over a texel's width across the line (at
        // ci, 0.67 mm, this moves s'_t by +0.5..+3 %). For R, the texel-wide
        // bins' means of every view that sees the whole core: each of them
        // measures the whole integral, however its pixels blur the line (a
        // 77-degree view spreads it over a millimetre), where the bins'
        // means over views mixed views that blur differently with views
        // whose core is left out (skin1 at the default scale: R -0.8 % in
        // every channel, though no view alone was below -0.5 %).
        let exitance = |per_radiance: &[f64]| {
            let fine = views
                .values()
                .zip(per_radiance)
                .fold(DistanceBins::new(bin, diag_max), |fine, (v, &k)| {
                    fine.merged(v.fine.scaled(k))
                });
            let whole = views
                .values()
                .zip(per_radiance)
                .filter(|(v, _)| v.whole_core);
            let mut for_r: Vec<Vec<Option<f64>>> =
                whole.map(|(v, &k)| v.coarse.scaled(k).means()).collect();
            if for_r.is_empty() {
                // No view sees the whole core: the bins of all views together.
                let merged = views
                    .values()
                    .zip(per_radiance)
                    .map(|(v, &k)| v.coarse.scaled(k))
                    .reduce(DistanceBins::merged)
                    .expect("at least one view");
                for_r.push(merged.means());
            }
            (Profile::new(fine.points(), grid.texel_mm), for_r)
        };
        let reflectance = |for_r: &[Vec<Option<f64>>], dp: Option<&EnteringStripe>| {
            for_r
                .iter()
                .map(|means| reflectance_from_profile(means, grid.texel_mm, dp))
                .sum::<f64>()
                / for_r.len() as f64
        };
        // Until a' is known, the light under the boundary is taken as isotropic.
        let (mut profile, mut means) =
            exitance(&ProfileModel::Dipole.exitance_per_radiance(1.0, opts.eta, &cos_views));
        if profile.distance_mm.len() < 5 {
            return Err(ModelError::Fit(format!(
                "channel {c}: only {} distance bins have valid texels",
                profile.distance_mm.len()
            )));
        }
        if !(profile.intensity.iter().sum::<f64>() > 0.0) {
            return Err(ModelError::Fit(format!(
                "channel {c}: no outgoing flux in the vertical stripe images"
            )));
        }
        // R and the fit depend on each other through the model's fill of
        // the unmeasured near field and through the radiance-to-exitance
        // conversion: a few rounds converge.
        let mut r = reflectance(&means, None);
        let mut fit = None;
        // The automatic range is chosen once, with the first R.
        let mut range = opts.range;
        for _ in 0..6 {
            let r_used = r.min(1.0);
            let f = fit_profile(&profile, r_used, opts.eta, opts.model, range, opts.norm)
                .map_err(|e| ModelError::Fit(format!("channel {c}: {e}")))?;
            range = Some((f.range_mm[0], f.range_mm[1]));
            let auto = fit
                .as_ref()
                .map_or(f.auto_range, |x: &(f64, ProfileFit, Profile)| {
                    x.1.auto_range
                });
            let f = ProfileFit {
                auto_range: auto,
                ..f
            };
            let dp = EnteringStripe::new(
                opts.model,
                f.alpha_prime,
                f.sigma_t_prime,
                opts.eta,
                diag_max,
            );
            let converted = exitance(&opts.model.exitance_per_radiance(
                f.alpha_prime,
                opts.eta,
                &cos_views,
            ));
            fit = Some((r_used, f, std::mem::replace(&mut profile, converted.0)));
            means = converted.1;
            let next = reflectance(&means, Some(&dp));
            stripes[c as usize] = Some(dp);
            // 1e-6 of R moves a' and s'_t by less than 1e-5 of themselves.
            if (next - r).abs() < 1e-6 * r {
                break;
            }
            r = next;
        }
        let (r_used, fit, profile) = fit.expect("at least one iteration");
        if r > 1.0 {
            notes.push(format!(
                "channel {c}: measured R = {r:.4} > 1, clamped to 1"
            ));
        }
        channels.push(ChannelFit {
            channel: c as usize,
            reflectance: r_used,
            profile,
            fit,
        });
        step();
    }
    let dipole = DipoleParams {
        alpha_prime: std::array::from_fn(|c| channels[c].fit.alpha_prime),
        sigma_t_prime: std::array::from_fn(|c| channels[c].fit.sigma_t_prime),
        eta: opts.eta,
        model: opts.model,
    };
    // Light entering per incident flux at normal incidence (f(w_i) is relative to it).
    let t_in = dipole::normal_transmittance(opts.eta);
    let tables = stripes.map(|s| s.expect("every channel was fitted"));
    timings.dipole = t0.elapsed().as_secs_f64();

    // 4: the entrance function.
    let t0 = Instant::now();
    let (entrance, entrance_samples) = fit_entrance(&data, opts, &mut notes)?;
    timings.entrance = t0.elapsed().as_secs_f64();
    step();

    // 5: the exiting function, per pass-2 view. The texels measured are
    // those every view and channel reaches (the window is cropped to them).
    let t0 = Instant::now();
    let mut views: BTreeMap<[i64; 3], [f64; 3]> = BTreeMap::new();
    for s in data.index.stripe.iter().filter(|s| s.pass == 2) {
        views.entry(dir_key(s.view_dir)).or_insert(s.view_dir);
    }
    // From the core out to every valid texel: the measured profile follows
    // the data wherever it goes, and a texel's sum weighs each stripe by its
    // signal, so far, faint stripes count little.
    let fv_range: [[f64; 2]; 3] = std::array::from_fn(|c| [0.0, channels[c].fit.range_mm[1]]);
    let fv_raw: Vec<Vec<[f64; 3]>> = views
        .keys()
        .collect::<Vec<_>>()
        .par_iter()
        .map(|key| -> Result<Vec<[f64; 3]>, ModelError> {
            let images: Vec<(&StripeEntry, Texture)> = data
                .index
                .stripe
                .iter()
                .filter(|s| s.pass == 2 && dir_key(s.view_dir) == **key)
                .map(|s| Ok((s, data.read_image(&s.file)?)))
                .collect::<Result<_, ModelError>>()?;
            let out = exiting_view(&images, &grid, &fv_range, &channels, &tables);
            step();
            Ok(out)
        })
        .collect::<Result<_, _>>()?;
    let window = measured_window(&fv_raw, w, h);
    let Some(window) = window else {
        return Err(ModelError::Fit(format!(
            "f_v: no texel is reached by the pass-2 stripes (within {:.2} mm) in every view and channel",
            fv_range[0][1].min(fv_range[1][1]).min(fv_range[2][1])
        )));
    };
    let [i0, j0, ww, wh] = window.map(|x| x as usize);
    if (ww, wh) != (w, h) {
        notes.push(format!(
            "f_v: pass-2 stripes reach texels {i0}..{} x {j0}..{} of the {w}x{h} window in every view and channel; the model covers those",
            i0 + ww,
            j0 + wh
        ));
    }
    let crop = |t: &Texture| Texture {
        width: ww,
        height: wh,
        data: (0..ww * wh)
            .map(|p| t.get(i0 + p % ww, j0 + p / ww))
            .collect(),
    };
    let exiting = ExitingFunction {
        views: views.values().map(|&v| f32v(v)).collect(),
        maps: fv_raw
            .iter()
            .map(|m| {
                crop(&Texture {
                    width: w,
                    height: h,
                    data: m.iter().map(|v| v.map(|x| x as f32)).collect(),
                })
            })
            .collect(),
    };
    timings.exiting = t0.elapsed().as_secs_f64();

    // 6: the local reflectance function from the lamp images.
    let t0 = Instant::now();
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
    timings.lrf = t0.elapsed().as_secs_f64();

    let model = MaterialModel {
        dipole,
        entrance,
        exiting,
        lrf: LocalReflectance { samples, maps },
        texel_mm: grid.texel_mm as f32,
        width: ww as u32,
        height: wh as u32,
        diagnostics: Some(FitDiagnostics {
            channels,
            entrance_samples,
            notes,
            timings: Some(timings.clone()),
            calibration: data.index.calibration.clone(),
            capture_dir: Some(capture_dir.display().to_string()),
            window: Some(window),
        }),
    };
    model.check(capture_dir)?;
    Ok((model, timings))
}

/// f(w_i) per channel at the measured laser directions, then resampled to the
/// regular (θ, φ) table by the 4 nearest measured directions (inverse-square
/// angular weights): the paper's interpolation from the four nearest laser
/// directions. Returns the table and the measured samples.
#[allow(clippy::type_complexity)]
fn fit_entrance(
    data: &Rectified,
    opts: &FitOptions,
    notes: &mut Vec<String>,
) -> Result<(EntranceFunction, Vec<([f32; 3], [f32; 3])>), ModelError> {
    let is_vertical = |d: [f64; 3]| d[2] > (2f64).to_radians().cos();
    // Mean per-stripe exitance flux / incident flux, keyed by (light, view, channel).
    let mut groups: BTreeMap<([i64; 3], [i64; 3], u8), (f64, usize, [f64; 3])> = BTreeMap::new();
    if !data.index.stripe.iter().any(|s| s.pass == 1) {
        notes.push(
            "no pass-1 images: entrance function set to the smooth-surface Fresnel ratio".into(),
        );
        return Ok((
            EntranceFunction::fresnel(opts.eta, opts.n_theta),
            Vec::new(),
        ));
    }
    // Pass 1 and, as more vertical references, pass 2. The whole stripe
    // counts, its core included (the near field's share of the light changes
    // with the angle of incidence), so views that see the laser's specular
    // reflection on the core are left out; views are made comparable through
    // the exitance per radiance, so a light whose vertical reference lacks
    // its view (the top camera sees the vertical laser's mirror reflection)
    // is still compared.
    let used: Vec<&StripeEntry> = data
        .index
        .stripe
        .iter()
        .filter(|s| {
            (s.pass == 1 || is_vertical(s.light_dir)) && cos_to_mirror(s) <= SPECULAR_VIEW_COS
        })
        .collect();
    if used.is_empty() {
        return Err(ModelError::Fit(
            "entrance function: every stripe image sees the laser's specular reflection".into(),
        ));
    }
    let fresnel_average = dipole::fresnel_hemispherical_average(opts.eta);
    // The three lasers' planes differ by fractions of a degree: light
    // directions within ~1 degree of a cluster's first member are one
    // direction, so each direction has all channels (clusters, not a grid:
    // rounding would split neighbours across a cell boundary).
    let mut clusters: Vec<[f64; 3]> = Vec::new();
    let light_keys: Vec<[i64; 3]> = used
        .iter()
        .map(|s| {
            if is_vertical(s.light_dir) {
                return VERTICAL_KEY;
            }
            let d = s.light_dir;
            let close = |c: &[f64; 3]| {
                (c[0] * d[0] + c[1] * d[1] + c[2] * d[2])
                    .clamp(-1.0, 1.0)
                    .acos()
                    < SAME_LIGHT_DIR
            };
            let first = match clusters.iter().find(|c| close(c)) {
                Some(c) => *c,
                None => {
                    clusters.push(d);
                    d
                }
            };
            dir_key(first)
        })
        .collect();
    // Each image's outgoing flux per mm of stripe over the band |d| <= reach
    // around its line: the mean radiance at each signed distance (so the
    // length of line inside the window does not matter) summed over the
    // band. One reach for all images (0.9 x the median extent), so a stripe
    // near the window's edge does not lose more of its profile than the
    // vertical reference.
    let grid = &data.index.grid;
    let extents: Vec<f64> = used.iter().map(|s| band_extent(s, grid)).collect();
    let reach = {
        let mut sorted = extents.clone();
        sorted.sort_by(f64::total_cmp);
        0.9 * sorted[sorted.len() / 2]
    };
    let fluxes: Vec<Option<f64>> = used
        .par_iter()
        .zip(&extents)
        .map(|(s, &e)| -> Result<Option<f64>, ModelError> {
            if e < reach {
                return Ok(None);
            }
            let img = data.read_image(&s.file)?;
            let k = dipole::exitance_per_radiance(s.view_dir[2], opts.eta, fresnel_average);
            Ok(Some(k * band_flux(&img, s, grid, reach) / s.flux_per_mm))
        })
        .collect::<Result<_, _>>()?;
    let short = fluxes.iter().filter(|f| f.is_none()).count();
    if short > 0 {
        notes.push(format!(
            "entrance function: {short} of {} stripe images left out: their line is within {reach:.1} mm of the window's edge",
            used.len()
        ));
    }
    for ((s, light), flux) in used.iter().zip(light_keys).zip(fluxes) {
        let Some(flux) = flux else { continue };
        let e = groups
            .entry((light, dir_key(s.view_dir), s.channel))
            .or_insert((0.0, 0, s.light_dir));
        e.0 += flux;
        e.1 += 1;
    }
    let mean = |g: &(f64, usize, [f64; 3])| g.0 / g.1 as f64;
    // The vertical's flux per channel, averaged over its views.
    let mean_reference: [f64; 3] = std::array::from_fn(|c| {
        let per_view: Vec<f64> = groups
            .iter()
            .filter(|((l, _, ch), _)| *l == VERTICAL_KEY && *ch as usize == c)
            .map(|(_, g)| mean(g))
            .collect();
        per_view.iter().sum::<f64>() / per_view.len() as f64
    });
    let mut lights: BTreeMap<[i64; 3], [f64; 3]> = BTreeMap::new();
    for (k, v) in &groups {
        lights.entry(k.0).or_insert(v.2);
    }
    let mut samples: Vec<([f32; 3], [f32; 3])> = vec![([0.0, 0.0, 1.0], [1.0; 3])];
    for (lk, ld) in &lights {
        // Near-vertical directions (the vertical stripe from another arc or
        // turntable angle, tilted by the rig's small errors) are the
        // reference itself, f = 1, not oblique samples.
        if *lk == VERTICAL_KEY || ld[2] > NEAR_VERTICAL_COS {
            continue;
        }
        let mut value = [f32::NAN; 3];
        for c in 0..3u8 {
            // Σ over the light's views of its flux and of the vertical's in
            // the same view, or the vertical's mean over views where that
            // view has no reference.
            let (mut num, mut den) = (0.0, 0.0);
            for ((l, v, ch), g) in &groups {
                if l == lk && *ch == c {
                    num += mean(g);
                    den += groups
                        .get(&(VERTICAL_KEY, *v, c))
                        .map_or(mean_reference[c as usize], mean);
                }
            }
            value[c as usize] = (num / den) as f32;
        }
        if value.iter().any(|v| !v.is_finite()) {
            // Its stripes all lie near the window's edge, or no vertical
            // reference shares a view: the table interpolates from the others.
            notes.push(format!(
                "entrance function: light direction {ld:.3?} left out (no usable stripe or vertical reference in some channel)"
            ));
            continue;
        }
        samples.push((f32v(*ld), value));
    }
    let n_theta = opts.n_theta.max(2);
    let n_phi = opts.n_phi.max(1);
    let mut table = EntranceFunction {
        n_theta,
        n_phi,
        values: vec![[0.0; 3]; n_theta * n_phi],
    };
    for k in 0..n_theta {
        for m in 0..n_phi {
            let (t, p) = (table.theta(k), table.phi(m));
            let d = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
            let mut near: Vec<(f32, [f32; 3])> = samples
                .iter()
                .map(|(s, v)| {
                    (
                        (s[0] * d[0] + s[1] * d[1] + s[2] * d[2])
                            .clamp(-1.0, 1.0)
                            .acos(),
                        *v,
                    )
                })
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            near.truncate(4);
            table.values[k * n_phi + m] = if near[0].0 < 1e-4 {
                near[0].1
            } else {
                let ws: Vec<f32> = near.iter().map(|x| 1.0 / (x.0 * x.0)).collect();
                let sum: f32 = ws.iter().sum();
                std::array::from_fn(|c| {
                    near.iter().zip(&ws).map(|(x, w)| x.1[c] * w).sum::<f32>() / sum
                })
            };
        }
    }
    Ok((table, samples))
}

/// f_v of one view over the whole window (NaN where a channel has no
/// stripe data): f_v(x) = A Σ_l L(x, l) / Σ_l flux_l Ī(d(x, l)), with Ī(d)
/// the view's own measured profile (radiance per flux, the mean over its
/// texels at distance d in texel-wide bins, smoothed [1, 2, 1] and
/// interpolated linearly), and A = Σ L / Σ T(0) I_D flux / π over the
/// fitted range (the formula after paper eq. 6, pooled over the view's
/// texels): A sets the view's level against the dipole, Ī its shape. With
/// I_D in place of Ī each texel's f_v took the model's misfit at its own
/// distances from the few stripes, so it varied with the distance from
/// them: bands parallel to the stripe lines. Distances from 0 (the core
/// is the strongest signal and, at ci and default scale, the only one
/// within the usable range for texels on a stripe) to the fitted range's
/// end count; Ī is the measured profile times the model's, I_D g(d), with
/// g the binned ratio, which is smooth where I_D is steep.
fn exiting_view(
    images: &[(&StripeEntry, Texture)],
    grid: &crate::rectified::Grid,
    fv_range: &[[f64; 2]; 3],
    channels: &[ChannelFit],
    tables: &[EnteringStripe; 3],
) -> Vec<[f64; 3]> {
    let (w, h) = (grid.width as usize, grid.height as usize);
    let tx = grid.texel_mm;
    let mut out = vec![[f64::NAN; 3]; w * h];
    for c in 0..3 {
        let [d0, d1] = fv_range[c];
        let [lo, hi] = channels[c].fit.range_mm;
        let nb = (d1 / tx).ceil() as usize + 1;
        // Per bin: Σ L / flux, Σ d, count; and the level A over the fitted range.
        let (mut sl, mut sm) = (vec![0.0; nb], vec![0.0; nb]);
        let (mut sd, mut n) = (vec![0.0; nb], vec![0.0; nb]);
        let (mut a_num, mut a_den) = (0.0, 0.0);
        for (s, img) in images.iter().filter(|(s, _)| s.channel as usize == c) {
            for j in 0..h {
                for i in 0..w {
                    let l = img.get(i, j)[c] as f64;
                    let d = s.distance(grid.centre(i, j));
                    if !l.is_finite() || d < d0 || d > d1 {
                        continue;
                    }
                    let b = ((d / tx) as usize).min(nb - 1);
                    sl[b] += l / s.flux_per_mm;
                    sm[b] += tables[c].texel_mean(d, tx);
                    sd[b] += d;
                    n[b] += 1.0;
                    if d >= lo && d <= hi {
                        a_num += l;
                        a_den += tables[c].texel_mean(d, tx) * s.flux_per_mm / PI;
                    }
                }
            }
        }
        if !(a_den > 0.0) {
            continue;
        }
        let level = a_num / a_den;
        // The measured profile against the model's, g = Σ L / Σ I_D per bin:
        // smooth where the profile is steep, so it interpolates well.
        let pts: Vec<(f64, f64)> = (0..nb)
            .filter(|&b| n[b] > 0.0 && sm[b] > 0.0)
            .map(|b| (sd[b] / n[b], sl[b] / sm[b]))
            .collect();
        if pts.is_empty() {
            continue;
        }
        // [1, 2, 1] smoothing between measured neighbours.
        let smooth: Vec<(f64, f64)> = (0..pts.len())
            .map(|k| {
                if k == 0 || k + 1 == pts.len() {
                    pts[k]
                } else {
                    (
                        pts[k].0,
                        0.25 * pts[k - 1].1 + 0.5 * pts[k].1 + 0.25 * pts[k + 1].1,
                    )
                }
            })
            .collect();
        let ratio = |d: f64| -> f64 {
            let k = smooth.partition_point(|p| p.0 < d);
            if k == 0 {
                smooth[0].1
            } else if k == smooth.len() {
                smooth[k - 1].1
            } else {
                let (a, b) = (smooth[k - 1], smooth[k]);
                let t = (d - a.0) / (b.0 - a.0);
                a.1 + t * (b.1 - a.1)
            }
        };
        let profile = |d: f64| tables[c].texel_mean(d, tx) * ratio(d);
        let mut num = vec![0.0; w * h];
        let mut den = vec![0.0; w * h];
        for (s, img) in images.iter().filter(|(s, _)| s.channel as usize == c) {
            for j in 0..h {
                for i in 0..w {
                    let l = img.get(i, j)[c] as f64;
                    let d = s.distance(grid.centre(i, j));
                    if l.is_finite() && d >= d0 && d <= d1 {
                        num[j * w + i] += l;
                        den[j * w + i] += s.flux_per_mm * profile(d);
                    }
                }
            }
        }
        // Where the scans reach: a texel whose expected signal is under
        // REACH of the median texel's is left unmeasured.
        let mut sorted: Vec<f64> = den.iter().copied().filter(|d| *d > 0.0).collect();
        sorted.sort_by(f64::total_cmp);
        let floor = sorted
            .get(sorted.len() / 2)
            .map_or(f64::INFINITY, |m| REACH * m);
        for p in 0..w * h {
            if den[p] > 0.0 && den[p] >= floor {
                out[p][c] = level * num[p] / den[p];
            }
        }
    }
    out
}

/// A texel counts as reached by a view's stripes when their summed
/// expected signal there is at least this share of the median texel's.
const REACH: f64 = 0.05;

/// The largest block of rows and columns around the window's centre whose
/// texels have f_v in every view and channel: [i0, j0, width, height].
fn measured_window(maps: &[Vec<[f64; 3]>], w: usize, h: usize) -> Option<[u32; 4]> {
    let ok = |i: usize, j: usize| {
        maps.iter()
            .all(|m| m[j * w + i].iter().all(|v| v.is_finite()))
    };
    // Grow a rectangle from the centre while the added row or column is whole.
    let (ci, cj) = (w / 2, h / 2);
    if !ok(ci, cj) {
        return None;
    }
    let (mut i0, mut i1, mut j0, mut j1) = (ci, ci + 1, cj, cj + 1);
    loop {
        let mut grew = false;
        if j0 > 0 && (i0..i1).all(|i| ok(i, j0 - 1)) {
            j0 -= 1;
            grew = true;
        }
        if j1 < h && (i0..i1).all(|i| ok(i, j1)) {
            j1 += 1;
            grew = true;
        }
        if i0 > 0 && (j0..j1).all(|j| ok(i0 - 1, j)) {
            i0 -= 1;
            grew = true;
        }
        if i1 < w && (j0..j1).all(|j| ok(i1, j)) {
            i1 += 1;
            grew = true;
        }
        if !grew {
            break;
        }
    }
    Some([i0 as u32, j0 as u32, (i1 - i0) as u32, (j1 - j0) as u32])
}

/// How far the window reaches from the stripe's line on its nearer side, mm
/// (the signed distance is linear: its extremes sit at corner texels).
fn band_extent(s: &StripeEntry, grid: &crate::rectified::Grid) -> f64 {
    let (w, h) = (grid.width as usize - 1, grid.height as usize - 1);
    let (mut lo, mut hi) = (0f64, 0f64);
    for (i, j) in [(0, 0), (w, 0), (0, h), (w, h)] {
        let d = s.signed_distance(grid.centre(i, j));
        lo = lo.min(d);
        hi = hi.max(d);
    }
    hi.min(-lo)
}

/// Outgoing radiance integrated across the stripe over |d| <= reach, per mm
/// of line: Σ over texel-wide signed-distance bins of the bin's mean
/// radiance (over its finite texels) times the bin width.
fn band_flux(img: &Texture, s: &StripeEntry, grid: &crate::rectified::Grid, reach: f64) -> f64 {
    let c = s.channel as usize;
    let mut bins = DistanceBins::new(grid.texel_mm, 2.0 * reach);
    for j in 0..grid.height as usize {
        for i in 0..grid.width as usize {
            let d = s.signed_distance(grid.centre(i, j));
            let l = img.get(i, j)[c] as f64;
            if d.abs() <= reach && l.is_finite() {
                bins.add_spread(0.0, d + reach, l);
            }
        }
    }
    bins.means().into_iter().flatten().sum::<f64>() * grid.texel_mm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_bins_sum_the_rows_wherever_the_line_falls() {
        // Texel rows every w mm across a line at offset a from the texel
        // grid: the bins' means times w sum to the rows' sum for any a (a
        // row on a bin edge counted whole went to one bin or the other).
        let w = 0.5;
        let profile = |d: f64| (-3.0 * d.abs()).exp();
        for a in [0.0, 0.1, 0.25, 0.4999, 0.5] {
            let mut bins = DistanceBins::new(w, 20.0);
            let mut rows = 0.0;
            for j in -30..=30 {
                let y = j as f64 * w + a;
                rows += profile(y) * w;
                for _ in 0..7 {
                    bins.add_spread(0.0, y.abs(), profile(y));
                }
            }
            let r = 2.0 * bins.means().iter().flatten().sum::<f64>() * w;
            assert!((r / rows - 1.0).abs() < 1e-9, "offset {a}: {r} vs {rows}");
        }
    }

    #[test]
    fn reflectance_continues_an_exponential_tail() {
        // I(d) = e^{-d}: R = 2 ∫ e^{-d} dd = 2, measured only to 5 mm.
        let bin = 0.05;
        let means: Vec<Option<f64>> = (0..100)
            .map(|k| Some((-(k as f64 + 0.5) * bin).exp()))
            .collect();
        let r = reflectance_from_profile(&means, bin, None);
        assert!((r - 2.0).abs() < 2e-3, "{r}");
    }

    #[test]
    fn reflectance_fills_the_near_field_from_the_model() {
        for model in [ProfileModel::Transport, ProfileModel::Dipole] {
            // The model's own profile, the first 0.5 mm masked and measured to 40 mm.
            let dp = EnteringStripe::new(model, 0.99, 2.0, 1.3, 40.0);
            let bin = 0.02;
            let means: Vec<Option<f64>> = (0..2000)
                .map(|k| {
                    let d = (k as f64 + 0.5) * bin;
                    (d > 0.5).then(|| dp.stripe(d))
                })
                .collect();
            let r = reflectance_from_profile(&means, bin, Some(&dp));
            let total = dp.t_in * model.total_reflectance(0.99, 1.3);
            assert!((r / total - 1.0).abs() < 0.01, "{model:?}: {r} vs {total}");
            // Without the model the near field is simply missing.
            assert!(reflectance_from_profile(&means, bin, None) < 0.95 * r);
            // A far third with no positive value (noise around 0): the
            // model's own tail beyond the last bin, by quadrature.
            let short: Vec<Option<f64>> = (0..300)
                .map(|k| {
                    let d = (k as f64 + 0.5) * bin;
                    if d < 4.0 { means[k] } else { Some(0.0) }
                })
                .collect();
            let expect = 2.0 * (short.iter().map(|m| m.unwrap_or(0.0)).sum::<f64>() * bin)
                + 2.0 * dp.tail(300.0 * bin)
                + 2.0
                    * (0..25)
                        .map(|k| dp.stripe((k as f64 + 0.5) * bin))
                        .sum::<f64>()
                    * bin;
            let got = reflectance_from_profile(&short, bin, Some(&dp));
            assert!(
                (got / expect - 1.0).abs() < 1e-6,
                "{model:?}: {got} vs {expect}"
            );
            assert!(dp.tail(300.0 * bin) < 0.05 * total, "{model:?}");
        }
    }
}
