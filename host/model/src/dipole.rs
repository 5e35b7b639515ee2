//! The classic dipole of Jensen et al. 2001 and what the fit builds on it:
//! R_d(r), the total diffuse reflectance R_total(a') of Jensen & Buhler 2002
//! and its f64 inversion, and the virtual laser stripe
//! I_D(d) = ∫ R_d(sqrt(d² + s²)) ds (paper eq. 6) by adaptive quadrature.
//!
//! Units: mm and mm^-1. R_d is in mm^-2 (exitance per incident flux), I_D in
//! mm^-1 (exitance per incident flux per mm of stripe).

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use std::sync::Arc;

use crate::ModelError;
use crate::profile::ProfileModel;
use crate::quad;
use crate::transport::{HalfSpace, RadialProfile};

/// Relative index of refraction the paper fits with (after Jensen et al. 2001).
pub const DEFAULT_ETA: f64 = 1.3;

/// Largest s'_t the fit considers, mm^-1 (paper: 0 to 10).
pub const SIGMA_T_PRIME_MAX: f64 = 10.0;

/// Internal diffuse Fresnel reflectance F_dr(eta) (polynomial fit).
pub fn fresnel_diffuse_reflectance(eta: f64) -> f64 {
    -1.440 / (eta * eta) + 0.710 / eta + 0.668 + 0.0636 * eta
}

/// Boundary mismatch A = (1 + F_dr) / (1 - F_dr).
pub fn boundary_a(eta: f64) -> f64 {
    let f_dr = fresnel_diffuse_reflectance(eta);
    (1.0 + f_dr) / (1.0 - f_dr)
}

/// Fresnel reflectance of unpolarised light entering a dielectric of relative
/// index `eta` from outside, at incidence cosine `cos_theta_i` (clamped to [0,1]).
pub fn fresnel_dielectric(cos_theta_i: f64, eta: f64) -> f64 {
    let ci = cos_theta_i.clamp(0.0, 1.0);
    let si2 = (1.0 - ci * ci).max(0.0);
    let st2 = si2 / (eta * eta);
    if st2 >= 1.0 {
        return 1.0;
    }
    let ct = (1.0 - st2).sqrt();
    let r_s = (ci - eta * ct) / (ci + eta * ct);
    let r_p = (eta * ci - ct) / (eta * ci + ct);
    0.5 * (r_s * r_s + r_p * r_p)
}

/// Cosine-weighted hemispherical average of [`fresnel_dielectric`],
/// 2 ∫ F(μ) μ dμ over μ in [0, 1] (midpoint rule, 128 steps: 1e-5).
pub fn fresnel_hemispherical_average(eta: f64) -> f64 {
    let n = 128;
    (0..n)
        .map(|k| {
            let mu = (k as f64 + 0.5) / n as f64;
            2.0 * fresnel_dielectric(mu, eta) * mu
        })
        .sum::<f64>()
        / n as f64
}

/// Exitance per unit radiance seen at `cos_view` from a smooth dielectric
/// lit diffusely from inside: M / L(θ) = π (1 - F̄) / (1 - F(θ)). Light that
/// has diffused is nearly isotropic under the surface, so the outgoing
/// radiance follows the Fresnel transmittance, not Lambert's law; π L alone
/// overstates the exitance by ~5 % near the normal at eta 1.5.
pub fn exitance_per_radiance(cos_view: f64, eta: f64, fresnel_average: f64) -> f64 {
    std::f64::consts::PI * (1.0 - fresnel_average) / (1.0 - fresnel_dielectric(cos_view, eta))
}

/// T(0) = 1 - F(0): the share of a normal beam that enters a smooth surface.
/// R_total(a') and the dipole are per entered flux; the model's f(w_i) is
/// relative to normal incidence, so light entering per incident flux is
/// T(0) f(w_i).
pub fn normal_transmittance(eta: f64) -> f64 {
    1.0 - fresnel_dielectric(1.0, eta)
}

/// Fresnel transmittance ratio T(θ)/T(0): the entrance function of a flat,
/// smooth surface (1 at normal incidence).
pub fn fresnel_transmittance_ratio(cos_theta_i: f64, eta: f64) -> f64 {
    (1.0 - fresnel_dielectric(cos_theta_i, eta)) / (1.0 - fresnel_dielectric(1.0, eta))
}

