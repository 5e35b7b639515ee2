//! Calibration on the simulated rig: render the calibration targets of
//! sim-light through its true (perturbed) rig, run every calibration step on
//! the 8-bit frames exactly as on the real rig, and report recovered against
//! true values. Only this module knows the frames are simulated.

use std::f64::consts::PI;

use glam::{DMat3, DQuat, DVec2, DVec3};
use sim_light::sample::{SceneDesc, TargetDesc};
use sim_light::{Illumination, LaserOn, RigTruth, SimQuality, World};

use qhm_imaging::calibration::{Calibration, LampCal, LaserCal, Turntable};
use qhm_imaging::camera::{CameraModel, Intrinsics, rodrigues, rodrigues_inv};
use qhm_imaging::corners::detect_board;
use qhm_imaging::hdr::{self, MergeOptions};
use qhm_imaging::image::{Image8, ImageF};
use qhm_imaging::photometric;
use qhm_imaging::rectify::{self, Grid};
use qhm_imaging::response::{self, Bracket, FitRange, MnOptions, ResponseCurve};
use qhm_imaging::zhang::{self, PlanarView, Raised, ZhangOptions};
use qhm_imaging::{Error, Result};

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

/// The simulated rig and how finely to simulate it.
pub struct SimCalibrator {
    pub rig: RigTruth,
    pub quality: SimQuality,
    pub seed: u64,
    /// Cameras to calibrate (the used ones: 1..=7).
    pub cameras: Vec<usize>,
}

const SENSOR_GAIN: f64 = 1.0;

/// Mitsunaga-Nayar on the sim's brackets: the shutter times are exact, so
/// the exposure ratios are not re-estimated (set free, they absorb the
/// noise's bias and the curve is off by 1-2 %), and 20 000 pixels are sampled.
fn mn_options() -> MnOptions {
    MnOptions {
        refine_ratios: false,
        samples: 20_000,
        ..MnOptions::default()
    }
}

/// Lamp photons per channel of a checkerboard frame, at least.
const GEOMETRY_PHOTONS: u64 = 400_000;

/// Lamp photons per channel of the colour-pattern frame, at least: the
/// patch means of two cameras share photons only where their pixels cover
/// the same texels, so at 40 k (ci) the gains were off by up to 4 %.
const COLOUR_PHOTONS: u64 = 1_000_000;

/// Where the response rows compare fitted and true curves (codes).
const RESPONSE_CHECKED: FitRange = FitRange {
    z_min: 20,
    z_max: 245,
};

/// Thickness of the spacer block the checkerboard is also imaged on, mm: the
/// image scale's change with this known depth change separates focal length
/// and distance, which the flat board alone cannot for the top camera.
pub const SPACER_MM: f64 = 20.0;

/// Cameras whose view is within this angle of straight down (radians) fit fy
/// apart from fx. A flat board's foreshortening compresses the image along the
/// camera's tilt as a pixel aspect would (to first order by sin(tilt)): the
/// steep cameras (5, 6, 7: 26, 13, 0 deg) see the aspect free of it and fit it
/// (top camera, seed 2: focal 0.47 -> 0.05 %, centre 15 -> 0.3 mm); for cameras
/// 3 and 4 a free aspect traded against their poses (focal 0.1 -> 0.45 %, and
/// camera 4's poses moved the laser-plane angle by up to 0.27 deg).
const ASPECT_MAX_TILT: f64 = 30.0 * PI / 180.0;

/// Light-arc (and turntable) angle of the laser-plane measurement, radians.
const LASER_ARC: f64 = 30.0 * PI / 180.0;

impl SimCalibrator {
    pub fn new(seed: u64, quality: SimQuality) -> Self {
        SimCalibrator {
            rig: RigTruth::perturbed(seed),
            quality,
            seed,
            cameras: (1..8).collect(),
        }
    }

    /// The same rig and seed, simulated at `quality` with `cameras`.
    fn with(&self, quality: SimQuality, cameras: Vec<usize>) -> SimCalibrator {
        SimCalibrator {
            rig: self.rig.clone(),
            quality,
            seed: self.seed,
            cameras,
        }
    }

    fn binning(&self) -> u32 {
        self.quality.downscale
    }

    fn world(&self, preset: &str) -> Result<World> {
        let desc = SceneDesc::preset(preset)
            .map_err(|e| Error::Input(format!("sim scene {preset}: {e}")))?;
        self.world_from(desc)
    }

    /// The simulated world of `desc` on this rig at this quality.
    fn world_from(&self, desc: SceneDesc) -> Result<World> {
        World::new(desc, self.rig.clone(), self.quality)
            .map_err(|e| Error::Input(format!("sim world: {e}")))
    }

