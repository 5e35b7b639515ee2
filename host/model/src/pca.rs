//! Principal components of an LRF over its texels: every texel's LRF (all
//! samples and channels, D = 3·samples values) is one row of an N x D
//! matrix, centred on the mean texel. The leading components come from
//! randomised subspace iteration with oversampling and a Rayleigh-Ritz step
//! (Halko, Martinsson and Tropp 2011): no D x D covariance is formed, so an
//! LRF of hundreds of samples stays cheap. Sums run in a fixed order, so the
//! result does not depend on the thread count.

use rayon::prelude::*;

use crate::model::Texture;

/// Texels per block of the X^T Y sums: each block's partial sum is added in
/// block order, whatever the threads.
const BLOCK: usize = 256;

/// The centred texel matrix.
pub(crate) struct TexelMatrix {
    pub n: usize,
    pub d: usize,
    /// Mean over texels, length D (index sample·3 + channel).
    pub mean: Vec<f64>,
    /// Row-major N x D, each row less `mean`.
    rows: Vec<f32>,
}

/// Leading principal directions, largest variance first.
pub(crate) struct Components {
    /// Orthonormal vectors of length D.
    pub basis: Vec<Vec<f64>>,
    /// Variance of the texels along each vector (eigenvalue of the covariance).
    pub variance: Vec<f64>,
    /// Each texel's coordinates on `basis`, row-major N x basis.len().
    pub coeffs: Vec<f32>,
}

impl TexelMatrix {
    /// The texels of `maps` (one texture per sample, all the same size).
    pub fn new(maps: &[Texture]) -> Self {
        let n = maps.first().map_or(0, |t| t.data.len());
        let texels: Vec<usize> = (0..n).collect();
        let samples: Vec<usize> = (0..maps.len()).collect();
        Self::select(maps, &texels, &samples)
    }

    /// The given texels of the given samples of `maps`.
    pub fn select(maps: &[Texture], texels: &[usize], samples: &[usize]) -> Self {
        let (n, d) = (texels.len(), 3 * samples.len());
        let mean: Vec<f64> = (0..d)
            .map(|i| {
                let m = &maps[samples[i / 3]].data;
                texels.iter().map(|&p| m[p][i % 3] as f64).sum::<f64>() / n.max(1) as f64
            })
            .collect();
        let mut rows = vec![0.0f32; n * d];
        rows.par_chunks_mut(d.max(1))
            .zip(texels)
            .for_each(|(row, &p)| {
                for (i, v) in row.iter_mut().enumerate() {
                    *v = (maps[samples[i / 3]].data[p][i % 3] as f64 - mean[i]) as f32;
                }
            });
        TexelMatrix { n, d, mean, rows }
    }

    pub fn row(&self, p: usize) -> &[f32] {
        &self.rows[p * self.d..(p + 1) * self.d]
    }

    /// Y = X Q^T: each texel's coordinates on the rows of `q` (N x q.len()).
    pub fn project(&self, q: &[Vec<f32>]) -> Vec<f32> {
        let l = q.len();
        let mut y = vec![0.0f32; self.n * l];
        y.par_chunks_mut(l.max(1)).enumerate().for_each(|(p, yp)| {
            let x = self.row(p);
            for (v, b) in yp.iter_mut().zip(q) {
                *v = dot32(x, b);
            }
        });
        y
    }

    /// Z = Y^T X (l x D) for Y of `l` columns, summed block by block in order.
    fn back_project(&self, y: &[f32], l: usize) -> Vec<Vec<f64>> {
        let d = self.d;
        let partial: Vec<Vec<f32>> = (0..self.n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|b| {
                let mut acc = vec![0.0f32; l * d];
                for p in b * BLOCK..((b + 1) * BLOCK).min(self.n) {
                    let x = self.row(p);
                    for j in 0..l {
                        let a = y[p * l + j];
                        for (z, v) in acc[j * d..(j + 1) * d].iter_mut().zip(x) {
                            *z += a * v;
                        }
                    }
                }
                acc
            })
            .collect();
        let mut z = vec![vec![0.0f64; d]; l];
        for acc in &partial {
            for (j, zj) in z.iter_mut().enumerate() {
                for (s, v) in zj.iter_mut().zip(&acc[j * d..(j + 1) * d]) {
                    *s += *v as f64;
                }
            }
        }
        z
    }
}

