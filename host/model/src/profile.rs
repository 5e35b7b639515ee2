//! The laser-stripe profile fit of paper section 4.2: a' from the total
//! diffuse reflectance R by inversion, then s'_t alone by a coarse-to-fine
//! search over (0, 10] mm^-1 minimising the misfit between I_D(d) and I(d)
//! over a distance range chosen clear of the stripe's near field and above
//! the noise. The misfit is by default Poisson-weighted, Σ (I_D - I)² / Ĩ
//! with Ĩ the smoothed profile (photon counts have a variance that grows as
//! I); the paper's eq. 6, the plain ||I_D - I||², is [`Norm::Absolute`]. On
//! Monte Carlo profiles the plain norm is ruled by the nearest points, where
//! the dipole's shape is worst, and s'_t moves by 10-20 % with the range
//! (docs/model-format.md).
//!
//! I_D(d) and R_total(a') come from a [`ProfileModel`]: by default radiative
//! transfer solved in the half-space ([`crate::radiative_transfer`]), which the
//! paper's dipole approximates; the dipole itself is 5-7 % off in s'_t at
//! eta 1.3 and does not hold below a' ~ 0.95 (docs/model-format.md).
//!
//! A profile I(d) is the outgoing exitance along lines at distance d from a
//! straight stripe, per unit incident flux per mm of stripe (mm^-1), on a flat
//! semi-infinite sample. I_D(d) and R_total(a') count the light that
//! entered: T(0) = 1 - F(0) of a normal stripe (4 % is reflected at eta
//! 1.5), so the measurement is T(0) I_D(d) and R = T(0) R_total(a').

use std::path::Path;

use glam::{DMat2, DMat3, DVec2, DVec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, number};
use crate::fresnel::normal_transmittance;
use crate::scaled_stripe::ScaledStripe;
use crate::subsurface::{ProfileModel, check_eta};

/// The CSV header of a profile file.
pub const CSV_HEADER: &str = "distance_mm,intensity_per_mm";

/// How the s'_t search measures the misfit between I_D(d) and I(d).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Norm {
    /// Σ (I_D - I)² / Ĩ, Ĩ the profile smoothed (a quadratic in ln I): the
    /// chi-square of photon counts, whose variance grows as I.
    #[default]
    Poisson,
    /// Σ (I_D - I)², the paper's eq. 6.
    Absolute,
}

/// The largest total diffuse reflectance a flat sample of relative index
/// `eta` can have per incident flux: 1 - F(0) = T(0), the share of a normal
/// beam that enters (the rest, F(0) = ((eta - 1) / (eta + 1))², is the
/// specular reflection, which R leaves out). 0.98299 at eta 1.3.
pub fn max_reflectance(eta: f64) -> f64 {
    normal_transmittance(eta)
}

/// Refuses a reflectance outside (0, [`max_reflectance`]], in the user's terms.
fn check_reflectance(reflectance: f64, eta: f64) -> Result<(), ModelError> {
    let max = max_reflectance(eta);
    if reflectance.is_finite() && reflectance > 0.0 && reflectance <= max {
        return Ok(());
    }
    let why = if reflectance.is_finite() && reflectance > max {
        format!(
            "above {max:.6}, the most a sample of index eta = {eta} reflects diffusely \
             ({:.2} % of a normal beam is reflected at its surface and never enters)",
            100.0 * (1.0 - max)
        )
    } else {
        "not a positive number".to_string()
    };
    Err(ModelError::Domain(format!(
        "reflectance R = {} is {why}; R must be in (0, {max:.6}] at eta = {eta}",
        number(reflectance)
    )))
}

/// Smallest s'_t considered, mm^-1 (s'_t = 0 has no dipole).
pub const SIGMA_T_PRIME_MIN: f64 = 0.01;

/// Largest s'_t the fit considers, mm^-1 (paper: 0 to 10).
pub const SIGMA_T_PRIME_MAX: f64 = 10.0;

/// A measured stripe profile, sorted by distance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    /// |d|, mm, ascending.
    pub distance_mm: Vec<f64>,
    /// I(d), mm^-1.
    pub intensity: Vec<f64>,
    /// Width of the distance bins the points average over (0 = point samples).
    pub bin_width_mm: f64,
}

