//! The camera model: pinhole with two radial distortion terms (k1, k2) and a
//! pose (Zhang 1999; the same convention as OpenCV).
//!
//! World -> camera: X_c = R X_w + t, R from the Rodrigues vector `rotation`.
//! The camera looks along +z_c, x_c to the right, y_c down the image.
//! x = X_c/Z_c, r^2 = x^2 + y^2, d = 1 + k1 r^2 + k2 r^4, u = fx x d + cx, v = fy y d + cy.

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

/// Intrinsic parameters and radial distortion, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
}

impl Intrinsics {
    /// Normalised image coordinates -> distorted pixel.
    pub fn distort_to_pixel(&self, x: DVec2) -> DVec2 {
        let r2 = x.length_squared();
        let d = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        DVec2::new(self.fx * x.x * d + self.cx, self.fy * x.y * d + self.cy)
    }

    /// Pixel -> undistorted normalised coordinates (fixed-point iteration, converges
    /// for the mild distortion of long lenses).
    pub fn pixel_to_normalised(&self, p: DVec2) -> DVec2 {
        let xd = DVec2::new((p.x - self.cx) / self.fx, (p.y - self.cy) / self.fy);
        if self.k1 == 0.0 && self.k2 == 0.0 {
            return xd;
        }
        let mut x = xd;
        for _ in 0..20 {
            let r2 = x.length_squared();
            let d = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
            let nx = xd / d;
            let done = (nx - x).length_squared() < 1e-24;
            x = nx;
            if done {
                break;
            }
        }
        x
    }
}

/// A calibrated camera: intrinsics and pose (world -> camera).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub intrinsics: Intrinsics,
    /// Rodrigues vector of R (world -> camera), radians.
    pub rotation: [f64; 3],
    /// t in X_c = R X_w + t, mm.
    pub translation: [f64; 3],
}

impl CameraModel {
    pub fn rotation_matrix(&self) -> DMat3 {
        rodrigues(DVec3::from(self.rotation))
    }

    /// World point -> camera frame.
    pub fn to_camera(&self, pw: DVec3) -> DVec3 {
        self.rotation_matrix() * pw + DVec3::from(self.translation)
    }

    /// World point -> pixel; None behind the camera.
    pub fn project(&self, pw: DVec3) -> Option<DVec2> {
        let pc = self.to_camera(pw);
        if pc.z <= 1e-9 {
            return None;
        }
        Some(
            self.intrinsics
                .distort_to_pixel(DVec2::new(pc.x / pc.z, pc.y / pc.z)),
        )
    }

    /// Centre of projection in the world frame, mm.
    pub fn centre(&self) -> DVec3 {
        -(self.rotation_matrix().transpose() * DVec3::from(self.translation))
    }

    /// World-frame ray direction (unit) through a pixel.
    pub fn ray(&self, pixel: DVec2) -> DVec3 {
        let x = self.intrinsics.pixel_to_normalised(pixel);
        (self.rotation_matrix().transpose() * DVec3::new(x.x, x.y, 1.0)).normalize()
    }

    /// A camera at `eye` looking at `target`, image "up" towards `up`.
    pub fn look_at(eye: DVec3, target: DVec3, up: DVec3, intrinsics: Intrinsics) -> Self {
        let z = (target - eye).normalize();
        let x = z.cross(up).normalize();
        let y = z.cross(x);
        // Rows of R are the camera axes in world coordinates.
        let r = DMat3::from_cols(x, y, z).transpose();
        let t = -(r * eye);
        CameraModel {
            intrinsics,
            rotation: rodrigues_inv(r).to_array(),
            translation: t.to_array(),
        }
    }
}

/// Rodrigues vector -> rotation matrix.
pub fn rodrigues(r: DVec3) -> DMat3 {
    let theta = r.length();
    if theta < 1e-12 {
        // First order: I + [r]x.
        return DMat3::from_cols(
            DVec3::new(1.0, r.z, -r.y),
            DVec3::new(-r.z, 1.0, r.x),
            DVec3::new(r.y, -r.x, 1.0),
        );
    }
    DMat3::from_axis_angle(r / theta, theta)
}

/// Rotation matrix -> Rodrigues vector.
pub fn rodrigues_inv(m: DMat3) -> DVec3 {
    let q = glam::DQuat::from_mat3(&m).normalize();
    let (axis, angle) = q.to_axis_angle();
    if angle.abs() < 1e-15 {
        DVec3::ZERO
    } else {
        axis * angle
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intr() -> Intrinsics {
        Intrinsics {
            fx: 5000.0,
            fy: 5010.0,
            cx: 512.0,
            cy: 384.0,
            k1: -0.3,
            k2: 0.5,
        }
    }

    #[test]
    fn rodrigues_round_trip() {
        for r in [
            DVec3::new(0.1, -0.2, 0.3),
            DVec3::new(3.0, 0.1, 0.0),
            DVec3::ZERO,
        ] {
            let back = rodrigues_inv(rodrigues(r));
            assert!((back - r).length() < 1e-9, "{r} -> {back}");
        }
    }

    #[test]
    fn look_at_centres_the_target_and_undistort_inverts() {
        let cam =
            CameraModel::look_at(DVec3::new(300.0, 0.0, 300.0), DVec3::ZERO, DVec3::Z, intr());
        let p = cam.project(DVec3::ZERO).unwrap();
        assert!((p - DVec2::new(512.0, 384.0)).length() < 1e-9);
        assert!((cam.centre() - DVec3::new(300.0, 0.0, 300.0)).length() < 1e-9);
        let q = cam.project(DVec3::new(20.0, 30.0, 0.0)).unwrap();
        let ray = cam.ray(q);
        let want = (DVec3::new(20.0, 30.0, 0.0) - cam.centre()).normalize();
        assert!((ray - want).length() < 1e-9);
        // Image up is world +z: a point above the target appears higher (smaller v).
        assert!(cam.project(DVec3::new(0.0, 0.0, 10.0)).unwrap().y < 384.0);
    }
}