    /// Brackets (one per camera of `self.cameras`) of one rig pose.
    fn capture(
        &self,
        world: &World,
        illum: &Illumination,
        exposures: &[f64],
        tag: u64,
    ) -> Result<Vec<Vec<Image8>>> {
        let mask = self.cameras.iter().fold(0u8, |m, &c| m | (1 << c));
        let pose = world
            .render_pose(illum, mask, self.seed ^ tag.wrapping_mul(0x9E37_79B9))
            .map_err(|e| Error::Input(format!("sim render: {e}")))?;
        self.cameras
            .iter()
            .map(|&k| {
                let rad = pose.images[k]
                    .as_ref()
                    .ok_or_else(|| Error::Input(format!("camera {k} not rendered")))?;
                exposures
                    .iter()
                    .enumerate()
                    .map(|(i, &t)| {
                        let f = world.sensor(k).expose(
                            rad,
                            t,
                            SENSOR_GAIN,
                            tag * 1000 + i as u64 * 17 + k as u64,
                        );
                        Image8::new(f.width as usize, f.height as usize, 3, f.rgb)
                    })
                    .collect()
            })
            .collect()
    }

    fn lamp_illum(&self, turntable: f64, lamp: usize) -> Illumination {
        Illumination {
            turntable_rad: turntable,
            light_arc_rad: 0.0,
            galvo_rad: 0.0,
            laser: None,
            lamps: 1 << lamp,
        }
    }

    /// The nominal camera k as a CameraModel at this binning (pixel centres on integers).
    pub fn nominal_camera(&self, k: usize) -> CameraModel {
        let g = hardware::NOMINAL_GEOMETRY;
        let m = g.cameras[k];
        let pos = DVec3::new(
            m.elevation.cos() * m.azimuth.cos(),
            m.elevation.cos() * m.azimuth.sin(),
            m.elevation.sin(),
        ) * m.distance;
        truth_like_camera(
            pos,
            g.sensor.focal_px,
            [g.sensor.width as f64 / 2.0, g.sensor.height as f64 / 2.0],
            self.binning(),
        )
    }

