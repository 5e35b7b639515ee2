//! What curvature does to subsurface exitance, from diffusion theory
//! solved exactly in a sphere.
//!
//! A point source one reduced mean free path under the surface of a sphere
//! of radius R (the screened Poisson equation with the Robin boundary
//! φ + 2AD ∂φ/∂n = 0, as the classic dipole approximates it on a plane) has
//! an exitance M_R(γ) = Σ_n g_n P_n(cos γ) at the angle γ from the source's
//! axis, with modified spherical Bessel functions i_n:
//!
//!   g_n ∝ (2n + 1) q_n / (1 + z_b σ_tr i_n'(x) / i_n(x)) / R²,
//!   q_n = i_n(σ_tr (R - z_r)) / i_n(σ_tr R), x = σ_tr R, z_b = 2AD
//!
//! (spelled out in [`sphere_exitance`]). At a chord r from the entry, with
//! R much larger than r and the diffusion lengths, M_R(r) / M_plane(r) =
//! 1 + F(r) / R: to first order the response is linear in the curvature
//! 1/R (for apple it holds to within a few per cent of the gain at
//! R = 10 mm). A convex surface sends out more than a plane: less of the
//! medium lies around the source, and the light's paths between entry and
//! exit run deeper under the boundary. The dipole's images, placed by the
//! entry's tangent plane, give little of that (see
//! [`crate::octree::RdTable::with_geometry`]).

use qhm_model::dipole::Dipole;

/// F(r) of one channel at the chords `rs` (mm): M_R(r) / M_plane(r) =
/// 1 + F(r) / R to first order in 1/R.
///
/// Two spheres of radii R_b and 2 R_b stand for the limit: M_Rb / M_2Rb =
/// 1 + F / (2 R_b) + O(1/R_b²). R_b is eight times the largest chord
/// asked for, and at least 40 times the dipole's lengths, so that the
/// second order stays at the per-cent level of F.
pub fn first_order(d: &Dipole, rs: &[f64]) -> Vec<f64> {
    let z_b = 0.5 * (d.z_v - d.z_r);
    let r_top = rs.iter().fold(0.0f64, |a, &b| a.max(b));
    let lengths = d.z_v + (1.0 / d.sigma_tr.max(1e-12)).min(20.0 * d.z_v);
    let r_b = (8.0 * r_top).max(40.0 * lengths);
    let near = sphere_exitance(r_b, d.z_r, z_b, d.sigma_tr, rs);
    let far = sphere_exitance(2.0 * r_b, d.z_r, z_b, d.sigma_tr, rs);
    near.iter()
        .zip(&far)
        .map(|(&a, &b)| {
            if a > 0.0 && b > 0.0 {
                2.0 * r_b * (a / b - 1.0)
            } else {
                0.0
            }
        })
        .collect()
}

/// Exitance of a sphere of radius `radius` at the chords `rs` from a unit
/// point source `z_r` under its surface, up to a factor that is the same
/// for every radius (σ_tr and the albedo's): the fluence's Legendre
/// series, g_n (2n + 1) q_n / (1 + z_b (σ_tr ρ_n(x) + n / R)) / R², where
/// ρ_n = i_{n+1} / i_n (i_n' / i_n = ρ_n + n / x).
pub fn sphere_exitance(radius: f64, z_r: f64, z_b: f64, sigma_tr: f64, rs: &[f64]) -> Vec<f64> {
    let kappa = sigma_tr.max(1e-12 / z_r);
    let x = kappa * radius;
    let x0 = kappa * (radius - z_r);
    // The terms fall off as ((R - z_r) / R)^n, or faster with absorption.
    let n_max = ((40.0 * radius / z_r) as usize).clamp(64, 4_000_000);
    let ratios = |y: f64| bessel_ratios(y, n_max);
    let (rho, rho0) = (ratios(x), ratios(x0));
    let mut g = Vec::with_capacity(n_max);
    let mut log_q = log_sinhc(x0) - log_sinhc(x);
    let mut top = 0.0f64;
    for n in 0..n_max {
        let nf = n as f64;
        let gn = (2.0 * nf + 1.0) * log_q.exp()
            / (1.0 + z_b * (kappa * rho[n] + nf / radius))
            / (radius * radius);
        top = top.max(gn);
        g.push(gn);
        if gn < 1e-13 * top && n > 16 {
            break;
        }
        log_q += (rho0[n] / rho[n]).ln();
    }
    // Σ g_n P_n(cos γ) at every chord at once, by Bonnet's recurrence
    // P_n = ((2n - 1) x P_{n-1} - (n - 1) P_{n-2}) / n: the chords'
    // recurrences are independent, so the inner loop runs across them.
    let cos_g: Vec<f64> = rs
        .iter()
        .map(|&r| {
            let s = (r / (2.0 * radius)).min(1.0);
            1.0 - 2.0 * s * s
        })
        .collect();
    let mut p0 = vec![1.0; rs.len()];
    let mut p1 = cos_g.clone();
    let mut m: Vec<f64> = cos_g
        .iter()
        .map(|&c| g[0] + g.get(1).map_or(0.0, |g1| g1 * c))
        .collect();
    for (n, gn) in g.iter().enumerate().skip(2) {
        let nf = n as f64;
        let (a, b) = ((2.0 * nf - 1.0) / nf, (nf - 1.0) / nf);
        for j in 0..rs.len() {
            let p2 = a * cos_g[j] * p1[j] - b * p0[j];
            m[j] += gn * p2;
            p0[j] = p1[j];
            p1[j] = p2;
        }
    }
    m
}

