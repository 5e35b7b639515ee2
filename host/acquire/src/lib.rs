//! Acquisition: the camera interface and its backends, the capture plan (paper
//! Fig. 4, Table 1), capture runs into a crash-safe capture directory, and the
//! built-in simulated rig.
//!
//! Main types: [`camera::Camera`] (a trigger-fired camera), [`plan::Plan`]
//! (ordered steps of the three passes), [`dir::CaptureDir`] (capture.toml,
//! journal, frames), [`run::run_capture`] (executes a plan through a
//! [`rig::Rig`] and cameras, resumable).

pub mod camera;
pub mod dir;
pub mod plan;

pub use camera::{Camera, CameraError, CameraInfo, CameraSettings, Frame, FrameMeta, PixelFormat};
pub use dir::{CaptureDir, DirError, Manifest};
pub use plan::{Plan, PlanConfig, PlanError, Scale};