/// The `r` leading principal components of `x` (fewer if D or N is smaller).
pub(crate) fn principal_components(x: &TexelMatrix, r: usize) -> Components {
    let r = r.min(x.d).min(x.n);
    if r == 0 {
        return Components {
            basis: Vec::new(),
            variance: Vec::new(),
            coeffs: Vec::new(),
        };
    }
    // Oversampled so the r-th direction converges in a few iterations.
    let l = (r + r.div_ceil(4).max(8)).min(x.d).min(x.n);
    // Deterministic start, then subspace iteration Q <- orth(X^T X Q).
    let mut q: Vec<Vec<f64>> = (0..l)
        .map(|j| {
            (0..x.d)
                .map(|i| ((i + 1) as f64 * (j as f64 + 1.3) * 0.618).sin())
                .collect()
        })
        .collect();
    orthonormalise(&mut q);
    for _ in 0..ITERATIONS {
        let y = x.project(&to_f32(&q));
        q = x.back_project(&y, l);
        orthonormalise(&mut q);
    }
    // Rayleigh-Ritz: the eigenvectors of Y^T Y in the found subspace.
    let qf = to_f32(&q);
    let y = x.project(&qf);
    let mut gram = vec![vec![0.0f64; l]; l];
    for a in 0..l {
        for b in a..l {
            let s: f64 = (0..x.n)
                .map(|p| y[p * l + a] as f64 * y[p * l + b] as f64)
                .sum();
            gram[a][b] = s;
            gram[b][a] = s;
        }
    }
    let (eigenvalues, w) = symmetric_eigen(gram);
    let basis: Vec<Vec<f64>> = (0..r)
        .map(|j| {
            let mut v = vec![0.0f64; x.d];
            for (i, qi) in q.iter().enumerate() {
                for (a, b) in v.iter_mut().zip(qi) {
                    *a += w[i][j] * b;
                }
            }
            v
        })
        .collect();
    let mut coeffs = vec![0.0f32; x.n * r];
    coeffs.par_chunks_mut(r).enumerate().for_each(|(p, c)| {
        let yp = &y[p * l..(p + 1) * l];
        for (j, cj) in c.iter_mut().enumerate() {
            *cj = (0..l).map(|i| yp[i] as f64 * w[i][j]).sum::<f64>() as f32;
        }
    });
    Components {
        basis,
        variance: eigenvalues[..r].iter().map(|e| e / x.n as f64).collect(),
        coeffs,
    }
}

/// Subspace iterations after the start (Halko et al.'s q; with oversampling
/// the leading directions' variances settle within 1e-3 in a few).
const ITERATIONS: usize = 6;

/// Vectors as f32, for [`TexelMatrix::project`].
pub(crate) fn to_f32(v: &[Vec<f64>]) -> Vec<Vec<f32>> {
    v.iter()
        .map(|b| b.iter().map(|&x| x as f32).collect())
        .collect()
}

