//! The rough dielectric boundary of a sample: Trowbridge-Reitz (GGX)
//! microfacets with Smith shadowing-masking and exact Fresnel, after pbrt-v4
//! (`TrowbridgeReitzDistribution`, `DielectricBxDF`).
//!
//! Directions are in the local shading frame: z is the outward surface
//! normal (air above, the medium below); `eta` is n_medium / n_air. As in pbrt,
//! `wo` points back along where the particle came from and `wi` is the new
//! direction; photons carry flux, so they use the importance-mode BTDF (no
//! 1/eta^2 radiance scaling).

use glam::Vec3;
use std::f32::consts::PI;

use crate::rng::Rng;
use crate::walk::unit_circle_from_bits;

/// Whether a BSDF value is for radiance or for flux-carrying particles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransportMode {
    Radiance,
    Importance,
}

#[inline]
fn cos2_theta(w: Vec3) -> f32 {
    w.z * w.z
}
#[inline]
fn tan2_theta(w: Vec3) -> f32 {
    (1.0 - cos2_theta(w)).max(0.0) / cos2_theta(w)
}

/// Unpolarised Fresnel reflectance of a dielectric interface; `cos_theta_i`
/// is measured against the normal on the side of the incident light.
pub fn fr_dielectric(cos_theta_i: f32, eta: f32) -> f32 {
    let (mut c, mut eta) = (cos_theta_i.clamp(-1.0, 1.0), eta);
    if c < 0.0 {
        eta = 1.0 / eta;
        c = -c;
    }
    let sin2_t = (1.0 - c * c) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let r_parl = (eta * c - cos_t) / (eta * c + cos_t);
    let r_perp = (c - eta * cos_t) / (c + eta * cos_t);
    (r_parl * r_parl + r_perp * r_perp) / 2.0
}

/// Refract `wi` about normal `n` (same side as `wi` or flipped); returns the
/// transmitted direction and the relative index actually used.
pub fn refract(wi: Vec3, n: Vec3, eta: f32) -> Option<(Vec3, f32)> {
    let (mut n, mut eta) = (n, eta);
    let mut cos_i = n.dot(wi);
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
        n = -n;
    }
    let sin2_i = (1.0 - cos_i * cos_i).max(0.0);
    let sin2_t = sin2_i / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((-wi / eta + (cos_i / eta - cos_t) * n, eta))
}

#[inline]
pub fn reflect(wo: Vec3, n: Vec3) -> Vec3 {
    -wo + 2.0 * wo.dot(n) * n
}

/// Isotropic Trowbridge-Reitz distribution of microfacet normals.
#[derive(Debug, Clone, Copy)]
pub struct TrowbridgeReitz {
    pub alpha: f32,
}

impl TrowbridgeReitz {
    /// Below this roughness the surface is treated as perfectly smooth.
    pub fn effectively_smooth(&self) -> bool {
        self.alpha < 1e-3
    }

    /// D(wm): density of normals, normalised so that integral D cos = 1.
    pub fn d(&self, wm: Vec3) -> f32 {
        let t2 = tan2_theta(wm);
        if !t2.is_finite() {
            return 0.0;
        }
        let c4 = cos2_theta(wm) * cos2_theta(wm);
        let e = t2 / (self.alpha * self.alpha);
        1.0 / (PI * self.alpha * self.alpha * c4 * (1.0 + e) * (1.0 + e))
    }

    pub fn lambda(&self, w: Vec3) -> f32 {
        let t2 = tan2_theta(w);
        if !t2.is_finite() {
            return 0.0;
        }
        ((1.0 + self.alpha * self.alpha * t2).sqrt() - 1.0) / 2.0
    }

