//! The calibration procedures on the frames of a calibration capture,
//! whatever rig took them: camera responses (Mitsunaga-Nayar), Zhang's
//! intrinsics, distortion and poses with the turntable axis, relative colour,
//! lamp irradiance, laser-plane angles and laser flux (docs/imaging.md).
//!
//! The input is a list of [`CalShot`]s: one bracket of one camera at one rig
//! pose, with the procedure it feeds (the caller builds them from the
//! capture's plan). [`compute`] runs the procedures in dependency order into
//! a [`Calibration`]; the first camera or target a procedure cannot use
//! stops it with an error that names both, and the calibration is left
//! unchanged.

use std::f64::consts::PI;
use std::path::PathBuf;

use glam::{DMat3, DQuat, DVec2, DVec3};
use rayon::prelude::*;

use crate::calibration::{Calibration, LampCal, LaserCal, Turntable};
use crate::camera::{CameraModel, Intrinsics, rodrigues, rodrigues_inv};
use crate::corners::detect_board;
use crate::hdr::{self, MergeOptions};
use crate::image::{Image8, ImageF};
use crate::photometric;
use crate::pipeline::{binned, read_png};
use crate::rectify::{self, Grid};
use crate::response::{self, Bracket, MnOptions};
use crate::zhang::{self, PlanarView, Raised, ZhangOptions};
use crate::{Error, Result};

/// Which procedure a shot feeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Procedure {
    Response,
    Geometry,
    Colour,
    Lamp,
    LaserPlane,
    LaserFlux,
}

/// The light of a shot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShotLight {
    /// Lamp index.
    Lamp(usize),
    /// Laser channel (0 red, 1 green, 2 blue).
    Laser(usize),
}

/// One exposure bracket of one camera at one rig pose.
#[derive(Debug, Clone)]
pub struct CalShot {
    pub procedure: Procedure,
    /// The target on the turntable, as the operator was asked for it.
    pub target: String,
    /// Height of the target's top surface above the turntable, mm.
    pub height_mm: f64,
    pub camera: usize,
    /// Turntable and light-arc angles, radians.
    pub turntable: f64,
    pub light_arc: f64,
    /// Laser clamp elevation, radians (laser shots).
    pub clamp: Option<f64>,
    pub light: ShotLight,
    /// Sensor binning of the frames.
    pub binning: u32,
    /// Frames with their exposure (times the sensor gain), shortest first.
    pub frames: Vec<(PathBuf, f64)>,
}

impl CalShot {
    /// "camera 3, checkerboard at turntable 11.5 deg": for errors.
    fn name(&self) -> String {
        format!(
            "camera {}, {} at turntable {:.1} deg",
            self.camera,
            self.target,
            self.turntable.to_degrees()
        )
    }

    fn fail(&self, why: impl std::fmt::Display) -> Error {
        Error::Input(format!("{}: {why}", self.name()))
    }

    fn read(&self) -> Result<(Vec<Image8>, Vec<f64>)> {
        let mut frames = Vec::new();
        for (path, _) in &self.frames {
            frames.push(read_png(path)?);
        }
        Ok((frames, self.frames.iter().map(|f| f.1).collect()))
    }
}

/// Reflectance of the reference white (its datasheet value).
pub const WHITE_ALBEDO: f64 = 0.95;
/// Step height of the two-height target, mm (the high half is at y >= 0).
pub const TWO_HEIGHT_STEP_MM: f64 = 10.0;
/// The checkerboard: inner corners every 5 mm, 11 x 11 of them, 12 x 12 squares.
const SQUARE_MM: f64 = 5.0;

/// Mitsunaga-Nayar with the shutter times taken as exact (set free, the
/// ratios absorb the noise's bias and the curve is off by 1-2 %), on
/// 60 000 sampled pixels (at 20 000, the simulated rig of seed 2 left
/// camera 1's curve 1.4 % off).
fn mn_options() -> MnOptions {
    MnOptions {
        refine_ratios: false,
        samples: 60_000,
        ..MnOptions::default()
    }
}

