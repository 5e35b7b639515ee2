//! The classic dipole of Jensen et al. 2001, one of the two light
//! transports a material's R_d(r) can come from ([`crate::subsurface`]):
//! R_d(r), the total diffuse reflectance R_total(a') of Jensen & Buhler 2002
//! and its f64 inversion, and the virtual laser stripe
//! I_D(d) = ∫ R_d(sqrt(d² + s²)) ds (paper eq. 6) by adaptive quadrature.
//! The smooth boundary's Fresnel terms are in [`crate::fresnel`].
//!
//! Units: mm and mm^-1. R_d is in mm^-2 (exitance per incident flux), I_D in
//! mm^-1 (exitance per incident flux per mm of stripe).

use std::f64::consts::PI;

use crate::error::ModelError;
use crate::quad;

/// Relative index of refraction the paper fits with (after Jensen et al. 2001).
pub const DEFAULT_ETA: f64 = 1.3;

/// Internal diffuse Fresnel reflectance F_dr(eta) (polynomial fit).
pub fn fresnel_diffuse_reflectance(eta: f64) -> f64 {
    -1.440 / (eta * eta) + 0.710 / eta + 0.668 + 0.0636 * eta
}

/// Boundary mismatch A = (1 + F_dr) / (1 - F_dr).
pub fn boundary_a(eta: f64) -> f64 {
    let f_dr = fresnel_diffuse_reflectance(eta);
    (1.0 + f_dr) / (1.0 - f_dr)
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
}