/// A dot product in eight lanes (vectorised; a fixed summation order).
fn dot32(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Modified Gram-Schmidt; a vanishing vector is replaced by a unit axis
/// orthogonal to the others so the basis keeps its size.
fn orthonormalise(v: &mut [Vec<f64>]) {
    for j in 0..v.len() {
        for attempt in 0..=v[j].len() {
            let (done, rest) = v.split_at_mut(j);
            let vj = &mut rest[0];
            for vi in done.iter() {
                let p = dot(vj, vi);
                for (a, b) in vj.iter_mut().zip(vi) {
                    *a -= p * b;
                }
            }
            let n = dot(vj, vj).sqrt();
            if n > 1e-12 {
                vj.iter_mut().for_each(|a| *a /= n);
                break;
            }
            let d = vj.len();
            *vj = (0..d)
                .map(|i| if i == (j + attempt) % d { 1.0 } else { 0.0 })
                .collect();
        }
    }
}

/// Eigenvalues (descending) and eigenvectors (columns of the returned
/// matrix) of a small symmetric matrix, by cyclic Jacobi rotations.
fn symmetric_eigen(mut a: Vec<Vec<f64>>) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut v: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    let scale: f64 = a.iter().map(|r| r.iter().map(|x| x * x).sum::<f64>()).sum();
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off <= 1e-30 * scale.max(f64::MIN_POSITIVE) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                // A <- J^T A J and V <- V J, J the rotation in the (p, q) plane:
                // columns p and q of A and V, then rows p and q of A.
                for row in a.iter_mut().chain(v.iter_mut()) {
                    let (rp, rq) = (row[p], row[q]);
                    row[p] = c * rp - s * rq;
                    row[q] = s * rp + c * rq;
                }
                let (ap, aq) = (a[p].clone(), a[q].clone());
                for (k, (xp, xq)) in ap.iter().zip(&aq).enumerate() {
                    a[p][k] = c * xp - s * xq;
                    a[q][k] = s * xp + c * xq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let values = order.iter().map(|&i| a[i][i].max(0.0)).collect();
    let vectors = (0..n)
        .map(|r| order.iter().map(|&i| v[r][i]).collect())
        .collect();
    (values, vectors)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Deterministic unit-variance noise: a sum of 12 uniforms less 6.
    pub(crate) fn gaussian(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = seed;
        move || {
            (0..12)
                .map(|_| {
                    rng = rng
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (rng >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        }
    }

    #[test]
    fn jacobi_diagonalises_a_symmetric_matrix() {
        let a = vec![
            vec![4.0, 1.0, 0.5],
            vec![1.0, 3.0, 0.2],
            vec![0.5, 0.2, 1.0],
        ];
        let (vals, vecs) = symmetric_eigen(a.clone());
        assert!(vals.windows(2).all(|w| w[0] >= w[1]));
        for j in 0..3 {
            for i in 0..3 {
                let av: f64 = (0..3).map(|k| a[i][k] * vecs[k][j]).sum();
                assert!((av - vals[j] * vecs[i][j]).abs() < 1e-10);
            }
        }
        assert!((vals.iter().sum::<f64>() - 8.0).abs() < 1e-10);
    }

    /// Texels along three known directions with known variances, plus a
    /// little isotropic noise: the variances and directions come back.
    #[test]
    fn known_directions_and_variances_are_recovered() {
        let (n, s) = (2000, 30);
        let d = 3 * s;
        let mut dirs: Vec<Vec<f64>> = (0..3)
            .map(|j| (0..d).map(|i| ((i * (j + 2)) as f64 * 0.7).cos()).collect())
            .collect();
        orthonormalise(&mut dirs);
        let sd = [3.0, 2.0, 1.0];
        let mut gauss = gaussian(12345);
        let noise = 0.01;
        let rows: Vec<Vec<f64>> = (0..n)
            .map(|_| {
                let c: Vec<f64> = sd.iter().map(|s| s * gauss()).collect();
                (0..d)
                    .map(|i| (0..3).map(|j| c[j] * dirs[j][i]).sum::<f64>() + noise * gauss())
                    .collect()
            })
            .collect();
        let maps: Vec<Texture> = (0..s)
            .map(|si| Texture {
                width: n,
                height: 1,
                data: rows
                    .iter()
                    .map(|r| std::array::from_fn(|ch| r[3 * si + ch] as f32))
                    .collect(),
            })
            .collect();
        let x = TexelMatrix::new(&maps);
        let pc = principal_components(&x, 3);
        for j in 0..3 {
            let want = sd[j] * sd[j];
            assert!(
                (pc.variance[j] / want - 1.0).abs() < 0.1,
                "component {j}: variance {} against {want}",
                pc.variance[j]
            );
            let cos = dot(&pc.basis[j], &dirs[j]).abs();
            assert!(cos > 0.99, "component {j}: cos {cos}");
        }
    }
}
