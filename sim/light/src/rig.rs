//! The rig as it really is: the nominal placements of `hardware` plus seeded
//! small errors that calibration has to find (camera poses, intrinsics and
//! distortion, lamp directions and colours, laser plane angle, turntable axis).
//!
//! Frame (hardware/src/lib.rs): origin at the turntable centre, z up, the
//! sample top is z = 0, the camera arc lies at azimuth 0, the light arc at
//! arc angle 0 lies at azimuth `light_arc_azimuth0` (pi). Angles in radians,
//! lengths in mm. Everything here is serde so tests can compare recovered
//! against true values.

use glam::{DMat3, DVec3};
use hardware::{LASERS, NOMINAL_GEOMETRY};
use serde::{Deserialize, Serialize};

use crate::rng::Rng;
use crate::sensor::Response;

/// One camera's true pose, intrinsics and sensor colour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraTruth {
    /// Centre of projection in the world frame, mm.
    pub position: [f64; 3],
    /// World-to-camera rotation, rows = camera x (right), y (down), z (forward).
    pub rotation: [[f64; 3]; 3],
    /// Focal lengths in pixels at full resolution.
    pub focal_px: [f64; 2],
    /// Principal point in pixels at full resolution.
    pub principal_px: [f64; 2],
    /// Radial distortion: x_d = x (1 + k1 r^2 + k2 r^4), r in normalised coordinates.
    pub k1: f64,
    pub k2: f64,
    pub width: u32,
    pub height: u32,
    /// Per-channel sensor gain relative to a nominal camera (relative colour calibration).
    pub colour_gain: [f64; 3],
    /// The camera's response curve.
    pub response: Response,
    pub used: bool,
}

impl CameraTruth {
    pub fn rotation_mat(&self) -> DMat3 {
        DMat3::from_cols_array_2d(&self.rotation).transpose()
    }
    pub fn position_vec(&self) -> DVec3 {
        DVec3::from_array(self.position)
    }

    /// Project a world point to full-resolution pixel coordinates (u right,
    /// v down); None behind the camera.
    pub fn project(&self, p: DVec3) -> Option<[f64; 2]> {
        let pc = self.rotation_mat() * (p - self.position_vec());
        if pc.z <= 0.0 {
            return None;
        }
        let (x, y) = (pc.x / pc.z, pc.y / pc.z);
        let r2 = x * x + y * y;
        let d = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        Some([
            self.focal_px[0] * x * d + self.principal_px[0],
            self.focal_px[1] * y * d + self.principal_px[1],
        ])
    }
}

/// A lamp: a directional source at the sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LampTruth {
    /// Unit vector towards the lamp with the light arc at angle 0.
    pub direction: [f64; 3],
    /// Irradiance on a surface facing the lamp, W m^-2 per RGB channel.
    pub irradiance: [f64; 3],
    pub used: bool,
}

/// The laser unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserTruth {
    /// Distance from the galvo mirror to the origin, mm.
    pub distance: f64,
    /// True minus nominal elevation of the laser plane at galvo 0 (the
    /// "laser plane angle" error calibration finds), radians.
    pub elevation_error: f64,
    /// Galvo zero offset, radians of beam deflection.
    pub galvo_offset: f64,
    /// Length of the stripe on the reference plane, mm.
    pub stripe_length: f64,
    /// Optical power at full drive per channel (red, green, blue laser), W.
    pub power_w: [f64; 3],
}

/// The whole rig as it is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigTruth {
    pub cameras: Vec<CameraTruth>,
    pub lamps: Vec<LampTruth>,
    pub laser: LaserTruth,
    /// Unit turntable rotation axis (nominally +z).
    pub turntable_axis: [f64; 3],
    /// Light-arc azimuth at arc angle 0.
    pub light_arc_azimuth0: f64,
    /// The seed that made the perturbations (None: nominal rig).
    pub seed: Option<u64>,
}

/// Nominal lamp irradiance, W m^-2 per channel (a warm halogen white).
pub const NOMINAL_LAMP_IRRADIANCE: [f64; 3] = [1.0, 0.85, 0.6];

fn look_at(position: DVec3) -> DMat3 {
    let forward = (-position).normalize();
    // Cameras sit on the arc at azimuth 0: image right is world +y for all.
    let right = DVec3::Y;
    let right = (right - forward * forward.dot(right)).normalize();
    let down = forward.cross(right);
    DMat3::from_cols(right, down, forward).transpose()
}

