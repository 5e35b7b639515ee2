//! Synthetic calibration data with known answers, for tests and benchmarks:
//! exposure brackets through a known response, checkerboards projected through
//! a known camera. (The simulated rig, sim-light, renders the real thing; these
//! are the minimal worlds each algorithm is checked against first.)

use glam::{DMat3, DVec2, DVec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;

use crate::camera::CameraModel;
use crate::image::Image8;
use crate::response::Bracket;

/// A known camera response: Z/255 = h(X), h(x) = (1 + a) y / (1 + a y), y = x^(1/gamma),
/// clipped to [0, 1]. Invertible in closed form.
#[derive(Debug, Clone, Copy)]
pub struct Response {
    pub gamma: f64,
    pub a: f64,
}

impl Response {
    pub fn gamma_s_curve(gamma: f64, a: f64) -> Self {
        Self { gamma, a }
    }
    /// Normalised output in [0, 1] for exposure x (saturates at x >= 1).
    pub fn output(&self, x: f64) -> f64 {
        let y = x.max(0.0).powf(1.0 / self.gamma);
        ((1.0 + self.a) * y / (1.0 + self.a * y)).min(1.0)
    }
    /// The exposure that gives pixel value z (in [0, 255]).
    pub fn exposure_of(&self, z: f64) -> f64 {
        let h = z / 255.0;
        let y = h / (1.0 + self.a - self.a * h);
        y.powf(self.gamma)
    }
}

/// Standard normal by Box-Muller (no extra crate for one distribution).
pub fn normal(rng: &mut Pcg64) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Quantise a normalised value with Gaussian read noise (in DN) to 8 bits.
pub fn quantise(v: f64, noise_dn: f64, rng: &mut Pcg64) -> u8 {
    (v * 255.0 + noise_dn * normal(rng))
        .round()
        .clamp(0.0, 255.0) as u8
}

/// Irradiance of the ramp scene at pixel (x, y), per channel: a log ramp over
/// ~4.5 decades across x, modulated slightly by y, with a saturated patch.
pub fn ramp_irradiance(x: usize, y: usize, w: usize, h: usize, c: usize) -> f64 {
    let u = x as f64 / (w - 1) as f64;
    let v = y as f64 / (h - 1) as f64;
    if u > 0.95 && v < 0.1 {
        return 1e6; // a specular highlight: saturated at every exposure
    }
    let gain = [1.0, 0.8, 0.55][c % 3];
    gain * 10f64.powf(-3.5 + 4.5 * u) * (1.0 + 0.3 * v)
}

/// An RGB bracket of the ramp scene through `resp`, read noise `noise_dn`, seeded.
pub fn bracket_of_ramp(
    w: usize,
    h: usize,
    times: &[f64],
    resp: &Response,
    noise_dn: f64,
    seed: u64,
) -> Bracket {
    let frames = times
        .iter()
        .enumerate()
        .map(|(k, &t)| {
            let mut rng = Pcg64::seed_from_u64(seed.wrapping_mul(1000).wrapping_add(k as u64));
            let mut data = Vec::with_capacity(w * h * 3);
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        let e = ramp_irradiance(x, y, w, h, c);
                        data.push(quantise(resp.output(e * t), noise_dn, &mut rng));
                    }
                }
            }
            Image8 {
                width: w,
                height: h,
                channels: 3,
                data,
            }
        })
        .collect();
    Bracket {
        frames,
        exposures: times.to_vec(),
    }
}

/// A planar checkerboard: `squares_x` x `squares_y` squares of `square_mm`,
/// centred on its own origin in its xy plane; inner corners are the targets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Checkerboard {
    pub squares_x: usize,
    pub squares_y: usize,
    pub square_mm: f64,
}

impl Checkerboard {
    /// Inner corners in board coordinates (z = 0), row-major in (i, j).
    pub fn corners(&self) -> Vec<DVec3> {
        let (w, h) = (
            self.squares_x as f64 * self.square_mm,
            self.squares_y as f64 * self.square_mm,
        );
        let mut out = Vec::new();
        for j in 1..self.squares_y {
            for i in 1..self.squares_x {
                out.push(DVec3::new(
                    i as f64 * self.square_mm - w / 2.0,
                    j as f64 * self.square_mm - h / 2.0,
                    0.0,
                ));
            }
        }
        out
    }
    /// Reflectance at board point (x, y): 0.05 black, 0.9 white, None outside.
    pub fn albedo(&self, x: f64, y: f64) -> Option<f64> {
        let (w, h) = (
            self.squares_x as f64 * self.square_mm,
            self.squares_y as f64 * self.square_mm,
        );
        let (u, v) = (x + w / 2.0, y + h / 2.0);
        if u < 0.0 || v < 0.0 || u >= w || v >= h {
            return None;
        }
        let parity =
            ((u / self.square_mm).floor() as i64 + (v / self.square_mm).floor() as i64) & 1;
        Some(if parity == 0 { 0.05 } else { 0.9 })
    }
}

/// Render a checkerboard lying with pose (R, t) (board -> world) through
/// `cam`: 4x4 supersampled, grey 0.3 background, 8-bit with read noise.
pub fn render_checkerboard(
    cam: &CameraModel,
    width: usize,
    height: usize,
    board: &Checkerboard,
    board_rot: DMat3,
    board_pos: DVec3,
    noise_dn: f64,
    seed: u64,
) -> Image8 {
    let centre = cam.centre();
    let normal = board_rot.col(2);
    let rt = cam.rotation_matrix().transpose();
    let rows: Vec<Vec<u8>> = (0..height)
        .into_par_iter()
        .map(|y| {
            let mut rng = Pcg64::seed_from_u64(seed ^ ((y as u64) << 20));
            (0..width)
                .map(|x| {
                    let mut sum = 0.0;
                    for sy in 0..4 {
                        for sx in 0..4 {
                            let p = DVec2::new(
                                x as f64 - 0.375 + 0.25 * sx as f64,
                                y as f64 - 0.375 + 0.25 * sy as f64,
                            );
                            let xn = cam.intrinsics.pixel_to_normalised(p);
                            let d = rt * DVec3::new(xn.x, xn.y, 1.0);
                            let denom = d.dot(normal);
                            let a = if denom.abs() < 1e-12 {
                                0.3
                            } else {
                                let s = (board_pos - centre).dot(normal) / denom;
                                let hit = board_rot.transpose() * (centre + s * d - board_pos);
                                if s > 0.0 {
                                    board.albedo(hit.x, hit.y).unwrap_or(0.3)
                                } else {
                                    0.3
                                }
                            };
                            sum += a;
                        }
                    }
                    quantise(0.85 * sum / 16.0, noise_dn, &mut rng)
                })
                .collect()
        })
        .collect();
    Image8 {
        width,
        height,
        channels: 1,
        data: rows.concat(),
    }
}