impl Profile {
    /// From points (signed distances are folded: the dipole is symmetric).
    pub fn new(points: impl IntoIterator<Item = (f64, f64)>, bin_width_mm: f64) -> Self {
        let mut p: Vec<(f64, f64)> = points.into_iter().map(|(d, i)| (d.abs(), i)).collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        Profile {
            distance_mm: p.iter().map(|x| x.0).collect(),
            intensity: p.iter().map(|x| x.1).collect(),
            bin_width_mm,
        }
    }

    /// Parses `distance_mm,intensity_per_mm` CSV text; `name` is used in errors.
    /// Blank lines and lines starting with `#` are skipped.
    pub fn parse_csv(text: &str, name: &str) -> Result<Self, ModelError> {
        let err = |line: usize, message: String| ModelError::Csv {
            path: name.to_string(),
            line,
            message,
        };
        let mut header_seen = false;
        let mut points = Vec::new();
        for (k, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            if !header_seen {
                let h: Vec<&str> = line.split(',').map(str::trim).collect();
                if h != ["distance_mm", "intensity_per_mm"] {
                    return Err(err(
                        k + 1,
                        format!("expected header `{CSV_HEADER}`, found `{line}`"),
                    ));
                }
                header_seen = true;
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if fields.len() != 2 {
                return Err(err(
                    k + 1,
                    format!("expected 2 fields, found {}", fields.len()),
                ));
            }
            let num = |s: &str, what: &str| -> Result<f64, ModelError> {
                let v: f64 = s
                    .parse()
                    .map_err(|_| err(k + 1, format!("{what} `{s}` is not a number")))?;
                if !v.is_finite() {
                    return Err(err(k + 1, format!("{what} `{s}` is not finite")));
                }
                Ok(v)
            };
            points.push((num(fields[0], "distance")?, num(fields[1], "intensity")?));
        }
        if !header_seen {
            return Err(err(
                1,
                format!("empty file; expected header `{CSV_HEADER}`"),
            ));
        }
        if points.len() < 3 {
            return Err(err(
                text.lines().count(),
                format!("{} data rows; at least 3 are needed", points.len()),
            ));
        }
        Ok(Profile::new(points, 0.0))
    }

    pub fn read_csv(path: &Path) -> Result<Self, ModelError> {
        let text = std::fs::read_to_string(path).map_err(|e| ModelError::io(path, e))?;
        Profile::parse_csv(&text, &path.display().to_string())
    }

    /// CSV text of this profile (header + rows).
    pub fn to_csv(&self) -> String {
        let mut s = format!("{CSV_HEADER}\n");
        for (d, i) in self.distance_mm.iter().zip(&self.intensity) {
            s.push_str(&format!("{d},{i}\n"));
        }
        s
    }

    /// Indices of points with d in [min, max].
    fn in_range(&self, range: (f64, f64)) -> Vec<usize> {
        (0..self.distance_mm.len())
            .filter(|&i| self.distance_mm[i] >= range.0 && self.distance_mm[i] <= range.1)
            .collect()
    }

    /// Noise floor: 5 σ of the point-to-point scatter in the far quarter of
    /// the profile (robust: median absolute second difference), and never
    /// below 1e-7 of the peak (noise-free data still ends somewhere useful).
    pub fn noise_floor(&self) -> f64 {
        let n = self.intensity.len();
        let peak = self.intensity.iter().cloned().fold(0.0, f64::max);
        let tail = &self.intensity[(3 * n / 4).min(n.saturating_sub(3))..];
        // Second differences cancel a smooth trend; Var(x0 - 2x1 + x2) = 6 σ².
        let mut d2: Vec<f64> = tail
            .windows(3)
            .map(|w| (w[0] - 2.0 * w[1] + w[2]).abs())
            .collect();
        let sigma = if d2.is_empty() {
            0.0
        } else {
            d2.sort_by(f64::total_cmp);
            d2[d2.len() / 2] / 0.6745 / 6f64.sqrt()
        };
        (5.0 * sigma).max(1e-7 * peak)
    }
}

/// What [`fit_profile`] found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProfileFit {
    /// The light transport I_D(d) and R_total(a') came from.
    #[serde(default = "ProfileModel::recorded_before_choice")]
    pub model: ProfileModel,
    pub alpha_prime: f64,
    pub sigma_t_prime: f64,
    pub sigma_s_prime: f64,
    pub sigma_a: f64,
    /// Relative RMS misfit over the range, sqrt(Σ w (I_D - I)² / Σ w I²)
    /// with the norm's weights w (1 / Ĩ for Poisson, 1 for absolute).
    pub residual: f64,
    /// The distance range used, mm.
    pub range_mm: [f64; 2],
    /// Whether the range was chosen automatically.
    pub auto_range: bool,
    /// Number of profile points inside the range.
    pub points: usize,
}

