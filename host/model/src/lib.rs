//! The quasi-homogeneous material model (Tong et al. 2005, eq. 4) and
//! everything that produces or reads it:
//!
//! - [`subsurface`]: the global term's parameters and the light transport
//!   behind R_d(r), the interface the fit and the renderer use, over two
//!   implementations:
//!   - [`dipole`]: R_d(r), R_total(a') and its inversion, the virtual stripe I_D(d);
//!   - [`radiative_transfer`]: the same, solved without diffusion
//!     (special functions in [`special`]);
//! - [`fresnel`]: the smooth boundary; [`scaled_stripe`]: I_D(d) for every s'_t;
//! - [`profile`]: the s'_t fit of a laser-stripe profile I(d) (paper eq. 6);
//! - [`model`]: [`MaterialModel`] = dipole + entrance f(w_i) + exiting f_v(x, w_o) + LRF;
//! - [`format`]: the versioned on-disk directory (docs/model-format.md);
//! - [`rectified`] and [`fit`]: the whole fit from a rectified capture;
//! - [`report`]: plots and an HTML page of a model and its fit.

pub mod dipole;
mod error;
pub mod fresnel;
pub mod quad;
pub mod radiative_transfer;
pub mod scaled_stripe;
pub mod special;
pub mod subsurface;

pub use dipole::Dipole;
pub use error::ModelError;
pub use subsurface::{DipoleParams, ProfileModel};
pub mod model;
pub mod profile;

pub use model::{
    DirWeights, EntranceFunction, ExitingFunction, LocalReflectance, MaterialModel, Texture,
};
pub use profile::{Profile, ProfileFit, fit_profile};
pub mod compress;
pub mod denoise;
mod exrio;
pub mod format;
mod pca;

pub use exrio::{read_rgb, write_rgb};
pub use format::{SaveOptions, SaveReport};
pub mod fit;
pub mod rectified;
pub mod report;
pub mod streaks;
pub mod synthetic_dataset;
