//! Lights: directional (sun-like, given by its irradiance on a surface facing
//! it), point (radiant intensity), and an HDR environment map in lat-long
//! layout, importance-sampled with a 2D piecewise-constant distribution.
//!
//! Environment convention: z is up; a direction with polar angle theta (from
//! +z) and azimuth phi = atan2(y, x) maps to u = phi / 2pi, v = theta / pi,
//! so the top row of the image is the zenith.

use std::f32::consts::{PI, TAU};
use std::path::Path;

use glam::Vec3;

use crate::distrib::Distribution2D;
use crate::error::RenderError;

/// A light other than the environment.
#[derive(Clone, Debug)]
pub enum Light {
    /// Parallel light arriving from `to_light` (unit), with `irradiance`
    /// (linear RGB) on a surface perpendicular to it.
    Directional { to_light: Vec3, irradiance: Vec3 },
    /// An isotropic point light with radiant `intensity` (per steradian).
    Point { position: Vec3, intensity: Vec3 },
}

/// Incident light at a point from one delta light.
pub struct LightSample {
    /// Unit direction towards the light.
    pub wi: Vec3,
    /// Distance to the light (infinite for directional lights).
    pub dist: f32,
    /// Irradiance on a surface perpendicular to `wi` (no cosine).
    pub e_perp: Vec3,
}

impl Light {
    pub fn sample(&self, p: Vec3) -> LightSample {
        match self {
            Light::Directional {
                to_light,
                irradiance,
            } => LightSample {
                wi: *to_light,
                dist: f32::INFINITY,
                e_perp: *irradiance,
            },
            Light::Point {
                position,
                intensity,
            } => {
                let d = *position - p;
                let dist2 = d.length_squared().max(1e-12);
                let dist = dist2.sqrt();
                LightSample {
                    wi: d / dist,
                    dist,
                    e_perp: *intensity / dist2,
                }
            }
        }
    }
}

/// A lat-long HDR environment map with its sampling distribution.
#[derive(Clone, Debug)]
pub struct EnvMap {
    pub width: usize,
    pub height: usize,
    pub texels: Vec<Vec3>,
    /// Rotation about +z, radians, applied to the map.
    pub rotation: f32,
    dist: Distribution2D,
}

impl EnvMap {
    /// Builds a map from row-major linear RGB radiance (negatives clamped).
    pub fn new(
        width: usize,
        height: usize,
        texels: Vec<Vec3>,
        rotation: f32,
    ) -> Result<EnvMap, RenderError> {
        if width < 2 || height < 2 || texels.len() != width * height {
            return Err(RenderError::Scene(format!(
                "environment map {width}x{height} with {} texels",
                texels.len()
            )));
        }
        if texels.iter().any(|t| !t.is_finite()) {
            return Err(RenderError::Scene(
                "environment map holds NaN or infinite radiance".into(),
            ));
        }
        let texels: Vec<Vec3> = texels.into_iter().map(|t| t.max(Vec3::ZERO)).collect();
        // Weight by sin(theta): rows near the poles cover little solid angle.
        let func: Vec<f32> = (0..height)
            .flat_map(|y| {
                let sin_t = (PI * (y as f32 + 0.5) / height as f32).sin();
                let texels = &texels;
                (0..width).map(move |x| luminance(texels[y * width + x]) * sin_t)
            })
            .collect();
        let dist = Distribution2D::new(&func, width, height);
        Ok(EnvMap {
            width,
            height,
            texels,
            rotation,
            dist,
        })
    }

    /// Reads an EXR lat-long map.
    pub fn load(path: &Path, rotation: f32, scale: f32) -> Result<EnvMap, RenderError> {
        let img = qhm_formats::exr::read_rgb(path)?;
        EnvMap::new(
            img.width,
            img.height,
            img.data
                .into_iter()
                .map(|t| Vec3::from(t) * scale)
                .collect(),
            rotation,
        )
    }

    /// A procedural sky: blue gradient, a bright sun disk with a glow at
    /// `sun` (unit, towards the sun), and a dim brown ground.
    pub fn sky(sun: Vec3, strength: f32) -> EnvMap {
        let sun = sun.normalize_or(Vec3::Z);
        Self::procedural(256, 128, |d| {
            let c = d.dot(sun).clamp(-1.0, 1.0);
            let sky = if d.z >= 0.0 {
                Vec3::new(0.35, 0.55, 1.0).lerp(Vec3::new(0.85, 0.9, 1.0), (1.0 - d.z).powi(3))
            } else {
                Vec3::new(0.25, 0.2, 0.15)
            };
            let glow = Vec3::new(1.0, 0.9, 0.7) * 2.0 * ((c - 1.0) * 12.0).exp();
            let disk = if c > 0.9990 {
                Vec3::new(1.0, 0.95, 0.85) * 400.0
            } else {
                Vec3::ZERO
            };
            (sky * 0.5 + glow + disk) * strength
        })
    }

