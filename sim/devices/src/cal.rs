//! The simulated rig's truth, for calibration: the calibration it truly has
//! (`qhm calibrate truth`), and the table of a computed calibration's values
//! against the true ones (printed after `qhm calibrate compute` or `all` on a
//! simulated capture, and only there). Nothing here takes part in computing
//! a calibration: that reads the frames (`qhm_imaging::cal_compute`).

use glam::{DVec2, DVec3};
use qhm_imaging::calibration::{Calibration, LampCal, LaserCal, Turntable};
use qhm_imaging::camera::{CameraModel, Intrinsics, rodrigues_inv};
use qhm_imaging::response::{self, FitRange, ResponseCurve};
use sim_light::RigTruth;

/// One line of the recovered-vs-true table.
#[derive(Debug, Clone)]
pub struct Row {
    pub quantity: String,
    pub recovered: f64,
    pub truth: f64,
    pub error: f64,
    pub target: String,
    pub ok: bool,
}

impl Row {
    fn report(quantity: String, recovered: f64, truth: f64, error: f64) -> Row {
        Row {
            quantity,
            recovered,
            truth,
            error,
            target: "report".into(),
            ok: true,
        }
    }
    fn missing(quantity: String) -> Row {
        Row {
            quantity,
            recovered: f64::NAN,
            truth: f64::NAN,
            error: f64::NAN,
            target: "calibrated".into(),
            ok: false,
        }
    }
}

impl std::fmt::Display for Row {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:<34} {:>14.6} {:>14.6} {:>12.3e}  {:<14} {}",
            self.quantity,
            self.recovered,
            self.truth,
            self.error,
            self.target,
            if self.ok { "ok" } else { "MISSED" }
        )
    }
}

/// The header line of the table.
pub fn header() -> String {
    format!(
        "{:<34} {:>14} {:>14} {:>12}  {:<14}",
        "quantity", "recovered", "true", "error", "target"
    )
}

/// Where the response rows compare fitted and true curves (codes).
const RESPONSE_CHECKED: FitRange = FitRange {
    z_min: 20,
    z_max: 245,
};

/// The true rig of a seed (the simulated rig's `RigTruth::perturbed`).
pub struct SimTruth {
    pub rig: RigTruth,
    /// Cameras calibrated (the used ones: 1..=7); the last is the reference.
    pub cameras: Vec<usize>,
}

impl SimTruth {
    pub fn new(seed: u64) -> Self {
        SimTruth {
            rig: RigTruth::perturbed(seed),
            cameras: hardware::NOMINAL_GEOMETRY
                .used_cameras()
                .map(|(i, _)| i)
                .collect(),
        }
    }

    /// The camera the others' colour, the lamps and the laser flux are
    /// calibrated against (the top one).
    fn reference_camera(&self) -> usize {
        self.cameras.last().copied().unwrap_or(7)
    }

    /// The true camera k as a CameraModel at `binning` (pixel centres on integers).
    pub fn true_camera(&self, k: usize, binning: u32) -> CameraModel {
        let c = &self.rig.cameras[k];
        let r = c.rotation_mat();
        let b = binning.max(1) as f64;
        let intr = Intrinsics {
            fx: c.focal_px[0] / b,
            fy: c.focal_px[1] / b,
            cx: c.principal_px[0] / b - 0.5,
            cy: c.principal_px[1] / b - 0.5,
            k1: c.k1,
            k2: c.k2,
        };
        let t = -(r * c.position_vec());
        CameraModel {
            intrinsics: intr,
            rotation: rodrigues_inv(r).to_array(),
            translation: t.to_array(),
        }
    }

    /// Radiance in camera units (reference camera, true response) per
    /// W sr^-1 m^-2 of true radiance, channel c.
    fn camera_unit(&self, c: usize) -> f64 {
        let kref = self.reference_camera();
        self.rig.cameras[kref].colour_gain[c] * sim_light::sensor::SENSITIVITY
            / sim_light::sensor::FULL_WELL_E
    }