/// Total diffuse reflectance R_total(a') = (a'/2)(1 + e^{-(4/3)A sqrt(3(1-a'))}) e^{-sqrt(3(1-a'))}.
pub fn total_reflectance(alpha_prime: f64, eta: f64) -> f64 {
    let a = boundary_a(eta);
    let s = (3.0 * (1.0 - alpha_prime).max(0.0)).sqrt();
    0.5 * alpha_prime * (1.0 + (-(4.0 / 3.0) * a * s).exp()) * (-s).exp()
}

/// Inverts [`total_reflectance`] for a' in f64 by bisection to ~1e-12 (a' of
/// milk-like materials is within 1e-3 of 1, so precision matters). R must be in (0, 1].
pub fn alpha_prime_from_reflectance(r: f64, eta: f64) -> Result<f64, ModelError> {
    if !(r.is_finite() && r > 0.0 && r <= 1.0) {
        return Err(ModelError::Domain(format!(
            "total diffuse reflectance R = {r} is outside (0, 1]"
        )));
    }
    if !(eta.is_finite() && eta > 1.0 && eta < 3.0) {
        return Err(ModelError::Domain(format!(
            "relative index eta = {eta} is outside (1, 3)"
        )));
    }
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    // R_total is monotone increasing in a'; 60 halvings reach 1e-18.
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if total_reflectance(mid, eta) < r {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-14 {
            break;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// The global (dipole) term of a material, per colour channel (R, G, B):
/// the medium's reduced coefficients and the light transport its R_d(r)
/// comes from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DipoleParams {
    /// Reduced albedo a' = s'_s / s'_t.
    pub alpha_prime: [f64; 3],
    /// Reduced extinction s'_t, mm^-1.
    pub sigma_t_prime: [f64; 3],
    /// Relative index of refraction.
    pub eta: f64,
    /// What R_d(r) is: the paper's dipole, or radiative transfer.
    #[serde(default = "ProfileModel::recorded_before_choice")]
    pub model: ProfileModel,
}

impl DipoleParams {
    /// From reduced scattering and absorption coefficients (mm^-1), as in the
    /// Jensen et al. 2001 table (dipole fits, so with the dipole's R_d).
    pub fn from_coefficients(sigma_s_prime: [f64; 3], sigma_a: [f64; 3], eta: f64) -> Self {
        let mut alpha_prime = [0.0; 3];
        let mut sigma_t_prime = [0.0; 3];
        for c in 0..3 {
            sigma_t_prime[c] = sigma_s_prime[c] + sigma_a[c];
            alpha_prime[c] = sigma_s_prime[c] / sigma_t_prime[c];
        }
        DipoleParams {
            alpha_prime,
            sigma_t_prime,
            eta,
            model: ProfileModel::Dipole,
        }
    }
    /// Reduced scattering s'_s = a' s'_t.
    pub fn sigma_s_prime(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.alpha_prime[c] * self.sigma_t_prime[c])
    }
    /// Absorption s_a = (1 - a') s'_t.
    pub fn sigma_a(&self) -> [f64; 3] {
        std::array::from_fn(|c| (1.0 - self.alpha_prime[c]) * self.sigma_t_prime[c])
    }
    /// Effective transport s_tr = sqrt(3 s_a s'_t).
    pub fn sigma_tr(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.channel(c).sigma_tr)
    }
    /// The single-channel classic dipole of channel `c`.
    pub fn channel(&self, c: usize) -> Dipole {
        Dipole::new(self.alpha_prime[c], self.sigma_t_prime[c], self.eta)
    }
    /// R_d(r) of the params' model, ready to evaluate (for transport, the
    /// radial profiles are computed here, about 0.3 s a channel, and kept).
    pub fn subsurface(&self) -> Subsurface {
        Subsurface {
            channels: std::array::from_fn(|c| match self.model {
                ProfileModel::Dipole => ChannelProfile::Dipole(self.channel(c)),
                ProfileModel::Transport => ChannelProfile::Transport {
                    profile: HalfSpace::shared(self.eta).radial_profile(self.alpha_prime[c]),
                    sigma_t_prime: self.sigma_t_prime[c],
                },
            }),
        }
    }
    /// R_d(r) for the three channels (mm^-2). Evaluating many r: use
    /// [`Self::subsurface`] once.
    pub fn rd(&self, r: f64) -> [f64; 3] {
        self.subsurface().rd(r)
    }
    /// Checks the parameters are physical: a' in [0, 1], s'_t in (0, 10·∞), eta in (1, 3).
    pub fn validate(&self) -> Result<(), String> {
        for c in 0..3 {
            let (a, s) = (self.alpha_prime[c], self.sigma_t_prime[c]);
            if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
                return Err(format!("alpha_prime[{c}] = {a} is outside [0, 1]"));
            }
            if !(s.is_finite() && s > 0.0) {
                return Err(format!("sigma_t_prime[{c}] = {s} must be > 0"));
            }
        }
        if !(self.eta.is_finite() && self.eta > 1.0 && self.eta < 3.0) {
            return Err(format!("eta = {} is outside (1, 3)", self.eta));
        }
        Ok(())
    }
}