/// One channel's fit with its measured data, kept in a model for the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelFit {
    pub channel: usize,
    pub reflectance: f64,
    pub profile: Profile,
    pub fit: ProfileFit,
}

/// Fits a profile (per incident flux, like R): a' by inverting R / T(0),
/// then s'_t over `range` (or an automatic range) against T(0) I_D(d).
/// R must be in (0, [`max_reflectance`]]; a fit that is not finite is an error.
pub fn fit_profile(
    profile: &Profile,
    reflectance: f64,
    eta: f64,
    model: ProfileModel,
    range: Option<(f64, f64)>,
    norm: Norm,
) -> Result<ProfileFit, ModelError> {
    // The measurement is per incident flux; the dipole is per entered flux,
    // and a normal stripe enters through T(0) (Jensen et al. 2001's F_t(w_i)).
    check_eta(eta)?;
    let t_in = normal_transmittance(eta);
    check_reflectance(reflectance, eta)?;
    let entered = Profile {
        intensity: profile.intensity.iter().map(|i| i / t_in).collect(),
        ..profile.clone()
    };
    let profile = &entered;
    let peak = profile.intensity.iter().fold(0.0f64, |m, i| m.max(i.abs()));
    let overflow = || {
        ModelError::Fit(format!(
            "no finite s'_t fits the profile (the misfit overflows: intensities reach \
             {:.3e} mm^-1, where a profile per unit incident flux integrates to at most R)",
            peak * t_in
        ))
    };
    let too_few = |n: usize, r: (f64, f64)| {
        ModelError::Fit(format!(
            "only {n} profile points in the range {:.3}:{:.3} mm; at least 3 are needed",
            r.0, r.1
        ))
    };
    // What needs no light transport is checked first: solving it takes seconds.
    if !(peak * peak).is_finite() {
        return Err(overflow());
    }
    match range {
        Some(r) => {
            if !(r.0.is_finite() && r.1.is_finite() && r.0 >= 0.0 && r.1 > r.0) {
                return Err(ModelError::Domain(format!(
                    "distance range {}:{} must satisfy 0 <= MIN < MAX",
                    r.0, r.1
                )));
            }
            let n = profile.in_range(r).len();
            if n < 3 {
                return Err(too_few(n, r));
            }
        }
        None => {
            auto_bounds(profile)?;
        }
    }
    let alpha_prime = model.albedo(reflectance / t_in, eta)?;
    let d_max = profile.distance_mm.last().copied().unwrap_or(0.0) + profile.bin_width_mm;
    let table = model.stripe_table(alpha_prime, eta, SIGMA_T_PRIME_MAX * d_max.max(1.0) * 1.01);
    let (range, auto) = match range {
        Some(r) => (r, false),
        None => (auto_range(profile, &table, norm)?, true),
    };
    let idx = profile.in_range(range);
    if idx.len() < 3 {
        return Err(too_few(idx.len(), range));
    }
    let (sigma_t_prime, residual) = search_sigma_t_prime(profile, &idx, &table, norm);
    if !(sigma_t_prime.is_finite() && residual.is_finite() && alpha_prime.is_finite()) {
        return Err(overflow());
    }
    Ok(ProfileFit {
        model,
        alpha_prime,
        sigma_t_prime,
        sigma_s_prime: alpha_prime * sigma_t_prime,
        sigma_a: (1.0 - alpha_prime) * sigma_t_prime,
        residual,
        range_mm: [range.0, range.1],
        auto_range: auto,
        points: idx.len(),
    })
}