fn rows(m: DMat3) -> [[f64; 3]; 3] {
    m.transpose().to_cols_array_2d()
}

fn spherical(elevation: f64, azimuth: f64) -> DVec3 {
    DVec3::new(
        elevation.cos() * azimuth.cos(),
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
    )
}

/// Small rotation by a random vector of angles with standard deviation `sd`.
fn small_rotation(rng: &mut Rng, sd: f64) -> DMat3 {
    let v = DVec3::new(rng.normal(), rng.normal(), rng.normal()) * sd;
    if v.length() == 0.0 {
        DMat3::IDENTITY
    } else {
        DMat3::from_axis_angle(v.normalize(), v.length())
    }
}

impl RigTruth {
    /// The rig exactly as designed (no errors), for tests and references.
    pub fn nominal() -> Self {
        Self::build(None)
    }

    /// The rig with seeded errors of the sizes a real build has:
    /// camera pose ~0.5 deg / 1 mm, focal ~1 %, principal point ~4 px,
    /// distortion k1 in [-0.2, 0.05], lamp directions ~0.5 deg, colours ~5 %,
    /// laser plane ~0.3 deg, turntable axis tilt ~0.05 deg.
    pub fn perturbed(seed: u64) -> Self {
        Self::build(Some(seed))
    }

    fn build(seed: Option<u64>) -> Self {
        let g = NOMINAL_GEOMETRY;
        let mut rng = Rng::new(seed.unwrap_or(0), 0x7269_6774_7275_7468);
        let on = seed.is_some() as u8 as f64;
        let deg = std::f64::consts::PI / 180.0;
        let mut cameras = Vec::with_capacity(8);
        for (k, m) in g.cameras.iter().enumerate() {
            let nominal_pos = spherical(m.elevation, m.azimuth) * m.distance;
            let pos = nominal_pos + DVec3::new(rng.normal(), rng.normal(), rng.normal()) * on;
            let rot = small_rotation(&mut rng, 0.5 * deg * on) * look_at(nominal_pos);
            let f = g.sensor.focal_px * (1.0 + 0.01 * rng.normal() * on);
            let aspect = 1.0 + 0.001 * rng.normal() * on;
            let c = [
                g.sensor.width as f64 / 2.0 + 4.0 * rng.normal() * on,
                g.sensor.height as f64 / 2.0 + 4.0 * rng.normal() * on,
            ];
            let k1 = (-0.2 + 0.25 * rng.uniform_f64()) * on;
            let k2 = 0.05 * rng.normal() * on;
            let gain = [0, 1, 2].map(|_| 1.0 + 0.05 * rng.normal() * on);
            let response = Response::perturbed(&mut rng, on);
            let _ = k;
            cameras.push(CameraTruth {
                position: pos.to_array(),
                rotation: rows(rot),
                focal_px: [f, f * aspect],
                principal_px: c,
                k1,
                k2,
                width: g.sensor.width,
                height: g.sensor.height,
                colour_gain: gain,
                response,
                used: m.used,
            });
        }
        let lamps = g
            .lamps
            .iter()
            .map(|l| {
                let d0 = spherical(l.elevation, g.light_arc_azimuth0);
                let d = (small_rotation(&mut rng, 0.5 * deg * on) * d0).normalize();
                // keep the lowest lamp grazing, not below the plane
                let d = if d.z < 0.0 {
                    DVec3::new(d.x, d.y, 0.0).normalize()
                } else {
                    d
                };
                let c = NOMINAL_LAMP_IRRADIANCE.map(|e| e * (1.0 + 0.05 * rng.normal() * on));
                LampTruth {
                    direction: d.to_array(),
                    irradiance: c,
                    used: l.used,
                }
            })
            .collect();
        let laser = LaserTruth {
            distance: g.laser.distance + 2.0 * rng.normal() * on,
            elevation_error: 0.3 * deg * rng.normal() * on,
            galvo_offset: 0.1 * deg * rng.normal() * on,
            stripe_length: g.laser.stripe_length,
            power_w: [0, 1, 2].map(|c| LASERS[c].power_w * (1.0 + 0.03 * rng.normal() * on)),
        };
        let tilt = small_rotation(&mut rng, 0.05 * deg * on) * DVec3::Z;
        RigTruth {
            cameras,
            lamps,
            laser,
            turntable_axis: tilt.normalize().to_array(),
            light_arc_azimuth0: g.light_arc_azimuth0,
            seed,
        }
    }