    /// Camera k's true inverse response: m with I(m) = z / 255, by bisection.
    fn true_linear(&self, k: usize, z: f64) -> f64 {
        let truth = &self.rig.cameras[k].response;
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if truth.eval(mid) * 255.0 < z {
                lo = mid
            } else {
                hi = mid
            }
        }
        0.5 * (lo + hi)
    }

    /// The scale of camera k's calibrated response for channel c against
    /// the true one (geometric mean of their ratio where it is checked).
    /// The response row leaves it out; the colour gains take it up (camera
    /// k's scale against the reference's), and the lamp and laser values
    /// are in the reference camera's calibrated units.
    fn response_scale(&self, cal: &Calibration, k: usize, c: usize) -> f64 {
        let Some(curve) = cal.camera(k).and_then(|cam| cam.response.get(c)) else {
            return 1.0;
        };
        let zs = RESPONSE_CHECKED.z_min..=RESPONSE_CHECKED.z_max;
        let n = zs.clone().count() as f64;
        (zs.map(|z| (curve.linear(z as f64) / self.true_linear(k, z as f64)).ln())
            .sum::<f64>()
            / n)
            .exp()
    }

    /// Lamp `li`'s true irradiance, channel c, in true camera units.
    fn true_lamp_irradiance(&self, li: usize, c: usize) -> f64 {
        self.rig.lamps[li].irradiance[c] * self.camera_unit(c)
    }

    /// Laser c's true flux per mm of stripe in true camera units.
    fn true_flux_per_mm(&self, c: usize) -> f64 {
        self.rig.laser.power_w[c] / self.rig.laser.stripe_length * self.camera_unit(c) * 1e6
    }

    /// The true laser-plane angle at clamp elevation `elev`, as the
    /// two-height target measures it (light arc and turntable at `arc`).
    fn true_plane_angle(&self, elev: f64, arc: f64) -> f64 {
        let az = hardware::NOMINAL_GEOMETRY.light_arc_azimuth0 + arc;
        let geo = self.rig.laser_geometry(elev, arc, 0.0);
        let horiz = (geo.origin - geo.centre)
            .truncate()
            .dot(DVec2::new(az.cos(), az.sin()));
        (geo.origin.z - geo.centre.z).atan2(horiz)
    }

    /// The table of `cal` against the truth; `plane_arc` is the light-arc
    /// angle the laser planes were measured at (the calibration plan's).
    pub fn rows(&self, cal: &Calibration, plane_arc: f64) -> Vec<Row> {
        let mut rows = Vec::new();
        for &k in &self.cameras {
            let curves = cal.camera(k).map(|c| c.response.as_slice()).unwrap_or(&[]);
            if curves.len() != 3 {
                rows.push(Row::missing(format!("camera {k} response")));
                continue;
            }
            let worst = (0..3)
                .map(|c| {
                    response::relative_error(
                        &|z| curves[c].linear(z),
                        &|z| self.true_linear(k, z),
                        RESPONSE_CHECKED,
                    )
                })
                .fold(0.0f64, f64::max);
            rows.push(Row {
                quantity: format!("camera {k} response max rel. error"),
                recovered: worst,
                truth: 0.0,
                error: worst,
                target: "< 0.01".into(),
                ok: worst < 0.01,
            });
        }
        for &k in &self.cameras {
            let (Some(rf), Some(rms)) = (
                cal.camera(k).and_then(|c| c.geometry),
                cal.camera(k).and_then(|c| c.reprojection_rms_px),
            ) else {
                rows.push(Row::missing(format!("camera {k} geometry")));
                continue;
            };
            let tf = self.true_camera(k, 1);
            let fe = (rf.intrinsics.fx / tf.intrinsics.fx - 1.0)
                .abs()
                .max((rf.intrinsics.fy / tf.intrinsics.fy - 1.0).abs());
            rows.push(Row {
                quantity: format!("camera {k} focal fx (px, full res)"),
                recovered: rf.intrinsics.fx,
                truth: tf.intrinsics.fx,
                error: fe,
                target: "< 0.005 rel".into(),
                ok: fe < 0.005,
            });
            rows.push(Row {
                quantity: format!("camera {k} reprojection RMS (px)"),
                recovered: rms,
                truth: 0.0,
                error: rms,
                target: "< 0.3".into(),
                ok: rms < 0.3,
            });
            let ce = (rf.centre() - tf.centre()).length();
            rows.push(Row::report(
                format!("camera {k} centre error (mm)"),
                ce,
                0.0,
                ce,
            ));
            rows.push(Row::report(
                format!("camera {k} k1"),
                rf.intrinsics.k1,
                tf.intrinsics.k1,
                (rf.intrinsics.k1 - tf.intrinsics.k1).abs(),
            ));
        }
        match &cal.turntable {
            Some(t) => {
                let truth = DVec3::from(self.rig.turntable_axis).normalize();
                let err = DVec3::from(t.axis)
                    .normalize()
                    .angle_between(truth)
                    .to_degrees();
                rows.push(Row::report(
                    "turntable axis error (deg)".into(),
                    err,
                    0.0,
                    err,
                ));
            }
            None => rows.push(Row::missing("turntable axis".into())),
        }
        let kref = self.reference_camera();
        for &k in &self.cameras {
            let Some(g) = cal.camera(k).and_then(|c| c.colour_gain) else {
                rows.push(Row::missing(format!("camera {k} colour gain")));
                continue;
            };
            let worst = (0..3)
                .map(|c| {
                    let truth = self.rig.cameras[kref].colour_gain[c]
                        / self.rig.cameras[k].colour_gain[c]
                        * self.response_scale(cal, kref, c)
                        / self.response_scale(cal, k, c);
                    (g[c] / truth - 1.0).abs()
                })
                .fold(0.0f64, f64::max);
            rows.push(Row {
                quantity: format!("camera {k} colour gain max rel. err"),
                recovered: worst,
                truth: 0.0,
                error: worst,
                target: "< 0.01".into(),
                ok: worst < 0.01,
            });
        }
        let g = hardware::NOMINAL_GEOMETRY;
        for (li, _) in g.used_lamps() {
            let Some(e) = cal
                .lamp
                .iter()
                .find(|l| l.index == li)
                .and_then(|l| l.irradiance)
            else {
                rows.push(Row::missing(format!("lamp {li} irradiance")));
                continue;
            };
            let worst = (0..3)
                .map(|c| {
                    let truth =
                        self.true_lamp_irradiance(li, c) * self.response_scale(cal, kref, c);
                    (e[c] / truth - 1.0).abs()
                })
                .fold(0.0f64, f64::max);
            rows.push(Row::report(
                format!("lamp {li} irradiance max rel. err"),
                worst,
                0.0,
                worst,
            ));
        }
        let laser = cal.laser.as_ref();
        for &elev in &g.laser.positions {
            let Some(&[_, angle]) =
                laser.and_then(|l| l.plane_angles.iter().find(|[e, _]| (e - elev).abs() < 1e-6))
            else {
                rows.push(Row::missing(format!(
                    "laser plane at {:.0} deg",
                    elev.to_degrees()
                )));
                continue;
            };
            let truth = self.true_plane_angle(elev, plane_arc);
            let err = (angle - truth).to_degrees();
            rows.push(Row {
                quantity: format!("laser plane angle at {:.0} deg (deg)", elev.to_degrees()),
                recovered: angle.to_degrees(),
                truth: truth.to_degrees(),
                error: err.abs(),
                target: "< 0.2 deg".into(),
                ok: err.abs() < 0.2,
            });
        }
        for c in 0..3 {
            let Some(flux) = laser.and_then(|l| l.flux_per_mm).map(|f| f[c]) else {
                rows.push(Row::missing(format!("laser {c} flux")));
                continue;
            };
            let truth = self.true_flux_per_mm(c) * self.response_scale(cal, kref, c);
            rows.push(Row::report(
                format!("laser {c} flux per mm rel. err"),
                flux,
                truth,
                (flux / truth - 1.0).abs(),
            ));
        }
        rows
    }

    /// The calibration the simulated rig truly has, in the units the steps
    /// use: a response table from the true curve, the true geometry, colour
    /// gains, lamps and laser (planes as measured at light arc `plane_arc`).
    /// A fit from frames rectified with it has no calibration error, which
    /// separates the fit's errors from the calibration's.
    pub fn truth(&self, cal: &mut Calibration, plane_arc: f64) {
        let g = hardware::NOMINAL_GEOMETRY;
        let kref = self.reference_camera();
        for &k in &self.cameras {
            let truth = &self.rig.cameras[k];
            // linear(Z) = m with I(m) = Z / 255 (m = 1 at saturation, as the
            // fitted curves). Z = 0 reads as black, as the fitted curves read
            // it: a quarter code there lifted the dark far field of a stripe
            // image enough to move skin1's blue a' by +0.016.
            let table = ResponseCurve::Table {
                g: (0..256)
                    .map(|z| {
                        if z == 0 {
                            1e-12
                        } else {
                            self.true_linear(k, z as f64)
                        }
                        .ln()
                    })
                    .collect(),
            };
            let cam = cal.camera_mut(k);
            cam.response = vec![table; 3];
            cam.colour_gain = Some(std::array::from_fn(|c| {
                self.rig.cameras[kref].colour_gain[c] / truth.colour_gain[c]
            }));
            cam.geometry = Some(self.true_camera(k, 1));
            cam.reprojection_rms_px = Some(0.0);
        }
        cal.turntable = Some(Turntable {
            axis: self.rig.turntable_axis,
        });
        cal.lamp = g
            .used_lamps()
            .map(|(li, _)| LampCal {
                index: li,
                direction: self.rig.lamps[li].direction,
                irradiance: Some(std::array::from_fn(|c| self.true_lamp_irradiance(li, c))),
            })
            .collect();
        let plane_angles = (g.laser.positions.iter())
            .map(|&elev| [elev, self.true_plane_angle(elev, plane_arc)])
            .collect();
        cal.laser = Some(LaserCal {
            plane_angles,
            flux_per_mm: Some(std::array::from_fn(|c| self.true_flux_per_mm(c))),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use qhm_imaging::hdr::{self, MergeOptions};
    use qhm_imaging::image::Image8;
    use sim_light::RadianceImage;
    use sim_light::sensor::Sensor;

    /// Frames of a flat radiance merged through the true calibration read
    /// back that radiance in the reference camera's units, on every camera;
    /// and the table of the truth against itself is within target everywhere.
    #[test]
    fn true_calibration_reads_back_the_rig() {
        let sim = SimTruth::new(3);
        let mut cal = Calibration::default();
        sim.truth(&mut cal, 0.5);
        let cal = Calibration::from_toml(&toml::to_string(&cal).unwrap()).unwrap();
        let radiance = [0.8f32, 0.5, 0.3];
        let exposures = [0.002, 0.005, 0.0125, 0.03];
        for k in 1..8 {
            let truth = &sim.rig.cameras[k];
            let sensor = Sensor {
                camera: k,
                colour_gain: truth.colour_gain,
                response: truth.response.clone(),
            };
            let flat = RadianceImage {
                width: 32,
                height: 32,
                data: vec![radiance; 32 * 32],
            };
            let frames: Vec<Image8> = (exposures.iter().enumerate())
                .map(|(i, &t)| {
                    let f = sensor.expose(&flat, t, 1.0, i as u64);
                    Image8::new(32, 32, 3, f.rgb).unwrap()
                })
                .collect();
            let refs: Vec<&Image8> = frames.iter().collect();
            let cam = cal.camera(k).unwrap();
            let hdr =
                hdr::merge(&refs, &exposures, &cam.response, MergeOptions::default()).unwrap();
            for c in 0..3 {
                let mean = hdr
                    .data
                    .iter()
                    .skip(c)
                    .step_by(3)
                    .map(|&v| v as f64)
                    .sum::<f64>()
                    / (32.0 * 32.0);
                let got = mean * cam.colour_gain.unwrap()[c];
                let want = radiance[c] as f64 * sim.camera_unit(c);
                assert!(
                    (got / want - 1.0).abs() < 0.01,
                    "camera {k} channel {c}: {got} vs {want}"
                );
                assert!((sim.response_scale(&cal, k, c) - 1.0).abs() < 1e-9);
            }
        }
        let rows = sim.rows(&cal, 0.5);
        assert_eq!(rows.len(), 58);
        assert!(rows.iter().all(|r| r.ok), "{rows:#?}");
        // A focal length 1 % off misses; a missing camera is a missed row.
        let mut off = cal.clone();
        off.camera_mut(3).geometry.as_mut().unwrap().intrinsics.fx *= 1.01;
        let missed: Vec<String> = (sim.rows(&off, 0.5).into_iter())
            .filter(|r| !r.ok)
            .map(|r| r.quantity)
            .collect();
        assert_eq!(missed, ["camera 3 focal fx (px, full res)"]);
        let mut partial = cal.clone();
        partial.camera_mut(4).geometry = None;
        let rows = sim.rows(&partial, 0.5);
        assert!(
            rows.iter()
                .any(|r| r.quantity == "camera 4 geometry" && !r.ok)
        );
    }
}
