//! Acquisition: the camera interface and its backends, the capture plan (paper
//! Fig. 4, Table 1), capture runs into a crash-safe capture directory, and the
//! built-in simulated rig.
//!
//! Main types: [`Camera`] (a trigger-fired camera), [`Plan`] (ordered steps of
//! the three passes), [`CaptureDir`] (capture.toml, journal, frames),
//! [`run_capture`] (executes the rest of a directory's plan through a
//! [`qhm_link::Link`] and cameras), [`Operator`] (the person at the rig),
//! [`SimRig`] (the built-in simulated rig).

pub mod camera;
pub mod dir;
pub mod operator;
pub mod plan;
pub mod run;
pub mod sim_rig;

pub use camera::{
    BoxFuture, Camera, CameraError, CameraInfo, CameraSettings, Frame, FrameMeta, PixelFormat,
};
pub use dir::{CaptureDir, DirError, Manifest};
pub use operator::{ConsoleOperator, Operator, OperatorError};
pub use plan::{Plan, PlanConfig, PlanError, Scale};
pub use run::{NoProgress, Progress, RunError, RunOptions, RunReport, run_capture, safe_off};
pub use sim_rig::{SimHandle, SimOperator, SimRig, SimRigConfig, SimRigError};