/// ρ_n(y) = i_{n+1}(y) / i_n(y) for n < `count`, by the backward
/// recurrence ρ_{n-1} = y / (2n + 1 + y ρ_n) (stable downwards), started
/// beyond `count` from the ratio's large-order form.
fn bessel_ratios(y: f64, count: usize) -> Vec<f64> {
    let start = count + 64 + y as usize;
    let v = start as f64 + 1.5;
    let mut rho = y / (v + (v * v + y * y).sqrt());
    let mut out = vec![0.0; count];
    for n in (0..start).rev() {
        // rho holds ρ_{n+1}; step to ρ_n.
        rho = y / (2.0 * n as f64 + 3.0 + y * rho);
        if n < count {
            out[n] = rho;
        }
    }
    out
}

/// ln(sinh(y) / y) = ln(i_0(y)), without overflow.
fn log_sinhc(y: f64) -> f64 {
    if y < 1e-4 {
        y * y / 6.0
    } else if y < 20.0 {
        (y.sinh() / y).ln()
    } else {
        y - (2.0 * y).ln() + (-(-2.0 * y).exp()).ln_1p()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bessel_ratios_follow_the_closed_forms() {
        // i_0 = sinh y / y, i_1 = (y cosh y - sinh y) / y².
        for y in [1e-3f64, 0.5, 3.0, 40.0] {
            let rho = bessel_ratios(y, 4);
            let want = (y * y.cosh() - y.sinh()) / (y * y.sinh());
            let small = y / 3.0 - y.powi(3) / 45.0;
            let want = if y < 1e-2 { small } else { want };
            assert!(
                (rho[0] / want - 1.0).abs() < 1e-6,
                "y {y}: {} vs {want}",
                rho[0]
            );
        }
    }

    #[test]
    fn a_large_sphere_is_a_plane_and_the_gain_is_first_order() {
        // apple's red (Jensen et al. 2001), eta 1.3
        let d = Dipole::new(2.29 / 2.293, 2.293, 1.3);
        let rs = [0.5, 1.0, 3.0, 5.0];
        let f = first_order(&d, &rs);
        // The same series with scipy's Bessel functions (40 mm sphere
        // against the half-space's Hankel transform): F(1 mm) = 0.532.
        assert!((f[1] / 0.532 - 1.0).abs() < 0.03, "F(1) {}", f[1]);
        // The same F from spheres of 20 and 40 mm: the response is linear
        // in 1/R.
        let z_b = 0.5 * (d.z_v - d.z_r);
        let m = |radius: f64| sphere_exitance(radius, d.z_r, z_b, d.sigma_tr, &rs);
        let (m20, m40) = (m(20.0), m(40.0));
        for i in 0..rs.len() {
            let f_40 = 40.0 * (m20[i] / m40[i] - 1.0);
            assert!(
                (f_40 / f[i] - 1.0).abs() < 0.1,
                "r {}: {f_40} vs {}",
                rs[i],
                f[i]
            );
            // A convex surface sends out more, the more the farther.
            assert!(f[i] > 0.0);
            if i > 0 {
                assert!(f[i] > f[i - 1]);
            }
        }
    }
}
