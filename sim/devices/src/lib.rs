//! The simulated rig as the host sees a real one. Only the `qhm` binary
//! (`--sim`, `qhm demo`) and the cross-crate tests link this crate; the
//! processing crates (qhm-link, qhm-acquire, qhm-imaging, qhm-model,
//! qhm-render) never know whether a rig is simulated (DESIGN.md principle 3).
//!
//! - [`rig`]: [`SimRig`], the emulated MCU behind an in-process [`qhm_link::Link`]
//!   and simulated cameras implementing [`qhm_acquire::Camera`], fired by its
//!   trigger lines; [`SimOperator`] implements [`qhm_acquire::Operator`] by
//!   changing the virtual world; [`SimHandle`] is the operator's hands and
//!   fault injection.
//! - [`cal`]: the simulated rig's true calibration, and the table of a
//!   computed calibration against it.

pub mod cal;
pub mod rig;

pub use cal::{Row, SimTruth};
pub use rig::{RenderStats, SimHandle, SimOperator, SimRig, SimRigConfig, SimRigError, noise_seed};
