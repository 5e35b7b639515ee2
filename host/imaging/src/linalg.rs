//! The little dense linear algebra calibration needs: symmetric eigen
//! decomposition (cyclic Jacobi) for DLT null spaces, and Cholesky solves for
//! normal equations. Matrices are row-major `Vec<f64>`; sizes stay small
//! (at most a few hundred unknowns).

/// Eigen decomposition of a symmetric n x n matrix `a` (row-major).
/// Returns eigenvalues ascending and the matching eigenvectors as rows.
pub fn sym_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<Vec<f64>>) {
    assert_eq!(a.len(), n * n);
    let mut m = a.to_vec();
    // v holds eigenvectors as columns while iterating.
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| m[i * n + j] * m[i * n + j])
            .sum();
        let scale: f64 = m.iter().map(|x| x * x).sum::<f64>().max(1e-300);
        if off <= 1e-30 * scale {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p * n + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let app = m[p * n + p];
                let aqq = m[q * n + q];
                // Rotation angle zeroing m[p][q] (Golub & Van Loan 8.4).
                let theta = (aqq - app) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let mkp = m[k * n + p];
                    let mkq = m[k * n + q];
                    m[k * n + p] = c * mkp - s * mkq;
                    m[k * n + q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let mpk = m[p * n + k];
                    let mqk = m[q * n + k];
                    m[p * n + k] = c * mpk - s * mqk;
                    m[q * n + k] = s * mpk + c * mqk;
                }
                for k in 0..n {
                    let vkp = v[k * n + p];
                    let vkq = v[k * n + q];
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| m[i * n + i].total_cmp(&m[j * n + j]));
    let values = order.iter().map(|&i| m[i * n + i]).collect();
    let vectors = order
        .iter()
        .map(|&j| (0..n).map(|k| v[k * n + j]).collect())
        .collect();
    (values, vectors)
}

/// The unit vector x minimising |A x| for the rows of A (each of length n):
/// the eigenvector of A^T A with the smallest eigenvalue.
pub fn null_vector(rows: &[Vec<f64>], n: usize) -> Vec<f64> {
    let mut ata = vec![0.0; n * n];
    for r in rows {
        for i in 0..n {
            for j in 0..n {
                ata[i * n + j] += r[i] * r[j];
            }
        }
    }
    let (_, vecs) = sym_eigen(&ata, n);
    vecs.into_iter().next().unwrap_or_else(|| vec![0.0; n])
}

/// Solve the symmetric positive definite system `a x = b` by Cholesky.
/// Returns None when `a` is not positive definite.
pub fn cholesky_solve(a: &[f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let mut sum = a[i * n + j];
            for k in 0..j {
                sum -= l[i * n + k] * l[j * n + k];
            }
            if i == j {
                if sum <= 0.0 || !sum.is_finite() {
                    return None;
                }
                l[i * n + i] = sum.sqrt();
            } else {
                l[i * n + j] = sum / l[j * n + j];
            }
        }
    }
    let mut y = vec![0.0; n];
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * y[k];
        }
        y[i] = s / l[i * n + i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let mut s = y[i];
        for k in i + 1..n {
            s -= l[k * n + i] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
    Some(x)
}

/// Linear least squares min |A x - b| through the normal equations, with a tiny
/// ridge for rank safety. `rows` are (coefficients, rhs).
pub fn least_squares(rows: &[(Vec<f64>, f64)], n: usize) -> Option<Vec<f64>> {
    let mut ata = vec![0.0; n * n];
    let mut atb = vec![0.0; n];
    for (r, b) in rows {
        for i in 0..n {
            if r[i] == 0.0 {
                continue;
            }
            atb[i] += r[i] * b;
            for j in 0..n {
                ata[i * n + j] += r[i] * r[j];
            }
        }
    }
    let trace: f64 = (0..n).map(|i| ata[i * n + i]).sum::<f64>() / n as f64;
    for i in 0..n {
        ata[i * n + i] += 1e-12 * trace.max(1e-300);
    }
    cholesky_solve(&ata, &atb, n)
}

/// Linear least squares min |A x - b| by Householder QR: better conditioned than
/// the normal equations, for polynomial fits. `a` has one row per equation.
pub fn lstsq_qr(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let m = a.len();
    let n = a.first()?.len();
    if m < n {
        return None;
    }
    // Column-major copy so Householder updates walk contiguous memory.
    let mut r: Vec<Vec<f64>> = (0..n)
        .map(|j| a.iter().map(|row| row[j]).collect())
        .collect();
    let mut y = b.to_vec();
    for k in 0..n {
        let norm = r[k][k..].iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm < 1e-300 {
            return None;
        }
        let alpha = if r[k][k] > 0.0 { -norm } else { norm };
        let mut v: Vec<f64> = r[k][k..].to_vec();
        v[0] -= alpha;
        let vnorm2: f64 = v.iter().map(|x| x * x).sum();
        if vnorm2 < 1e-300 {
            continue;
        }
        for col in r.iter_mut().skip(k) {
            let dot: f64 = v.iter().zip(&col[k..]).map(|(a, b)| a * b).sum();
            let f = 2.0 * dot / vnorm2;
            for (ci, vi) in col[k..].iter_mut().zip(&v) {
                *ci -= f * vi;
            }
        }
        let dot: f64 = v.iter().zip(&y[k..]).map(|(a, b)| a * b).sum();
        let f = 2.0 * dot / vnorm2;
        for (yi, vi) in y[k..].iter_mut().zip(&v) {
            *yi -= f * vi;
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let mut s = y[i];
        for j in i + 1..n {
            s -= r[j][i] * x[j];
        }
        if r[i][i].abs() < 1e-14 * r[0][0].abs().max(1e-300) {
            return None;
        }
        x[i] = s / r[i][i];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    #[test]
    fn qr_fits_a_line_exactly() {
        let a: Vec<Vec<f64>> = (0..5).map(|i| vec![1.0, i as f64]).collect();
        let b: Vec<f64> = (0..5).map(|i| 2.0 + 3.0 * i as f64).collect();
        let x = lstsq_qr(&a, &b).unwrap();
        assert!((x[0] - 2.0).abs() < 1e-12 && (x[1] - 3.0).abs() < 1e-12);
    }

    use super::*;

    #[test]
    fn eigen_of_known_matrix() {
        // [[2,1],[1,2]] has eigenvalues 1 and 3.
        let (vals, vecs) = sym_eigen(&[2.0, 1.0, 1.0, 2.0], 2);
        assert!((vals[0] - 1.0).abs() < 1e-12 && (vals[1] - 3.0).abs() < 1e-12);
        assert!((vecs[0][0] + vecs[0][1]).abs() < 1e-12);
    }

    #[test]
    fn null_vector_of_rank_deficient_rows() {
        let rows = vec![vec![1.0, 2.0, 3.0], vec![2.0, -1.0, 0.0]];
        let x = null_vector(&rows, 3);
        for r in &rows {
            let d: f64 = r.iter().zip(&x).map(|(a, b)| a * b).sum();
            assert!(d.abs() < 1e-10);
        }
    }

    #[test]
    fn cholesky_solves_and_refuses_indefinite() {
        let a = [4.0, 2.0, 2.0, 3.0];
        let x = cholesky_solve(&a, &[2.0, 1.0], 2).unwrap();
        assert!((4.0 * x[0] + 2.0 * x[1] - 2.0).abs() < 1e-12);
        assert!((2.0 * x[0] + 3.0 * x[1] - 1.0).abs() < 1e-12);
        assert!(cholesky_solve(&[1.0, 2.0, 2.0, 1.0], &[1.0, 1.0], 2).is_none());
    }
}
