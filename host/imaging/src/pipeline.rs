//! The rectification pipeline over a whole capture: for every shot (one rig
//! pose, one light, one camera, an exposure bracket of 8-bit frames) merge the
//! bracket to HDR with the camera's response, rectify onto the texel grid with
//! the calibrated geometry, scale to radiance in camera units, and for laser
//! stripes fit the line and keep the user's distance interval; then write the
//! rectified dataset (`rectified` module). The capture layout is the caller's
//! business (`qhm rectify` maps qhm-acquire's plan onto [`Shot`]s).

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use crate::calibration::Calibration;
use crate::camera::CameraModel;
use crate::hdr::{self, MergeOptions};
use crate::image::{Image8, ImageF};
use crate::rectified::{Index, LampEntry, StripeEntry, Writer};
use crate::rectify::{self, Grid};
use crate::response::ResponseCurve;
use crate::shards::{Shard, ShardIndex, ShardSource, ShardWriter};
use crate::{Error, Result};

/// What lit a shot.
#[derive(Debug, Clone, PartialEq)]
pub enum ShotLight {
    /// A laser stripe: `channel` 0 red, 1 green, 2 blue; the clamp's nominal
    /// elevation; `power` the drive as a fraction of full power.
    Laser {
        pass: u8,
        channel: usize,
        clamp_elevation: f64,
        power: f64,
    },
    /// Lamp `index` on.
    Lamp { index: usize },
}

/// One rectified image to make.
#[derive(Debug, Clone, PartialEq)]
pub struct Shot {
    pub light: ShotLight,
    pub turntable: f64,
    pub light_arc: f64,
    pub camera: usize,
    /// The bracket: frame files (PNG) with exposure times, s.
    pub frames: Vec<(PathBuf, f64)>,
}

/// Options of the pipeline.
#[derive(Debug, Clone)]
pub struct RectifyOptions {
    pub grid: Grid,
    /// Sensor binning of the frames relative to the calibrated full resolution.
    pub binning: u32,
    /// Linear sensor gain the frames were taken with.
    pub sensor_gain: f64,
    /// Stripe texels: threshold as a fraction of the brightest texel.
    pub threshold: f64,
    /// Kept distance interval from the stripe line, mm.
    pub d_min: f64,
    pub d_max: f64,
    pub merge: MergeOptions,
    /// Light-arc azimuth at arc angle 0 (hardware geometry).
    pub light_arc_azimuth0: f64,
}

/// Read an 8-bit PNG as RGB.
pub fn read_png(path: &Path) -> Result<Image8> {
    let img = image::open(path)
        .map_err(|e| Error::Format {
            path: path.into(),
            msg: e.to_string(),
        })?
        .to_rgb8();
    let (w, h) = img.dimensions();
    Image8::new(w as usize, h as usize, 3, img.into_raw())
}

/// A full-resolution camera model as seen through `binning` x `binning` pixels.
pub fn binned(cam: &CameraModel, binning: u32) -> CameraModel {
    let b = binning.max(1) as f64;
    let mut c = *cam;
    let k = &mut c.intrinsics;
    // Pixel centres on integers: a binned pixel covers b full pixels starting at b i - 0.5.
    k.fx /= b;
    k.fy /= b;
    k.cx = (k.cx + 0.5) / b - 0.5;
    k.cy = (k.cy + 0.5) / b - 0.5;
    c
}

fn spherical(elevation: f64, azimuth: f64) -> DVec3 {
    DVec3::new(
        elevation.cos() * azimuth.cos(),
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
    )
}

/// The rectified image of one shot plus its index entry (file left empty).
pub enum Rectified {
    Stripe(ImageF, StripeEntry),
    Lamp(ImageF, LampEntry),
}

