//! A pinhole camera: eye, look-at target, up vector and vertical field of view.

use glam::Vec3;

use crate::bvh::Ray;

#[derive(Clone, Debug)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Vertical field of view, radians.
    pub fov_y: f32,
}

impl Camera {
    /// A camera at `eye` looking at `target` with z up.
    pub fn look_at(eye: Vec3, target: Vec3, fov_y: f32) -> Camera {
        Camera {
            eye,
            target,
            up: Vec3::Z,
            fov_y,
        }
    }

    /// The ray through film position (x, y) in pixels (origin top left) of
    /// a `width` x `height` image.
    pub fn ray(&self, x: f32, y: f32, width: u32, height: u32) -> Ray {
        let fwd = (self.target - self.eye).normalize();
        // If up is parallel to the view, pick any perpendicular.
        let right = fwd
            .cross(self.up)
            .try_normalize()
            .unwrap_or_else(|| fwd.any_orthonormal_vector());
        let up = right.cross(fwd);
        let tan = (self.fov_y * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let sx = (2.0 * x / width as f32 - 1.0) * tan * aspect;
        let sy = (1.0 - 2.0 * y / height as f32) * tan;
        Ray {
            o: self.eye,
            d: (fwd + right * sx + up * sy).normalize(),
        }
    }
}
