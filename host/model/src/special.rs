//! Special functions and the integral transforms over them that the
//! radiative-transfer solver needs: Bessel J0, the Hankel (J0) transform and
//! the cosine transform of a function tabulated on a grid, each with its
//! asymptotic tail.

use std::f64::consts::PI;

use crate::quad::GL4;

/// Bessel J0 (Abramowitz & Stegun 9.4.1 and 9.4.3, |error| < 5e-8).
pub fn bessel_j0(x: f64) -> f64 {
    let x = x.abs();
    if x <= 3.0 {
        let y = (x / 3.0).powi(2);
        1.0 + y
            * (-2.249_999_7
                + y * (1.265_620_8
                    + y * (-0.316_386_6
                        + y * (0.044_447_9 + y * (-0.003_944_4 + y * 0.000_210_0)))))
    } else {
        let y = 3.0 / x;
        let f0 = 0.797_884_56
            + y * (-0.000_000_77
                + y * (-0.005_527_40
                    + y * (-0.000_095_12
                        + y * (0.001_372_37 + y * (-0.000_728_05 + y * 0.000_144_76)))));
        let theta = x - std::f64::consts::FRAC_PI_4
            + y * (-0.041_663_97
                + y * (-0.000_039_54
                    + y * (0.002_625_73
                        + y * (-0.000_541_25 + y * (-0.000_293_33 + y * 0.000_135_58)))));
        f0 * theta.cos() / x.sqrt()
    }
}

/// ∫_0^∞ f(k) J0(kx) k dk with f linear between the grid's nodes, by
/// 4-point Gauss-Legendre on panels of at most a quarter period of J0, and
/// beyond the last node K the asymptotic series
/// -f(K) K J1(Kx)/x - f'(K) K J0(Kx)/x² (as in [`filon_cos`]).
pub fn hankel_j0(k: &[f64], f: &[f64], x: f64) -> f64 {
    let max_h = if x > 0.0 { 0.5 * PI / x } else { f64::INFINITY };
    let mut sum = 0.0;
    for i in 0..k.len() - 1 {
        let (k0, k1) = (k[i], k[i + 1]);
        let n = ((k1 - k0) / max_h).ceil().max(1.0) as usize;
        let h = (k1 - k0) / n as f64;
        let slope = (f[i + 1] - f[i]) / (k1 - k0);
        for j in 0..n {
            let mid = k0 + (j as f64 + 0.5) * h;
            for &(t, w) in &GL4 {
                let kk = mid + 0.5 * h * t;
                sum += 0.5 * h * w * (f[i] + slope * (kk - k0)) * kk * bessel_j0(kk * x);
            }
        }
    }
    let n = k.len();
    if n >= 2 && k[n - 1] * x > 4.0 * PI {
        let (kk, fk) = (k[n - 1], f[n - 1]);
        let slope = (f[n - 1] - f[n - 2]) / (k[n - 1] - k[n - 2]);
        // J1 = -J0', by a central difference.
        let z = kk * x;
        let j1 = (bessel_j0(z - 1e-4) - bessel_j0(z + 1e-4)) / 2e-4;
        sum -= fk * kk * j1 / x + slope * kk * bessel_j0(z) / (x * x);
    }
    sum
}

/// ∫_0^∞ f(k) cos(kx) dk: Filon's rule over the grid (f linear between
/// nodes), and beyond its last node the first two terms of the asymptotic
/// series, -f(K) sin(Kx)/x - f'(K) cos(Kx)/x², which cancel the ripple of
/// period 2π/K that cutting the integral off would leave (valid for
/// Kx >> 1; closer to the line, within 0.2 mfp, the cut stays).
pub fn filon_cos(k: &[f64], f: &[f64], x: f64) -> f64 {
    let mut sum = 0.0;
    for i in 0..k.len() - 1 {
        let (k0, k1, f0, f1) = (k[i], k[i + 1], f[i], f[i + 1]);
        let h = k1 - k0;
        if x * h < 1e-3 {
            // Trapezoid when cos barely turns over the segment.
            sum += 0.5 * h * (f0 * (k0 * x).cos() + f1 * (k1 * x).cos());
            continue;
        }
        let slope = (f1 - f0) / h;
        let (s0, s1, c0, c1) = (
            (k0 * x).sin(),
            (k1 * x).sin(),
            (k0 * x).cos(),
            (k1 * x).cos(),
        );
        sum += (f1 * s1 - f0 * s0) / x + slope * (c1 - c0) / (x * x);
    }
    let n = k.len();
    if n >= 2 && k[n - 1] * x > 4.0 * PI {
        let (kk, fk) = (k[n - 1], f[n - 1]);
        let slope = (f[n - 1] - f[n - 2]) / (k[n - 1] - k[n - 2]);
        sum -= fk * (kk * x).sin() / x + slope * (kk * x).cos() / (x * x);
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn j0_matches_its_integral() {
        for &x in &[0.0, 0.5, 2.9, 3.1, 7.0, 30.0] {
            let n = 4000;
            let v: f64 = (0..n)
                .map(|i| ((i as f64 + 0.5) / n as f64 * PI).sin())
                .map(|s| (x * s).cos())
                .sum::<f64>()
                / n as f64;
            assert!(
                (bessel_j0(x) - v).abs() < 1e-7,
                "{x}: {} vs {v}",
                bessel_j0(x)
            );
        }
    }
}