/// A material's R_d(r) per channel, per entered flux (mm^-2), with its
/// total and disc integrals: what the renderer and the LRF's global part use.
pub struct Subsurface {
    channels: [ChannelProfile; 3],
}

enum ChannelProfile {
    Dipole(Dipole),
    /// Unit-s'_t radial profile, scaled: R_d(r) = s'_t² R_1(s'_t r).
    Transport {
        profile: Arc<RadialProfile>,
        sigma_t_prime: f64,
    },
}

impl Subsurface {
    /// R_d(r) for the three channels, mm^-2.
    pub fn rd(&self, r: f64) -> [f64; 3] {
        std::array::from_fn(|c| match &self.channels[c] {
            ChannelProfile::Dipole(d) => d.rd(r),
            ChannelProfile::Transport {
                profile,
                sigma_t_prime: st,
            } => st * st * profile.rd(st * r),
        })
    }
    /// R_d integrated over the plane (the total diffuse reflectance).
    pub fn total(&self, c: usize) -> f64 {
        match &self.channels[c] {
            ChannelProfile::Dipole(d) => d.total(),
            ChannelProfile::Transport { profile, .. } => profile.total,
        }
    }
    /// R_d integrated over the disc of radius `r0` around the source.
    pub fn disc_integral(&self, c: usize, r0: f64) -> f64 {
        match &self.channels[c] {
            ChannelProfile::Dipole(d) => d.disc_integral(r0),
            ChannelProfile::Transport {
                profile,
                sigma_t_prime: st,
            } => profile.disc_integral(st * r0),
        }
    }
}

/// A single-channel classic dipole with its derived constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dipole {
    pub alpha_prime: f64,
    pub sigma_t_prime: f64,
    pub sigma_tr: f64,
    /// Real source depth z_r = 1/s'_t.
    pub z_r: f64,
    /// Virtual source height z_v = z_r (1 + 4A/3).
    pub z_v: f64,
}

impl Dipole {
    pub fn new(alpha_prime: f64, sigma_t_prime: f64, eta: f64) -> Self {
        let sigma_a = (1.0 - alpha_prime).max(0.0) * sigma_t_prime;
        let z_r = 1.0 / sigma_t_prime;
        Dipole {
            alpha_prime,
            sigma_t_prime,
            sigma_tr: (3.0 * sigma_a * sigma_t_prime).sqrt(),
            z_r,
            z_v: z_r * (1.0 + 4.0 * boundary_a(eta) / 3.0),
        }
    }

    /// Diffuse reflectance profile R_d(r), mm^-2.
    pub fn rd(&self, r: f64) -> f64 {
        let r2 = r * r;
        let term = |z: f64| {
            let d = (r2 + z * z).sqrt();
            z * (self.sigma_tr * d + 1.0) * (-self.sigma_tr * d).exp() / (d * d * d)
        };
        self.alpha_prime / (4.0 * PI) * (term(self.z_r) + term(self.z_v))
    }

    /// R_d integrated over the whole plane (equals R_total of Jensen & Buhler).
    pub fn total(&self) -> f64 {
        0.5 * self.alpha_prime
            * ((-self.sigma_tr * self.z_r).exp() + (-self.sigma_tr * self.z_v).exp())
    }

    /// R_d integrated over a disc of radius `r0` around the source, closed form:
    /// 2π∫_0^{r0} r R_d dr = (a'/2) Σ_z [e^{-s_tr z} - z e^{-s_tr d0}/d0], d0 = sqrt(r0²+z²).
    pub fn disc_integral(&self, r0: f64) -> f64 {
        let part = |z: f64| {
            let d0 = (r0 * r0 + z * z).sqrt();
            (-self.sigma_tr * z).exp() - z * (-self.sigma_tr * d0).exp() / d0
        };
        0.5 * self.alpha_prime * (part(self.z_r) + part(self.z_v))
    }