/// Cameras whose view is within this angle of straight down (radians) fit fy
/// apart from fx. A flat board's foreshortening compresses the image along the
/// camera's tilt as a pixel aspect would (to first order by sin(tilt)): the
/// steep cameras (5, 6, 7: 26, 13, 0 deg) see the aspect free of it and fit it
/// (top camera, seed 2: focal 0.47 -> 0.05 %, centre 15 -> 0.3 mm); for cameras
/// 3 and 4 a free aspect traded against their poses (focal 0.1 -> 0.45 %, and
/// camera 4's poses moved the laser-plane angle by up to 0.27 deg).
const ASPECT_MAX_TILT: f64 = 30.0 * PI / 180.0;

/// Runs every procedure the shots feed, in dependency order (response,
/// geometry, colour, lamps, laser plane, laser flux), into `cal`; `progress`
/// hears each procedure's name as it starts. On error `cal` is unchanged.
pub fn compute(shots: &[CalShot], cal: &mut Calibration, progress: &dyn Fn(&str)) -> Result<()> {
    let mut next = cal.clone();
    let of =
        |p: Procedure| -> Vec<&CalShot> { shots.iter().filter(|s| s.procedure == p).collect() };
    type Step = fn(&[&CalShot], &mut Calibration) -> Result<()>;
    let steps: [(&str, Procedure, Step); 6] = [
        ("response", Procedure::Response, response),
        ("geometry", Procedure::Geometry, geometry),
        ("colour", Procedure::Colour, colour),
        ("lamps", Procedure::Lamp, lamps),
        ("laser plane", Procedure::LaserPlane, laser_plane),
        ("laser flux", Procedure::LaserFlux, laser_flux),
    ];
    for (name, p, step) in steps {
        let mine = of(p);
        if mine.is_empty() {
            return Err(Error::Input(format!(
                "the calibration capture has no frames for the {name} step"
            )));
        }
        progress(name);
        step(&mine, &mut next)?;
    }
    *cal = next;
    Ok(())
}

/// The response of every camera with response shots (one curve per channel).
fn response(shots: &[&CalShot], cal: &mut Calibration) -> Result<()> {
    let fitted: Vec<Result<Vec<_>>> = shots
        .par_iter()
        .map(|s| {
            let (frames, exposures) = s.read()?;
            let b = Bracket { frames, exposures };
            (0..3)
                .map(|c| response::fit_mitsunaga_nayar(&b, c, mn_options()).map(|f| f.curve))
                .collect::<Result<Vec<_>>>()
                .map_err(|e| s.fail(format!("response: {e}")))
        })
        .collect();
    for (s, curves) in shots.iter().zip(fitted) {
        cal.camera_mut(s.camera).response = curves?;
    }
    Ok(())
}

/// The shot's bracket merged to linear radiance with the camera's response.
fn merged(cal: &Calibration, s: &CalShot) -> Result<ImageF> {
    let resp = cal
        .camera(s.camera)
        .map(|c| c.response.clone())
        .filter(|r| !r.is_empty())
        .ok_or_else(|| s.fail("no response curve (the response step did not measure it)"))?;
    let (frames, exposures) = s.read()?;
    let refs: Vec<&Image8> = frames.iter().collect();
    hdr::merge(&refs, &exposures, &resp, MergeOptions::default())
}

/// Camera k's calibrated geometry at the shot's binning.
fn cam_at(cal: &Calibration, s: &CalShot) -> Result<CameraModel> {
    let g = (cal.camera(s.camera).and_then(|c| c.geometry))
        .ok_or_else(|| s.fail("no geometry (the checkerboard step did not calibrate it)"))?;
    Ok(binned(&g, s.binning))
}

