//! Camera sensors: radiance in, 8-bit RGB frames out.
//!
//! Model, per pixel and channel c (documented in docs/sim.md so calibration
//! can be checked against it):
//!   electrons e = L * colour_gain[c] * SENSITIVITY * exposure_s   (L in W sr^-1 m^-2)
//!   e' = Poisson(e) + N(0, READ_NOISE_E)                            (shot and read noise;
//!        above POISSON_EXACT_UP_TO e-, one normal of variance e + READ_NOISE_E^2)
//!   m  = clamp(e' * gain / FULL_WELL_E, 0, 1)                       (gain: linear, 1 = unity)
//!   Z  = round(255 * response(m))                                   (8-bit, saturates at 255)
//! `response` is a monotone cubic with response(0) = 0, response(1) = 1
//! (Mitsunaga-Nayar form), slightly different for every camera.

use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::RadianceImage;
use crate::rng::{Rng, mix64};

/// Electrons per (W sr^-1 m^-2 * s) at colour gain 1: a 1 W sr^-1 m^-2
/// radiance fills the well in 10 ms at unity gain.
pub const SENSITIVITY: f64 = 2.0e6;
/// Full-well capacity, electrons.
pub const FULL_WELL_E: f64 = 20_000.0;
/// Read noise, electrons rms.
pub const READ_NOISE_E: f64 = 12.0;
/// Mean electron counts up to this are drawn from the exact Poisson law;
/// above it shot noise is normal, and with the read noise one normal of
/// variance e + READ_NOISE_E^2 (its error is far below the read noise).
pub const POISSON_EXACT_UP_TO: f64 = 30.0;

/// Electrons read out for a mean of `e`: shot noise plus read noise.
#[inline]
fn electrons(rng: &mut Rng, e: f64) -> f64 {
    let z: f64 = StandardNormal.sample(rng);
    if e > POISSON_EXACT_UP_TO {
        e + (e + READ_NOISE_E * READ_NOISE_E).sqrt() * z
    } else {
        rng.poisson(e) + READ_NOISE_E * z
    }
}

/// Camera response I(m) = c1 m + c2 m^2 + c3 m^3, with c1 + c2 + c3 = 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Response {
    pub coeffs: [f64; 3],
}

impl Default for Response {
    /// A gamma-like compressive curve: slope 1.9 at black, 0.4 at white.
    fn default() -> Self {
        Response {
            coeffs: [1.9, -1.2, 0.3],
        }
    }
}

impl Response {
    pub(crate) fn perturbed(rng: &mut Rng, on: f64) -> Self {
        // perturb the slopes at black (c1) and at white (s1 = 3 - 2 c1 - c2),
        // both stay positive and the curve monotone
        let c1 = 1.9 + 0.1 * rng.normal().clamp(-2.0, 2.0) * on;
        let s1 = 0.4 + 0.05 * rng.normal().clamp(-2.0, 2.0) * on;
        let c2 = 3.0 - 2.0 * c1 - s1;
        Response {
            coeffs: [c1, c2, 1.0 - c1 - c2],
        }
    }

    /// I(m) for m in [0, 1].
    pub fn eval(&self, m: f64) -> f64 {
        let [c1, c2, c3] = self.coeffs;
        m * (c1 + m * (c2 + m * c3))
    }

    /// Whether the curve rises strictly on [0, 1] (dI/dm > 0).
    pub fn is_monotone(&self) -> bool {
        let [c1, c2, c3] = self.coeffs;
        (0..=100).all(|i| {
            let m = i as f64 / 100.0;
            c1 + 2.0 * c2 * m + 3.0 * c3 * m * m > 0.0
        })
    }
}

/// What the camera recorded with a frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameMeta {
    pub camera: usize,
    pub exposure_s: f64,
    pub gain: f64,
    pub noise_seed: u64,
    /// Pixels with at least one channel at 255.
    pub saturated_pixels: u64,
}

/// An 8-bit RGB frame, row-major, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
    pub meta: FrameMeta,
}

/// One camera's sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    pub camera: usize,
    pub colour_gain: [f64; 3],
    pub response: Response,
}

