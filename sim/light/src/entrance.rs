//! The true entrance function f(w_i) of a sample: the share of a parallel
//! beam's flux from direction w_i that enters the volume, tallied photon by
//! photon by the Monte Carlo (no fit, no diffusion model). A photon counts
//! once, the first time it refracts into the volume (the top or, in a
//! cellular sample, a cell wall after any reflections in open cells). Beams
//! fall uniformly (in horizontal area) over the footprint, so the count
//! over the photons that reach the sample is the entering share of the
//! incident flux. On a smooth homogeneous slab it is the Fresnel
//! transmittance T(theta) = 1 - F(cos theta).

use glam::Vec3;
use serde::Serialize;

use crate::Error;
use crate::microfacet::fr_dielectric;
use crate::sample::SceneDesc;
use crate::walk::Source;
use crate::world::World;

/// f at one incidence angle.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct EntrancePoint {
    pub theta_deg: f64,
    /// Entering share of the incident flux.
    pub f: f64,
    /// Its binomial standard error.
    pub f_err: f64,
    /// f(theta) / f(0) and its standard error.
    pub ratio: f64,
    pub ratio_err: f64,
    /// Fresnel T(theta) / T(0) of the sample's top index (a smooth boundary).
    pub fresnel_ratio: f64,
    /// The share of the incident flux that leaves through the top after
    /// subsurface transport (the diffuse exitance, in this channel), and its
    /// ratio to the vertical's: what laser stripes measure of f.
    pub exitance: f64,
    pub exitance_ratio: f64,
    pub exitance_ratio_err: f64,
}

/// Unpolarised Fresnel transmittance from air into index `eta` at `theta_deg`.
pub fn fresnel_transmittance(theta_deg: f64, eta: f64) -> f64 {
    1.0 - fr_dielectric(theta_deg.to_radians().cos() as f32, eta as f32) as f64
}

/// f(theta) for each angle (degrees from the normal, in [0, 89]) in one
/// colour channel, `photons` per angle; f(0) is always measured first (with
/// its own seed) for the ratios. The lamp comes from azimuth 0 (+x).
pub fn entrance_function(
    world: &World,
    thetas_deg: &[f64],
    channel: usize,
    photons: u64,
    seed: u64,
) -> Result<Vec<EntrancePoint>, Error> {
    let SceneDesc::Sample(s) = world.desc() else {
        return Err(Error::InvalidIllumination(
            "the entrance function needs a sample, not a calibration target".into(),
        ));
    };
    if channel > 2 {
        return Err(Error::InvalidIllumination(format!(
            "channel {channel} (0 red, 1 green, 2 blue)"
        )));
    }
    if photons == 0 {
        return Err(Error::InvalidIllumination("photons must be > 0".into()));
    }
    if let Some(t) = thetas_deg
        .iter()
        .find(|t| !(t.is_finite() && (0.0..=89.0).contains(*t)))
    {
        return Err(Error::InvalidIllumination(format!(
            "incidence angle {t} degrees not in [0, 89]"
        )));
    }
    let eta = s.surface.eta;
    let measure = |theta: f64, k: u64| {
        let th = theta.to_radians();
        let source = Source::Lamp {
            to_lamp: Vec3::new(th.sin() as f32, 0.0, th.cos() as f32),
        };
        let t = world.trace(&source, channel, photons, seed ^ (k << 32), None);
        let hit = (t.launched - t.missed).max(1) as f64;
        let share = |n: u64| {
            let p = n as f64 / hit;
            (p, (p * (1.0 - p) / hit).sqrt())
        };
        (share(t.entered), share(t.exited))
    };
    let ((f0, e0), (x0, xe0)) = measure(0.0, 0);
    let t0 = fresnel_transmittance(0.0, eta);
    Ok(thetas_deg
        .iter()
        .enumerate()
        .map(|(k, &theta)| {
            let ((f, e), (x, xe)) = if theta == 0.0 {
                ((f0, e0), (x0, xe0))
            } else {
                measure(theta, k as u64 + 1)
            };
            let ratio_err = |p: f64, pe: f64, q: f64, qe: f64| {
                p / q * ((pe / p.max(1e-12)).powi(2) + (qe / q.max(1e-12)).powi(2)).sqrt()
            };
            EntrancePoint {
                theta_deg: theta,
                f,
                f_err: e,
                ratio: f / f0,
                ratio_err: ratio_err(f, e, f0, e0),
                fresnel_ratio: fresnel_transmittance(theta, eta) / t0,
                exitance: x,
                exitance_ratio: x / x0.max(1e-12),
                exitance_ratio_err: ratio_err(x, xe, x0, xe0),
            }
        })
        .collect())
}
