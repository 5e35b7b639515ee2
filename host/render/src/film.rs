//! The rendered image and its outputs: EXR (linear RGB f32, the radiance as
//! computed) and PNG through a documented tone map:
//!
//! 1. exposure: c *= k, with k given, or automatic k = 2 / L99 where L99 is
//!    the 99th percentile of pixel luminance (so bright highlights roll off);
//! 2. per channel filmic roll-off c' = 1 - exp(-c);
//! 3. the sRGB transfer curve, then 8-bit quantisation.
//!
//! Negative radiance never reaches the tone map: the renderer clamps sums to
//! zero first, and the tone map clamps again defensively.

use std::path::Path;

use glam::Vec3;

use crate::error::RenderError;
use crate::light::luminance;

/// A linear RGB image, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            pixels: vec![[0.0; 3]; (width * height) as usize],
        }
    }

    pub fn get(&self, x: u32, y: u32) -> Vec3 {
        Vec3::from(self.pixels[(y * self.width + x) as usize])
    }

    /// Mean of each channel over a pixel rectangle [x0, x1) x [y0, y1).
    pub fn mean(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> Vec3 {
        let mut s = Vec3::ZERO;
        for y in y0..y1 {
            for x in x0..x1 {
                s += self.get(x, y);
            }
        }
        s / ((x1 - x0) * (y1 - y0)).max(1) as f32
    }

    /// Writes `.exr` (linear) or `.png` (tone mapped, `exposure` None = auto),
    /// by the file extension.
    pub fn save(&self, path: &Path, exposure: Option<f32>) -> Result<(), RenderError> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref()
        {
            Some("exr") => self.write_exr(path),
            Some("png") => self.write_png(path, exposure),
            _ => Err(RenderError::Settings(format!(
                "output {} must end in .exr or .png",
                path.display()
            ))),
        }
    }

    pub fn write_exr(&self, path: &Path) -> Result<(), RenderError> {
        let (w, h) = (self.width as usize, self.height as usize);
        Ok(qhm_formats::exr::write_rgb_pixels(
            path,
            w,
            h,
            &self.pixels,
        )?)
    }

    /// The automatic exposure k = 2 / L99 (1 for a black image).
    pub fn auto_exposure(&self) -> f32 {
        let mut l: Vec<f32> = self
            .pixels
            .iter()
            .map(|p| luminance(Vec3::from(*p)).max(0.0))
            .filter(|v| v.is_finite())
            .collect();
        if l.is_empty() {
            return 1.0;
        }
        let k = ((l.len() - 1) as f32 * 0.99) as usize;
        let (_, p99, _) = l.select_nth_unstable_by(k, f32::total_cmp);
        if *p99 > 0.0 { 2.0 / *p99 } else { 1.0 }
    }

    /// 8-bit sRGB pixels after the tone map.
    pub fn tone_mapped(&self, exposure: Option<f32>) -> Vec<u8> {
        let k = exposure.unwrap_or_else(|| self.auto_exposure());
        self.pixels
            .iter()
            .flat_map(|p| p.map(|c| to_srgb8(1.0 - (-(c.max(0.0) * k)).exp())))
            .collect()
    }

    pub fn write_png(&self, path: &Path, exposure: Option<f32>) -> Result<(), RenderError> {
        let bytes = self.tone_mapped(exposure);
        image::save_buffer(
            path,
            &bytes,
            self.width,
            self.height,
            image::ColorType::Rgb8,
        )
        .map_err(|e| RenderError::Png {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }
}

fn to_srgb8(c: f32) -> u8 {
    let c = if c.is_finite() {
        c.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trips() {
        let dir = tempdir();
        let mut img = Image::new(3, 2);
        img.pixels[4] = [1.5, 0.25, 7.0];
        let p = dir.join("a.exr");
        img.save(&p, None).unwrap();
        let env = crate::light::EnvMap::load(&p, 0.0, 1.0).unwrap();
        assert_eq!(env.texels[4], Vec3::new(1.5, 0.25, 7.0));
    }

    #[test]
    fn tone_map_is_monotone_and_clamps_negatives() {
        let mut img = Image::new(4, 1);
        img.pixels = vec![[-1.0; 3], [0.0; 3], [0.5; 3], [1.0; 3]];
        let b = img.tone_mapped(Some(1.0));
        assert_eq!(b[0], 0);
        assert_eq!(b[3], 0);
        assert!(b[6] > 0 && b[9] > b[6]);
        assert!(img.save(Path::new("/tmp/x.bmp"), None).is_err());
    }

    fn tempdir() -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("qhm-render-film-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }
}
