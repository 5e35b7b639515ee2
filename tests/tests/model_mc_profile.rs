//! Issue 5 accuracy on the simulated world: fit a Monte Carlo laser-stripe
//! profile of a homogeneous slab (sim-light, no diffusion inside) with the
//! dipole profile fit, and compare a' and s'_t with the slab's truth.
//!
//! I(d) is the exit-position histogram of a vertical stripe across a central
//! band, per entering photon per mm of stripe and per mm² of surface; R is the
//! fraction of entering photons that leave through the top (the dipole models
//! light that has entered; the specular part belongs to the LRF).

use glam::Vec3;
use qhm_model::profile::{Norm, Profile, fit_profile};
use sim_light::*;

/// (I(d) profile, R, photons) of a smooth homogeneous slab with reduced
/// coefficients s'_s, s_a (isotropic scattering, eta 1.3).
fn mc_profile(sigma_s: f64, sigma_a: f64, photons: u64, seed: u64) -> (Profile, f64) {
    let desc = SceneDesc::Sample(SampleDesc {
        name: "homogeneous".into(),
        size_mm: [300.0, 300.0, 150.0],
        seed: 0,
        surface: SurfaceDesc {
            eta: 1.3,
            roughness: 0.0,
            ..SurfaceDesc::default()
        },
        volume: VolumeDesc {
            material: MaterialDesc::Coefficients(Coefficients {
                sigma_s: [sigma_s; 3],
                sigma_a: [sigma_a; 3],
            }),
            inclusions: vec![],
        },
    });
    let world = World::new(desc, RigTruth::nominal(), SimQuality::ci()).unwrap();
    let length = 80.0f32;
    let stripe = Source::Stripe {
        origin: Vec3::new(0.0, 0.0, 800.0),
        centre: Vec3::ZERO,
        dir: Vec3::Y,
        length,
    };
    let (n, cell) = (160usize, 0.25f32); // 40 x 40 mm
    let grid = ExitGrid::new(n, cell);
    let t = world.trace(&stripe, 0, photons, seed, Some(&grid));
    assert!(t.balanced(), "{t:?}");
    let entered = (t.launched - t.missed - t.reflected) as f64;
    let counts = grid.values();
    // Central band along the stripe, far from its ends (|y| < 10 mm).
    let (j0, j1) = (n / 2 - 40, n / 2 + 40);
    let per_mm = entered / length as f64;
    let area = (cell * cell) as f64 * (j1 - j0) as f64;
    let points = (0..n).map(|i| {
        let x = (i as f64 + 0.5) * cell as f64 - n as f64 * cell as f64 / 2.0;
        let c: u64 = (j0..j1).map(|j| counts[j * n + i] as u64).sum();
        (x, c as f64 / area / per_mm)
    });
    (Profile::new(points, cell as f64), t.exited as f64 / entered)
}

fn check(sigma_s: f64, sigma_a: f64, photons: u64) {
    let st = sigma_s + sigma_a;
    let a = sigma_s / st;
    let (profile, r) = mc_profile(sigma_s, sigma_a, photons, 7);
    let fit = fit_profile(&profile, r, 1.3, None, Norm::Poisson).unwrap();
    eprintln!(
        "s'_s {sigma_s} s_a {sigma_a}: R {r:.4}; a' {:.5} (true {a:.5}), s'_t {:.4} (true {st:.4}), range {:?}, residual {:.3e}",
        fit.alpha_prime, fit.sigma_t_prime, fit.range_mm, fit.residual
    );
    assert!(
        (fit.alpha_prime - a).abs() < 0.002,
        "a' {} vs {a}",
        fit.alpha_prime
    );
    let rel = (fit.sigma_t_prime - st).abs() / st;
    assert!(
        rel < 0.05,
        "s'_t {} vs {st} ({:.1} %)",
        fit.sigma_t_prime,
        rel * 100.0
    );
}

#[test]
fn mc_stripe_profile_of_a_homogeneous_slab_fits_the_truth() {
    // Skim-milk-like red channel (Jensen et al. 2001): s'_s 0.70, s_a 0.0014 would
    // need a huge slab; a white, translucent slab of s'_t ~ 1.5 keeps CI fast.
    check(1.5, 0.006, 400_000);
}

#[test]
fn mc_stripe_profile_of_a_more_absorbing_slab_fits_the_truth() {
    // a' = 0.952, s'_t = 2.1: a shorter diffusion length, where the dipole is poorer.
    check(2.0, 0.1, 400_000);
}