/// Automatic distance range. Far end: the last distance before the profile
/// drops under the noise floor. Near end: clear of the stripe's near field,
/// where the dipole is known to be wrong: beyond twice the half-maximum
/// distance and beyond 2 mean free paths 2/s'_t (s'_t from a first fit over
/// everything beyond the half maximum; two refinements).
pub fn auto_range(
    profile: &Profile,
    table: &ScaledStripe,
    norm: Norm,
) -> Result<(f64, f64), ModelError> {
    let (d_min0, d_max) = auto_bounds(profile)?;
    let d = &profile.distance_mm;
    let enough = |lo: f64| d.iter().filter(|&&x| x >= lo && x <= d_max).count() >= 5;
    let mut d_min = d_min0;
    for _ in 0..2 {
        let idx = profile.in_range((d_min, d_max));
        let (st, _) = search_sigma_t_prime(profile, &idx, table, norm);
        let want = d_min0.max(2.0 / st);
        // Keep at least 5 points: shrink towards the far end only while possible.
        d_min = if enough(want) { want } else { d_min };
    }
    Ok((d_min, d_max))
}

/// The automatic range before its near end is refined: (near end clear of
/// the half maximum, far end above the noise floor), or why there is none.
fn auto_bounds(profile: &Profile) -> Result<(f64, f64), ModelError> {
    let d = &profile.distance_mm;
    let i = &profile.intensity;
    let (peak_k, peak) = i
        .iter()
        .enumerate()
        .fold((0, f64::MIN), |b, (k, &v)| if v > b.1 { (k, v) } else { b });
    if !(peak > 0.0) {
        return Err(ModelError::Fit(
            "the profile has no positive intensity".into(),
        ));
    }
    let floor = profile.noise_floor();
    let mut far = peak_k;
    while far + 1 < d.len() && i[far + 1] > floor {
        far += 1;
    }
    let d_max = d[far];
    let half = (peak_k..d.len())
        .find(|&k| i[k] < 0.5 * peak)
        .map_or(d[peak_k], |k| d[k]);
    let d_min0 = (2.0 * half).max(d[peak_k]);
    let enough = |lo: f64| d.iter().filter(|&&x| x >= lo && x <= d_max).count() >= 5;
    if !enough(d_min0) {
        return Err(ModelError::Fit(format!(
            "no usable distance range: the profile is above the noise floor ({floor:.3e}) only up to {d_max:.3} mm, \
             and the near field reaches {d_min0:.3} mm; pass --range"
        )));
    }
    Ok((d_min0, d_max))
}

/// Weighted sum of squared differences between I_D and the profile at `idx`.
fn misfit(
    profile: &Profile,
    idx: &[usize],
    weight: &[f64],
    table: &ScaledStripe,
    sigma_t_prime: f64,
) -> f64 {
    let w = profile.bin_width_mm;
    idx.iter()
        .zip(weight)
        .map(|(&k, w8)| {
            let d = profile.distance_mm[k];
            let model = table.bin_mean(d, w, sigma_t_prime);
            w8 * (model - profile.intensity[k]).powi(2)
        })
        .sum()
}

/// Each point's weight in the misfit. Poisson: 1 / Ĩ(d), Ĩ the profile
/// smoothed by a quadratic in ln I(d) over the points (not the noisy I
/// itself, whose low outliers would weigh most and pull the fit down).
fn misfit_weights(profile: &Profile, idx: &[usize], norm: Norm) -> Vec<f64> {
    let pts: Vec<(f64, f64)> = idx
        .iter()
        .map(|&k| (profile.distance_mm[k], profile.intensity[k]))
        .collect();
    match norm {
        Norm::Absolute => vec![1.0; pts.len()],
        Norm::Poisson => {
            let c = log_quadratic(&pts);
            pts.iter()
                .map(|&(d, _)| (-(c[0] + c[1] * d + c[2] * d * d)).exp())
                .collect()
        }
    }
}

