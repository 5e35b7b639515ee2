//! The qhm program's library side: glue between the pipeline crates
//! (`qhm-link`, `qhm-acquire`, `qhm-imaging`, `qhm-model`, `qhm-render`)
//! used by the binary and by the cross-crate tests.
//!
//! - [`calibrate`]: the calibration capture and the procedures on its frames.
//! - [`pipeline`]: capture plan -> exposure-bracket shots and rectification settings.
//! - [`demo`]: the whole job on the built-in simulated rig (`qhm demo`).
//! - [`entrance_check`]: a model's fitted f(w_i) against the simulated sample's true one.
//! - [`output`]: the rule for writing outputs (refuse, `--force`, staged directories).

pub mod calibrate;
pub mod demo;
pub mod entrance_check;
pub mod idle;
pub mod output;
pub mod pipeline;
pub mod real_rig;
