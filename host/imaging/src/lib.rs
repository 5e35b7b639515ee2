//! qhm-imaging: from raw camera frames to calibrated, rectified radiance
//! (paper sections 4.1-4.2).
//!
//! The main types, one module per stage:
//! - [`response::ResponseCurve`]: a camera's inverse response, fitted by
//!   Mitsunaga-Nayar (the paper's) or Debevec-Malik from exposure brackets.
//! - [`hdr::merge`]: brackets + response -> linear radiance, saturated pixels NaN.
//! - [`camera::CameraModel`]: pinhole with radial distortion (k1, k2) and pose.
//! - [`corners`] and [`zhang`]: checkerboard corners to sub-pixel, Zhang's
//!   calibration with Levenberg-Marquardt refinement ([`lm`]).
//! - [`photometric`]: colour gains, lamp directions, laser plane angle and flux.
//! - [`rectify`]: resampling onto the reference plane, laser stripe lines.
//! - [`cal_compute`]: the calibration procedures on a calibration capture's frames.
//! - [`calibration::Calibration`]: the versioned calibration file.
//! - [`rectified`]: the rectified dataset (index.toml + EXR) read by the fitter.
//!
//! Units: mm, radians, linear RGB f32. Pixel coordinates have (0, 0) at the
//! centre of the top-left pixel.

pub mod cal_compute;
pub mod calibration;
pub mod camera;
pub mod corners;
pub mod exr_io;
pub mod hdr;
pub mod image;
pub mod linalg;
pub mod lm;
pub mod photometric;
pub mod pipeline;
pub mod rectified;
pub mod rectify;
pub mod response;
pub mod shards;
pub mod synthetic_calibration;
pub mod zhang;

pub use calibration::Calibration;
pub use camera::CameraModel;
pub use image::{Image8, ImageF};
pub use response::ResponseCurve;

/// Everything that can go wrong in calibration, HDR and rectification.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Inputs that cannot be used: mismatched sizes, too few views, empty brackets.
    #[error("invalid input: {0}")]
    Input(String),
    /// A fit or solve did not converge or is degenerate.
    #[error("numerical failure: {0}")]
    Numeric(String),
    /// The checkerboard could not be found in an image.
    #[error("checkerboard not found: {0}")]
    Corners(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A calibration or index file is malformed or of an unknown version.
    #[error("{path}: {msg}")]
    Format {
        path: std::path::PathBuf,
        msg: String,
    },
    /// The EXR library rejected a file.
    #[error("{path}: EXR: {msg}")]
    Exr {
        path: std::path::PathBuf,
        msg: String,
    },
}

pub type Result<T> = std::result::Result<T, Error>;