/// Process one shot.
pub fn process_shot(shot: &Shot, cal: &Calibration, opts: &RectifyOptions) -> Result<Rectified> {
    let camcal = cal
        .camera(shot.camera)
        .ok_or_else(|| Error::Input(format!("camera {} is not in the calibration", shot.camera)))?;
    let geometry = camcal.geometry.as_ref().ok_or_else(|| {
        Error::Input(format!(
            "camera {} has no geometric calibration",
            shot.camera
        ))
    })?;
    let response: Vec<ResponseCurve> = if camcal.response.is_empty() {
        vec![ResponseCurve::linear_camera()]
    } else {
        camcal.response.clone()
    };
    let frames: Vec<Image8> = shot
        .frames
        .iter()
        .map(|(p, _)| read_png(p))
        .collect::<Result<_>>()?;
    let refs: Vec<&Image8> = frames.iter().collect();
    let exposures: Vec<f64> = shot.frames.iter().map(|(_, t)| *t).collect();
    let hdr = hdr::merge(&refs, &exposures, &response, opts.merge)?;
    let cam = binned(geometry, opts.binning);
    let gain = camcal.colour_gain.unwrap_or([1.0; 3]);
    let scale: Vec<f32> = (0..3)
        .map(|c| (gain[c] / opts.sensor_gain) as f32)
        .collect();
    let axis = cal.axis();
    let mut rect = rectify::rectify(&hdr, &cam, axis, shot.turntable, &opts.grid, &scale);
    let view_dir = rectify::direction_in_sample(geometry.centre(), axis, shot.turntable);
    let to_sample = rectify::sample_to_world(axis, shot.turntable).transpose();
    match &shot.light {
        ShotLight::Laser {
            pass,
            channel,
            clamp_elevation,
            power,
        } => {
            let c = *channel;
            if c > 2 {
                return Err(Error::Input(format!("laser channel {c}")));
            }
            for (k, v) in rect.data.iter_mut().enumerate() {
                if k % 3 != c && v.is_finite() {
                    *v = 0.0;
                }
            }
            // The threshold is relative to a robust peak (the 99th percentile),
            // not the maximum: one Monte Carlo or sensor outlier must not put
            // the whole stripe below it.
            let mut values: Vec<f32> = rect
                .data
                .iter()
                .skip(c)
                .step_by(3)
                .copied()
                .filter(|v| v.is_finite())
                .collect();
            let peak = if values.is_empty() {
                0.0
            } else {
                let k = ((values.len() - 1) as f64 * 0.99).round() as usize;
                *values.select_nth_unstable_by(k, f32::total_cmp).1
            };
            let line =
                rectify::fit_stripe_line(&rect, c, &opts.grid, peak * opts.threshold as f32)?;
            rectify::keep_distance_interval(
                &mut rect, &opts.grid, &line, c, opts.d_min, opts.d_max,
            );
            let laser = cal.laser.as_ref();
            // The laser plane's measured angle stands for the emission elevation.
            let elevation = laser
                .and_then(|l| {
                    l.plane_angles
                        .iter()
                        .min_by(|a, b| {
                            (a[0] - clamp_elevation)
                                .abs()
                                .total_cmp(&(b[0] - clamp_elevation).abs())
                        })
                        .filter(|a| (a[0] - clamp_elevation).abs() < 1e-3)
                        .map(|a| a[1])
                })
                .unwrap_or(*clamp_elevation);
            let emitter = spherical(elevation, opts.light_arc_azimuth0 + shot.light_arc) * 600.0;
            let centre_w = rectify::sample_to_world(axis, shot.turntable)
                * DVec3::new(line.point.x, line.point.y, 0.0);
            let light_dir = (to_sample * (emitter - centre_w)).normalize();
            let flux = laser
                .and_then(|l| l.flux_per_mm)
                .map_or(f64::NAN, |f| f[c] * power);
            let entry = StripeEntry {
                file: String::new(),
                pass: *pass,
                channel: c as u8,
                light_dir: light_dir.to_array(),
                view_dir: view_dir.to_array(),
                camera: shot.camera as u32,
                flux_per_mm: flux,
                line_point: line.point.to_array(),
                line_dir: line.dir.to_array(),
            };
            Ok(Rectified::Stripe(rect, entry))
        }
        ShotLight::Lamp { index } => {
            let lamp = cal.lamp.iter().find(|l| l.index == *index);
            let dir_w = lamp
                .map(|l| DVec3::from(l.direction))
                .ok_or_else(|| Error::Input(format!("lamp {index} is not in the calibration")))?;
            let dir_w = glam::DMat3::from_rotation_z(shot.light_arc) * dir_w;
            let entry = LampEntry {
                file: String::new(),
                light_dir: (to_sample * dir_w).normalize().to_array(),
                view_dir: view_dir.to_array(),
                camera: shot.camera as u32,
                irradiance: lamp.and_then(|l| l.irradiance).unwrap_or([f64::NAN; 3]),
            };
            Ok(Rectified::Lamp(rect, entry))
        }
    }
}