    /// The virtual laser stripe I_D(d) = ∫_{-∞}^{∞} R_d(sqrt(d² + s²)) ds, mm^-1,
    /// by adaptive Gauss-Kronrod after mapping s = L t/(1-t) onto [0, 1), with
    /// L = sqrt(d² + z_r²) the width of the near field, so that both the peak
    /// and the long exponential (or, for a' = 1, algebraic) tail are resolved.
    pub fn stripe(&self, d: f64) -> f64 {
        let d2 = d * d;
        let l = (d2 + self.z_r * self.z_r).sqrt();
        let f = |t: f64| {
            if t >= 1.0 {
                return 0.0;
            }
            let u = 1.0 - t;
            let s = l * t / u;
            self.rd((d2 + s * s).sqrt()) * l / (u * u)
        };
        2.0 * quad::integrate(f, 0.0, 1.0, 1e-9, 1e-300, 400)
    }

    /// Average of I_D over the bin [d - w/2, d + w/2] (5-point Gauss-Legendre),
    /// to compare with binned measurements; `w = 0` is a point sample.
    pub fn stripe_bin(&self, d: f64, w: f64) -> f64 {
        if w <= 0.0 {
            return self.stripe(d);
        }
        quad::GL5
            .iter()
            .map(|&(x, wt)| 0.5 * wt * self.stripe((d + 0.5 * w * x).abs()))
            .sum()
    }
}

/// I_D(d) for one a' and every s'_t at once, from the scaling law that the
/// dipole and radiative transfer share (lengths scale with 1/s'_t):
/// R_d(r; a', s'_t) = s'_t² R_d(s'_t r; a', 1), hence
/// I_D(d; a', s'_t) = s'_t g(s'_t d) with g(x) = I_D(x; a', 1). g is computed
/// once on a grid in u = ln(1 + x) (by quadrature for the dipole, by
/// [`crate::transport`] otherwise) and interpolated linearly in (u, ln g),
/// which makes each candidate of the s'_t search a table lookup.
#[derive(Clone, Debug)]
pub struct ScaledStripe {
    pub alpha_prime: f64,
    pub eta: f64,
    h: f64,
    ln_g: Vec<f64>,
}

impl ScaledStripe {
    /// The dipole's table, good for s'_t d <= `x_max`.
    pub fn new(alpha_prime: f64, eta: f64, x_max: f64) -> Self {
        use rayon::prelude::*;
        let unit = Dipole::new(alpha_prime, 1.0, eta);
        Self::from_unit_profile(alpha_prime, eta, x_max, |xs| {
            xs.par_iter().map(|&x| unit.stripe(x)).collect()
        })
    }

    /// The table from any profile g(x) of unit s'_t obeying the same
    /// scaling law, evaluated at once on the grid by `unit_profile`.
    pub fn from_unit_profile(
        alpha_prime: f64,
        eta: f64,
        x_max: f64,
        unit_profile: impl FnOnce(&[f64]) -> Vec<f64>,
    ) -> Self {
        let h = 0.002;
        let n = ((1.0 + x_max.max(1.0)).ln() / h).ceil() as usize + 2;
        let xs: Vec<f64> = (0..n).map(|k| (k as f64 * h).exp() - 1.0).collect();
        let ln_g = unit_profile(&xs)
            .into_iter()
            .map(|g| if g > 0.0 { g.ln().max(-700.0) } else { -700.0 })
            .collect();
        ScaledStripe {
            alpha_prime,
            eta,
            h,
            ln_g,
        }
    }

    /// I_D(d) for reduced extinction `sigma_t_prime`.
    pub fn eval(&self, d: f64, sigma_t_prime: f64) -> f64 {
        let u = (1.0 + sigma_t_prime * d.abs()).ln() / self.h;
        let k = u.floor() as usize;
        let ln_g = if k + 1 >= self.ln_g.len() {
            -700.0
        } else {
            let f = u - k as f64;
            self.ln_g[k] * (1.0 - f) + self.ln_g[k + 1] * f
        };
        sigma_t_prime * ln_g.exp()
    }

