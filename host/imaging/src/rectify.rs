//! Rectification onto the reference plane (paper 4.2): every image resampled
//! at the texel centres of the sample's top surface (z = 0 in the sample frame,
//! which turns with the turntable), and laser stripe lines.
//!
//! For a point p of the sample frame, the world point is R_axis(theta) p; the
//! calibrated camera projects it (with distortion) to a pixel, and the image is
//! sampled bilinearly there. A texel is the mean of such samples over its
//! area, at most half a pixel apart: sums over texels then keep the flux of
//! features a pixel wide (a stripe's core), which a texel-centre sample
//! alone aliases by several per cent at CI scale. Stripes: texels brighter
//! than a threshold give a line by weighted total least squares; texels are
//! kept within a distance interval from that line, with their distances.

use glam::{DMat3, DVec2, DVec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::CameraModel;
use crate::image::ImageF;
use crate::{Error, Result};

/// The texel grid on the reference plane (the contract's `[grid]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub width: usize,
    pub height: usize,
    pub texel_mm: f64,
    /// Sample-frame xy of texel (0, 0)'s outer corner, mm.
    pub origin_mm: [f64; 2],
}

impl Grid {
    /// A square grid of `n` texels centred on the turntable axis.
    pub fn centred(n: usize, texel_mm: f64) -> Self {
        let half = n as f64 * texel_mm / 2.0;
        Grid {
            width: n,
            height: n,
            texel_mm,
            origin_mm: [-half, -half],
        }
    }
    /// Sample-frame xy of texel (i, j)'s centre.
    pub fn texel_centre(&self, i: usize, j: usize) -> DVec2 {
        DVec2::new(
            self.origin_mm[0] + (i as f64 + 0.5) * self.texel_mm,
            self.origin_mm[1] + (j as f64 + 0.5) * self.texel_mm,
        )
    }
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return Err(Error::Input(format!("grid {}x{}", self.width, self.height)));
        }
        if !(self.texel_mm > 0.0 && self.texel_mm.is_finite()) {
            return Err(Error::Input(format!("texel size {} mm", self.texel_mm)));
        }
        Ok(())
    }
}

/// Sample frame -> world at turntable angle `theta` about the (unit) `axis` through the origin.
pub fn sample_to_world(axis: DVec3, theta: f64) -> DMat3 {
    DMat3::from_axis_angle(axis.normalize(), theta)
}

/// Resample `img` onto `grid` as seen by `cam` with the turntable at `theta`.
/// `scale[c]` multiplies channel c (exposure, colour gain, radiometric scale).
/// Texels that project outside the image, or onto NaN pixels, are NaN.
pub fn rectify(
    img: &ImageF,
    cam: &CameraModel,
    axis: DVec3,
    theta: f64,
    grid: &Grid,
    scale: &[f32],
) -> ImageF {
    rectify_at_height(img, cam, axis, theta, grid, scale, 0.0)
}

/// As [`rectify`], onto the plane z = `plane_z` of the sample frame (calibration
/// targets with a raised surface).
pub fn rectify_at_height(
    img: &ImageF,
    cam: &CameraModel,
    axis: DVec3,
    theta: f64,
    grid: &Grid,
    scale: &[f32],
    plane_z: f64,
) -> ImageF {
    // Sample -> camera in one matrix, computed once (not per texel).
    let r_cs = cam.rotation_matrix() * sample_to_world(axis, theta);
    let t = DVec3::from(cam.translation);
    let k = cam.intrinsics;
    let to_pixel = |p: DVec2| {
        let pc = r_cs * DVec3::new(p.x, p.y, plane_z) + t;
        (pc.z > 1e-9).then(|| k.distort_to_pixel(DVec2::new(pc.x / pc.z, pc.y / pc.z)))
    };
    let n = subsamples_per_side(grid, &to_pixel);
    // Sub-sample offsets as fractions of the half-texel axes: within a texel
    // the projection is affine to well below a pixel, so each texel projects
    // three points and its samples follow from them.
    let offsets: Vec<(f64, f64)> = (0..n * n)
        .map(|s| {
            let at = |m: usize| (2 * m + 1) as f64 / n as f64 - 1.0;
            (at(s % n), at(s / n))
        })
        .collect();
    let weight = 1.0 / offsets.len() as f32;
    let half = 0.5 * grid.texel_mm;
    let ch = img.channels;
    let mut out = ImageF::zeros(grid.width, grid.height, ch);
    out.data
        .par_chunks_mut(grid.width * ch)
        .enumerate()
        .for_each(|(j, row)| {
            for i in 0..grid.width {
                let centre = grid.texel_centre(i, j);
                let texel = &mut row[i * ch..(i + 1) * ch];
                let axes = (
                    to_pixel(centre),
                    to_pixel(centre + DVec2::X * half),
                    to_pixel(centre + DVec2::Y * half),
                );
                let (Some(q), Some(qx), Some(qy)) = axes else {
                    texel.fill(f32::NAN);
                    continue;
                };
                let (ax, ay) = (qx - q, qy - q);
                texel.fill(0.0);
                for &(u, v) in &offsets {
                    let p = q + ax * u + ay * v;
                    img.bilinear_add(p.x, p.y, weight, texel);
                }
                for (c, v) in texel.iter_mut().enumerate() {
                    *v *= scale.get(c).copied().unwrap_or(1.0);
                }
            }
        });
    out
}