    /// Smith masking of one direction.
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated Smith shadowing-masking.
    pub fn g(&self, wo: Vec3, wi: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// Density of visible normals from `w`; the pdf of `sample_wm`.
    pub fn pdf(&self, w: Vec3, wm: Vec3) -> f32 {
        self.g1(w) / w.z.abs() * self.d(wm) * w.dot(wm).abs()
    }

    /// Sample a visible normal from `w` (Heitz 2018), paired with `pdf`.
    pub fn sample_wm(&self, w: Vec3, u: [f32; 2]) -> Vec3 {
        let a = self.alpha;
        let mut wh = Vec3::new(a * w.x, a * w.y, w.z).normalize();
        if wh.z < 0.0 {
            wh = -wh;
        }
        let t1 = if wh.z < 0.99999 {
            Vec3::Z.cross(wh).normalize()
        } else {
            Vec3::X
        };
        let t2 = wh.cross(t1);
        // uniform disk (polar), warped to the projected hemisphere
        let r = u[0].sqrt();
        // (cos, sin) of 2 pi u[1] from a table, no libm call (< 2e-7 off)
        let (c, s) = unit_circle_from_bits((u[1] * 4_294_967_296.0) as u32);
        let (px, mut py) = (r * c, r * s);
        let h = (1.0 - px * px).max(0.0).sqrt();
        let tt = (1.0 + wh.z) / 2.0;
        py = (1.0 - tt) * h + tt * py;
        let pz = (1.0 - px * px - py * py).max(0.0).sqrt();
        let nh = px * t1 + py * t2 + pz * wh;
        Vec3::new(a * nh.x, a * nh.y, nh.z.max(1e-6)).normalize()
    }

    /// `w` stretched to the frame where the visible normals are those of a
    /// unit hemisphere, on its upper side: what `sample_wm_cap` takes.
    pub fn to_hemisphere(&self, w: Vec3) -> Vec3 {
        let wh = Vec3::new(self.alpha * w.x, self.alpha * w.y, w.z).normalize();
        if wh.z < 0.0 { -wh } else { wh }
    }

    /// Sample a visible normal from `w`, given as `to_hemisphere(w)`, by a
    /// spherical cap (Dupuy and Benyoub 2023): the density `pdf(w, wm)` of
    /// `sample_wm`, from other numbers, in fewer dependent steps.
    #[inline]
    pub fn sample_wm_cap(&self, wh: Vec3, u: [f32; 2]) -> Vec3 {
        self.sample_wm_cap_scaled(wh, 1.0, u).normalize()
    }

    /// `sample_wm_cap` for `wh` scaled by `k` > 0 (unit `wh / k`), before
    /// its normalisation: a vector along wm. The scaled sphere's cap spares
    /// the walls' lobe a normalisation (a square root and a division) on
    /// the chain that every sampled direction waits for.
    #[inline(always)]
    fn sample_wm_cap_scaled(&self, wh: Vec3, k: f32, u: [f32; 2]) -> Vec3 {
        let a = self.alpha;
        // a uniform point on the sphere of radius k's cap z > -wh.z, plus wh
        let z = (1.0 - u[0]) * (k + wh.z) - wh.z;
        let r = (k * k - z * z).max(0.0).sqrt();
        let (c, s) = unit_circle_from_bits((u[1] * 4_294_967_296.0) as u32);
        let h = Vec3::new(r * c + wh.x, r * s + wh.y, z + wh.z);
        Vec3::new(a * h.x, a * h.y, h.z.max(1e-6 * k))
    }
}

/// The lobe of a rough dielectric that returns its masked share to itself
/// (the cell walls': see `crate::cellwalk`), seen from `wo`: density
/// f(wo, wi) |cos wi| / A(wo), A the albedo of `Dielectric::sample_importance`.
/// Sampled as that is (a visible normal, reflection with probability F,
/// else refraction), kept with probability its survival weight
/// G(wo, wi) / G1(wo), drawn again until kept. The numbers that depend on
/// `wo` alone are computed once for all the draws.
#[derive(Debug, Clone, Copy)]
pub struct ResampledLobe {
    bsdf: Dielectric,
    wo: Vec3,
    /// `wo` in the unit-hemisphere frame (`TrowbridgeReitz::to_hemisphere`),
    /// times its length there before normalisation, s_o.
    wh: Vec3,
    /// |cos theta_o| and s_o = sqrt(cos^2 theta_o + alpha^2 sin^2 theta_o):
    /// 1 + 2 Lambda(wo) = s_o / |cos theta_o|.
    z_o: f32,
    s_o: f32,
    inv_eta: f32,
}

impl ResampledLobe {
    pub fn new(bsdf: &Dielectric, wo: Vec3) -> ResampledLobe {
        let a = bsdf.mf.alpha;
        let wh = Vec3::new(a * wo.x, a * wo.y, wo.z);
        ResampledLobe {
            bsdf: *bsdf,
            wo,
            wh: if wo.z < 0.0 { -wh } else { wh },
            z_o: wo.z.abs(),
            s_o: wh.length(),
            inv_eta: 1.0 / bsdf.eta,
        }
    }

