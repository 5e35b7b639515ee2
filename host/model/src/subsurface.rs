//! A material's global term and the light transport behind it: the
//! parameters ([`DipoleParams`]: a', s'_t, eta and the model), the choice of
//! transport ([`ProfileModel`]: the paper's dipole, [`crate::dipole`], or
//! radiative transfer, [`crate::radiative_transfer`]) with what the fit asks
//! of either, and R_d(r) ready to evaluate ([`Subsurface`]). The interface
//! the fit and the renderer use; the implementations below it know nothing
//! of each other.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::dipole::{self, Dipole};
use crate::error::{ModelError, number};
use crate::fresnel;
use crate::radiative_transfer::{HalfSpace, RadialProfile};
use crate::scaled_stripe::ScaledStripe;

/// The light transport a profile is modelled with: what I_D(d) and
/// R_total(a') are.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProfileModel {
    /// Radiative transfer in the half-space, solved without diffusion
    /// ([`crate::radiative_transfer`]): what the dipole approximates.
    #[default]
    Transport,
    /// The paper's classic dipole with Jensen & Buhler's R_total(a').
    Dipole,
}

impl ProfileModel {
    /// Fits stored before the model was recorded used the dipole.
    pub fn recorded_before_choice() -> Self {
        ProfileModel::Dipole
    }

    /// a' from the total diffuse reflectance per entered flux.
    pub fn albedo(self, reflectance: f64, eta: f64) -> Result<f64, ModelError> {
        match self {
            ProfileModel::Dipole => dipole::alpha_prime_from_reflectance(reflectance, eta),
            ProfileModel::Transport => {
                check_eta(eta)?;
                HalfSpace::shared(eta).albedo_from_reflectance(reflectance)
            }
        }
    }

    /// R_total(a') per entered flux.
    pub fn total_reflectance(self, alpha_prime: f64, eta: f64) -> f64 {
        match self {
            ProfileModel::Dipole => dipole::total_reflectance(alpha_prime, eta),
            ProfileModel::Transport => HalfSpace::shared(eta).total_reflectance(alpha_prime),
        }
    }

    /// I_D(d) of a' for every s'_t, good for s'_t d <= `x_max`.
    pub fn stripe_table(self, alpha_prime: f64, eta: f64, x_max: f64) -> ScaledStripe {
        match self {
            ProfileModel::Dipole => ScaledStripe::new(alpha_prime, eta, x_max),
            ProfileModel::Transport => {
                ScaledStripe::from_unit_profile(alpha_prime, eta, x_max, |xs| {
                    HalfSpace::shared(eta).line_profile(alpha_prime, xs)
                })
            }
        }
    }

    /// Exitance per unit radiance seen from outside at each of
    /// `cos_views`, for light of reduced albedo `alpha_prime` leaving the
    /// sample: what turns a camera's radiance into I(d). The dipole takes
    /// the light under the boundary as isotropic; transport has its exact
    /// angular distribution, which at a' 0.8 sends 6 % less along the
    /// normal (eta 1.3).
    pub fn exitance_per_radiance(self, alpha_prime: f64, eta: f64, cos_views: &[f64]) -> Vec<f64> {
        match self {
            ProfileModel::Dipole => {
                let fa = fresnel::fresnel_hemispherical_average(eta);
                cos_views
                    .iter()
                    .map(|&c| fresnel::exitance_per_radiance(c, eta, fa))
                    .collect()
            }
            ProfileModel::Transport => {
                let emergent = HalfSpace::shared(eta).emergent(alpha_prime);
                cos_views
                    .iter()
                    .map(|&c| emergent.exitance_per_radiance(c))
                    .collect()
            }
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ProfileModel::Transport => "transport",
            ProfileModel::Dipole => "dipole",
        }
    }
}

pub(crate) fn check_eta(eta: f64) -> Result<(), ModelError> {
    if eta.is_finite() && eta > 1.0 && eta < 3.0 {
        Ok(())
    } else {
        Err(ModelError::Domain(format!(
            "relative index eta = {} is outside (1, 3)",
            number(eta)
        )))
    }
}

/// The global (dipole) term of a material, per colour channel (R, G, B):
/// the medium's reduced coefficients and the light transport its R_d(r)
/// comes from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DipoleParams {
    /// Reduced albedo a' = s'_s / s'_t.
    pub alpha_prime: [f64; 3],
    /// Reduced extinction s'_t, mm^-1.
    pub sigma_t_prime: [f64; 3],
    /// Relative index of refraction.
    pub eta: f64,
    /// What R_d(r) is: the paper's dipole, or radiative transfer.
    #[serde(default = "ProfileModel::recorded_before_choice")]
    pub model: ProfileModel,
}

