//! Optional LRF compression: one PCA basis over the (light, view, channel)
//! dimension shared by all texels, and k coefficients per texel. An LRF of
//! S samples on N texels shrinks from 3·S·N floats to (k+1)·3·S + k·N.
//! The basis comes from subspace iteration on the centred data (no D×D
//! covariance is formed, so many samples stay cheap).

use std::path::Path;

use rayon::prelude::*;

use crate::ModelError;
use crate::exrio::{read_rgb, write_rgb};
use crate::model::Texture;

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
        let s = maps.len();
        let (width, height) = (maps[0].width, maps[0].height);
        let n = width * height;
        let d = 3 * s;
        let k = k.clamp(1, d.min(n));
        let x: Vec<Vec<f64>> = (0..n)
            .into_par_iter()
            .map(|p| (0..d).map(|i| maps[i / 3].data[p][i % 3] as f64).collect())
            .collect();
        let mut mean = vec![0.0f64; d];
        for row in &x {
            for i in 0..d {
                mean[i] += row[i] / n as f64;
            }
        }
        let xc: Vec<Vec<f64>> = x
            .into_par_iter()
            .map(|row| row.iter().zip(&mean).map(|(a, m)| a - m).collect())
            .collect();
        // Deterministic start, then subspace iteration Q <- orth(Xᵀ X Q).
        let mut q: Vec<Vec<f64>> = (0..k)
            .map(|j| {
                (0..d)
                    .map(|i| ((i + 1) as f64 * (j as f64 + 1.3) * 0.618).sin())
                    .collect()
            })
            .collect();
        orthonormalise(&mut q);
        for _ in 0..60 {
            let y: Vec<Vec<f64>> = xc
                .par_iter()
                .map(|row| q.iter().map(|b| dot(row, b)).collect())
                .collect();
            let mut z: Vec<Vec<f64>> = (0..k)
                .into_par_iter()
                .map(|j| {
                    let mut v = vec![0.0; d];
                    for (row, yr) in xc.iter().zip(&y) {
                        for i in 0..d {
                            v[i] += row[i] * yr[j];
                        }
                    }
                    v
                })
                .collect();
            orthonormalise(&mut z);
            q = z;
        }
        let coeffs = xc
            .par_iter()
            .map(|row| q.iter().map(|b| dot(row, b) as f32).collect())
            .collect();
        Pca {
            width,
            height,
            samples: s,
            mean: mean.iter().map(|&m| m as f32).collect(),
            basis: q
                .iter()
                .map(|b| b.iter().map(|&v| v as f32).collect())
                .collect(),
            coeffs,
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

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Modified Gram-Schmidt; a vanishing vector is replaced by a unit axis
/// orthogonal to the others so the basis keeps its size.
fn orthonormalise(v: &mut [Vec<f64>]) {
    for j in 0..v.len() {
        for attempt in 0..=v[j].len() {
            for i in 0..j {
                let p = dot(&v[j], &v[i]);
                let vi = v[i].clone();
                for (a, b) in v[j].iter_mut().zip(&vi) {
                    *a -= p * b;
                }
            }
            let n = dot(&v[j], &v[j]).sqrt();
            if n > 1e-12 {
                v[j].iter_mut().for_each(|a| *a /= n);
                break;
            }
            let d = v[j].len();
            v[j] = (0..d)
                .map(|i| if i == (j + attempt) % d { 1.0 } else { 0.0 })
                .collect();
        }
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
