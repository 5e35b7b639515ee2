//! Piecewise-constant 1D and 2D distributions for importance sampling (pbrt
//! style): each `sample_*` returns the point and its pdf, beside a `*_pdf`.

/// A piecewise-constant density over [0, 1) with `func.len()` cells.
#[derive(Clone, Debug)]
pub struct Distribution1D {
    func: Vec<f32>,
    cdf: Vec<f32>,
    integral: f32,
}

impl Distribution1D {
    /// `func` must be non-negative; an all-zero function samples uniformly.
    pub fn new(func: &[f32]) -> Self {
        let n = func.len().max(1);
        let func: Vec<f32> = if func.is_empty() {
            vec![1.0]
        } else {
            func.iter().map(|f| f.max(0.0)).collect()
        };
        let mut cdf = vec![0f32; n + 1];
        for i in 0..n {
            cdf[i + 1] = cdf[i] + func[i] / n as f32;
        }
        let integral = cdf[n];
        if integral > 0.0 {
            for c in &mut cdf {
                *c /= integral;
            }
        } else {
            for (i, c) in cdf.iter_mut().enumerate() {
                *c = i as f32 / n as f32;
            }
        }
        Distribution1D {
            func,
            cdf,
            integral,
        }
    }

    pub fn count(&self) -> usize {
        self.func.len()
    }

    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Returns (x in [0, 1), pdf(x), cell index).
    pub fn sample_continuous(&self, u: f32) -> (f32, f32, usize) {
        let n = self.func.len();
        // Last cell whose cdf start is <= u.
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .saturating_sub(1)
            .min(n - 1);
        let width = self.cdf[i + 1] - self.cdf[i];
        let du = if width > 0.0 {
            (u - self.cdf[i]) / width
        } else {
            0.5
        };
        let x = ((i as f32 + du.clamp(0.0, 1.0)) / n as f32).min(1.0 - f32::EPSILON);
        (x, self.pdf_cell(i), i)
    }

    /// Density of cell `i` with respect to x in [0, 1).
    pub fn pdf_cell(&self, i: usize) -> f32 {
        if self.integral > 0.0 {
            self.func[i] / self.integral
        } else {
            1.0
        }
    }
}

/// A piecewise-constant density over [0, 1)^2: a marginal over rows and a
/// conditional per row.
#[derive(Clone, Debug)]
pub struct Distribution2D {
    rows: Vec<Distribution1D>,
    marginal: Distribution1D,
}

impl Distribution2D {
    /// `func` is row-major, `width` x `height`.
    pub fn new(func: &[f32], width: usize, height: usize) -> Self {
        let rows: Vec<Distribution1D> = (0..height)
            .map(|y| Distribution1D::new(&func[y * width..(y + 1) * width]))
            .collect();
        let marginal = Distribution1D::new(&rows.iter().map(|r| r.integral()).collect::<Vec<_>>());
        Distribution2D { rows, marginal }
    }

    /// Returns ((u, v), pdf(u, v)).
    pub fn sample_continuous(&self, u0: f32, u1: f32) -> ([f32; 2], f32) {
        let (v, pdf_v, row) = self.marginal.sample_continuous(u1);
        let (u, pdf_u, _) = self.rows[row].sample_continuous(u0);
        ([u, v], pdf_u * pdf_v)
    }

    /// Density at (u, v) with respect to area in [0, 1)^2.
    pub fn pdf(&self, u: f32, v: f32) -> f32 {
        let h = self.rows.len();
        let w = self.rows[0].count();
        let y = ((v * h as f32) as usize).min(h - 1);
        let x = ((u * w as f32) as usize).min(w - 1);
        if self.marginal.integral() > 0.0 {
            self.rows[y].func[x] / self.marginal.integral()
        } else {
            1.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_follow_the_function_and_pdf_matches() {
        let f = [1.0, 0.0, 3.0, 4.0];
        let d = Distribution1D::new(&f);
        let mut counts = [0usize; 4];
        let n = 8000;
        for k in 0..n {
            let (x, pdf, i) = d.sample_continuous((k as f32 + 0.5) / n as f32);
            counts[i] += 1;
            assert_eq!(i, (x * 4.0) as usize);
            assert!((pdf - f[i] / 2.0).abs() < 1e-6);
        }
        assert_eq!(counts[1], 0);
        assert!((counts[3] as f32 / n as f32 - 0.5).abs() < 0.01);
    }

    #[test]
    fn pdf_2d_integrates_to_one() {
        let (w, h) = (8, 4);
        let f: Vec<f32> = (0..w * h).map(|i| ((i * 7) % 5) as f32).collect();
        let d = Distribution2D::new(&f, w, h);
        let mut total = 0.0;
        for y in 0..h {
            for x in 0..w {
                total += d.pdf((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32)
                    / (w * h) as f32;
            }
        }
        assert!((total - 1.0).abs() < 1e-5);
        let ([u, v], pdf) = d.sample_continuous(0.3, 0.7);
        assert!((pdf - d.pdf(u, v)).abs() < 1e-5);
    }
}