    /// The true camera k as a CameraModel at this binning.
    pub fn true_camera(&self, k: usize) -> CameraModel {
        let c = &self.rig.cameras[k];
        let r = c.rotation_mat();
        let b = self.binning() as f64;
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

    /// Camera responses from a bracket of the colour pattern (Mitsunaga-Nayar).
    pub fn response(&self, cal: &mut Calibration, rows: &mut Vec<Row>) -> Result<()> {
        let world = self.world("colour-pattern")?;
        let exposures = [0.002, 0.005, 0.0125, 0.03, 0.075, 0.2];
        let brackets = self.capture(&world, &self.lamp_illum(0.0, 7), &exposures, 1)?;
        for (&k, frames) in self.cameras.iter().zip(brackets) {
            let b = Bracket {
                frames,
                exposures: exposures.to_vec(),
            };
            let mut curves = Vec::new();
            let mut worst = 0.0f64;
            for c in 0..3 {
                let fit = response::fit_mitsunaga_nayar(&b, c, mn_options())?;
                let e = response::relative_error(
                    &|z| fit.curve.linear(z),
                    &|z| self.true_linear(k, z),
                    RESPONSE_CHECKED,
                );
                worst = worst.max(e);
                curves.push(fit.curve);
            }
            rows.push(Row {
                quantity: format!("camera {k} response max rel. error"),
                recovered: worst,
                truth: 0.0,
                error: worst,
                target: "< 0.01".into(),
                ok: worst < 0.01,
            });
            cal.camera_mut(k).response = curves;
        }
        Ok(())
    }

    fn merged(
        &self,
        cal: &Calibration,
        k: usize,
        frames: &[Image8],
        exposures: &[f64],
    ) -> Result<ImageF> {
        let resp = cal
            .camera(k)
            .map(|c| c.response.clone())
            .filter(|r| !r.is_empty())
            .ok_or_else(|| {
                Error::Input(format!(
                    "camera {k} has no response; run the response step first"
                ))
            })?;
        let refs: Vec<&Image8> = frames.iter().collect();
        hdr::merge(&refs, exposures, &resp, MergeOptions::default())
    }

    /// How the checkerboard frames are simulated: at most 2x binned (the lowest
    /// camera's squares are 6 px tall there, 3 px at 4x) and with at least
    /// `GEOMETRY_PHOTONS` per channel (Monte Carlo noise limits the corners).
    fn geometry_quality(&self) -> SimQuality {
        let mut q = self.quality;
        q.downscale = q.downscale.min(2);
        q.lamp_photons = q.lamp_photons.max(GEOMETRY_PHOTONS);
        q
    }

    /// How the colour-pattern frame is simulated: at most 2x binned (at 8x a
    /// patch's central half is 4 x 4 pixels, and the patch edges blur into
    /// it) and with at least `COLOUR_PHOTONS` per channel. Colour gains are
    /// ratios of linear values, so they hold at any binning (ci, seeds 1-4:
    /// the worst camera 2.0, 4.2, 1.9, 3.4 % -> 0.6, 2.0, 1.9, 2.6 %, both
    /// against the bare gain ratio, which leaves out the response scales).
    fn colour_quality(&self) -> SimQuality {
        let mut q = self.quality;
        q.downscale = q.downscale.min(2);
        q.lamp_photons = q.lamp_photons.max(COLOUR_PHOTONS);
        q
    }

    /// The checkerboard scene, the board on a spacer of `height_mm` (0: on the turntable).
    fn checkerboard_world(&self, height_mm: f64) -> Result<World> {
        let mut desc = SceneDesc::preset("checkerboard")
            .map_err(|e| Error::Input(format!("sim scene checkerboard: {e}")))?;
        if let SceneDesc::Target {
            target: TargetDesc::Checkerboard { height_mm: h, .. },
        } = &mut desc
        {
            *h = height_mm;
        }
        self.world_from(desc)
    }

    /// The board's corners found in one frame of camera k, the board's top at
    /// z = `height` turned by `theta`; None if too few are visible or found.
    fn board_view(
        &self,
        img: &Image8,
        k: usize,
        theta: f64,
        height: f64,
        board: &[DVec2],
    ) -> Option<PlanarView> {
        let nominal = self.nominal_camera(k);
        let rz = DMat3::from_rotation_z(theta);
        let pred: Vec<Option<DVec2>> = board
            .iter()
            .map(|p| nominal.project(rz * DVec3::new(p.x, p.y, height)))
            .collect();
        let visible: Vec<usize> = (0..board.len())
            .filter(|&i| {
                pred[i].is_some_and(|q| {
                    q.x > 8.0
                        && q.y > 8.0
                        && q.x < img.width as f64 - 9.0
                        && q.y < img.height as f64 - 9.0
                })
            })
            .collect();
        if visible.len() < 12 {
            return None;
        }
        let pts: Vec<DVec2> = visible
            .iter()
            .map(|&i| pred[i].unwrap_or_default())
            .collect();
        // Square size in pixels near the board centre, from the prediction.
        let square_px = match (
            nominal.project(rz * DVec3::new(5.0, 0.0, height)),
            nominal.project(rz * DVec3::new(0.0, 5.0, height)),
            nominal.project(rz * DVec3::new(0.0, 0.0, height)),
        ) {
            (Some(a), Some(c), Some(o)) => (a - o).length().min((c - o).length()),
            _ => return None,
        };
        // The 12 x 12 squares' centres and colours (bright where floor(x/5) + floor(y/5) is odd).
        let squares: Vec<(DVec2, bool)> = (-6..6)
            .flat_map(|j: i32| (-6..6).map(move |i: i32| (i, j)))
            .filter_map(|(i, j)| {
                let c = DVec3::new((i as f64 + 0.5) * 5.0, (j as f64 + 0.5) * 5.0, height);
                nominal
                    .project(rz * c)
                    .map(|q| (q, (i + j).rem_euclid(2) == 1))
            })
            .collect();
        // The board's axes at each corner, as image vectors to the next corners.
        let axes: Vec<(DVec2, DVec2)> = visible
            .iter()
            .map(|&i| {
                let p = DVec3::new(board[i].x, board[i].y, height);
                let at = |d: DVec3| nominal.project(rz * (p + d)).unwrap_or_default();
                let o = pred[i].unwrap_or_default(); // at(DVec3::ZERO)
                (at(DVec3::X * 5.0) - o, at(DVec3::Y * 5.0) - o)
            })
            .collect();
        let gray = img.gray_f32();
        let Ok(found) = detect_board(
            &gray, img.width, img.height, &pts, &axes, &squares, square_px,
        ) else {
            return None;
        };
        let mut v = PlanarView {
            object: Vec::new(),
            image: Vec::new(),
            raised: None,
        };
        for (&i, f) in visible.iter().zip(found) {
            if let Some(f) = f {
                v.object.push(board[i]);
                v.image.push(f);
            }
        }
        (v.object.len() >= 12).then_some(v)
    }

    /// Intrinsics, distortion and poses (Zhang), turntable axis, from the checkerboard.
    pub fn geometry(&self, cal: &mut Calibration, rows: &mut Vec<Row>) -> Result<()> {
        let q = self.geometry_quality();
        if q != self.quality {
            return self.with(q, self.cameras.clone()).geometry(cal, rows);
        }
        let thetas: Vec<f64> = (0..6).map(|i| i as f64 * PI / 3.0 + 0.2).collect();
        let b = self.binning() as f64;
        // Inner corners of the 60 mm board of 5 mm squares, sample frame.
        let board: Vec<DVec2> = (-5..=5)
            .flat_map(|j| (-5..=5).map(move |i| DVec2::new(i as f64 * 5.0, j as f64 * 5.0)))
            .collect();
        let mut per_cam: Vec<Vec<PlanarView>> = vec![Vec::new(); self.cameras.len()];
        let mut per_cam_theta: Vec<Vec<f64>> = vec![Vec::new(); self.cameras.len()];
        // The board on the turntable at every angle, then on the spacer at every
        // angle: a raised view is tied to the view of the same angle on the turntable.
        let mut base_of: Vec<Vec<Option<usize>>> =
            vec![vec![None; thetas.len()]; self.cameras.len()];
        for height in [0.0, SPACER_MM] {
            let world = self.checkerboard_world(height)?;
            for (vi, &theta) in thetas.iter().enumerate() {
                if height > 0.0 && base_of.iter().all(|c| c[vi].is_none()) {
                    continue;
                }
                let tag = 100 + vi as u64 + if height > 0.0 { 50 } else { 0 };
                let frames = self.capture(&world, &self.lamp_illum(theta, 7), &[0.03], tag)?;
                for (ci, (&k, f)) in self.cameras.iter().zip(frames).enumerate() {
                    let raised = if height > 0.0 {
                        match base_of[ci][vi] {
                            Some(base) => Some(Raised {
                                base,
                                height_mm: height,
                            }),
                            None => continue,
                        }
                    } else {
                        None
                    };
                    let Some(mut v) = self.board_view(&f[0], k, theta, height, &board) else {
                        continue;
                    };
                    v.raised = raised;
                    if height == 0.0 {
                        base_of[ci][vi] = Some(per_cam[ci].len());
                    }
                    per_cam[ci].push(v);
                    per_cam_theta[ci].push(theta);
                }
            }
        }
        let mut axis_samples = Vec::new();
        for (ci, &k) in self.cameras.iter().enumerate() {
            let views = &per_cam[ci];
            // The views on the turntable (board origin = world origin).
            let on_table: Vec<usize> = (0..views.len())
                .filter(|&i| views[i].raised.is_none())
                .collect();
            if on_table.len() < 2 {
                rows.push(Row {
                    quantity: format!("camera {k} checkerboard views"),
                    recovered: views.len() as f64,
                    truth: thetas.len() as f64,
                    error: f64::NAN,
                    target: ">= 2".into(),
                    ok: false,
                });
                continue;
            }
            let g = hardware::NOMINAL_GEOMETRY;
            let (w, h) = (
                (g.sensor.width as f64 / b) as usize,
                (g.sensor.height as f64 / b) as usize,
            );
            let opts = ZhangOptions {
                image_width: w,
                image_height: h,
                distortion: true,
                fix_principal_point: true,
                // The mechanical distance only when no raised view gives it.
                centre_distance: (on_table.len() == views.len())
                    .then_some((g.cameras[k].distance, 1.0)),
                initial_focal: Some(g.sensor.focal_px / b),
                // The lens's centring tolerance, ~4 px at full resolution.
                principal_sd: Some(4.0 / b),
                // fy apart from fx where the board's tilt does not mimic it.
                fit_aspect: PI / 2.0 - g.cameras[k].elevation <= ASPECT_MAX_TILT,
            };
            let res = match zhang::calibrate(views, opts) {
                Ok(r) => r,
                Err(e) => {
                    rows.push(Row {
                        quantity: format!("camera {k} Zhang: {e}"),
                        recovered: f64::NAN,
                        truth: f64::NAN,
                        error: f64::NAN,
                        target: "converge".into(),
                        ok: false,
                    });
                    continue;
                }
            };
            // World pose: views are sample -> camera at turntable theta_i; world = Rz(theta) sample.
            let view_thetas = &per_cam_theta[ci];
            let mut q_sum = glam::DVec4::ZERO;
            let mut t_sum = DVec3::ZERO;
            let mut q0: Option<DQuat> = None;
            for &i in &on_table {
                let (r, t) = &res.poses[i];
                let rcw = rodrigues(*r) * DMat3::from_rotation_z(view_thetas[i]).transpose();
                let mut q = DQuat::from_mat3(&rcw);
                if let Some(q0) = q0 {
                    if q.dot(q0) < 0.0 {
                        q = -q;
                    }
                } else {
                    q0 = Some(q);
                }
                q_sum += glam::DVec4::from(q);
                t_sum += *t;
            }
            let q = DQuat::from_vec4(q_sum).normalize();
            let n = on_table.len() as f64;
            let model = CameraModel {
                intrinsics: res.intrinsics,
                rotation: rodrigues_inv(DMat3::from_quat(q)).to_array(),
                translation: (t_sum / n).to_array(),
            };
            // Turntable axis from the relative rotation of the first and last views (sample frame).
            if on_table.len() >= 2 {
                let r0 = rodrigues(res.poses[on_table[0]].0);
                let r1 = rodrigues(res.poses[on_table[on_table.len() - 1]].0);
                let rel = r0.transpose() * r1;
                let (ax, ang) = DQuat::from_mat3(&rel).to_axis_angle();
                if ang.abs() > 0.3 {
                    axis_samples.push(if ax.z < 0.0 { -ax } else { ax });
                }
            }
            let truth = self.true_camera(k);
            let full = |m: &CameraModel| full_res(m, b);
            let (rf, tf) = (full(&model), full(&truth));
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
                recovered: res.rms * b,
                truth: 0.0,
                error: res.rms * b,
                target: "< 0.3".into(),
                ok: res.rms * b < 0.3,
            });
            let ce = (model.centre() - truth.centre()).length();
            rows.push(Row {
                quantity: format!("camera {k} centre error (mm)"),
                recovered: ce,
                truth: 0.0,
                error: ce,
                target: "report".into(),
                ok: true,
            });
            rows.push(Row {
                quantity: format!("camera {k} k1"),
                recovered: rf.intrinsics.k1,
                truth: tf.intrinsics.k1,
                error: (rf.intrinsics.k1 - tf.intrinsics.k1).abs(),
                target: "report".into(),
                ok: true,
            });
            let c = cal.camera_mut(k);
            c.geometry = Some(full(&model));
            c.reprojection_rms_px = Some(res.rms * b);
        }
        if !axis_samples.is_empty() {
            let axis = (axis_samples.iter().copied().sum::<DVec3>()).normalize();
            let truth = DVec3::from(self.rig.turntable_axis).normalize();
            let err = axis.angle_between(truth).to_degrees();
            rows.push(Row {
                quantity: "turntable axis error (deg)".into(),
                recovered: err,
                truth: 0.0,
                error: err,
                target: "report".into(),
                ok: true,
            });
            cal.turntable = Some(Turntable {
                axis: axis.to_array(),
            });
        }
        Ok(())
    }

    /// Camera model at this binning from a full-resolution calibration entry.
    fn cam_at_binning(&self, cal: &Calibration, k: usize) -> Result<CameraModel> {
        let g = cal.camera(k).and_then(|c| c.geometry).ok_or_else(|| {
            Error::Input(format!(
                "camera {k} has no geometry; run the geometry step first"
            ))
        })?;
        Ok(qhm_imaging::pipeline::binned(&g, self.binning()))
    }

    /// Relative colour of the cameras from the colour pattern (reference: the top camera).
    pub fn colour(&self, cal: &mut Calibration, rows: &mut Vec<Row>) -> Result<()> {
        let q = self.colour_quality();
        if q != self.quality {
            return self.with(q, self.cameras.clone()).colour(cal, rows);
        }
        let world = self.world("colour-pattern")?;
        let exposures = [0.005, 0.02, 0.08];
        let brackets = self.capture(&world, &self.lamp_illum(0.0, 7), &exposures, 2)?;
        let patch = 9.0;
        // Texels (0.1 mm) finer than the pixels, so a patch's mean integrates
        // every pixel of it: the same photons for every camera (the Monte Carlo
        // noise cancels in the ratios) rather than ~20 point samples of it.
        let grid = Grid::centred(540, 0.1);
        let mut means = Vec::new();
        let mut measured = Vec::new();
        for (&k, frames) in self.cameras.iter().zip(&brackets) {
            let Ok(cam) = self.cam_at_binning(cal, k) else {
                rows.push(Row {
                    quantity: format!("camera {k} colour: no geometry"),
                    recovered: f64::NAN,
                    truth: f64::NAN,
                    error: f64::NAN,
                    target: "calibrated".into(),
                    ok: false,
                });
                continue;
            };
            measured.push(k);
            let hdr = self.merged(cal, k, frames, &exposures)?;
            let rect = rectify::rectify(&hdr, &cam, cal.axis(), 0.0, &grid, &[1.0; 3]);
            // Mean of the central half of each of the 24 patches (4 rows x 6 columns).
            let mut m = Vec::new();
            for row in 0..4 {
                for col in 0..6 {
                    let cx = -3.0 * patch + (col as f64 + 0.5) * patch;
                    let cy = 2.0 * patch - (row as f64 + 0.5) * patch;
                    let mut acc = [0.0; 3];
                    let mut n = 0.0;
                    for j in 0..grid.height {
                        for i in 0..grid.width {
                            let p = grid.texel_centre(i, j);
                            if (p.x - cx).abs() < patch / 4.0 && (p.y - cy).abs() < patch / 4.0 {
                                let v = [rect.get(i, j, 0), rect.get(i, j, 1), rect.get(i, j, 2)];
                                if v.iter().all(|x| x.is_finite()) {
                                    for c in 0..3 {
                                        acc[c] += v[c] as f64;
                                    }
                                    n += 1.0;
                                }
                            }
                        }
                    }
                    m.push(if n > 0.0 {
                        acc.map(|a| a / n)
                    } else {
                        [f64::NAN; 3]
                    });
                }
            }
            means.push(m);
        }
        let reference = measured
            .len()
            .checked_sub(1)
            .ok_or_else(|| Error::Input("no camera has geometry".into()))?;
        let gains = photometric::colour_gains(&means, reference)?;
        let kref = measured[reference];
        for (&k, g) in measured.iter().zip(&gains) {
            let mut worst = 0.0f64;
            for c in 0..3 {
                let truth = self.rig.cameras[kref].colour_gain[c]
                    / self.rig.cameras[k].colour_gain[c]
                    * self.response_scale(cal, kref, c)
                    / self.response_scale(cal, k, c);
                worst = worst.max((g[c] / truth - 1.0).abs());
            }
            rows.push(Row {
                quantity: format!("camera {k} colour gain max rel. err"),
                recovered: worst,
                truth: 0.0,
                error: worst,
                target: "< 0.01".into(),
                ok: worst < 0.01,
            });
            cal.camera_mut(k).colour_gain = Some(*g);
        }
        Ok(())
    }

    /// The camera the others' colour is calibrated against (the top one).
    fn reference_camera(&self) -> usize {
        self.cameras.last().copied().unwrap_or(7)
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
    /// two-height target measures it (light arc and turntable at LASER_ARC).
    fn true_plane_angle(&self, elev: f64) -> f64 {
        let az = hardware::NOMINAL_GEOMETRY.light_arc_azimuth0 + LASER_ARC;
        let geo = self.rig.laser_geometry(elev, LASER_ARC, 0.0);
        let horiz = (geo.origin - geo.centre)
            .truncate()
            .dot(DVec2::new(az.cos(), az.sin()));
        (geo.origin.z - geo.centre.z).atan2(horiz)
    }

    /// Lamp irradiance from the reference white (directions: nominal, see docs).
    pub fn lamps(&self, cal: &mut Calibration, rows: &mut Vec<Row>) -> Result<()> {
        let world = self.world("white")?;
        let rho = 0.95;
        let g = hardware::NOMINAL_GEOMETRY;
        let k = self.reference_camera();
        let cam = self.cam_at_binning(cal, k)?;
        let gain = cal
            .camera(k)
            .and_then(|c| c.colour_gain)
            .unwrap_or([1.0; 3]);
        for (li, lamp) in g.lamps.iter().enumerate().filter(|(_, l)| l.used) {
            let dir = DVec3::new(
                lamp.elevation.cos() * g.light_arc_azimuth0.cos(),
                lamp.elevation.cos() * g.light_arc_azimuth0.sin(),
                lamp.elevation.sin(),
            );
            let exposures = [0.01, 0.04, 0.16, 0.64];
            let frames = self
                .with(self.quality, vec![k])
                .capture(
                    &world,
                    &self.lamp_illum(0.0, li),
                    &exposures,
                    300 + li as u64,
                )?
                .remove(0);
            let hdr = self.merged(cal, k, &frames, &exposures)?;
            let grid = Grid::centred(200, 0.1);
            let rect =
                rectify::rectify(&hdr, &cam, cal.axis(), 0.0, &grid, &gain.map(|x| x as f32));
            let mut l = [0.0; 3];
            for c in 0..3 {
                let v: Vec<f64> = rect
                    .data
                    .iter()
                    .skip(c)
                    .step_by(3)
                    .filter(|v| v.is_finite())
                    .map(|&v| v as f64)
                    .collect();
                l[c] = v.iter().sum::<f64>() / v.len().max(1) as f64;
            }
            let e = photometric::lamp_irradiance(l, rho, dir.z)?;
            let mut worst = 0.0f64;
            for c in 0..3 {
                let truth = self.true_lamp_irradiance(li, c) * self.response_scale(cal, k, c);
                worst = worst.max((e[c] / truth - 1.0).abs());
            }
            rows.push(Row {
                quantity: format!("lamp {li} irradiance max rel. err"),
                recovered: worst,
                truth: 0.0,
                error: worst,
                target: "report".into(),
                ok: true,
            });
            cal.lamp.retain(|x| x.index != li);
            cal.lamp.push(LampCal {
                index: li,
                direction: dir.to_array(),
                irradiance: Some(e),
            });
        }
        cal.lamp.sort_by_key(|l| l.index);
        Ok(())
    }

    /// Laser-plane angle (two-height target) and flux per channel (reference white).
    pub fn laser(&self, cal: &mut Calibration, rows: &mut Vec<Row>) -> Result<()> {
        let k = self.reference_camera();
        let cam = self.cam_at_binning(cal, k)?;
        let gain = cal
            .camera(k)
            .and_then(|c| c.colour_gain)
            .unwrap_or([1.0; 3]);
        let one = self.with(self.quality, vec![k]);
        let g = hardware::NOMINAL_GEOMETRY;
        // The plane angle is measured with a mid-elevation camera (chosen when the top
        // one's focal rested on a distance prior; kept, docs/imaging.md).
        let k_geo = if self.cameras.contains(&4) { 4 } else { k };
        let cam_geo = self.cam_at_binning(cal, k_geo)?;
        let one_geo = self.with(self.quality, vec![k_geo]);
        let mut angles = Vec::new();
        // Two-height target (sample y < 0 low, y >= 0 high). The simulated stripe is
        // infinitely thin, so its image is a one-pixel line; along world y (light arc
        // at 0) it runs along the image rows and its sub-pixel position is lost. With
        // the light arc turned by LASER_ARC the stripe crosses the rows, and the
        // turntable turned by as much keeps it along sample y, across the step.
        let mut world = self.world("two-height")?;
        let (arc, theta) = (LASER_ARC, LASER_ARC);
        let axis = cal.axis();
        for &elev in &g.laser.positions {
            world.set_laser_mount(elev);
            let illum = Illumination {
                turntable_rad: theta,
                light_arc_rad: arc,
                galvo_rad: 0.0,
                laser: Some(LaserOn {
                    channel: 0,
                    power: 1.0,
                }),
                lamps: 0,
            };
            // A 10 mW stripe on white clips above ~0.1 ms: the bracket goes far below.
            let exposures = [2e-6, 8e-6, 3.2e-5, 1.28e-4, 5.12e-4, 2.048e-3];
            let frames = one_geo
                .capture(&world, &illum, &exposures, 400 + (elev * 1000.0) as u64)?
                .remove(0);
            let hdr = self.merged(cal, k_geo, &frames, &exposures)?;
            // 56 mm: at 30 deg the stripe on the high step is 17 mm from the low one,
            // plus the galvo's zero offset (~1 mm), plus the centroid's 1.5 mm reach.
            let grid = Grid::centred(560, 0.1);
            let mut halves = Vec::new();
            for (z, keep_low) in [(0.0, true), (10.0, false)] {
                let rect = rectify::rectify_at_height(
                    &hdr,
                    &cam_geo,
                    axis,
                    theta,
                    &grid,
                    &[1.0, 0.0, 0.0],
                    z,
                );
                // Only this step's half of the target, away from the edge.
                let mine = |y: f64| if keep_low { y < -2.0 } else { y > 2.0 };
                halves.push(photometric::stripe_centres(&rect, 0, &grid, mine));
            }
            // Towards the laser, in the sample frame.
            let az = g.light_arc_azimuth0 + arc;
            let towards = DMat3::from_rotation_z(-theta) * DVec3::new(az.cos(), az.sin(), 0.0);
            let d = photometric::parallel_offset(&halves[0], &halves[1], towards.truncate())
                .map_err(|e| Error::Input(format!("laser at {:.0} deg: {e}", elev.to_degrees())))?;
            let angle = 10f64.atan2(d);
            let truth = self.true_plane_angle(elev);
            let err = (angle - truth).to_degrees();
            rows.push(Row {
                quantity: format!("laser plane angle at {:.0} deg (deg)", elev.to_degrees()),
                recovered: angle.to_degrees(),
                truth: truth.to_degrees(),
                error: err.abs(),
                target: "< 0.2 deg".into(),
                ok: err.abs() < 0.2,
            });
            angles.push([elev, angle]);
        }
        // Flux: vertical stripe on the reference white, each laser.
        let mut world = self.world("white")?;
        world.set_laser_mount(PI / 2.0);
        let rho = 0.95;
        let mut flux = [0.0; 3];
        for c in 0..3 {
            let illum = Illumination {
                turntable_rad: 0.0,
                light_arc_rad: 0.0,
                galvo_rad: 0.0,
                laser: Some(LaserOn {
                    channel: c,
                    power: 1.0,
                }),
                lamps: 0,
            };
            let exposures = [2e-6, 8e-6, 3.2e-5, 1.28e-4, 5.12e-4, 2.048e-3];
            let frames = one
                .capture(&world, &illum, &exposures, 500 + c as u64)?
                .remove(0);
            let hdr = self.merged(cal, k, &frames, &exposures)?;
            // Texels far finer than a pixel: the stripe's image is a line one
            // pixel wide, and its bilinear interpolant summed on 0.2 mm texels
            // aliased (seed 3, ci: the flux -1.7, -2.7, -3.1 %; at 0.05 mm
            // -0.0, -1.0, -1.4 %).
            let grid = Grid::centred(800, 0.05);
            let mut scale = [0f32; 3];
            scale[c] = gain[c] as f32;
            let rect = rectify::rectify(&hdr, &cam, cal.axis(), 0.0, &grid, &scale);
            let vals: Vec<f32> = rect.data.iter().skip(c).step_by(3).copied().collect();
            // The whole 40 mm window sees 40 mm of the stripe (it runs along the window).
            let window = grid.width as f64 * grid.texel_mm;
            flux[c] =
                photometric::laser_flux_per_mm(&vals, grid.texel_mm * grid.texel_mm, rho, window)?;
            let truth = self.true_flux_per_mm(c) * self.response_scale(cal, k, c);
            let err = (flux[c] / truth - 1.0).abs();
            rows.push(Row {
                quantity: format!("laser {c} flux per mm rel. err"),
                recovered: flux[c],
                truth,
                error: err,
                target: "report".into(),
                ok: true,
            });
        }
        cal.laser = Some(LaserCal {
            plane_angles: angles,
            flux_per_mm: Some(flux),
        });
        Ok(())
    }

    /// The calibration the simulated rig truly has, in the units the steps
    /// use: a response table from the true curve, the true geometry, colour
    /// gains, lamps and laser. A fit from frames rectified with it has no
    /// calibration error, which separates the fit's errors from the steps'.
    pub fn truth(&self, cal: &mut Calibration) {
        let g = hardware::NOMINAL_GEOMETRY;
        let b = self.binning() as f64;
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
            cam.geometry = Some(full_res(&self.true_camera(k), b));
            cam.reprojection_rms_px = Some(0.0);
        }
        cal.turntable = Some(Turntable {
            axis: self.rig.turntable_axis,
        });
        cal.lamp = (g.lamps.iter().enumerate())
            .filter(|(_, l)| l.used)
            .map(|(li, _)| LampCal {
                index: li,
                direction: self.rig.lamps[li].direction,
                irradiance: Some(std::array::from_fn(|c| self.true_lamp_irradiance(li, c))),
            })
            .collect();
        let plane_angles = (g.laser.positions.iter())
            .map(|&elev| [elev, self.true_plane_angle(elev)])
            .collect();
        cal.laser = Some(LaserCal {
            plane_angles,
            flux_per_mm: Some(std::array::from_fn(|c| self.true_flux_per_mm(c))),
        });
    }
}

