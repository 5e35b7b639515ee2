//! Issue 5 accuracy on the simulated world: fit a Monte Carlo laser-stripe
//! profile of a homogeneous slab (sim-light, no diffusion inside) with the
//! profile fit (radiative transfer solved in the half-space, qhm_model::
//! transport), and compare a' and s'_t with the slab's truth; and compare
//! the two independent solutions of the same transport problem directly.
//!
//! I(d) is the exit-position histogram of a vertical stripe across a central
//! band, per incident photon per mm of stripe and per mm² of surface; R is the
//! fraction of incident photons that leave through the top below it (the
//! specular reflection is not counted: it belongs to the LRF). The fit
//! divides both by T(0), the share that enters.

use glam::Vec3;
use qhm_model::ProfileModel;
use qhm_model::fresnel::normal_transmittance;
use qhm_model::profile::{Norm, Profile, fit_profile};
use qhm_model::radiative_transfer::HalfSpace;
use sim_light::*;

/// (I(d) profile, R) of a large homogeneous slab (300 x 300 x 150 mm,
/// isotropic scattering) with reduced coefficients s'_s, s_a, index `eta`
/// and GGX `roughness` on top, lit by a vertical stripe of colour `channel`.
fn mc_profile(
    sigma_s: f64,
    sigma_a: f64,
    eta: f64,
    roughness: f64,
    photons: u64,
    seed: u64,
) -> (Profile, f64) {
    let desc = SceneDesc::Sample(SampleDesc {
        name: "homogeneous".into(),
        size_mm: [300.0, 300.0, 150.0],
        seed: 0,
        surface: SurfaceDesc {
            eta,
            roughness,
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
    // Per incident flux, as a capture measures it (the specular reflection
    // off the smooth top is part of the incident flux, not of I(d)).
    let incident = (t.launched - t.missed) as f64;
    let counts = grid.values();
    // Central band along the stripe, far from its ends (|y| < 10 mm).
    let (j0, j1) = (n / 2 - 40, n / 2 + 40);
    let per_mm = incident / length as f64;
    let area = (cell * cell) as f64 * (j1 - j0) as f64;
    let points = (0..n).map(|i| {
        let x = (i as f64 + 0.5) * cell as f64 - n as f64 * cell as f64 / 2.0;
        let c: u64 = (j0..j1).map(|j| counts[j * n + i] as u64).sum();
        (x, c as f64 / area / per_mm)
    });
    (
        Profile::new(points, cell as f64),
        t.exited as f64 / incident,
    )
}

/// The fit's a' and s'_t errors (absolute, relative) on a Monte Carlo profile.
fn errors(
    sigma_s: f64,
    sigma_a: f64,
    eta: f64,
    roughness: f64,
    photons: u64,
) -> Result<(f64, f64), qhm_model::ModelError> {
    let st = sigma_s + sigma_a;
    let a = sigma_s / st;
    let (profile, r) = mc_profile(sigma_s, sigma_a, eta, roughness, photons, 7);
    let fit = fit_profile(
        &profile,
        r,
        eta,
        ProfileModel::Transport,
        None,
        Norm::Poisson,
    )?;
    eprintln!(
        "s'_s {sigma_s} s_a {sigma_a} eta {eta}: R {r:.4}; a' {:.5} (true {a:.5}), s'_t {:.4} (true {st:.4}), range {:?}, residual {:.3e}",
        fit.alpha_prime, fit.sigma_t_prime, fit.range_mm, fit.residual
    );
    Ok((fit.alpha_prime - a, fit.sigma_t_prime / st - 1.0))
}

fn check(sigma_s: f64, sigma_a: f64, photons: u64) {
    let (da, ds) = errors(sigma_s, sigma_a, 1.3, 0.0, photons).unwrap();
    assert!(da.abs() < 0.002, "a' off by {da}");
    assert!(ds.abs() < 0.05, "s'_t off by {:.1} %", ds * 100.0);
}

#[test]
fn mc_stripe_profile_of_a_homogeneous_slab_fits_the_truth() {
    // A white, translucent slab of s'_t ~ 1.5.
    check(1.5, 0.006, 400_000);
}

#[test]
fn mc_stripe_profile_of_a_more_absorbing_slab_fits_the_truth() {
    // a' = 0.952, s'_t = 2.1: a shorter diffusion length, where the dipole is poorer.
    check(2.0, 0.1, 400_000);
}

/// Every channel of the homogeneous presets, each with its own eta, under
/// a smooth top (the boundary the transport model describes), the stripe's
/// light per incident flux as a capture measures it: a' within 0.002 and
/// s'_t within 5 % (issue 5's targets; measured: <= 0.0008 and 2.2 %),
/// at every albedo. Only ketchup's green and blue (a' 0.07 and 0.02), whose
/// light leaves within a millimetre of the stripe, have no distance range
/// to fit, and must say so.
#[test]
fn mc_stripe_profiles_of_the_homogeneous_presets_fit_the_truth() {
    let mut failures = Vec::new();
    for name in [
        "marble",
        "whole-milk",
        "skim-milk",
        "cream",
        "apple",
        "potato",
        "skin1",
        "skin2",
        "ketchup",
    ] {
        let (k, eta) = material_preset(name).unwrap();
        for c in 0..3 {
            let (ss, sa) = (k.sigma_s[c], k.sigma_a[c]);
            let a = ss / (ss + sa);
            match errors(ss, sa, eta, 0.0, 200_000) {
                Ok((da, ds)) => {
                    eprintln!(
                        "{name} channel {c}: a' {a:.4} off by {da:+.4}, s'_t off by {:+.1} %",
                        ds * 100.0
                    );
                    if da.abs() >= 0.002 || ds.abs() >= 0.05 {
                        failures.push(format!(
                            "{name} channel {c}: a' {da:+.4}, s'_t {:+.1} %",
                            ds * 100.0
                        ));
                    }
                }
                Err(e) if a < 0.1 && e.to_string().contains("no usable distance range") => {
                    eprintln!("{name} channel {c}: a' {a:.4}: {e}")
                }
                Err(e) => failures.push(format!("{name} channel {c}: {e}")),
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The same transport problem solved twice, independently: Monte Carlo
/// random walks (sim-light) and the Fourier-domain integral equation of
/// qhm_model::radiative_transfer. R agrees within 0.5 % (measured: 0.01 %)
/// and the stripe's profile, in 1 mm bands from 0.5 to 6.5 mm while above a
/// twentieth of the first, within 3 % (Monte Carlo noise there: 1-2 %);
/// the classic dipole is 5-12 % off over the same bands.
#[test]
fn monte_carlo_and_transport_solution_agree() {
    for (name, c) in [("whole-milk", 0), ("marble", 0), ("skin2", 2)] {
        let (k, eta) = material_preset(name).unwrap();
        let (ss, sa) = (k.sigma_s[c], k.sigma_a[c]);
        let (st, a) = (ss + sa, ss / (ss + sa));
        let (profile, r) = mc_profile(ss, sa, eta, 0.0, 6_000_000, 11);
        let half_space = HalfSpace::shared(eta);
        let t_in = normal_transmittance(eta);
        let r_exact = t_in * half_space.total_reflectance(a);
        eprintln!("{name}: R Monte Carlo {r:.5}, transport {r_exact:.5}");
        assert!(
            (r / r_exact - 1.0).abs() < 0.005,
            "{name}: R {r} vs {r_exact}"
        );
        let xs: Vec<f64> = profile.distance_mm.iter().map(|d| d * st).collect();
        let g = half_space.line_profile(a, &xs);
        let mut first = None;
        for band in 0..6 {
            let (lo, hi) = (0.5 + band as f64, 1.5 + band as f64);
            let (mut mc, mut exact) = (0.0, 0.0);
            for (k, &d) in profile.distance_mm.iter().enumerate() {
                if d >= lo && d < hi {
                    mc += profile.intensity[k];
                    exact += t_in * st * g[k];
                }
            }
            if exact < 0.05 * *first.get_or_insert(exact) {
                break;
            }
            let ratio = mc / exact;
            eprintln!("{name} {lo:.1}-{hi:.1} mm: Monte Carlo / transport {ratio:.4}");
            assert!((ratio - 1.0).abs() < 0.03, "{name} {lo}-{hi} mm: {ratio}");
        }
    }
}