    /// A photo studio: dim grey walls, a large soft key box, a smaller rim
    /// box behind the object and a floor bounce.
    pub fn studio(strength: f32) -> EnvMap {
        let key = Vec3::new(-0.6, -0.5, 0.62).normalize();
        let rim = Vec3::new(0.5, 0.75, 0.45).normalize();
        Self::procedural(256, 128, |d| {
            let mut l = Vec3::splat(0.08) + Vec3::splat(0.06) * d.z.max(0.0);
            if d.dot(key) > 0.93 {
                l += Vec3::new(1.0, 0.97, 0.92) * 12.0;
            }
            if d.dot(rim) > 0.98 {
                l += Vec3::new(0.9, 0.95, 1.0) * 25.0;
            }
            if d.z < -0.2 {
                l += Vec3::splat(0.1);
            }
            l * strength
        })
    }

    fn procedural(w: usize, h: usize, f: impl Fn(Vec3) -> Vec3) -> EnvMap {
        let texels = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                f(dir_from_uv(
                    (x as f32 + 0.5) / w as f32,
                    (y as f32 + 0.5) / h as f32,
                ))
            })
            .collect();
        EnvMap::new(w, h, texels, 0.0).expect("procedural maps are finite and sized")
    }

    fn uv_of(&self, d: Vec3) -> (f32, f32) {
        let theta = d.z.clamp(-1.0, 1.0).acos();
        let phi = (d.y.atan2(d.x) - self.rotation).rem_euclid(TAU);
        (phi / TAU, theta / PI)
    }

    /// Radiance arriving from direction `d` (unit, pointing away from the scene).
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        let (u, v) = self.uv_of(d);
        let x = ((u * self.width as f32) as usize).min(self.width - 1);
        let y = ((v * self.height as f32) as usize).min(self.height - 1);
        self.texels[y * self.width + x]
    }

    /// Samples a direction proportionally to radiance x sin(theta); returns
    /// (wi, radiance, pdf per solid angle).
    pub fn sample(&self, u0: f32, u1: f32) -> (Vec3, Vec3, f32) {
        let ([u, v], pdf_uv) = self.dist.sample_continuous(u0, u1);
        let sin_t = (v * PI).sin();
        let mut wi = dir_from_uv(u, v);
        wi = rotate_z(wi, self.rotation);
        if sin_t <= 0.0 || pdf_uv <= 0.0 {
            return (wi, Vec3::ZERO, 0.0);
        }
        // Jacobian of (u, v) -> direction: 2 pi^2 sin(theta).
        (wi, self.radiance(wi), pdf_uv / (2.0 * PI * PI * sin_t))
    }

    /// Solid-angle density of [`EnvMap::sample`] for direction `wi`.
    pub fn pdf(&self, wi: Vec3) -> f32 {
        let (u, v) = self.uv_of(wi);
        let sin_t = (v * PI).sin();
        if sin_t <= 0.0 {
            return 0.0;
        }
        self.dist.pdf(u, v) / (2.0 * PI * PI * sin_t)
    }
}

fn rotate_z(d: Vec3, a: f32) -> Vec3 {
    let (s, c) = a.sin_cos();
    Vec3::new(c * d.x - s * d.y, s * d.x + c * d.y, d.z)
}

/// Direction of lat-long coordinates (u, v) in [0, 1)^2, unrotated.
pub fn dir_from_uv(u: f32, v: f32) -> Vec3 {
    let (theta, phi) = (v * PI, u * TAU);
    Vec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

/// Rec. 709 luminance of linear RGB.
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn importance_sampled_irradiance_matches_quadrature() {
        let env = EnvMap::studio(1.0);
        // Irradiance on an upward surface: E = ∫ L cos dω, by dense quadrature...
        let (w, h) = (env.width, env.height);
        let mut exact = Vec3::ZERO;
        for y in 0..h {
            for x in 0..w {
                let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
                let d = dir_from_uv(u, v);
                let dw = (TAU / w as f32) * (PI / h as f32) * (v * PI).sin();
                exact += env.texels[y * w + x] * d.z.max(0.0) * dw;
            }
        }
        // ...and by importance sampling with a stratified grid.
        let n = 256;
        let mut est = Vec3::ZERO;
        for i in 0..n {
            for j in 0..n {
                let (wi, l, pdf) =
                    env.sample((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                if pdf > 0.0 {
                    assert!((pdf - env.pdf(wi)).abs() / pdf < 1e-2);
                    est += l * wi.z.max(0.0) / pdf;
                }
            }
        }
        est /= (n * n) as f32;
        let rel = ((est - exact).length() / exact.length()).abs();
        assert!(rel < 0.02, "est {est} exact {exact}");
    }

    #[test]
    fn rotation_moves_the_sun() {
        let mut env = EnvMap::sky(Vec3::new(1.0, 0.0, 1.0), 1.0);
        let before = env.radiance(Vec3::new(1.0, 0.0, 1.0).normalize());
        env.rotation = PI / 2.0;
        let after = env.radiance(Vec3::new(0.0, 1.0, 1.0).normalize());
        assert!((before - after).length() < 1e-3 * before.length());
        assert!(before.x > 100.0);
    }

    #[test]
    fn nan_map_is_rejected() {
        let t = vec![Vec3::NAN; 8];
        assert!(EnvMap::new(4, 2, t, 0.0).is_err());
    }
}