    /// Rotation taking world coordinates into the sample's frame at
    /// turntable angle `turntable_rad` (the sample turns by +angle about the
    /// true axis, so the world turns by -angle seen from the sample).
    pub fn world_to_sample(&self, turntable_rad: f64) -> DMat3 {
        DMat3::from_axis_angle(DVec3::from_array(self.turntable_axis), -turntable_rad)
    }

    /// Unit direction towards lamp `k` in the world frame.
    pub fn lamp_direction(&self, k: usize, light_arc_rad: f64) -> DVec3 {
        DMat3::from_rotation_z(light_arc_rad) * DVec3::from_array(self.lamps[k].direction)
    }

    /// The laser plane in the world frame for a mount elevation (nominal,
    /// radians), light-arc angle and galvo beam deflection: returns the
    /// emission point, the stripe direction `t` and the centre of the
    /// stripe on the reference plane z = 0.
    pub fn laser_geometry(
        &self,
        elevation_rad: f64,
        light_arc_rad: f64,
        galvo_rad: f64,
    ) -> LaserGeometry {
        let az = self.light_arc_azimuth0 + light_arc_rad;
        let e = elevation_rad + self.laser.elevation_error;
        let origin = spherical(e, az) * self.laser.distance;
        let t = DVec3::new(-az.sin(), az.cos(), 0.0);
        let b0 = (-origin).normalize();
        let b = DMat3::from_axis_angle(t, galvo_rad + self.laser.galvo_offset) * b0;
        let centre = if b.z < -1e-9 {
            origin + b * (-origin.z / b.z)
        } else {
            // the beam misses the plane (absurd galvo angle): park it far away
            origin + b * 1e6
        };
        LaserGeometry {
            origin,
            stripe_dir: t,
            centre,
            length: self.laser.stripe_length,
        }
    }
}

/// A laser stripe: a fan from `origin` drawing the segment
/// `centre + s stripe_dir`, |s| <= length / 2, on the plane z = 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserGeometry {
    pub origin: DVec3,
    pub stripe_dir: DVec3,
    pub centre: DVec3,
    pub length: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_cameras_see_the_origin_at_the_centre() {
        let rig = RigTruth::nominal();
        for c in rig.cameras.iter().filter(|c| c.used) {
            let [u, v] = c.project(DVec3::ZERO).unwrap();
            assert!(
                (u - 512.0).abs() < 1e-6 && (v - 384.0).abs() < 1e-6,
                "{u} {v}"
            );
            // +y world is to the right in every image
            let [u2, _] = c.project(DVec3::new(0.0, 10.0, 0.0)).unwrap();
            assert!(u2 > u + 50.0);
        }
    }

    #[test]
    fn perturbation_is_small_seeded_and_serialisable() {
        let a = RigTruth::perturbed(3);
        let b = RigTruth::perturbed(3);
        let c = RigTruth::perturbed(4);
        assert_eq!(a, b);
        assert_ne!(a, c);
        let n = RigTruth::nominal();
        for (p, q) in a.cameras.iter().zip(&n.cameras) {
            let d = (p.position_vec() - q.position_vec()).length();
            assert!(d > 0.0 && d < 6.0, "{d}");
            assert!((p.focal_px[0] / q.focal_px[0] - 1.0).abs() < 0.05);
        }
        let back: RigTruth = toml::from_str(&toml::to_string(&a).unwrap()).unwrap();
        assert_eq!(back.cameras[3].k1, a.cameras[3].k1);
    }

    #[test]
    fn vertical_laser_sweeps_across_the_arc() {
        let rig = RigTruth::nominal();
        let half_pi = std::f64::consts::FRAC_PI_2;
        let g0 = rig.laser_geometry(half_pi, 0.0, 0.0);
        assert!(g0.centre.length() < 1e-9);
        assert!((g0.origin.z - 600.0).abs() < 1e-9);
        // at arc angle 0 the stripe runs along y, the galvo moves it along x
        assert!((g0.stripe_dir.dot(DVec3::Y).abs() - 1.0).abs() < 1e-12);
        let g1 = rig.laser_geometry(half_pi, 0.0, 0.01);
        assert!((g1.centre.x.abs() - 600.0 * 0.01f64.tan()).abs() < 1e-6);
        assert!(g1.centre.y.abs() < 1e-9);
    }
}