    /// Mean of I_D over [d - w/2, d + w/2] (5-point Gauss-Legendre): what a
    /// distance bin or an area-mean texel `w` wide measures; `w = 0` is
    /// the point value.
    pub fn bin_mean(&self, d: f64, w: f64, sigma_t_prime: f64) -> f64 {
        if w <= 0.0 {
            return self.eval(d, sigma_t_prime);
        }
        quad::GL5
            .iter()
            .map(|&(x, wt)| 0.5 * wt * self.eval(d + 0.5 * w * x, sigma_t_prime))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn optics_reference_values() {
        assert!((fresnel_diffuse_reflectance(1.3) - 0.4448).abs() < 5e-4);
        assert!((boundary_a(1.3) - 2.602).abs() < 2e-3);
        let a = alpha_prime_from_reflectance(0.91, 1.3).unwrap();
        assert!((a - 0.99959).abs() < 1e-5, "{a}");
        let a = alpha_prime_from_reflectance(0.50, 1.3).unwrap();
        assert!((a - 0.9726).abs() < 1e-4, "{a}");
        let a = alpha_prime_from_reflectance(0.10, 1.3).unwrap();
        assert!((a - 0.592).abs() < 1e-3, "{a}");
    }

    #[test]
    fn inversion_round_trips_to_1e_12() {
        for &a in &[0.1, 0.5, 0.9, 0.99, 0.999, 0.9999, 0.99999] {
            let r = total_reflectance(a, 1.3);
            let back = alpha_prime_from_reflectance(r, 1.3).unwrap();
            assert!((back - a).abs() < 1e-11, "{a} -> {r} -> {back}");
        }
        assert!((total_reflectance(1.0, 1.3) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn inversion_rejects_bad_input() {
        assert!(alpha_prime_from_reflectance(0.0, 1.3).is_err());
        assert!(alpha_prime_from_reflectance(1.2, 1.3).is_err());
        assert!(alpha_prime_from_reflectance(f64::NAN, 1.3).is_err());
        assert!(alpha_prime_from_reflectance(0.5, 0.9).is_err());
    }

    #[test]
    fn rd_integrates_to_total_reflectance() {
        for &(a, st) in &[(0.99, 1.0), (0.9, 2.5), (0.999, 0.7), (1.0, 1.5)] {
            let dp = Dipole::new(a, st, 1.3);
            // 2π ∫ r R_d(r) dr over [0, ∞) with r = t/(1-t).
            let f = |t: f64| {
                if t >= 1.0 {
                    return 0.0;
                }
                let u = 1.0 - t;
                let r = t / u;
                2.0 * PI * r * dp.rd(r) / (u * u)
            };
            let numeric = quad::integrate(f, 0.0, 1.0, 1e-11, 0.0, 2000);
            let closed = total_reflectance(a, 1.3);
            assert!((dp.total() - closed).abs() < 1e-12);
            // a' = 1 has an algebraic 1/r^2 tail in r R_d: looser.
            let tol = if a == 1.0 { 1e-4 } else { 1e-8 };
            assert!(
                (numeric - closed).abs() < tol,
                "a'={a} s't={st}: {numeric} vs {closed}"
            );
            assert!((dp.disc_integral(1e6) - closed).abs() < 1e-5);
        }
    }

    /// K_1 by Abramowitz & Stegun 9.8.7/9.8.8 (|error| < 2.2e-7 relative),
    /// an independent route to I_D: ∫(σρ+1)e^{-σρ}/ρ³ ds = 2σ K_1(σh)/h.
    fn bessel_k1(x: f64) -> f64 {
        if x <= 2.0 {
            let t = x / 3.75;
            let t2 = t * t;
            let i1 = x
                * (0.5
                    + t2 * (0.87890594
                        + t2 * (0.51498869
                            + t2 * (0.15084934
                                + t2 * (0.02658733 + t2 * (0.00301532 + t2 * 0.00032411))))));
            let y = x * x / 4.0;
            (x / 2.0).ln() * i1
                + (1.0 / x)
                    * (1.0
                        + y * (0.15443144
                            + y * (-0.67278579
                                + y * (-0.18156897
                                    + y * (-0.01919402 + y * (-0.00110404 - y * 0.00004686))))))
        } else {
            let y = 2.0 / x;
            (-x).exp() / x.sqrt()
                * (1.25331414
                    + y * (0.23498619
                        + y * (-0.03655620
                            + y * (0.01504268
                                + y * (-0.00780353 + y * (0.00325614 - y * 0.00068245))))))
        }
    }

    #[test]
    fn stripe_matches_bessel_closed_form() {
        for &(a, st) in &[(0.99, 1.0), (0.9, 3.0), (0.95, 0.4)] {
            let dp = Dipole::new(a, st, 1.3);
            for &d in &[0.0, 0.05, 0.3, 1.0, 3.0, 8.0] {
                let closed: f64 = [dp.z_r, dp.z_v]
                    .iter()
                    .map(|&z| {
                        let h = (d * d + z * z).sqrt();
                        z * 2.0 * dp.sigma_tr * bessel_k1(dp.sigma_tr * h) / h
                    })
                    .sum::<f64>()
                    * a
                    / (4.0 * PI);
                let q = dp.stripe(d);
                assert!(
                    ((q - closed) / closed).abs() < 2e-6,
                    "a'={a} s't={st} d={d}: {q} vs {closed}"
                );
            }
        }
    }

    #[test]
    fn stripe_integrates_to_total_reflectance() {
        for &(a, st) in &[(0.99, 1.0), (0.8, 4.0), (0.999, 1.6)] {
            let dp = Dipole::new(a, st, 1.3);
            let f = |t: f64| {
                if t >= 1.0 {
                    return 0.0;
                }
                let u = 1.0 - t;
                dp.stripe(t / u) / (u * u)
            };
            let numeric = 2.0 * quad::integrate(f, 0.0, 1.0, 1e-9, 0.0, 400);
            let closed = total_reflectance(a, 1.3);
            assert!(
                ((numeric - closed) / closed).abs() < 1e-6,
                "a'={a} s't={st}: {numeric} vs {closed}"
            );
        }
    }

    #[test]
    fn scaled_stripe_matches_quadrature() {
        for &a in &[0.999, 0.95, 0.6] {
            let table = ScaledStripe::new(a, 1.3, 200.0);
            for &st in &[0.3, 1.0, 4.2, 9.5] {
                let dp = Dipole::new(a, st, 1.3);
                for &d in &[0.0, 0.1, 0.7, 2.0, 6.0, 15.0] {
                    let (q, t) = (dp.stripe(d), table.eval(d, st));
                    assert!(
                        ((q - t) / q).abs() < 5e-5,
                        "a'={a} s't={st} d={d}: {q} vs {t}"
                    );
                }
            }
        }
    }

    #[test]
    fn fresnel_ratio_is_one_at_normal_and_falls_to_zero_at_grazing() {
        assert!((fresnel_transmittance_ratio(1.0, 1.3) - 1.0).abs() < 1e-12);
        assert!(fresnel_transmittance_ratio(0.0, 1.3) < 1e-9);
        // eta = 1.5 at normal incidence: R = 0.04.
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-12);
        let r60 = fresnel_transmittance_ratio((60f64).to_radians().cos(), 1.3);
        assert!(r60 < 1.0 && r60 > 0.9, "{r60}");
    }

    #[test]
    fn hemispherical_fresnel_and_exitance_conversion() {
        // Glass (n = 1.5) reflects ~9.2 % of diffuse light: F̄ = 0.0918.
        let fa = fresnel_hemispherical_average(1.5);
        assert!((fa - 0.0918).abs() < 1e-3, "{fa}");
        // Fresnel-shaped radiance L(θ) = M / k(θ) integrates back to M.
        let n = 2000;
        let m: f64 = (0..n)
            .map(|k| {
                let th = (k as f64 + 0.5) / n as f64 * std::f64::consts::FRAC_PI_2;
                let l = 1.0 / exitance_per_radiance(th.cos(), 1.5, fa);
                2.0 * std::f64::consts::PI * l * th.cos() * th.sin() * std::f64::consts::FRAC_PI_2
                    / n as f64
            })
            .sum();
        assert!((m - 1.0).abs() < 1e-4, "{m}");
        // Near the normal π L overstates M by (1 - F̄) / (1 - F(0)) - 1 ≈ 5.7 %.
        let k0 = exitance_per_radiance(1.0, 1.5, fa) / std::f64::consts::PI;
        assert!((k0 - 0.9460).abs() < 2e-3, "{k0}");
    }

    #[test]
    fn params_derived_quantities() {
        let p = DipoleParams::from_coefficients([2.55, 3.21, 3.77], [0.0011, 0.0024, 0.014], 1.3);
        let ss = p.sigma_s_prime();
        let sa = p.sigma_a();
        assert!((ss[0] - 2.55).abs() < 1e-12 && (sa[2] - 0.014).abs() < 1e-12);
        assert!(p.validate().is_ok());
        let bad = DipoleParams {
            alpha_prime: [1.1, 0.5, 0.5],
            ..p
        };
        assert!(bad.validate().is_err());
    }
}
