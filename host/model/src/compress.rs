//! Optional LRF compression: one PCA basis over the (light, view, channel)
//! dimension shared by all texels, and k coefficients per texel. An LRF of
//! S samples on N texels shrinks from 3·S·N floats to (k+1)·3·S + k·N.
//! The basis is the leading principal components ([`crate::pca`]).

use std::path::Path;

use rayon::prelude::*;

use crate::ModelError;
use crate::exrio::{read_rgb, write_rgb};
use crate::model::Texture;
use crate::pca::{TexelMatrix, principal_components, to_f32};

/// A PCA-coded LRF.
#[derive(Clone, Debug, PartialEq)]
pub struct Pca {
    width: usize,
    height: usize,
    samples: usize,
    /// Mean over texels, length D = 3·samples (index sample·3 + channel).
    mean: Vec<f32>,
    /// k orthonormal basis vectors of length D.
    basis: Vec<Vec<f32>>,
    /// Per texel, k coefficients.
    coeffs: Vec<Vec<f32>>,
}

impl Pca {
    /// Fits `k` components (clamped to the data's size) to the LRF maps.
    pub fn fit(maps: &[Texture], k: usize) -> Self {
        let x = TexelMatrix::new(maps);
        let pc = principal_components(&x, k.max(1));
        let k = pc.basis.len();
        Pca {
            width: maps[0].width,
            height: maps[0].height,
            samples: maps.len(),
            mean: x.mean.iter().map(|&m| m as f32).collect(),
            basis: to_f32(&pc.basis),
            coeffs: pc.coeffs.chunks(k.max(1)).map(|c| c.to_vec()).collect(),
        }
    }

    pub fn k(&self) -> usize {
        self.basis.len()
    }

    /// Floats stored: mean and basis, plus the coefficients.
    pub fn floats(&self) -> usize {
        (self.k() + 1) * 3 * self.samples + self.k() * self.width * self.height
    }

    /// Decodes back to one texture per sample.
    pub fn expand(&self) -> Vec<Texture> {
        (0..self.samples)
            .into_par_iter()
            .map(|s| {
                let data = self
                    .coeffs
                    .iter()
                    .map(|c| {
                        std::array::from_fn(|ch| {
                            let i = s * 3 + ch;
                            self.mean[i]
                                + c.iter()
                                    .zip(&self.basis)
                                    .map(|(a, b)| a * b[i])
                                    .sum::<f32>()
                        })
                    })
                    .collect();
                Texture {
                    width: self.width,
                    height: self.height,
                    data,
                }
            })
            .collect()
    }

    /// Relative RMS error of the decoded maps against `maps`.
    pub fn rel_rms_error(&self, maps: &[Texture]) -> f64 {
        let dec = self.expand();
        let (mut e2, mut n2) = (0.0f64, 0.0f64);
        for (a, b) in maps.iter().zip(&dec) {
            for (p, q) in a.data.iter().zip(&b.data) {
                for c in 0..3 {
                    e2 += ((p[c] - q[c]) as f64).powi(2);
                    n2 += (p[c] as f64).powi(2);
                }
            }
        }
        (e2 / n2.max(f64::MIN_POSITIVE)).sqrt()
    }