/// A camera at `pos` looking at the origin with image right = world +y (as the rig is built).
fn truth_like_camera(pos: DVec3, focal_px: f64, principal: [f64; 2], binning: u32) -> CameraModel {
    let forward = (-pos).normalize();
    let right = (DVec3::Y - forward * forward.dot(DVec3::Y)).normalize();
    let down = forward.cross(right);
    let r = DMat3::from_cols(right, down, forward).transpose();
    let b = binning as f64;
    let intr = Intrinsics {
        fx: focal_px / b,
        fy: focal_px / b,
        cx: principal[0] / b - 0.5,
        cy: principal[1] / b - 0.5,
        k1: 0.0,
        k2: 0.0,
    };
    CameraModel {
        intrinsics: intr,
        rotation: rodrigues_inv(r).to_array(),
        translation: (-(r * pos)).to_array(),
    }
}

/// A binned camera model back at full resolution (inverse of `pipeline::binned`).
pub fn full_res(m: &CameraModel, b: f64) -> CameraModel {
    let mut c = *m;
    let k = &mut c.intrinsics;
    k.fx *= b;
    k.fy *= b;
    k.cx = (k.cx + 0.5) * b - 0.5;
    k.cy = (k.cy + 0.5) * b - 0.5;
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim_light::RadianceImage;
    use sim_light::sensor::Sensor;

    /// Frames of a flat radiance merged through the true calibration read
    /// back that radiance in the reference camera's units, on every camera.
    #[test]
    fn true_calibration_reads_back_the_rig() {
        let sim = SimCalibrator::new(3, SimQuality::ci());
        let mut cal = Calibration::default();
        sim.truth(&mut cal);
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
                    let f = sensor.expose(&flat, t, SENSOR_GAIN, i as u64);
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
    }
}