impl Sensor {
    /// Expose the sensor to a radiance image (cheap: reuse the same radiance
    /// for a whole exposure bracket). Deterministic per `noise_seed`.
    pub fn expose(
        &self,
        radiance: &RadianceImage,
        exposure_s: f64,
        gain: f64,
        noise_seed: u64,
    ) -> Frame {
        let w = radiance.width as usize;
        let exposure_s = if exposure_s.is_finite() {
            exposure_s.max(0.0)
        } else {
            0.0
        };
        let gain = if gain.is_finite() { gain.max(0.0) } else { 0.0 };
        let mut rgb = vec![0u8; radiance.data.len() * 3];
        let saturated: u64 = rgb
            .par_chunks_mut(w.max(1) * 3)
            .enumerate()
            .map(|(row, out)| {
                let mut rng =
                    Rng::new(mix64(noise_seed ^ ((self.camera as u64) << 56)), row as u64);
                let mut sat = 0u64;
                for (x, px) in out.chunks_exact_mut(3).enumerate() {
                    let l = radiance.data[row * w + x];
                    let mut any = false;
                    for c in 0..3 {
                        let e =
                            (l[c] as f64).max(0.0) * self.colour_gain[c] * SENSITIVITY * exposure_s;
                        let m = (electrons(&mut rng, e) * gain / FULL_WELL_E).clamp(0.0, 1.0);
                        // Rounds half up, as round() does here (the value is
                        // never negative), without a libm call per channel.
                        let z = (255.0 * self.response.eval(m)).clamp(0.0, 255.0) + 0.5;
                        let z = z as u8;
                        any |= z == 255;
                        px[c] = z;
                    }
                    sat += any as u64;
                }
                sat
            })
            .sum();
        Frame {
            width: radiance.width,
            height: radiance.height,
            rgb,
            meta: FrameMeta {
                camera: self.camera,
                exposure_s,
                gain,
                noise_seed,
                saturated_pixels: saturated,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(l: f32) -> RadianceImage {
        RadianceImage {
            width: 64,
            height: 16,
            data: vec![[l, l, l]; 64 * 16],
        }
    }

    fn sensor() -> Sensor {
        Sensor {
            camera: 1,
            colour_gain: [1.0; 3],
            response: Response::default(),
        }
    }

    #[test]
    fn response_is_monotone_and_normalised() {
        let r = Response::default();
        assert!(r.is_monotone());
        assert!((r.eval(1.0) - 1.0).abs() < 1e-12 && r.eval(0.0) == 0.0);
        let mut rng = Rng::new(1, 2);
        for _ in 0..100 {
            let p = Response::perturbed(&mut rng, 1.0);
            assert!(p.is_monotone());
            assert!((p.eval(1.0) - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn mean_level_follows_the_model() {
        // L = 0.5, 4 ms: e = 4000 of 20000 -> m = 0.2 -> I = 0.3336 -> 85
        let f = sensor().expose(&flat(0.5), 0.004, 1.0, 9);
        let mean = f.rgb.iter().map(|&z| z as f64).sum::<f64>() / f.rgb.len() as f64;
        let expect = 255.0 * Response::default().eval(0.2);
        assert!((mean - expect).abs() < 0.5, "{mean} vs {expect}");
        // shot noise: sd of m = sqrt(4000 + 144)/20000 -> ~1.57 codes after slope
        let var = f
            .rgb
            .iter()
            .map(|&z| (z as f64 - mean).powi(2))
            .sum::<f64>()
            / f.rgb.len() as f64;
        assert!(var.sqrt() > 0.8 && var.sqrt() < 2.5, "{}", var.sqrt());
        assert_eq!(f.meta.saturated_pixels, 0);
    }

    /// Shot and read noise add up to the model's variance e + 144 on both
    /// sides of the exact-Poisson bound, and the mean level stays e.
    #[test]
    fn noise_variance_is_shot_plus_read_noise() {
        let linear = Sensor {
            response: Response {
                coeffs: [1.0, 0.0, 0.0],
            },
            ..sensor()
        };
        // gain g: one code is 20000 / (255 g) electrons
        for (e, gain) in [(25.0, 40.0), (400.0, 10.0), (5000.0, 1.0)] {
            let l = e / (SENSITIVITY * 0.01);
            let mut codes = Vec::new();
            for seed in 0..40 {
                let f = linear.expose(&flat(l as f32), 0.01, gain, seed);
                codes.extend(f.rgb.iter().map(|&z| z as f64));
            }
            let per_code = FULL_WELL_E / (255.0 * gain);
            let n = codes.len() as f64;
            let mean = codes.iter().sum::<f64>() / n;
            let var = codes.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / n;
            // 8-bit quantisation adds 1/12 code^2
            let var_e = (var - 1.0 / 12.0) * per_code * per_code;
            let expect = e + READ_NOISE_E * READ_NOISE_E;
            assert!(
                (mean * per_code - e).abs() < 0.02 * e + 0.5 * per_code,
                "e {e}: mean {}",
                mean * per_code
            );
            assert!(
                (var_e / expect - 1.0).abs() < 0.06,
                "e {e}: variance {var_e} vs {expect}"
            );
        }
    }

    #[test]
    fn saturates_and_is_deterministic() {
        let f = sensor().expose(&flat(5.0), 0.01, 1.0, 1);
        assert!(f.rgb.iter().all(|&z| z == 255));
        assert_eq!(f.meta.saturated_pixels, 64 * 16);
        let a = sensor().expose(&flat(0.3), 0.01, 2.0, 5);
        let b = sensor().expose(&flat(0.3), 0.01, 2.0, 5);
        let c = sensor().expose(&flat(0.3), 0.01, 2.0, 6);
        assert_eq!(a, b);
        assert_ne!(a.rgb, c.rgb);
        // dark frame: read noise only, clamped at 0
        let d = sensor().expose(&flat(0.0), 0.01, 1.0, 5);
        assert!(d.rgb.iter().all(|&z| z < 4));
    }
}
