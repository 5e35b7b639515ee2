//! I_D(d) tabulated for one a' and every s'_t: the table the s'_t search
//! looks its candidates up in, for either light transport.

use crate::dipole::Dipole;
use crate::quad;

/// I_D(d) for one a' and every s'_t at once, from the scaling law that the
/// dipole and radiative transfer share (lengths scale with 1/s'_t):
/// R_d(r; a', s'_t) = s'_t² R_d(s'_t r; a', 1), hence
/// I_D(d; a', s'_t) = s'_t g(s'_t d) with g(x) = I_D(x; a', 1). g is computed
/// once on a grid in u = ln(1 + x) (by quadrature for the dipole, by
/// [`crate::radiative_transfer`] otherwise) and interpolated linearly in (u, ln g),
/// which makes each candidate of the s'_t search a table lookup.
#[derive(Clone, Debug)]
pub struct ScaledStripe {
    pub alpha_prime: f64,
    pub eta: f64,
    h: f64,
    ln_g: Vec<f64>,
}

impl ScaledStripe {
    /// The dipole's table, good for s'_t d <= `x_max`.
    pub fn new(alpha_prime: f64, eta: f64, x_max: f64) -> Self {
        use rayon::prelude::*;
        let unit = Dipole::new(alpha_prime, 1.0, eta);
        Self::from_unit_profile(alpha_prime, eta, x_max, |xs| {
            xs.par_iter().map(|&x| unit.stripe(x)).collect()
        })
    }

    /// The table from any profile g(x) of unit s'_t obeying the same
    /// scaling law, evaluated at once on the grid by `unit_profile`.
    pub fn from_unit_profile(
        alpha_prime: f64,
        eta: f64,
        x_max: f64,
        unit_profile: impl FnOnce(&[f64]) -> Vec<f64>,
    ) -> Self {
        let h = 0.002;
        let n = ((1.0 + x_max.max(1.0)).ln() / h).ceil() as usize + 2;
        let xs: Vec<f64> = (0..n).map(|k| (k as f64 * h).exp() - 1.0).collect();
        let ln_g = unit_profile(&xs)
            .into_iter()
            .map(|g| if g > 0.0 { g.ln().max(-700.0) } else { -700.0 })
            .collect();
        ScaledStripe {
            alpha_prime,
            eta,
            h,
            ln_g,
        }
    }

    /// I_D(d) for reduced extinction `sigma_t_prime`.
    pub fn eval(&self, d: f64, sigma_t_prime: f64) -> f64 {
        let u = (1.0 + sigma_t_prime * d.abs()).ln() / self.h;
        let k = u.floor() as usize;
        let ln_g = if k + 1 >= self.ln_g.len() {
            -700.0
        } else {
            let f = u - k as f64;
            self.ln_g[k] * (1.0 - f) + self.ln_g[k + 1] * f
        };
        sigma_t_prime * ln_g.exp()
    }

    /// Mean of I_D over [d - w/2, d + w/2] (5-point Gauss-Legendre): what a
    /// distance bin or an area-mean texel `w` wide measures; `w = 0` is
    /// the point value.
    pub fn bin_mean(&self, d: f64, w: f64, sigma_t_prime: f64) -> f64 {
        if w <= 0.0 {
            return self.eval(d, sigma_t_prime);
        }
        quad::GL5
            .iter()
            .map(|&(x, wt)| 0.5 * wt * self.eval(d + 0.5 * w * x, sigma_t_prime))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_stripe_matches_quadrature() {
        for &a in &[0.999, 0.95, 0.6] {
            let table = ScaledStripe::new(a, 1.3, 200.0);
            for &st in &[0.3, 1.0, 4.2, 9.5] {
                let dp = Dipole::new(a, st, 1.3);
                for &d in &[0.0, 0.1, 0.7, 2.0, 6.0, 15.0] {
                    let (q, t) = (dp.stripe(d), table.eval(d, st));
                    assert!(
                        ((q - t) / q).abs() < 5e-5,
                        "a'={a} s't={st} d={d}: {q} vs {t}"
                    );
                }
            }
        }
    }
}