/// The nominal camera k (hardware geometry) at `binning`.
pub fn nominal_camera(k: usize, binning: u32) -> CameraModel {
    let g = hardware::NOMINAL_GEOMETRY;
    let m = g.cameras[k];
    let pos = DVec3::new(
        m.elevation.cos() * m.azimuth.cos(),
        m.elevation.cos() * m.azimuth.sin(),
        m.elevation.sin(),
    ) * m.distance;
    // Looking at the origin with image right = world +y (as the rig is built).
    let forward = (-pos).normalize();
    let right = (DVec3::Y - forward * forward.dot(DVec3::Y)).normalize();
    let down = forward.cross(right);
    let r = DMat3::from_cols(right, down, forward).transpose();
    let full = CameraModel {
        intrinsics: Intrinsics {
            fx: g.sensor.focal_px,
            fy: g.sensor.focal_px,
            cx: g.sensor.width as f64 / 2.0 - 0.5,
            cy: g.sensor.height as f64 / 2.0 - 0.5,
            k1: 0.0,
            k2: 0.0,
        },
        rotation: rodrigues_inv(r).to_array(),
        translation: (-(r * pos)).to_array(),
    };
    binned(&full, binning)
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

/// The board's corners found in one frame of camera k, the board's top at
/// z = `height` turned by `theta`; None if too few are visible or found.
fn board_view(
    img: &Image8,
    nominal: &CameraModel,
    theta: f64,
    height: f64,
    board: &[DVec2],
) -> Option<PlanarView> {
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
        nominal.project(rz * DVec3::new(SQUARE_MM, 0.0, height)),
        nominal.project(rz * DVec3::new(0.0, SQUARE_MM, height)),
        nominal.project(rz * DVec3::new(0.0, 0.0, height)),
    ) {
        (Some(a), Some(c), Some(o)) => (a - o).length().min((c - o).length()),
        _ => return None,
    };
    // The 12 x 12 squares' centres and colours (bright where floor(x/5) + floor(y/5) is odd).
    let squares: Vec<(DVec2, bool)> = (-6..6)
        .flat_map(|j: i32| (-6..6).map(move |i: i32| (i, j)))
        .filter_map(|(i, j)| {
            let c = DVec3::new(
                (i as f64 + 0.5) * SQUARE_MM,
                (j as f64 + 0.5) * SQUARE_MM,
                height,
            );
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
            (at(DVec3::X * SQUARE_MM) - o, at(DVec3::Y * SQUARE_MM) - o)
        })
        .collect();
    let gray = img.gray_f32();
    let found = detect_board(
        &gray, img.width, img.height, &pts, &axes, &squares, square_px,
    )
    .ok()?;
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

/// Intrinsics, distortion and poses (Zhang), turntable axis, from the
/// checkerboard on the turntable and on the spacer: a raised view is tied to
/// the view of the same camera and turntable angle on the turntable, and the
/// image scale's change with the known height separates focal length and
/// distance, which the flat board alone cannot for the top camera.
fn geometry(shots: &[&CalShot], cal: &mut Calibration) -> Result<()> {
    // Inner corners of the 60 mm board of 5 mm squares, sample frame.
    let board: Vec<DVec2> = (-5..=5)
        .flat_map(|j| (-5..=5).map(move |i| DVec2::new(i as f64 * SQUARE_MM, j as f64 * SQUARE_MM)))
        .collect();
    let mut cameras: Vec<usize> = shots.iter().map(|s| s.camera).collect();
    cameras.sort_unstable();
    cameras.dedup();
    // The cameras are independent; each one's result is applied in order.
    let fitted: Vec<Result<(CameraModel, f64, Option<DVec3>)>> = cameras
        .par_iter()
        .map(|&k| camera_geometry(k, shots, &board))
        .collect();
    let mut axis_samples = Vec::new();
    for (k, fitted) in cameras.into_iter().zip(fitted) {
        let (model, rms_px, axis) = fitted?;
        axis_samples.extend(axis);
        let c = cal.camera_mut(k);
        c.geometry = Some(model);
        c.reprojection_rms_px = Some(rms_px);
    }
    if !axis_samples.is_empty() {
        let axis = (axis_samples.iter().copied().sum::<DVec3>()).normalize();
        cal.turntable = Some(Turntable {
            axis: axis.to_array(),
        });
    }
    Ok(())
}

/// Camera `k`'s model (full resolution) and reprojection RMS (full-resolution
/// px) from its checkerboard views, and the turntable axis its views show
/// when they span enough of a turn.
fn camera_geometry(
    k: usize,
    shots: &[&CalShot],
    board: &[DVec2],
) -> Result<(CameraModel, f64, Option<DVec3>)> {
    let g = hardware::NOMINAL_GEOMETRY;
    let mut mine: Vec<&CalShot> = shots.iter().copied().filter(|s| s.camera == k).collect();
    // On the turntable first: the raised views refer to them.
    mine.sort_by(|a, b| a.height_mm.total_cmp(&b.height_mm));
    let b = mine[0].binning;
    if let Some(s) = mine.iter().find(|s| s.binning != b) {
        return Err(s.fail(format!("binning {} differs from {b}", s.binning)));
    }
    let nominal = nominal_camera(k, b);
    // Corners of every view at once (the frames are independent); the
    // raised views are then matched to theirs in order.
    let found: Vec<Option<PlanarView>> = mine
        .par_iter()
        .map(|s| {
            let (frames, _) = s.read()?;
            let frame = frames.last().ok_or_else(|| s.fail("no frame"))?;
            Ok(board_view(frame, &nominal, s.turntable, s.height_mm, board))
        })
        .collect::<Result<_>>()?;
    let mut views: Vec<PlanarView> = Vec::new();
    let mut thetas: Vec<f64> = Vec::new();
    for (s, found) in mine.iter().zip(found) {
        let raised = if s.height_mm > 0.0 {
            let base = (0..views.len())
                .find(|&i| views[i].raised.is_none() && (thetas[i] - s.turntable).abs() < 1e-9);
            match base {
                Some(base) => Some(Raised {
                    base,
                    height_mm: s.height_mm,
                }),
                None => continue,
            }
        } else {
            None
        };
        let Some(mut v) = found else {
            continue;
        };
        v.raised = raised;
        views.push(v);
        thetas.push(s.turntable);
    }
    let on_table: Vec<usize> = (0..views.len())
        .filter(|&i| views[i].raised.is_none())
        .collect();
    if on_table.len() < 2 {
        return Err(Error::Input(format!(
            "camera {k}: the {} was found in {} of {} views on the turntable (2 needed)",
            mine[0].target,
            on_table.len(),
            mine.iter().filter(|s| s.height_mm <= 0.0).count(),
        )));
    }
    let bf = b as f64;
    let opts = ZhangOptions {
        image_width: (g.sensor.width as f64 / bf) as usize,
        image_height: (g.sensor.height as f64 / bf) as usize,
        distortion: true,
        fix_principal_point: true,
        // The mechanical distance only when no raised view gives it.
        centre_distance: (on_table.len() == views.len()).then_some((g.cameras[k].distance, 1.0)),
        initial_focal: Some(g.sensor.focal_px / bf),
        // The lens's centring tolerance, ~4 px at full resolution.
        principal_sd: Some(4.0 / bf),
        // fy apart from fx where the board's tilt does not mimic it.
        fit_aspect: PI / 2.0 - g.cameras[k].elevation <= ASPECT_MAX_TILT,
    };
    let res = zhang::calibrate(&views, opts).map_err(|e| {
        Error::Numeric(format!(
            "camera {k}: Zhang's calibration on the {}: {e}",
            mine[0].target
        ))
    })?;
    // World pose: views are sample -> camera at turntable theta_i; world = Rz(theta) sample.
    let mut q_sum = glam::DVec4::ZERO;
    let mut t_sum = DVec3::ZERO;
    let mut q0: Option<DQuat> = None;
    for &i in &on_table {
        let (r, t) = &res.poses[i];
        let rcw = rodrigues(*r) * DMat3::from_rotation_z(thetas[i]).transpose();
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
    let model = CameraModel {
        intrinsics: res.intrinsics,
        rotation: rodrigues_inv(DMat3::from_quat(q)).to_array(),
        translation: (t_sum / on_table.len() as f64).to_array(),
    };
    // Turntable axis from the relative rotation of the first and last views (sample frame).
    let r0 = rodrigues(res.poses[on_table[0]].0);
    let r1 = rodrigues(res.poses[on_table[on_table.len() - 1]].0);
    let (ax, ang) = DQuat::from_mat3(&(r0.transpose() * r1)).to_axis_angle();
    let axis = (ang.abs() > 0.3).then_some(if ax.z < 0.0 { -ax } else { ax });
    Ok((full_res(&model, bf), res.rms * bf, axis))
}

/// Relative colour of the cameras from the colour pattern, against the
/// highest camera measured (the top one).
fn colour(shots: &[&CalShot], cal: &mut Calibration) -> Result<()> {
    let patch = 9.0;
    // Texels (0.1 mm) finer than the pixels, so a patch's mean integrates
    // every pixel of it: the same photons for every camera (Monte Carlo
    // noise of a simulated rig cancels in the ratios) rather than ~20 point
    // samples of it.
    let grid = Grid::centred(540, 0.1);
    let mut sorted: Vec<&CalShot> = shots.to_vec();
    sorted.sort_by_key(|s| s.camera);
    let mut means = Vec::new();
    for s in &sorted {
        let cam = cam_at(cal, s)?;
        let hdr = merged(cal, s)?;
        let rect = rectify::rectify(&hdr, &cam, cal.axis(), s.turntable, &grid, &[1.0; 3]);
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
    let gains = photometric::colour_gains(&means, sorted.len() - 1)
        .map_err(|e| Error::Input(format!("{}: colour gains: {e}", sorted[0].target)))?;
    for (s, g) in sorted.iter().zip(&gains) {
        cal.camera_mut(s.camera).colour_gain = Some(*g);
    }
    Ok(())
}

/// The mean of channel `c` over the finite texels of a rectified image.
fn channel_mean(rect: &ImageF, c: usize) -> f64 {
    let v: Vec<f64> = (rect.data.iter().skip(c).step_by(3))
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .collect();
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Lamp irradiance from the reference white (directions: nominal, see docs).
fn lamps(shots: &[&CalShot], cal: &mut Calibration) -> Result<()> {
    let g = hardware::NOMINAL_GEOMETRY;
    for s in shots {
        let ShotLight::Lamp(li) = s.light else {
            return Err(s.fail("a lamp shot without a lamp"));
        };
        let lamp = g
            .lamps
            .get(li)
            .ok_or_else(|| s.fail(format!("no lamp {li}")))?;
        let az = g.light_arc_azimuth0 + s.light_arc;
        let dir = DVec3::new(
            lamp.elevation.cos() * az.cos(),
            lamp.elevation.cos() * az.sin(),
            lamp.elevation.sin(),
        );
        let cam = cam_at(cal, s)?;
        let gain = (cal.camera(s.camera).and_then(|c| c.colour_gain)).unwrap_or([1.0; 3]);
        let hdr = merged(cal, s)?;
        let grid = Grid::centred(200, 0.1);
        let rect = rectify::rectify(
            &hdr,
            &cam,
            cal.axis(),
            s.turntable,
            &grid,
            &gain.map(|x| x as f32),
        );
        let l = std::array::from_fn(|c| channel_mean(&rect, c));
        let e = photometric::lamp_irradiance(l, WHITE_ALBEDO, dir.z)
            .map_err(|e| s.fail(format!("lamp {li}: {e}")))?;
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

/// Laser-plane angle at each clamp elevation from the two-height target
/// (the low half at y < 0, the high one `TWO_HEIGHT_STEP_MM` up at y >= 0).
/// The stripe's image is one pixel wide; along world y (light arc at 0) it
/// would run along the image rows and its sub-pixel position be lost, so the
/// light arc is turned, and the turntable by as much to keep the stripe along
/// sample y, across the step.
fn laser_plane(shots: &[&CalShot], cal: &mut Calibration) -> Result<()> {
    let g = hardware::NOMINAL_GEOMETRY;
    let mut angles = Vec::new();
    for s in shots {
        let elev = s
            .clamp
            .ok_or_else(|| s.fail("a laser shot without a clamp elevation"))?;
        let cam = cam_at(cal, s)?;
        let hdr = merged(cal, s)?;
        let channel = match s.light {
            ShotLight::Laser(c) => c,
            ShotLight::Lamp(_) => return Err(s.fail("a laser-plane shot under a lamp")),
        };
        let mut weights = [0.0f32; 3];
        weights[channel] = 1.0;
        // 56 mm: at 30 deg the stripe on the high step is 17 mm from the low one,
        // plus the galvo's zero offset (~1 mm), plus the centroid's 1.5 mm reach.
        let grid = Grid::centred(560, 0.1);
        let mut halves = Vec::new();
        for (z, keep_low) in [(0.0, true), (TWO_HEIGHT_STEP_MM, false)] {
            let rect =
                rectify::rectify_at_height(&hdr, &cam, cal.axis(), s.turntable, &grid, &weights, z);
            // Only this step's half of the target, away from the edge.
            let mine = |y: f64| if keep_low { y < -2.0 } else { y > 2.0 };
            halves.push(photometric::stripe_centres(&rect, channel, &grid, mine));
        }
        // Towards the laser, in the sample frame.
        let az = g.light_arc_azimuth0 + s.light_arc;
        let towards = DMat3::from_rotation_z(-s.turntable) * DVec3::new(az.cos(), az.sin(), 0.0);
        let d = photometric::parallel_offset(&halves[0], &halves[1], towards.truncate())
            .map_err(|e| s.fail(format!("laser at {:.0} deg: {e}", elev.to_degrees())))?;
        angles.push([elev, TWO_HEIGHT_STEP_MM.atan2(d)]);
    }
    angles.sort_by(|a, b| b[0].total_cmp(&a[0]));
    let flux = cal.laser.as_ref().and_then(|l| l.flux_per_mm);
    cal.laser = Some(LaserCal {
        plane_angles: angles,
        flux_per_mm: flux,
    });
    Ok(())
}

/// Laser flux per mm of stripe, each channel, from the vertical stripe on the
/// reference white.
fn laser_flux(shots: &[&CalShot], cal: &mut Calibration) -> Result<()> {
    let mut flux = [f64::NAN; 3];
    for s in shots {
        let ShotLight::Laser(c) = s.light else {
            return Err(s.fail("a laser-flux shot under a lamp"));
        };
        let cam = cam_at(cal, s)?;
        let gain = (cal.camera(s.camera).and_then(|c| c.colour_gain)).unwrap_or([1.0; 3]);
        let hdr = merged(cal, s)?;
        // Texels far finer than a pixel: the stripe's image is a line one
        // pixel wide, and its bilinear interpolant summed on 0.2 mm texels
        // aliased (seed 3, ci: the flux -1.7, -2.7, -3.1 %; at 0.05 mm
        // -0.0, -1.0, -1.4 %).
        let grid = Grid::centred(800, 0.05);
        let mut scale = [0f32; 3];
        scale[c] = gain[c] as f32;
        let rect = rectify::rectify(&hdr, &cam, cal.axis(), s.turntable, &grid, &scale);
        let vals: Vec<f32> = rect.data.iter().skip(c).step_by(3).copied().collect();
        // The whole 40 mm window sees 40 mm of the stripe (it runs along the window).
        let window = grid.width as f64 * grid.texel_mm;
        flux[c] = photometric::laser_flux_per_mm(
            &vals,
            grid.texel_mm * grid.texel_mm,
            WHITE_ALBEDO,
            window,
        )
        .map_err(|e| s.fail(format!("laser {c} flux: {e}")))?;
    }
    if let Some(c) = flux.iter().position(|f| !f.is_finite()) {
        return Err(Error::Input(format!(
            "the calibration capture has no laser-flux frames of laser {c}"
        )));
    }
    let angles = cal
        .laser
        .as_ref()
        .map_or(Vec::new(), |l| l.plane_angles.clone());
    cal.laser = Some(LaserCal {
        plane_angles: angles,
        flux_per_mm: Some(flux),
    });
    Ok(())
}
