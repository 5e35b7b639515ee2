//! The smooth boundary's shapes, for a material whose f and f_v are the
//! smooth surface's idealisation ([`crate::Material::smooth_boundary`]) and
//! for the plain-dipole modes: on entry g(cos θ_i), the rise of the
//! half-space's diffuse reflectance with the angle of incidence, and on exit
//! S(cos θ_o), the emergent radiance's shape per unit exitance.

use glam::Vec3;

/// g(cos θ_i) per channel: the half-space's diffuse reflectance for a beam
/// incident at θ_i over that at normal incidence, both per entered flux
/// (`qhm_model::radiative_transfer::oblique_reflectance` at the refracted cosine).
/// The irradiance that enters is multiplied by it. 1 at the normal,
/// rising towards grazing incidence, more for a lower albedo.
#[derive(Clone, Debug)]
pub struct EntryShape {
    values: Vec<Vec3>,
}

impl EntryShape {
    const N: usize = 17;

    pub fn new(d: &qhm_model::DipoleParams) -> EntryShape {
        // Tabulated in the refracted cosine mu0, from the critical angle's
        // (grazing incidence) to 1, where g is smooth.
        let mu_c = (1.0 - 1.0 / (d.eta * d.eta)).max(0.0).sqrt();
        let mu0: Vec<f64> = (0..Self::N)
            .map(|k| mu_c + (1.0 - mu_c) * k as f64 / (Self::N - 1) as f64)
            .chain(std::iter::once(1.0))
            .collect();
        let r: Vec<Vec<f64>> = (0..3)
            .map(|c| {
                qhm_model::radiative_transfer::oblique_reflectance(d.eta, d.alpha_prime[c], &mu0)
            })
            .collect();
        let g = |c: usize, k: usize| {
            let v = r[c][k] / r[c][Self::N];
            if v.is_finite() { v as f32 } else { 1.0 }
        };
        EntryShape {
            values: (0..Self::N)
                .map(|k| Vec3::new(g(0, k), g(1, k), g(2, k)))
                .collect(),
        }
        .with_mu_c(mu_c as f32)
    }

    fn with_mu_c(mut self, mu_c: f32) -> EntryShape {
        self.values.push(Vec3::splat(mu_c));
        self
    }

    /// g at the cosine of incidence `cos_i` outside (refracted with eta).
    #[inline]
    pub fn eval(&self, cos_i: f32, eta: f32) -> Vec3 {
        let n = self.values.len() - 1;
        let mu_c = self.values[n].x;
        let s2 = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
        let mu0 = (1.0 - s2).max(0.0).sqrt();
        let x = ((mu0 - mu_c) / (1.0 - mu_c)).clamp(0.0, 1.0) * (n - 1) as f32;
        let i = (x as usize).min(n - 2);
        let t = x - i as f32;
        self.values[i] * (1.0 - t) + self.values[i + 1] * t
    }
}

/// S(cos θ_o) per channel: pi times the radiance the model's light
/// transport sends out at θ_o per unit exitance (`ProfileModel::
/// exitance_per_radiance`: for radiative transfer the emergent radiance of
/// the half-space, for the dipole the normalised Fresnel shape). ∫ S cos dw
/// / pi = 1, so the exitance Σ R_d E A is kept; S = 1 is Lambertian. It
/// falls to 0 at grazing (Fresnel) and is above 1 near the normal.
#[derive(Clone, Debug)]
pub struct ExitShape {
    values: Vec<Vec3>,
}

impl ExitShape {
    const N: usize = 129;

    pub fn new(d: &qhm_model::DipoleParams) -> ExitShape {
        let cos: Vec<f64> = (0..Self::N)
            .map(|k| k as f64 / (Self::N - 1) as f64)
            .collect();
        let per: Vec<Vec<f64>> = (0..3)
            .map(|c| d.model.exitance_per_radiance(d.alpha_prime[c], d.eta, &cos))
            .collect();
        let s = |v: f64| {
            let x = std::f64::consts::PI / v;
            if x.is_finite() {
                x.max(0.0) as f32
            } else {
                0.0
            }
        };
        ExitShape {
            values: (0..Self::N)
                .map(|k| Vec3::new(s(per[0][k]), s(per[1][k]), s(per[2][k])))
                .collect(),
        }
    }

    #[inline]
    pub fn eval(&self, cos: f32) -> Vec3 {
        let x = cos.clamp(0.0, 1.0) * (Self::N - 1) as f32;
        let i = (x as usize).min(Self::N - 2);
        let t = x - i as f32;
        self.values[i] * (1.0 - t) + self.values[i + 1] * t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_shape_keeps_the_exitance_and_falls_to_grazing() {
        for name in ["skin1", "marble"] {
            let mut d = crate::materials::preset(name).unwrap();
            for model in [
                qhm_model::ProfileModel::Dipole,
                qhm_model::ProfileModel::Transport,
            ] {
                d.model = model;
                let s = ExitShape::new(&d);
                // ∫ S cos dw / pi = 2 ∫ S(mu) mu dmu = 1.
                let n = 2000;
                let mut sum = Vec3::ZERO;
                for k in 0..n {
                    let mu = (k as f32 + 0.5) / n as f32;
                    sum += s.eval(mu) * (2.0 * mu / n as f32);
                }
                assert!(
                    (sum - Vec3::ONE).abs().max_element() < 0.01,
                    "{name} {model:?}: {sum}"
                );
                let (normal, grazing) = (s.eval(1.0), s.eval(0.02));
                assert!(
                    normal.min_element() > 0.95 && grazing.max_element() < 0.5,
                    "{name} {model:?}: {normal} {grazing}"
                );
            }
        }
    }

    #[test]
    fn entry_shape_is_one_at_the_normal_and_rises_obliquely() {
        let d = crate::materials::preset("skin1").unwrap();
        let g = EntryShape::new(&d);
        assert!((g.eval(1.0, 1.3) - Vec3::ONE).abs().max_element() < 1e-4);
        let grazing = g.eval(0.05, 1.3);
        // Lower albedo (blue, a' 0.68) rises most.
        assert!(grazing.z > grazing.x && grazing.x > 1.05, "{grazing}");
    }
}
