//! A small Levenberg-Marquardt least-squares solver (Marquardt's diagonal
//! scaling, forward-difference Jacobian). Enough for calibration problems of a
//! few hundred parameters and a few thousand residuals.

use crate::linalg::cholesky_solve;

/// Outcome of a minimisation.
#[derive(Debug, Clone, Copy)]
pub struct LmReport {
    pub iterations: usize,
    /// Sum of squared residuals at the start and at the end.
    pub initial_cost: f64,
    pub final_cost: f64,
}

/// Minimise sum_i r_i(p)^2 over `p`. `residuals(p, out)` fills `out` (length `m`).
/// `steps[k]` is the finite-difference step of parameter k.
pub fn minimise<F>(
    p: &mut [f64],
    m: usize,
    steps: &[f64],
    max_iter: usize,
    residuals: F,
) -> LmReport
where
    F: Fn(&[f64], &mut [f64]) + Sync,
{
    let n = p.len();
    let mut r = vec![0.0; m];
    residuals(p, &mut r);
    let mut cost: f64 = r.iter().map(|x| x * x).sum();
    let initial_cost = cost;
    let mut lambda = 1e-3;
    let mut jac = vec![0.0; n * m]; // row k = d r / d p_k
    let mut iterations = 0;
    for it in 0..max_iter {
        iterations = it + 1;
        // Jacobian columns in parallel: each needs its own perturbed copy of p.
        use rayon::prelude::*;
        jac.par_chunks_mut(m).enumerate().for_each(|(k, col)| {
            let mut q = p.to_vec();
            q[k] += steps[k];
            residuals(&q, col);
            for (c, r0) in col.iter_mut().zip(&r) {
                *c = (*c - r0) / steps[k];
            }
        });
        // Each column's nonzero rows: a view's pose moves only that view's
        // residuals, so most pairs of columns never overlap and the products
        // outside the overlap are exact zeros.
        let spans: Vec<(usize, usize)> = jac
            .chunks(m)
            .map(|col| match col.iter().position(|x| *x != 0.0) {
                Some(first) => (
                    first,
                    m - col.iter().rev().position(|x| *x != 0.0).unwrap_or(0),
                ),
                None => (0, 0),
            })
            .collect();
        let mut jtj = vec![0.0; n * n];
        let mut jtr = vec![0.0; n];
        jtj.par_chunks_mut(n).enumerate().for_each(|(a, row)| {
            let ja = &jac[a * m..(a + 1) * m];
            for (b, v) in row.iter_mut().enumerate().skip(a) {
                let jb = &jac[b * m..(b + 1) * m];
                let (lo, hi) = (spans[a].0.max(spans[b].0), spans[a].1.min(spans[b].1));
                *v = if lo < hi {
                    ja[lo..hi].iter().zip(&jb[lo..hi]).map(|(x, y)| x * y).sum()
                } else {
                    0.0
                };
            }
        });
        for a in 0..n {
            for b in 0..a {
                jtj[a * n + b] = jtj[b * n + a];
            }
            let (lo, hi) = spans[a];
            jtr[a] = jac[a * m + lo..a * m + hi]
                .iter()
                .zip(&r[lo..hi])
                .map(|(x, y)| x * y)
                .sum();
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut a = jtj.clone();
            for k in 0..n {
                a[k * n + k] += lambda * jtj[k * n + k].max(1e-12);
            }
            let neg: Vec<f64> = jtr.iter().map(|x| -x).collect();
            let Some(delta) = cholesky_solve(&a, &neg, n) else {
                lambda *= 10.0;
                continue;
            };
            let trial: Vec<f64> = p.iter().zip(&delta).map(|(a, b)| a + b).collect();
            let mut rt = vec![0.0; m];
            residuals(&trial, &mut rt);
            let ct: f64 = rt.iter().map(|x| x * x).sum();
            if ct.is_finite() && ct < cost {
                let rel = (cost - ct) / cost.max(1e-300);
                p.copy_from_slice(&trial);
                r = rt;
                cost = ct;
                lambda = (lambda * 0.3).max(1e-12);
                improved = true;
                if rel < 1e-12 {
                    return LmReport {
                        iterations,
                        initial_cost,
                        final_cost: cost,
                    };
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    LmReport {
        iterations,
        initial_cost,
        final_cost: cost,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exponential() {
        // y = 2 exp(-0.5 x) sampled exactly; start far away.
        let xs: Vec<f64> = (0..20).map(|i| i as f64 * 0.3).collect();
        let mut p = [1.0, -0.1];
        let rep = minimise(&mut p, xs.len(), &[1e-7, 1e-7], 100, |p, out| {
            for (o, &x) in out.iter_mut().zip(&xs) {
                *o = p[0] * (p[1] * x).exp() - 2.0 * (-0.5 * x).exp();
            }
        });
        assert!(
            (p[0] - 2.0).abs() < 1e-6 && (p[1] + 0.5).abs() < 1e-6,
            "{p:?} {rep:?}"
        );
        assert!(rep.final_cost < 1e-12);
    }
}