    /// One draw from four uniform numbers: `wi` when it is kept, None when
    /// the draw is degenerate or the roulette ends it (draw again).
    #[inline]
    pub fn try_sample(&self, uc: f32, u: [f32; 2], u_keep: f32) -> Option<Vec3> {
        let (wo, a) = (self.wo, self.bsdf.mf.alpha);
        if self.bsdf.mf.effectively_smooth() {
            // delta lobes, weight 1: nothing is masked
            return self.bsdf.sample_importance(wo, uc, u).map(|(wi, _)| wi);
        }
        if wo.z == 0.0 {
            return None;
        }
        // m along the sampled normal, |m|^2 = l: Fresnel's choice is a ratio
        // of forms of one degree in cos theta and cos theta_t, so it needs
        // them only scaled by |m| (no normalisation waits on a square root);
        // the directions need 1 / l, computed alongside
        let m = self.bsdf.mf.sample_wm_cap_scaled(self.wh, self.s_o, u);
        let l = m.length_squared();
        let inv_l = 1.0 / l;
        // |m| cos theta_i, with eta = n_wall / n_air relative to the side wo comes from
        let cm = wo.dot(m);
        let (eta, inv_eta, c) = if cm < 0.0 {
            (self.inv_eta, self.bsdf.eta, -cm)
        } else {
            (self.bsdf.eta, self.inv_eta, cm)
        };
        // |m|^2 sin^2 theta_t; total internal reflection where it reaches |m|^2
        let sin2_t = (l - c * c).max(0.0) * (inv_eta * inv_eta);
        let refracted = if sin2_t >= l {
            None
        } else {
            // |m| cos theta_t
            let cos_t = (l - sin2_t).sqrt();
            // uc >= F = (r_parl^2 + r_perp^2) / 2, with r_parl = a / A and
            // r_perp = b / B, compared without a division
            let (a, aa) = (eta * c - cos_t, eta * c + cos_t);
            let (b, bb) = (c - eta * cos_t, c + eta * cos_t);
            let (a2, aa2, b2, bb2) = (a * a, aa * aa, b * b, bb * bb);
            // (refract: n = m / |m| on wo's side)
            (2.0 * uc * aa2 * bb2 >= a2 * bb2 + b2 * aa2)
                .then(|| -wo * inv_eta + ((c * inv_eta - cos_t) * inv_l * cm.signum()) * m)
        };
        let wi = match refracted {
            Some(wt) if wt.z * wo.z < 0.0 => wt,
            Some(_) => return None,
            None => {
                let wr = -wo + (2.0 * cm * inv_l) * m;
                if wr.z * wo.z <= 0.0 {
                    return None;
                }
                wr
            }
        };
        // kept with probability G / G1 = (1 + k_o) / (k_o + k_i), k = 1 +
        // 2 Lambda = s / |cos theta|: u (s_o z_i + s_i z_o) < (z_o + s_o) z_i,
        // i.e. u s_i z_o < z_i (z_o + s_o (1 - u)), both sides >= 0, squared
        // (no division, no square root)
        let zi = wi.z.abs();
        let s2 = zi * zi + a * a * (1.0 - zi * zi).max(0.0);
        let lhs = u_keep * self.z_o;
        let rhs = zi * (self.z_o + self.s_o * (1.0 - u_keep));
        (lhs * lhs * s2 < rhs * rhs).then_some(wi)
    }
}

/// Bins of the albedo tables over |cos theta|.
const ALBEDO_BINS: usize = 64;
/// Samples per bin of the albedo tables.
const ALBEDO_SAMPLES: usize = 4096;

/// A rough dielectric's single-scattering albedo A(u) (importance mode,
/// what the photon walk keeps per sample), per side and |cos theta| of u,
/// local frame (+z the air). A boundary that returns its masked share to
/// the lobe (the cell walls; a top with `conserve_energy`) sends light
/// arriving from u towards v with density f(u, v) |cos v| / A(u): the
/// photon walk's splats and the camera paths' weights divide by it.
#[derive(Debug, Clone)]
pub struct SingleScatteringAlbedo {
    /// [air side, wall side][bin]: mean at bin centres.
    table: [[f32; ALBEDO_BINS]; 2],
}

impl SingleScatteringAlbedo {
    /// Stratified Monte Carlo, seeded: the same table every render.
    pub fn new(bsdf: &Dielectric) -> SingleScatteringAlbedo {
        let mut table = [[1.0f32; ALBEDO_BINS]; 2];
        if bsdf.mf.effectively_smooth() {
            return SingleScatteringAlbedo { table };
        }
        let mut rng = Rng::new(0x57a1_1a1b, 0);
        for (side, row) in table.iter_mut().enumerate() {
            for (b, a) in row.iter_mut().enumerate() {
                let mu = (b as f32 + 0.5) / ALBEDO_BINS as f32;
                let z = if side == 0 { mu } else { -mu };
                let u = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, z);
                let n = (ALBEDO_SAMPLES as f32).sqrt() as usize;
                let mut sum = 0.0f64;
                for i in 0..n {
                    for j in 0..n {
                        let uv = [
                            (i as f32 + rng.uniform()) / n as f32,
                            (j as f32 + rng.uniform()) / n as f32,
                        ];
                        if let Some((_, weight)) = bsdf.sample_importance(u, rng.uniform(), uv) {
                            sum += weight.min(1.0) as f64;
                        }
                    }
                }
                *a = (sum / (n * n) as f64) as f32;
            }
        }
        SingleScatteringAlbedo { table }
    }