/// Samples per texel side so that they are at most half a pixel apart
/// (measured at the grid's centre; 1 to 8).
fn subsamples_per_side(grid: &Grid, to_pixel: &impl Fn(DVec2) -> Option<DVec2>) -> usize {
    let c = grid.texel_centre(grid.width / 2, grid.height / 2);
    let Some(p) = to_pixel(c) else { return 1 };
    let texel_px = [DVec2::X, DVec2::Y]
        .iter()
        .filter_map(|&d| to_pixel(c + d * grid.texel_mm).map(|q| q.distance(p)))
        .fold(0.0f64, f64::max);
    (2.0 * texel_px).ceil().clamp(1.0, 8.0) as usize
}

/// Unit vector from the sample-frame origin towards a world point (camera, laser), sample frame.
pub fn direction_in_sample(world_point: DVec3, axis: DVec3, theta: f64) -> DVec3 {
    (sample_to_world(axis, theta).transpose() * world_point).normalize()
}

/// A stripe's centre line on the reference plane, sample frame, mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StripeLine {
    pub point: DVec2,
    pub dir: DVec2,
}

impl StripeLine {
    /// Unsigned distance of a point from the line, mm.
    pub fn distance(&self, p: DVec2) -> f64 {
        let d = p - self.point;
        (d.x * self.dir.y - d.y * self.dir.x).abs()
    }
}

/// Fit the stripe line to the texels of channel `c` whose value exceeds
/// `threshold` (absolute, same units as the image), weighted by value.
pub fn fit_stripe_line(rect: &ImageF, c: usize, grid: &Grid, threshold: f32) -> Result<StripeLine> {
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    let mut pts = Vec::new();
    for j in 0..rect.height {
        for i in 0..rect.width {
            let v = rect.get(i, j, c);
            if v.is_finite() && v > threshold {
                let p = grid.texel_centre(i, j);
                let w = v as f64;
                sw += w;
                sx += w * p.x;
                sy += w * p.y;
                pts.push((p, w));
            }
        }
    }
    if pts.len() < 3 {
        return Err(Error::Input(format!(
            "only {} stripe texels above the threshold",
            pts.len()
        )));
    }
    let m = DVec2::new(sx / sw, sy / sw);
    let (mut cxx, mut cxy, mut cyy) = (0.0, 0.0, 0.0);
    for (p, w) in &pts {
        let d = *p - m;
        cxx += w * d.x * d.x;
        cxy += w * d.x * d.y;
        cyy += w * d.y * d.y;
    }
    // Principal axis of the 2x2 covariance.
    let angle = 0.5 * (2.0 * cxy).atan2(cxx - cyy);
    let dir = DVec2::new(angle.cos(), angle.sin());
    Ok(StripeLine { point: m, dir })
}

/// A texel kept for the stripe profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StripePoint {
    pub i: usize,
    pub j: usize,
    pub distance_mm: f64,
    pub value: f32,
}