/// Least-squares ln I = c0 + c1 d + c2 d² over the points with I > 0 (a
/// straight line with fewer than 4 such points), by the normal equations.
fn log_quadratic(pts: &[(f64, f64)]) -> [f64; 3] {
    let pos: Vec<(f64, f64)> = pts
        .iter()
        .filter(|p| p.1 > 0.0)
        .map(|&(d, i)| (d, i.ln()))
        .collect();
    let flat = [pos.first().map_or(0.0, |p| p.1), 0.0, 0.0];
    if pos.len() >= 4 {
        let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
        for &(d, y) in &pos {
            let x = DVec3::new(1.0, d, d * d);
            a += DMat3::from_cols(x * x.x, x * x.y, x * x.z);
            b += x * y;
        }
        if a.determinant().abs() > 1e-300 {
            return (a.inverse() * b).to_array();
        }
    } else {
        let (mut a, mut b) = (DMat2::ZERO, DVec2::ZERO);
        for &(d, y) in &pos {
            let x = DVec2::new(1.0, d);
            a += DMat2::from_cols(x * x.x, x * x.y);
            b += x * y;
        }
        if a.determinant().abs() > 1e-300 {
            let c = a.inverse() * b;
            return [c.x, c.y, 0.0];
        }
    }
    flat
}