    /// Writes `lrf/pca_basis.exr` (width = samples, row 0 = mean, rows 1..=k
    /// basis) and `lrf/pca_coeff_M.exr` (coefficients 3M..3M+2 as RGB).
    pub fn write(&self, dir: &Path) -> Result<Vec<String>, ModelError> {
        let s = self.samples;
        let mut basis = Texture::filled(s, self.k() + 1, [0.0; 3]);
        for j in 0..=self.k() {
            let v = if j == 0 {
                &self.mean
            } else {
                &self.basis[j - 1]
            };
            for i in 0..s {
                basis.data[j * s + i] = [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
            }
        }
        let mut files = vec!["lrf/pca_basis.exr".to_string()];
        write_rgb(&dir.join(&files[0]), &basis)?;
        for m in 0..self.k().div_ceil(3) {
            let t = Texture {
                width: self.width,
                height: self.height,
                data: self
                    .coeffs
                    .iter()
                    .map(|c| std::array::from_fn(|ch| c.get(3 * m + ch).copied().unwrap_or(0.0)))
                    .collect(),
            };
            let f = format!("lrf/pca_coeff_{m}.exr");
            write_rgb(&dir.join(&f), &t)?;
            files.push(f);
        }
        Ok(files)
    }

    /// Reads what [`Pca::write`] wrote, checking every size.
    pub fn read(
        dir: &Path,
        files: &[String],
        k: usize,
        samples: usize,
        width: usize,
        height: usize,
    ) -> Result<Self, ModelError> {
        let mpath = dir.join("manifest.toml");
        if k == 0 || files.len() != 1 + k.div_ceil(3) {
            return Err(ModelError::invalid(
                &mpath,
                format!(
                    "lrf: pca with {k} components needs {} files, found {}",
                    1 + k.div_ceil(3),
                    files.len()
                ),
            ));
        }
        let bpath = dir.join(&files[0]);
        let b = read_rgb(&bpath)?;
        if (b.width, b.height) != (samples, k + 1) {
            return Err(ModelError::invalid(
                &bpath,
                format!(
                    "basis is {}×{}, expected {samples}×{}",
                    b.width,
                    b.height,
                    k + 1
                ),
            ));
        }
        let row =
            |j: usize| -> Vec<f32> { (0..samples).flat_map(|i| b.data[j * samples + i]).collect() };
        let mut coeffs = vec![vec![0.0f32; k]; width * height];
        for (m, f) in files[1..].iter().enumerate() {
            let p = dir.join(f);
            let t = read_rgb(&p)?;
            if (t.width, t.height) != (width, height) {
                return Err(ModelError::invalid(
                    &p,
                    format!(
                        "{}×{} texels, the manifest says {width}×{height}",
                        t.width, t.height
                    ),
                ));
            }
            for (c, v) in coeffs.iter_mut().zip(&t.data) {
                for ch in 0..3 {
                    if 3 * m + ch < k {
                        c[3 * m + ch] = v[ch];
                    }
                }
            }
        }
        Ok(Pca {
            width,
            height,
            samples,
            mean: row(0),
            basis: (1..=k).map(row).collect(),
            coeffs,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Maps that are exactly rank 2 around a mean: 2 components are lossless.
    fn rank2(s: usize, w: usize, h: usize) -> Vec<Texture> {
        (0..s)
            .map(|i| Texture {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|p| {
                        let (a, b) = ((p as f32 * 0.37).sin(), (p as f32 * 0.11).cos());
                        std::array::from_fn(|c| {
                            0.2 + a * (i as f32 + c as f32 * 0.5).cos()
                                + b * (0.3 * i as f32 - c as f32)
                        })
                    })
                    .collect(),
            })
            .collect()
    }

    #[test]
    fn low_rank_data_is_reproduced() {
        let maps = rank2(6, 8, 5);
        let pca = Pca::fit(&maps, 2);
        assert!(
            pca.rel_rms_error(&maps) < 1e-4,
            "{}",
            pca.rel_rms_error(&maps)
        );
        let one = Pca::fit(&maps, 1);
        assert!(one.rel_rms_error(&maps) > 1e-2);
        assert_eq!(pca.floats(), 3 * 18 + 2 * 40);
    }

    #[test]
    fn write_read_round_trip() {
        let maps = rank2(4, 6, 3);
        let pca = Pca::fit(&maps, 4);
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("lrf")).unwrap();
        let files = pca.write(dir.path()).unwrap();
        assert_eq!(files.len(), 3);
        let back = Pca::read(dir.path(), &files, 4, 4, 6, 3).unwrap();
        assert_eq!(back, pca);
        assert!(Pca::read(dir.path(), &files, 4, 5, 6, 3).is_err());
        assert!(Pca::read(dir.path(), &files[..2], 4, 4, 6, 3).is_err());
    }
}