/// Process every shot (in parallel, in chunks) and write `out` (CAPTURE_DIR/rectified).
/// `progress(done, total)` is called as shots finish.
pub fn rectify_capture(
    shots: &[Shot],
    cal: &Calibration,
    opts: &RectifyOptions,
    out: &Path,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Index> {
    let mut writer = Writer::create(out, opts.grid)?;
    writer.set_calibration(crate::rectified::calibration_summary(cal));
    let mut done = 0;
    // Chunks bound memory and keep the index in shot order.
    for chunk in shots.chunks(64) {
        let results: Vec<Result<Rectified>> = chunk
            .par_iter()
            .map(|s| process_shot(s, cal, opts))
            .collect();
        for r in results {
            match r? {
                Rectified::Stripe(img, e) => writer.add_stripe(&img, e)?,
                Rectified::Lamp(img, e) => writer.add_lamp(&img, e)?,
            }
            done += 1;
            progress(done, shots.len());
        }
    }
    writer.finish()
}

/// Process share `shard` of the shots (see the `shards` module) into `out`
/// (CAPTURE_DIR/rectified), each image under its number in the whole
/// dataset; `force` as for [`ShardWriter::create`]. `progress(done, total)`
/// counts this share's shots.
#[allow(clippy::too_many_arguments)]
pub fn rectify_shard(
    shots: &[Shot],
    cal: &Calibration,
    opts: &RectifyOptions,
    out: &Path,
    shard: Shard,
    source: ShardSource,
    force: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<ShardIndex> {
    // A shot's image number is its rank among the shots of its kind, as the
    // unsharded writer numbers them.
    let (mut stripes, mut lamps) = (0, 0);
    let numbers: Vec<usize> = shots
        .iter()
        .map(|s| {
            let counter = match s.light {
                ShotLight::Laser { .. } => &mut stripes,
                ShotLight::Lamp { .. } => &mut lamps,
            };
            *counter += 1;
            *counter - 1
        })
        .collect();
    let mine: Vec<usize> = (0..shots.len()).filter(|&i| shard.takes(i)).collect();
    let mut writer = ShardWriter::create(out, opts.grid, shard, source, stripes, lamps, force)?;
    writer.set_calibration(crate::rectified::calibration_summary(cal));
    let mut done = 0;
    for chunk in mine.chunks(64) {
        let results: Vec<Result<Rectified>> = chunk
            .par_iter()
            .map(|&i| process_shot(&shots[i], cal, opts))
            .collect();
        for (&i, r) in chunk.iter().zip(results) {
            match r? {
                Rectified::Stripe(img, e) => writer.add_stripe(numbers[i], &img, e)?,
                Rectified::Lamp(img, e) => writer.add_lamp(numbers[i], &img, e)?,
            }
            done += 1;
            progress(done, mine.len());
        }
    }
    writer.finish()
}

/// The unit vector in the sample frame from `p` (sample xy) towards a world point.
pub fn towards(world: DVec3, p: DVec2, axis: DVec3, theta: f64) -> DVec3 {
    let to_sample = rectify::sample_to_world(axis, theta).transpose();
    (to_sample * world - DVec3::new(p.x, p.y, 0.0)).normalize()
}