    /// A(u) for a local direction u, linear between bin centres.
    pub fn at(&self, u: Vec3) -> f32 {
        let row = &self.table[(u.z < 0.0) as usize];
        let x = (u.z.abs() * ALBEDO_BINS as f32 - 0.5).clamp(0.0, (ALBEDO_BINS - 1) as f32);
        let i = (x as usize).min(ALBEDO_BINS - 2);
        let f = x - i as f32;
        (row[i] * (1.0 - f) + row[i + 1] * f).max(1e-3)
    }
}

/// A sampled scattering direction with its BSDF value and pdf.
#[derive(Debug, Clone, Copy)]
pub struct BsdfSample {
    pub wi: Vec3,
    pub f: f32,
    pub pdf: f32,
    /// `f |cos wi| / pdf`: the particle's survival weight (<= 1 in importance mode).
    pub weight: f32,
}

/// Rough dielectric interface (pbrt-v4 `DielectricBxDF`).
#[derive(Debug, Clone, Copy)]
pub struct Dielectric {
    pub eta: f32,
    pub mf: TrowbridgeReitz,
}

impl Dielectric {
    pub fn new(eta: f32, roughness_alpha: f32) -> Self {
        Dielectric {
            eta,
            mf: TrowbridgeReitz {
                alpha: roughness_alpha,
            },
        }
    }

    /// Generalised half vector of a pair, facing +z, or None if degenerate.
    fn half_vector(&self, wo: Vec3, wi: Vec3) -> Option<(Vec3, f32, bool)> {
        let (co, ci) = (wo.z, wi.z);
        if co == 0.0 || ci == 0.0 {
            return None;
        }
        let reflect = co * ci > 0.0;
        let etap = if reflect {
            1.0
        } else if co > 0.0 {
            self.eta
        } else {
            1.0 / self.eta
        };
        let wm = wi * etap + wo;
        if wm.length_squared() == 0.0 {
            return None;
        }
        let mut wm = wm.normalize();
        if wm.z < 0.0 {
            wm = -wm;
        }
        // discard back-facing microfacets
        if wm.dot(wi) * ci < 0.0 || wm.dot(wo) * co < 0.0 {
            return None;
        }
        Some((wm, etap, reflect))
    }

    /// f(wo, wi); zero for a smooth interface (delta lobes are only sampled).
    pub fn f(&self, wo: Vec3, wi: Vec3, mode: TransportMode) -> f32 {
        if self.mf.effectively_smooth() {
            return 0.0;
        }
        let Some((wm, etap, reflect)) = self.half_vector(wo, wi) else {
            return 0.0;
        };
        let fr = fr_dielectric(wo.dot(wm), self.eta);
        if reflect {
            self.mf.d(wm) * self.mf.g(wo, wi) * fr / (4.0 * wi.z * wo.z).abs()
        } else {
            let denom = {
                let s = wi.dot(wm) + wo.dot(wm) / etap;
                s * s * wi.z * wo.z
            };
            let mut ft = self.mf.d(wm)
                * (1.0 - fr)
                * self.mf.g(wo, wi)
                * (wi.dot(wm) * wo.dot(wm) / denom).abs();
            if mode == TransportMode::Radiance {
                ft /= etap * etap;
            }
            ft
        }
    }