/// Coarse-to-fine search of s'_t over [SIGMA_T_PRIME_MIN, 10]: a 0.05 mm^-1
/// grid, then six levels each sampling ±1 previous step at a tenth of it.
/// Returns (s'_t, relative RMS residual).
pub fn search_sigma_t_prime(
    profile: &Profile,
    idx: &[usize],
    table: &ScaledStripe,
    norm: Norm,
) -> (f64, f64) {
    let weight = misfit_weights(profile, idx, norm);
    let eval = |s: f64| misfit(profile, idx, &weight, table, s);
    let best_of = |grid: Vec<f64>| {
        grid.into_par_iter().map(|s| (s, eval(s))).reduce(
            || (f64::NAN, f64::INFINITY),
            |a, b| if b.1 < a.1 { b } else { a },
        )
    };
    let mut step = 0.05;
    let n = ((SIGMA_T_PRIME_MAX - SIGMA_T_PRIME_MIN) / step).round() as usize;
    let mut best = best_of(
        (0..=n)
            .map(|k| SIGMA_T_PRIME_MIN + k as f64 * step)
            .collect(),
    );
    for _ in 0..6 {
        let fine = step / 10.0;
        let grid = (-10..=10)
            .map(|k| best.0 + k as f64 * fine)
            .filter(|s| (SIGMA_T_PRIME_MIN..=SIGMA_T_PRIME_MAX).contains(s))
            .collect();
        let cand = best_of(grid);
        if cand.1 <= best.1 {
            best = cand;
        }
        step = fine;
    }
    let norm_sq: f64 = idx
        .iter()
        .zip(&weight)
        .map(|(&k, w8)| w8 * profile.intensity[k].powi(2))
        .sum();
    (best.0, (best.1 / norm_sq.max(f64::MIN_POSITIVE)).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::dipole::{self, Dipole};
    use crate::radiative_transfer::HalfSpace;

    /// A synthetic profile of `model` itself, per incident flux as measured,
    /// T(0) I_D(d), with optional multiplicative noise from a fixed-seed LCG.
    fn synthetic_of(model: ProfileModel, a: f64, st: f64, noise: f64, seed: u64) -> Profile {
        let ds: Vec<f64> = (0..200).map(|k| k as f64 * 0.1).collect();
        let ideal: Vec<f64> = match model {
            ProfileModel::Dipole => {
                let dp = Dipole::new(a, st, 1.3);
                ds.iter().map(|&d| dp.stripe(d)).collect()
            }
            ProfileModel::Transport => {
                let xs: Vec<f64> = ds.iter().map(|d| d * st).collect();
                let g = HalfSpace::shared(1.3).line_profile(a, &xs);
                g.iter().map(|g| st * g).collect()
            }
        };
        let t_in = normal_transmittance(1.3);
        let mut state = seed;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        Profile::new(
            ds.iter().zip(ideal).map(|(&d, i)| {
                let n = (uniform() - 0.5) * 2.0 * noise;
                (d, t_in * i * (1.0 + n) + noise * 1e-4 * (uniform() - 0.5))
            }),
            0.0,
        )
    }

    fn synthetic(a: f64, st: f64, noise: f64, seed: u64) -> Profile {
        synthetic_of(ProfileModel::Dipole, a, st, noise, seed)
    }

    #[test]
    fn recovers_sigma_t_prime_from_each_models_own_data() {
        for model in [ProfileModel::Dipole, ProfileModel::Transport] {
            for &(a, st) in &[(0.99, 1.0), (0.95, 2.5), (0.999, 0.7), (0.9, 6.0)] {
                let r = normal_transmittance(1.3) * model.total_reflectance(a, 1.3);
                let p = synthetic_of(model, a, st, 0.0, 1);
                let fit = fit_profile(&p, r, 1.3, model, None, Norm::Poisson).unwrap();
                assert_eq!(fit.model, model);
                assert!((fit.alpha_prime - a).abs() < 1e-8, "{model:?} {a}: {fit:?}");
                assert!(
                    ((fit.sigma_t_prime - st) / st).abs() < 1e-4,
                    "{model:?} {st}: {fit:?}"
                );
                assert!(fit.residual < 1e-4, "{model:?}: {fit:?}");
            }
        }
    }

    #[test]
    fn fit_is_stable_under_small_range_changes() {
        let (a, st) = (0.98, 1.5);
        let r = normal_transmittance(1.3) * dipole::total_reflectance(a, 1.3);
        let p = synthetic(a, st, 0.03, 7);
        let base = fit_profile(&p, r, 1.3, ProfileModel::Dipole, None, Norm::Poisson).unwrap();
        assert!(base.auto_range);
        assert!(((base.sigma_t_prime - st) / st).abs() < 0.03, "{base:?}");
        let [lo, hi] = base.range_mm;
        for (dl, dh) in [
            (-0.2, 0.0),
            (0.2, 0.0),
            (0.0, -0.5),
            (0.0, 0.5),
            (0.3, -0.5),
        ] {
            let range = Some((lo + dl, hi + dh));
            let f = fit_profile(&p, r, 1.3, ProfileModel::Dipole, range, Norm::Poisson).unwrap();
            let rel = (f.sigma_t_prime - base.sigma_t_prime).abs() / base.sigma_t_prime;
            assert!(
                rel < 0.02,
                "range {:?}: {} vs {}",
                f.range_mm,
                f.sigma_t_prime,
                base.sigma_t_prime
            );
        }
    }

    #[test]
    fn poisson_weights_follow_the_smoothed_profile_not_its_outliers() {
        // ln I = 1 - 0.5 d + 0.01 d², exactly recovered; one point dropped to
        // a tenth keeps nearly the weight of its neighbours.
        let pts: Vec<(f64, f64)> = (0..20)
            .map(|k| {
                let d = 1.0 + 0.5 * k as f64;
                (d, (1.0 - 0.5 * d + 0.01 * d * d).exp())
            })
            .collect();
        let c = log_quadratic(&pts);
        assert!(
            (c[0] - 1.0).abs() < 1e-9 && (c[1] + 0.5).abs() < 1e-9 && (c[2] - 0.01).abs() < 1e-9
        );
        let mut p = Profile::new(pts.iter().copied(), 0.0);
        p.intensity[10] *= 0.1;
        let idx: Vec<usize> = (0..20).collect();
        let w = misfit_weights(&p, &idx, Norm::Poisson);
        assert!(w[10] < 2.0 * w[9] && w[10] > 0.5 * w[11], "{:?}", &w[8..13]);
        assert!(w[19] > w[0], "weights grow as I falls");
        assert_eq!(misfit_weights(&p, &idx, Norm::Absolute), vec![1.0; 20]);
    }

    #[test]
    fn auto_range_avoids_near_field_and_noise() {
        let (a, st) = (0.98, 1.5);
        let p = synthetic(a, st, 0.05, 3);
        let table = ProfileModel::Dipole.stripe_table(a, 1.3, 200.0);
        let (lo, hi) = auto_range(&p, &table, Norm::Poisson).unwrap();
        assert!(lo >= 2.0 / st - 0.2, "near end {lo}");
        assert!(hi > lo + 1.0 && hi <= 19.9, "far end {hi}");
    }

    #[test]
    fn csv_errors_name_the_line() {
        let e = Profile::parse_csv("distance_mm,intensity_per_mm\n0,1\n0.1,abc\n", "p.csv")
            .unwrap_err();
        assert_eq!(e.to_string(), "p.csv:3: intensity `abc` is not a number");
        let e = Profile::parse_csv("d,i\n0,1\n", "p.csv").unwrap_err();
        assert!(e.to_string().starts_with("p.csv:1: expected header"), "{e}");
        let e =
            Profile::parse_csv("distance_mm,intensity_per_mm\n0,1\n1,2,3\n", "p.csv").unwrap_err();
        assert!(e.to_string().contains(":3: expected 2 fields"), "{e}");
        let e =
            Profile::parse_csv("distance_mm,intensity_per_mm\n0,1\n1,inf\n", "p.csv").unwrap_err();
        assert!(
            e.to_string().contains(":3: intensity `inf` is not finite"),
            "{e}"
        );
        let e = Profile::parse_csv("distance_mm,intensity_per_mm\n0,1\n", "p.csv").unwrap_err();
        assert!(e.to_string().contains("at least 3"), "{e}");
        let e = Profile::parse_csv("", "p.csv").unwrap_err();
        assert!(e.to_string().contains("empty file"), "{e}");
    }

    #[test]
    fn csv_round_trips_and_folds_negative_distances() {
        let p = Profile::parse_csv(
            "# a comment\ndistance_mm, intensity_per_mm\n\n-1,0.5\n0,1\n2,0.25\n",
            "x",
        )
        .unwrap();
        assert_eq!(p.distance_mm, vec![0.0, 1.0, 2.0]);
        assert_eq!(p.intensity, vec![1.0, 0.5, 0.25]);
        let q = Profile::parse_csv(&p.to_csv(), "y").unwrap();
        assert_eq!(p, q);
    }

    #[test]
    fn reflectance_limit_is_one_minus_normal_fresnel_and_named_in_user_terms() {
        let p = synthetic(0.99, 1.0, 0.0, 1);
        let max = max_reflectance(1.3);
        assert!((max - (1.0 - (0.3f64 / 2.3).powi(2))).abs() < 1e-12);
        for model in [ProfileModel::Dipole, ProfileModel::Transport] {
            for r in [1.0, 0.999999, 0.983] {
                let e = fit_profile(&p, r, 1.3, model, None, Norm::Poisson)
                    .unwrap_err()
                    .to_string();
                assert!(e.contains(&format!("R = {r} is above 0.982987")), "{e}");
                assert!(e.contains("(0, 0.982987] at eta = 1.3"), "{e}");
                assert!(!e.contains("T(0)") && !e.contains("R /"), "{e}");
            }
            assert!(fit_profile(&p, max, 1.3, model, None, Norm::Poisson).is_ok());
            for r in [0.0, -0.5, f64::NAN] {
                let e = fit_profile(&p, r, 1.3, model, None, Norm::Poisson).unwrap_err();
                assert!(e.to_string().contains("not a positive number"), "{e}");
            }
        }
    }

    #[test]
    fn an_overflowing_profile_is_an_error_not_nan() {
        let p = Profile::new((0..50).map(|k| (k as f64 * 0.2, 1e300)), 0.0);
        for model in [ProfileModel::Dipole, ProfileModel::Transport] {
            let e = fit_profile(&p, 0.5, 1.3, model, Some((1.0, 8.0)), Norm::Absolute)
                .unwrap_err()
                .to_string();
            assert!(e.contains("no finite s'_t"), "{e}");
            let auto = fit_profile(&p, 0.5, 1.3, model, None, Norm::Poisson);
            assert!(auto.is_err(), "{auto:?}");
        }
    }

    #[test]
    fn bad_range_and_reflectance_are_errors() {
        let p = synthetic(0.99, 1.0, 0.0, 1);
        for model in [ProfileModel::Dipole, ProfileModel::Transport] {
            let fit = |r, range| fit_profile(&p, r, 1.3, model, range, Norm::Poisson);
            assert!(fit(0.5, Some((2.0, 1.0))).is_err());
            assert!(fit(0.5, Some((50.0, 60.0))).is_err());
            assert!(fit(1.5, None).is_err());
            assert!(fit_profile(&p, 0.5, 0.9, model, None, Norm::Poisson).is_err());
        }
    }
}