/// Keep the texels within [d_min, d_max] mm of the line (returned with their
/// distances); every other texel of `rect` is set to NaN in all channels.
pub fn keep_distance_interval(
    rect: &mut ImageF,
    grid: &Grid,
    line: &StripeLine,
    c: usize,
    d_min: f64,
    d_max: f64,
) -> Vec<StripePoint> {
    let mut kept = Vec::new();
    for j in 0..rect.height {
        for i in 0..rect.width {
            let d = line.distance(grid.texel_centre(i, j));
            let v = rect.get(i, j, c);
            if d >= d_min && d <= d_max && v.is_finite() {
                kept.push(StripePoint {
                    i,
                    j,
                    distance_mm: d,
                    value: v,
                });
            } else {
                for k in 0..rect.channels {
                    rect.set(i, j, k, f32::NAN);
                }
            }
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;

    /// A world-fixed texture rendered through a distorted camera at a turntable
    /// angle, rectified back: each texel must land on its true position. The
    /// texture is a smooth function of sample-frame position, so the alignment
    /// error in texels is (value error) / |gradient|.
    #[test]
    fn rectified_texels_align_with_true_positions() {
        let intr = Intrinsics {
            fx: 5100.0,
            fy: 5105.0,
            cx: 515.0,
            cy: 380.0,
            k1: -0.3,
            k2: 1.0,
        };
        let cam = CameraModel::look_at(DVec3::new(200.0, 20.0, 400.0), DVec3::ZERO, DVec3::X, intr);
        let theta = 0.7;
        let axis = DVec3::new(0.002, -0.001, 1.0).normalize();
        let grid = Grid::centred(64, 0.5);
        // Texture in sample frame: a ramp in x plus a ramp in y (mm): f = 3x + 5y.
        let f = |p: DVec2| 3.0 * p.x + 5.0 * p.y;
        let (w, h) = (1024, 768);
        let to_sample = sample_to_world(axis, theta).transpose();
        let mut img = ImageF::zeros(w, h, 1);
        let n = DVec3::new(0.0, 0.0, 1.0);
        for y in 0..h {
            for x in 0..w {
                // Pixel ray -> the turned sample plane.
                let d = cam.ray(DVec2::new(x as f64, y as f64));
                let o = cam.centre();
                let nw = sample_to_world(axis, theta) * n;
                let s = -o.dot(nw) / d.dot(nw);
                let ps = to_sample * (o + s * d);
                img.set(x, y, 0, f(ps.truncate()) as f32);
            }
        }
        let rect = rectify(&img, &cam, axis, theta, &grid, &[1.0]);
        let grad = (3.0f64 * 3.0 + 5.0 * 5.0).sqrt() * grid.texel_mm; // value change per texel
        let mut worst = 0.0f64;
        for j in 0..grid.height {
            for i in 0..grid.width {
                let want = f(grid.texel_centre(i, j));
                let got = rect.get(i, j, 0) as f64;
                assert!(got.is_finite());
                worst = worst.max((got - want).abs() / grad);
            }
        }
        assert!(worst < 0.05, "misalignment {worst} texel");
    }

    /// A line one pixel wide (a stripe's core) seen from straight above, with
    /// texels 2.5 pixels wide: texel-centre samples would catch its peak or
    /// miss it depending on where it falls; area means keep its flux
    /// wherever it falls.
    #[test]
    fn texels_keep_the_flux_of_a_line_one_pixel_wide() {
        let intr = Intrinsics {
            fx: 4000.0,
            fy: 4000.0,
            cx: 512.0,
            cy: 384.0,
            k1: 0.0,
            k2: 0.0,
        };
        // 0.1 mm per pixel on the plane 400 mm below.
        let cam = CameraModel::look_at(DVec3::new(0.0, 0.0, 400.0), DVec3::ZERO, DVec3::X, intr);
        let grid = Grid::centred(64, 0.25);
        let window_mm = 64.0 * 0.25;
        for column in 500..510 {
            let mut img = ImageF::zeros(1024, 768, 1);
            for y in 0..768 {
                img.set(column, y, 0, 1.0);
            }
            // Radiance 1 over one 0.1 mm pixel column, across the whole window.
            let want = 0.1 * window_mm;
            let rect = rectify(&img, &cam, DVec3::Z, 0.0, &grid, &[1.0]);
            let got: f64 =
                rect.data.iter().map(|&v| v as f64).sum::<f64>() * grid.texel_mm * grid.texel_mm;
            assert!(
                (got / want - 1.0).abs() < 0.02,
                "column {column}: flux {got} vs {want}"
            );
        }
    }

    #[test]
    fn stripe_line_and_interval() {
        let grid = Grid::centred(40, 0.5);
        let mut rect = ImageF::zeros(40, 40, 3);
        // A stripe along direction (cos 0.3, sin 0.3) through (1, -2), exponential falloff.
        let line = StripeLine {
            point: DVec2::new(1.0, -2.0),
            dir: DVec2::new(0.3f64.cos(), 0.3f64.sin()),
        };
        for j in 0..40 {
            for i in 0..40 {
                let d = line.distance(grid.texel_centre(i, j));
                rect.set(i, j, 1, (100.0 * (-3.0 * d).exp()) as f32);
            }
        }
        let fit = fit_stripe_line(&rect, 1, &grid, 30.0).unwrap();
        assert!(
            fit.dir.dot(line.dir).abs() > (0.5f64.to_radians()).cos(),
            "{:?}",
            fit.dir
        );
        assert!(line.distance(fit.point) < 0.1);
        let kept = keep_distance_interval(&mut rect, &grid, &fit, 1, 1.0, 4.0);
        assert!(!kept.is_empty());
        assert!(
            kept.iter()
                .all(|k| k.distance_mm >= 1.0 && k.distance_mm <= 4.0)
        );
        let nan = rect.data.chunks(3).filter(|p| p[1].is_nan()).count();
        assert_eq!(nan + kept.len(), 1600);
        assert!(fit_stripe_line(&ImageF::zeros(4, 4, 1), 0, &Grid::centred(4, 1.0), 1.0).is_err());
    }
}
