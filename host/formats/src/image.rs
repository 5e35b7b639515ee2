//! An RGB f32 image: the rectified dataset's images, the material model's
//! textures. Row-major, row 0 first (the EXR's first row); NaN marks a texel
//! without a valid value.

/// An RGB f32 image stored row-major, row 0 first, sampled with wrap-around.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<[f32; 3]>,
}

impl RgbImage {
    pub fn filled(width: usize, height: usize, v: [f32; 3]) -> Self {
        RgbImage {
            width,
            height,
            data: vec![v; width * height],
        }
    }
    pub fn get(&self, i: usize, j: usize) -> [f32; 3] {
        self.data[j * self.width + i]
    }
    /// Bilinear lookup at `uv` in [0, 1)^2 (texel centres at (i + 0.5)/width), wrapping.
    pub fn sample(&self, uv: [f32; 2]) -> [f32; 3] {
        let (w, h) = (self.width as i64, self.height as i64);
        let x = uv[0] * self.width as f32 - 0.5;
        let y = uv[1] * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |v: i64, n: i64| v.rem_euclid(n) as usize;
        let (i0, j0) = (x0 as i64, y0 as i64);
        let p00 = self.get(wrap(i0, w), wrap(j0, h));
        let p10 = self.get(wrap(i0 + 1, w), wrap(j0, h));
        let p01 = self.get(wrap(i0, w), wrap(j0 + 1, h));
        let p11 = self.get(wrap(i0 + 1, w), wrap(j0 + 1, h));
        std::array::from_fn(|c| {
            (p00[c] * (1.0 - fx) + p10[c] * fx) * (1.0 - fy)
                + (p01[c] * (1.0 - fx) + p11[c] * fx) * fy
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_interpolates_between_centres_and_wraps() {
        let mut t = RgbImage::filled(2, 1, [0.0; 3]);
        t.data[1] = [2.0, 4.0, 6.0];
        // Half-way between the two texel centres.
        assert_eq!(t.sample([0.5, 0.5]), [1.0, 2.0, 3.0]);
        // At texel 0's centre, and wrapping past the right edge back to it.
        assert_eq!(t.sample([0.25, 0.5]), [0.0; 3]);
        assert_eq!(t.sample([1.25, 0.5]), [0.0; 3]);
    }
}