impl DipoleParams {
    /// From reduced scattering and absorption coefficients (mm^-1), as in the
    /// Jensen et al. 2001 table (dipole fits, so with the dipole's R_d).
    pub fn from_coefficients(sigma_s_prime: [f64; 3], sigma_a: [f64; 3], eta: f64) -> Self {
        let mut alpha_prime = [0.0; 3];
        let mut sigma_t_prime = [0.0; 3];
        for c in 0..3 {
            sigma_t_prime[c] = sigma_s_prime[c] + sigma_a[c];
            alpha_prime[c] = sigma_s_prime[c] / sigma_t_prime[c];
        }
        DipoleParams {
            alpha_prime,
            sigma_t_prime,
            eta,
            model: ProfileModel::Dipole,
        }
    }
    /// Reduced scattering s'_s = a' s'_t.
    pub fn sigma_s_prime(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.alpha_prime[c] * self.sigma_t_prime[c])
    }
    /// Absorption s_a = (1 - a') s'_t.
    pub fn sigma_a(&self) -> [f64; 3] {
        std::array::from_fn(|c| (1.0 - self.alpha_prime[c]) * self.sigma_t_prime[c])
    }
    /// Effective transport s_tr = sqrt(3 s_a s'_t).
    pub fn sigma_tr(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.channel(c).sigma_tr)
    }
    /// The single-channel classic dipole of channel `c`.
    pub fn channel(&self, c: usize) -> Dipole {
        Dipole::new(self.alpha_prime[c], self.sigma_t_prime[c], self.eta)
    }
    /// R_d(r) of the params' model, ready to evaluate (for transport, the
    /// radial profiles are computed here, about 0.3 s a channel, and kept).
    pub fn subsurface(&self) -> Subsurface {
        Subsurface {
            channels: std::array::from_fn(|c| match self.model {
                ProfileModel::Dipole => ChannelProfile::Dipole(self.channel(c)),
                ProfileModel::Transport => ChannelProfile::Transport {
                    profile: HalfSpace::shared(self.eta).radial_profile(self.alpha_prime[c]),
                    sigma_t_prime: self.sigma_t_prime[c],
                },
            }),
        }
    }
    /// R_d(r) for the three channels (mm^-2). Evaluating many r: use
    /// [`Self::subsurface`] once.
    pub fn rd(&self, r: f64) -> [f64; 3] {
        self.subsurface().rd(r)
    }
    /// Checks the parameters are physical: a' in [0, 1], s'_t in (0, 10·∞), eta in (1, 3).
    pub fn validate(&self) -> Result<(), String> {
        for c in 0..3 {
            let (a, s) = (self.alpha_prime[c], self.sigma_t_prime[c]);
            if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
                return Err(format!("alpha_prime[{c}] = {a} is outside [0, 1]"));
            }
            if !(s.is_finite() && s > 0.0) {
                return Err(format!("sigma_t_prime[{c}] = {s} must be > 0"));
            }
        }
        if !(self.eta.is_finite() && self.eta > 1.0 && self.eta < 3.0) {
            return Err(format!("eta = {} is outside (1, 3)", self.eta));
        }
        Ok(())
    }
}

/// A material's R_d(r) per channel, per entered flux (mm^-2), with its
/// total and disc integrals: what the renderer and the LRF's global part use.
pub struct Subsurface {
    channels: [ChannelProfile; 3],
}

enum ChannelProfile {
    Dipole(Dipole),
    /// Unit-s'_t radial profile, scaled: R_d(r) = s'_t² R_1(s'_t r).
    Transport {
        profile: Arc<RadialProfile>,
        sigma_t_prime: f64,
    },
}

impl Subsurface {
    /// R_d(r) for the three channels, mm^-2.
    pub fn rd(&self, r: f64) -> [f64; 3] {
        std::array::from_fn(|c| match &self.channels[c] {
            ChannelProfile::Dipole(d) => d.rd(r),
            ChannelProfile::Transport {
                profile,
                sigma_t_prime: st,
            } => st * st * profile.rd(st * r),
        })
    }
    /// R_d integrated over the plane (the total diffuse reflectance).
    pub fn total(&self, c: usize) -> f64 {
        match &self.channels[c] {
            ChannelProfile::Dipole(d) => d.total(),
            ChannelProfile::Transport { profile, .. } => profile.total,
        }
    }
    /// R_d integrated over the disc of radius `r0` around the source.
    pub fn disc_integral(&self, c: usize, r0: f64) -> f64 {
        match &self.channels[c] {
            ChannelProfile::Dipole(d) => d.disc_integral(r0),
            ChannelProfile::Transport {
                profile,
                sigma_t_prime: st,
            } => profile.disc_integral(st * r0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_derived_quantities() {
        let p = DipoleParams::from_coefficients([2.55, 3.21, 3.77], [0.0011, 0.0024, 0.014], 1.3);
        let ss = p.sigma_s_prime();
        let sa = p.sigma_a();
        assert!((ss[0] - 2.55).abs() < 1e-12 && (sa[2] - 0.014).abs() < 1e-12);
        assert!(p.validate().is_ok());
        let bad = DipoleParams {
            alpha_prime: [1.1, 0.5, 0.5],
            ..p
        };
        assert!(bad.validate().is_err());
    }
}
