//! The fitted entrance function against the simulated sample's true one:
//! at every laser direction the fit measured, f(w_i) (per channel, 1 at the
//! vertical) beside the Monte Carlo's tallies relative to the vertical's
//! (`sim_light::entrance`): the diffuse exitance per incident flux, which
//! is what f must be (the paper measures f as that ratio of stripe images,
//! and the renderer takes f as how much more an oblique beam returns, its
//! global term scaled back to normal incidence's total), and the share of
//! the beam that refracts into the volume. The two differ where an oblique
//! beam, entering shallower, loses less of its light in the volume.

use anyhow::{Result, bail};
use qhm_model::MaterialModel;
use serde::Serialize;
use sim_light::World;
use sim_light::entrance::entrance_function;

/// One measured laser direction of the model.
#[derive(Debug, Clone, Serialize)]
pub struct EntranceCheck {
    pub theta_deg: f64,
    pub phi_deg: f64,
    /// The model's measured f, R/G/B.
    pub fitted: [f64; 3],
    /// The true entering share relative to the vertical's, f(θ)/f(0), and
    /// its standard error (green; the sample has one index).
    pub truth: f64,
    pub truth_err: f64,
    /// The smooth surface's T(θ)/T(0) at the sample's index.
    pub fresnel: f64,
    /// The true diffuse exitance per incident flux relative to the
    /// vertical's, R/G/B, and its standard error: what f is judged against.
    pub exitance: [f64; 3],
    pub exitance_err: [f64; 3],
}

impl EntranceCheck {
    /// fitted / true exitance ratio - 1, per channel.
    pub fn errors(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.fitted[c] / self.exitance[c] - 1.0)
    }
}

/// The largest |fitted / true exitance ratio - 1| over directions and channels.
pub fn worst_error(checks: &[EntranceCheck]) -> f64 {
    checks
        .iter()
        .flat_map(|c| c.errors())
        .fold(0.0, |a, e| a.max(e.abs()))
}

/// Compares the model's measured entrance samples (its fit diagnostics) with
/// the truth of `world`'s sample, `photons` per incidence angle. Directions
/// within 0.05° of each other share one tally.
pub fn check_entrance(
    world: &World,
    model: &MaterialModel,
    photons: u64,
    seed: u64,
) -> Result<Vec<EntranceCheck>> {
    let Some(d) = model.diagnostics.as_ref() else {
        bail!("the model has no fit diagnostics, so no measured entrance samples");
    };
    if d.entrance_samples.is_empty() {
        bail!("the model has no measured entrance samples (its capture had no oblique stripes)");
    }
    let angles: Vec<(f64, f64)> = d
        .entrance_samples
        .iter()
        .map(|(w, _)| {
            let w = w.map(f64::from);
            let theta = w[2].clamp(-1.0, 1.0).acos().to_degrees();
            (theta, w[1].atan2(w[0]).to_degrees().rem_euclid(360.0))
        })
        .collect();
    let mut thetas: Vec<f64> = Vec::new();
    for &(t, _) in &angles {
        let t = (t * 20.0).round() / 20.0;
        if !thetas.contains(&t) {
            thetas.push(t);
        }
    }
    let truth =
        [0, 1, 2].map(|c| entrance_function(world, &thetas, c, photons, seed ^ (c as u64) << 48));
    let [r, g, b] = truth;
    let truth = [r?, g?, b?];
    Ok(d.entrance_samples
        .iter()
        .zip(&angles)
        .map(|((_, f), &(theta, phi))| {
            let t = (theta * 20.0).round() / 20.0;
            let at = |c: usize| {
                truth[c]
                    .iter()
                    .find(|p| p.theta_deg == t)
                    .expect("every angle was tallied")
            };
            let p = at(1);
            EntranceCheck {
                theta_deg: theta,
                phi_deg: phi,
                fitted: f.map(f64::from),
                truth: p.ratio,
                truth_err: p.ratio_err,
                fresnel: p.fresnel_ratio,
                exitance: [0, 1, 2].map(|c| at(c).exitance_ratio),
                exitance_err: [0, 1, 2].map(|c| at(c).exitance_ratio_err),
            }
        })
        .collect())
}
