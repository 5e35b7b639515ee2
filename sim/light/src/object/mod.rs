//! Ground truth for any object: Monte Carlo light transport through a
//! closed triangle mesh whose inside is filled with a sample's volume (the
//! sample's material description tiled in 3D), bounded by the sample's
//! dielectric, seen by a pinhole camera under directional and point lights
//! and an environment map. No diffusion model anywhere (DESIGN.md
//! principle 2).
//!
//! Main types: [`ObjectMesh`] (triangles with per-vertex normals),
//! [`PinholeCamera`], [`DeltaLight`], [`EnvImage`], [`ObjectScene`];
//! [`render_object`] returns an [`ObjectImage`]: the per-pixel radiance
//! estimate and the variance of that estimate.
//!
//! Camera model, light units and environment-map convention are those of
//! qhm's renderer: film position (x, y) in pixels from the top left, pixel
//! values the mean radiance over the pixel; a directional light is given by
//! its irradiance on a surface facing it, a point light by its radiant
//! intensity; the environment is a lat-long map with z up (u = phi / 2 pi,
//! v = theta / pi, nearest texel, rotated about z). The estimator is in
//! [`integrator`]; a cellular sample's (air cells with refracting walls,
//! the lattice tiled in object space, pores open where cells cut the
//! surface) in `cellular`.

pub mod bvh;
mod cellular;
pub mod integrator;

use glam::Vec3;

use crate::sample::SampleDesc;

pub use integrator::{ObjectImage, ObjectStats, RenderOptions, render_object};

/// Errors of an object render.
#[derive(Debug, thiserror::Error)]
pub enum ObjectError {
    /// The mesh has no triangles, or bad indices or values.
    #[error("object mesh: {0}")]
    Mesh(String),
    /// A render setting out of range.
    #[error("object render: {0}")]
    Settings(String),
    /// The sample cannot fill an object (e.g. a calibration target).
    #[error("object sample: {0}")]
    Sample(String),
}

/// A closed triangle mesh in mm.
#[derive(Debug, Clone)]
pub struct ObjectMesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex unit normals (shading normals); a zero vector means "use
    /// the face normal".
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl ObjectMesh {
    /// Checks indices, finiteness and that something is there.
    pub fn validate(&self) -> Result<(), ObjectError> {
        let bad = |m: String| Err(ObjectError::Mesh(m));
        if self.triangles.is_empty() {
            return bad("no triangles".into());
        }
        if self.normals.len() != self.positions.len() {
            return bad(format!(
                "{} normals for {} vertices",
                self.normals.len(),
                self.positions.len()
            ));
        }
        if !self.positions.iter().all(|p| p.is_finite())
            || !self.normals.iter().all(|n| n.is_finite())
        {
            return bad("a vertex position or normal is not finite".into());
        }
        let n = self.positions.len() as u32;
        if let Some(t) = self.triangles.iter().find(|t| t.iter().any(|&i| i >= n)) {
            return bad(format!("triangle {t:?} indexes past {n} vertices"));
        }
        Ok(())
    }

    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Unit geometric normal (winding order; orientation is not relied on).
    pub fn face_normal(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(c - a).normalize_or_zero()
    }

    /// Interpolated shading normal at barycentrics (b1, b2), or the face
    /// normal where the vertex normals are missing or cancel.
    pub fn shading_normal(&self, t: usize, b1: f32, b2: f32) -> Vec3 {
        let [i, j, k] = self.triangles[t].map(|i| i as usize);
        let n = self.normals[i] * (1.0 - b1 - b2) + self.normals[j] * b1 + self.normals[k] * b2;
        let fn_ = self.face_normal(t);
        match n.try_normalize() {
            Some(n) if self.normals[i] != Vec3::ZERO => {
                // agree with the winding's face normal (flipped together later)
                if n.dot(fn_) < 0.0 { -n } else { n }
            }
            _ => fn_,
        }
    }

    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }
}

/// A pinhole camera (qhm-render's `Camera`): eye, look-at target, up, vertical
/// field of view in radians.
#[derive(Debug, Clone, Copy)]
pub struct PinholeCamera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub fov_y: f32,
}

impl PinholeCamera {
    /// Unit direction of the ray through film position (x, y) in pixels
    /// (origin top left) of a `width` x `height` image.
    pub fn ray_dir(&self, x: f32, y: f32, width: u32, height: u32) -> Vec3 {
        let fwd = (self.target - self.eye).normalize();
        let right = fwd
            .cross(self.up)
            .try_normalize()
            .unwrap_or_else(|| fwd.any_orthonormal_vector());
        let up = right.cross(fwd);
        let tan = (self.fov_y * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let sx = (2.0 * x / width as f32 - 1.0) * tan * aspect;
        let sy = (1.0 - 2.0 * y / height as f32) * tan;
        (fwd + right * sx + up * sy).normalize()
    }
}

/// A light other than the environment (qhm-render's `Light`).
#[derive(Debug, Clone, Copy)]
pub enum DeltaLight {
    /// Parallel light arriving from `to_light` (unit), with `irradiance` on a
    /// surface facing it.
    Directional { to_light: Vec3, irradiance: Vec3 },
    /// Isotropic point light of radiant `intensity` (per steradian).
    Point { position: Vec3, intensity: Vec3 },
}

impl DeltaLight {
    /// (unit direction towards the light, distance, irradiance facing it) at `x`.
    pub fn at(&self, x: Vec3) -> (Vec3, f32, Vec3) {
        match *self {
            DeltaLight::Directional {
                to_light,
                irradiance,
            } => (to_light, f32::INFINITY, irradiance),
            DeltaLight::Point {
                position,
                intensity,
            } => {
                let d = position - x;
                let r2 = d.length_squared().max(1e-12);
                (d / r2.sqrt(), r2.sqrt(), intensity / r2)
            }
        }
    }
}

/// A lat-long environment map of linear RGB radiance (qhm-render's
/// `EnvMap` convention), row-major, top row the zenith.
#[derive(Debug, Clone)]
pub struct EnvImage {
    pub width: usize,
    pub height: usize,
    pub texels: Vec<Vec3>,
    /// Rotation about +z, radians.
    pub rotation: f32,
}

impl EnvImage {
    /// Radiance arriving from direction `d` (unit, pointing away from the scene).
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        use std::f32::consts::{PI, TAU};
        let theta = d.z.clamp(-1.0, 1.0).acos();
        let phi = (d.y.atan2(d.x) - self.rotation).rem_euclid(TAU);
        let x = ((phi / TAU * self.width as f32) as usize).min(self.width - 1);
        let y = ((theta / PI * self.height as f32) as usize).min(self.height - 1);
        self.texels[y * self.width + x]
    }
}

/// Everything rendered: the object, what fills it, camera and lights.
#[derive(Debug, Clone)]
pub struct ObjectScene {
    pub mesh: ObjectMesh,
    pub sample: SampleDesc,
    pub camera: PinholeCamera,
    pub lights: Vec<DeltaLight>,
    pub env: Option<EnvImage>,
    /// Show the environment behind the object (else black).
    pub env_visible: bool,
}

#[cfg(test)]
mod tests;
