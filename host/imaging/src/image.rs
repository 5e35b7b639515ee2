//! Plain interleaved images: 8-bit camera frames and f32 radiance.

use crate::{Error, Result};

/// An 8-bit frame as the camera delivers it, `channels` interleaved values per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Image8 {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<u8>,
}

/// A linear f32 image (radiance), `channels` interleaved values per pixel; NaN = not valid.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl Image8 {
    pub fn new(width: usize, height: usize, channels: usize, data: Vec<u8>) -> Result<Self> {
        if width == 0 || height == 0 || channels == 0 || data.len() != width * height * channels {
            return Err(Error::Input(format!(
                "image {width}x{height}x{channels} with {} values",
                data.len()
            )));
        }
        Ok(Self {
            width,
            height,
            channels,
            data,
        })
    }
    #[inline]
    pub fn get(&self, x: usize, y: usize, c: usize) -> u8 {
        self.data[(y * self.width + x) * self.channels + c]
    }
    /// One channel as f32 in [0, 255].
    pub fn channel_f32(&self, c: usize) -> Vec<f32> {
        self.data
            .iter()
            .skip(c)
            .step_by(self.channels)
            .map(|&v| v as f32)
            .collect()
    }
    /// Luminance-like mean of the channels as f32 in [0, 255].
    pub fn gray_f32(&self) -> Vec<f32> {
        self.data
            .chunks_exact(self.channels)
            .map(|p| p.iter().map(|&v| v as f32).sum::<f32>() / self.channels as f32)
            .collect()
    }
}

impl ImageF {
    pub fn zeros(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; width * height * channels],
        }
    }
    #[inline]
    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.data[(y * self.width + x) * self.channels + c]
    }
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, c: usize, v: f32) {
        self.data[(y * self.width + x) * self.channels + c] = v;
    }
    /// Adds `weight` times the bilinear lookup at pixel coordinates (x, y)
    /// (pixel centres on integers) to `out`, every channel at once. Outside
    /// the image `out` becomes NaN, and a NaN pixel makes its channel NaN.
    pub fn bilinear_add(&self, x: f64, y: f64, weight: f32, out: &mut [f32]) {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64)
        {
            out.fill(f32::NAN);
            return;
        }
        let x0 = (x.floor() as usize).min(self.width.saturating_sub(2));
        let y0 = (y.floor() as usize).min(self.height.saturating_sub(2));
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let w = [
            (1.0 - fx) * (1.0 - fy) * weight,
            fx * (1.0 - fy) * weight,
            (1.0 - fx) * fy * weight,
            fx * fy * weight,
        ];
        let ch = self.channels;
        let at = |x: usize, y: usize| (y * self.width + x) * ch;
        let corners = [at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1)];
        for (c, o) in out.iter_mut().enumerate().take(ch) {
            *o += corners
                .iter()
                .zip(w)
                .map(|(&k, w)| self.data[k + c] * w)
                .sum::<f32>();
        }
    }
}

/// Bilinear lookup in a single-channel f32 plane (no NaN handling needed).
pub fn bilinear_plane(data: &[f32], width: usize, height: usize, x: f64, y: f64) -> f32 {
    let xc = x.clamp(0.0, (width - 1) as f64);
    let yc = y.clamp(0.0, (height - 1) as f64);
    let x0 = (xc.floor() as usize).min(width.saturating_sub(2));
    let y0 = (yc.floor() as usize).min(height.saturating_sub(2));
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    let (fx, fy) = ((xc - x0 as f64) as f32, (yc - y0 as f64) as f32);
    let at = |x: usize, y: usize| data[y * width + x];
    (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy)
        + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_interpolates_and_flags_outside() {
        let mut im = ImageF::zeros(3, 2, 1);
        im.set(1, 0, 0, 2.0);
        im.set(1, 1, 0, 4.0);
        let at = |x: f64, y: f64| {
            let mut v = [0.0f32];
            im.bilinear_add(x, y, 1.0, &mut v);
            v[0]
        };
        assert!((at(0.5, 0.5) - 1.5).abs() < 1e-6);
        assert!((at(2.0, 1.0) - 0.0).abs() < 1e-6);
        assert!(at(-0.1, 0.0).is_nan());
        assert!(at(0.0, 1.01).is_nan());
    }

    #[test]
    fn bad_sizes_are_refused() {
        assert!(Image8::new(2, 2, 3, vec![0; 11]).is_err());
    }
}
