//! The smooth dielectric boundary of a sample: Fresnel reflectance and what
//! follows from it (the hemispherical average, the share of a normal beam
//! that enters, the entrance ratio T(θ)/T(0), and the exitance per radiance
//! of light diffusing out). The dipole, radiative transfer, the fit and the
//! renderer all use these.

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

#[cfg(test)]
mod tests {
    use super::*;

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
}