    /// pdf of `sample_f` choosing `wi` given `wo`.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if self.mf.effectively_smooth() {
            return 0.0;
        }
        let Some((wm, etap, reflect)) = self.half_vector(wo, wi) else {
            return 0.0;
        };
        let r = fr_dielectric(wo.dot(wm), self.eta);
        let t = 1.0 - r;
        if reflect {
            self.mf.pdf(wo, wm) / (4.0 * wo.dot(wm).abs()) * r / (r + t)
        } else {
            let s = wi.dot(wm) + wo.dot(wm) / etap;
            let dwm_dwi = wi.dot(wm).abs() / (s * s);
            self.mf.pdf(wo, wm) * dwm_dwi * t / (r + t)
        }
    }

    /// Sample only the transmitted direction from `wo` (a visible microfacet
    /// normal, then refraction): `(wi, pdf)` with the pdf in solid angle of
    /// `wi`. Used from the camera side to pick where light inside the medium
    /// must come from to reach a camera. None for a smooth interface, at
    /// total internal reflection, or for a degenerate sample.
    pub fn sample_transmission(&self, wo: Vec3, u: [f32; 2]) -> Option<(Vec3, f32)> {
        if self.mf.effectively_smooth() || wo.z == 0.0 {
            return None;
        }
        let wm = self.mf.sample_wm(wo, u);
        let (wi, etap) = refract(wo, wm, self.eta)?;
        if wi.z * wo.z >= 0.0 {
            return None;
        }
        let pdf = self.transmission_pdf(wo, wi, wm, etap);
        (pdf.is_finite() && pdf > 0.0).then_some((wi, pdf))
    }

    /// Visible-normal density of `wm` times the refraction Jacobian dwm/dwi.
    fn transmission_pdf(&self, wo: Vec3, wi: Vec3, wm: Vec3, etap: f32) -> f32 {
        let sden = wi.dot(wm) + wo.dot(wm) / etap;
        self.mf.pdf(wo, wm) * wi.dot(wm).abs() / (sden * sden)
    }

    /// The pdf of `sample_transmission(wo)` returning `wi`.
    pub fn pdf_transmission(&self, wo: Vec3, wi: Vec3) -> f32 {
        if self.mf.effectively_smooth() || wo.z <= 0.0 || wi.z >= 0.0 {
            return 0.0;
        }
        let Some((wm, etap, _)) = self.half_vector(wo, wi) else {
            return 0.0;
        };
        self.transmission_pdf(wo, wi, wm, etap)
    }

    /// What the photon walks need of `sample_f` in importance mode: the
    /// same direction from the same numbers, and the survival weight
    /// f |cos wi| / pdf, which for visible-normal sampling is
    /// G(wo, wi) / G1(wo), without the BSDF value and pdf.
    #[inline]
    pub fn sample_importance(&self, wo: Vec3, uc: f32, u: [f32; 2]) -> Option<(Vec3, f32)> {
        if self.mf.effectively_smooth() {
            return self
                .sample_f(wo, uc, u, TransportMode::Importance)
                .map(|s| (s.wi, s.weight));
        }
        if wo.z == 0.0 {
            return None;
        }
        let wm = self.mf.sample_wm(wo, u);
        let wi = if uc < fr_dielectric(wo.dot(wm), self.eta) {
            let wi = reflect(wo, wm);
            if wi.z * wo.z <= 0.0 {
                return None;
            }
            wi
        } else {
            let (wi, _) = refract(wo, wm, self.eta)?;
            if wi.z * wo.z >= 0.0 || wi.z == 0.0 {
                return None;
            }
            wi
        };
        let lo = self.mf.lambda(wo);
        Some((wi, (1.0 + lo) / (1.0 + lo + self.mf.lambda(wi))))
    }

    /// Sample reflection or transmission, paired with `pdf`.
    pub fn sample_f(
        &self,
        wo: Vec3,
        uc: f32,
        u: [f32; 2],
        mode: TransportMode,
    ) -> Option<BsdfSample> {
        if self.mf.effectively_smooth() {
            let r = fr_dielectric(wo.z, self.eta);
            if uc < r {
                let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                return Some(BsdfSample {
                    wi,
                    f: 0.0,
                    pdf: 0.0,
                    weight: 1.0,
                });
            }
            let (wi, etap) = refract(wo, Vec3::Z, self.eta)?;
            let weight = if mode == TransportMode::Radiance {
                1.0 / (etap * etap)
            } else {
                1.0
            };
            return Some(BsdfSample {
                wi,
                f: 0.0,
                pdf: 0.0,
                weight,
            });
        }
        if wo.z == 0.0 {
            return None;
        }
        let wm = self.mf.sample_wm(wo, u);
        let r = fr_dielectric(wo.dot(wm), self.eta);
        let t = 1.0 - r;
        let s = if uc < r / (r + t) {
            let wi = reflect(wo, wm);
            if wi.z * wo.z <= 0.0 {
                return None;
            }
            let pdf = self.mf.pdf(wo, wm) / (4.0 * wo.dot(wm).abs()) * r / (r + t);
            let f = self.mf.d(wm) * self.mf.g(wo, wi) * r / (4.0 * wi.z * wo.z).abs();
            BsdfSample {
                wi,
                f,
                pdf,
                weight: 0.0,
            }
        } else {
            let (wi, etap) = refract(wo, wm, self.eta)?;
            if wi.z * wo.z >= 0.0 || wi.z == 0.0 {
                return None;
            }
            let sden = wi.dot(wm) + wo.dot(wm) / etap;
            let dwm_dwi = wi.dot(wm).abs() / (sden * sden);
            let pdf = self.mf.pdf(wo, wm) * dwm_dwi * t / (r + t);
            let mut f = t
                * self.mf.d(wm)
                * self.mf.g(wo, wi)
                * (wi.dot(wm) * wo.dot(wm) / (wi.z * wo.z * sden * sden)).abs();
            if mode == TransportMode::Radiance {
                f /= etap * etap;
            }
            BsdfSample {
                wi,
                f,
                pdf,
                weight: 0.0,
            }
        };
        if s.pdf.is_nan() || s.pdf <= 0.0 || !s.f.is_finite() {
            return None;
        }
        Some(BsdfSample {
            weight: s.f * s.wi.z.abs() / s.pdf,
            ..s
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn albedo_table_is_below_one_and_falls_towards_grazing() {
        let a = SingleScatteringAlbedo::new(&Dielectric::new(1.5, 0.3));
        for z in [0.95f32, -0.95] {
            let s = (1.0 - z * z).sqrt();
            let v = a.at(Vec3::new(s, 0.0, z));
            assert!(v > 0.85 && v <= 1.0, "{z} {v}");
        }
        let g = a.at(Vec3::new(0.999, 0.0, 0.04));
        assert!(g < a.at(Vec3::new(0.3, 0.0, 0.95)), "{g}");
        let smooth = SingleScatteringAlbedo::new(&Dielectric::new(1.5, 0.0));
        assert_eq!(smooth.at(Vec3::Z), 1.0);
    }

    fn sph(theta: f32, phi: f32) -> Vec3 {
        Vec3::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    }

    #[test]
    fn fresnel_known_values() {
        // normal incidence: ((eta-1)/(eta+1))^2
        assert!((fr_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        assert!((fr_dielectric(-1.0, 1.3) - (0.3f32 / 2.3).powi(2)).abs() < 1e-6);
        // total internal reflection beyond the critical angle (41.8 deg at 1.5)
        assert_eq!(fr_dielectric(-(50.0f32.to_radians().cos()), 1.5), 1.0);
    }

    #[test]
    fn ggx_projected_area_is_one() {
        // integral of D(wm) cos(theta_m) over the hemisphere = 1
        for alpha in [0.1f32, 0.3, 0.7] {
            let mf = TrowbridgeReitz { alpha };
            let (nt, np) = (2000, 8);
            let mut s = 0.0f64;
            for i in 0..nt {
                let th = (i as f32 + 0.5) / nt as f32 * PI / 2.0;
                let wm = sph(th, 0.0);
                s += (mf.d(wm) * wm.z * th.sin()) as f64
                    * (PI as f64 / 2.0 / nt as f64)
                    * (2.0 * PI as f64);
            }
            let _ = np;
            assert!((s - 1.0).abs() < 5e-3, "alpha {alpha}: {s}");
        }
    }

    #[test]
    fn sample_f_matches_f_and_pdf() {
        let bsdf = Dielectric::new(1.3, 0.3);
        let mut rng = Rng::new(3, 0);
        for wo in [
            sph(0.3, 0.2),
            sph(1.2, 2.0),
            -sph(0.4, 1.0),
            -sph(1.0, -0.5),
        ] {
            for _ in 0..200 {
                let Some(s) = bsdf.sample_f(
                    wo,
                    rng.uniform(),
                    [rng.uniform(), rng.uniform()],
                    TransportMode::Importance,
                ) else {
                    continue;
                };
                let f = bsdf.f(wo, s.wi, TransportMode::Importance);
                let pdf = bsdf.pdf(wo, s.wi);
                assert!((f - s.f).abs() <= 1e-3 * f.max(1.0), "f {f} vs {}", s.f);
                assert!(
                    (pdf - s.pdf).abs() <= 1e-3 * pdf.max(1.0),
                    "pdf {pdf} vs {}",
                    s.pdf
                );
                assert!(s.weight <= 1.0 + 1e-4, "importance weight {}", s.weight);
            }
        }
    }

    #[test]
    fn sample_importance_is_sample_f_in_importance_mode() {
        let mut rng = Rng::new(4, 0);
        for bsdf in [Dielectric::new(1.5, 0.3), Dielectric::new(1.0 / 1.3, 0.6)] {
            let (mut same, mut n) = (0, 0);
            for k in 0..4000 {
                let wo = sph(1.55 * rng.uniform(), 6.0 * rng.uniform());
                let wo = if k % 2 == 0 { wo } else { -wo };
                let (uc, u) = (rng.uniform(), [rng.uniform(), rng.uniform()]);
                let a = bsdf.sample_f(wo, uc, u, TransportMode::Importance);
                let b = bsdf.sample_importance(wo, uc, u);
                n += 1;
                match (a, b) {
                    (Some(a), Some((wi, w))) => {
                        assert!((a.wi - wi).length() < 1e-6, "{:?} vs {wi:?}", a.wi);
                        assert!((a.weight - w).abs() < 1e-4, "{} vs {w}", a.weight);
                        same += 1;
                    }
                    (None, None) => same += 1,
                    _ => {}
                }
            }
            // only degenerate samples (a zero pdf in sample_f) may differ
            assert!(same as f64 >= 0.999 * n as f64, "{same} of {n}");
        }
    }

    #[test]
    fn pdf_integrates_to_at_most_one() {
        // sum over all wi of pdf dwi: 1 minus the mass of invalid samples
        let bsdf = Dielectric::new(1.3, 0.25);
        for wo in [sph(0.2, 0.0), -sph(0.5, 0.0)] {
            let (nt, np) = (600, 240);
            let mut s = 0.0f64;
            for i in 0..nt {
                let th = (i as f32 + 0.5) / nt as f32 * PI;
                for j in 0..np {
                    let ph = (j as f32 + 0.5) / np as f32 * 2.0 * PI;
                    let wi = sph(th, ph);
                    s += bsdf.pdf(wo, wi) as f64 * th.sin() as f64;
                }
            }
            s *= (PI as f64 / nt as f64) * (2.0 * PI as f64 / np as f64);
            assert!(s > 0.9 && s < 1.02, "wo {wo:?}: {s}");
        }
    }

    #[test]
    fn transmitted_energy_matches_sampling() {
        // furnace for the NEE estimator: the integral of f |cos| over the
        // outside hemisphere equals the expected survival weight of sampled
        // transmissions, so splatted and walked light agree
        let bsdf = Dielectric::new(1.3, 0.3);
        let wo = -sph(0.35, 0.7); // a photon arriving from inside
        let (nt, np) = (800, 240);
        let mut quad = 0.0f64;
        for i in 0..nt {
            let th = (i as f32 + 0.5) / nt as f32 * PI / 2.0;
            for j in 0..np {
                let ph = (j as f32 + 0.5) / np as f32 * 2.0 * PI;
                let wi = sph(th, ph);
                quad += (bsdf.f(wo, wi, TransportMode::Importance) * wi.z * th.sin()) as f64;
            }
        }
        quad *= (PI as f64 / 2.0 / nt as f64) * (2.0 * PI as f64 / np as f64);
        let mut rng = Rng::new(5, 1);
        let n = 400_000;
        let mut mc = 0.0f64;
        for _ in 0..n {
            if let Some(s) = bsdf.sample_f(
                wo,
                rng.uniform(),
                [rng.uniform(), rng.uniform()],
                TransportMode::Importance,
            ) && s.wi.z > 0.0
            {
                mc += s.weight as f64;
            }
        }
        mc /= n as f64;
        assert!(
            (quad - mc).abs() < 0.01,
            "quadrature {quad} vs sampled {mc}"
        );
        // roughly 1 - F at normal-ish incidence from inside (F ~ 0.017)
        assert!(quad > 0.8 && quad < 1.0, "{quad}");
    }

    /// Histogram of the directions a wall lobe keeps, over (cos theta_i,
    /// azimuth from wo's) in 16 x 8 bins, from `n` draws of `draw`.
    fn lobe_histogram(n: usize, mut draw: impl FnMut() -> Option<Vec3>, wo: Vec3) -> Vec<f64> {
        let mut h = vec![0.0f64; 16 * 8];
        let phi_o = wo.y.atan2(wo.x);
        for _ in 0..n {
            let Some(wi) = draw() else { continue };
            let i = (((wi.z + 1.0) * 8.0) as usize).min(15);
            let dphi = (wi.y.atan2(wi.x) - phi_o).rem_euclid(2.0 * PI);
            let j = ((dphi / (2.0 * PI) * 8.0) as usize).min(7);
            h[i * 8 + j] += 1.0;
        }
        h
    }

    /// Chi-square per degree of freedom of two histograms of equal totals.
    fn chi2_per_dof(a: &[f64], b: &[f64]) -> f64 {
        let (mut chi2, mut dof) = (0.0, 0);
        for (x, y) in a.iter().zip(b) {
            if x + y > 20.0 {
                chi2 += (x - y) * (x - y) / (x + y);
                dof += 1;
            }
        }
        chi2 / (dof.max(2) - 1) as f64
    }

    /// The resampled lobe (spherical caps, no divisions in the roulette)
    /// against sample_importance with Russian roulette drawn again until a
    /// direction survives (what the walls did before), from both sides;
    /// and the comparison fails for a wall of another index.
    #[test]
    fn resampled_lobe_matches_sample_importance_with_roulette() {
        let bsdf = Dielectric::new(1.5, 0.3);
        let reference = |wo: Vec3, rng: &mut Rng| {
            (0..64).find_map(|_| {
                match bsdf.sample_importance(wo, rng.uniform(), [rng.uniform(), rng.uniform()]) {
                    Some((wi, w)) if w >= 1.0 || rng.uniform() < w => Some(wi),
                    _ => None,
                }
            })
        };
        let lobe_draw = |lobe: &ResampledLobe, rng: &mut Rng| {
            (0..64).find_map(|_| {
                lobe.try_sample(rng.uniform(), [rng.uniform(), rng.uniform()], rng.uniform())
            })
        };
        let n = 200_000;
        for (k, wo) in [
            sph(0.2, 0.3),
            sph(1.3, 2.0),
            -sph(0.5, 1.0),
            -sph(1.4, -0.7),
        ]
        .into_iter()
        .enumerate()
        {
            let mut rng = Rng::new(11, k as u64);
            let a = lobe_histogram(n, || reference(wo, &mut rng), wo);
            let lobe = ResampledLobe::new(&bsdf, wo);
            let b = lobe_histogram(n, || lobe_draw(&lobe, &mut rng), wo);
            let c = chi2_per_dof(&a, &b);
            assert!(c < 1.5, "wo {wo:?}: chi2/dof {c}");
            // the test can fail: a wall of index 1.3 differs
            let other = ResampledLobe::new(&Dielectric::new(1.3, 0.3), wo);
            let b = lobe_histogram(n, || lobe_draw(&other, &mut rng), wo);
            let c = chi2_per_dof(&a, &b);
            assert!(c > 3.0, "wo {wo:?}: index 1.3 passes, chi2/dof {c}");
        }
    }

    #[test]
    fn cap_and_heitz_visible_normals_agree() {
        // the same density pdf(w, wm), binned over (cos theta_m, azimuth)
        let mf = TrowbridgeReitz { alpha: 0.4 };
        let mut rng = Rng::new(12, 0);
        for w in [sph(0.3, 0.5), sph(1.45, -1.0), -sph(0.8, 2.5)] {
            let n = 200_000;
            let a = lobe_histogram(
                n,
                || Some(mf.sample_wm(w, [rng.uniform(), rng.uniform()])),
                w,
            );
            let wh = mf.to_hemisphere(w);
            let b = lobe_histogram(
                n,
                || Some(mf.sample_wm_cap(wh, [rng.uniform(), rng.uniform()])),
                w,
            );
            let c = chi2_per_dof(&a, &b);
            assert!(c < 1.5, "w {w:?}: chi2/dof {c}");
        }
    }
}
