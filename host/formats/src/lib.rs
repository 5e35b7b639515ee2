//! qhm-formats: the file formats one stage writes and another reads, each
//! defined once here so writer and reader cannot drift apart.
//!
//! - [`rectified`]: the rectified dataset (`CAPTURE_DIR/rectified/index.toml`
//!   plus EXR images), written by rectification (qhm-imaging), read by the
//!   fit (qhm-model).
//! - [`image::RgbImage`] and [`exr`]: RGB f32 images and the one EXR reader
//!   and writer of the workspace (rectified images, model textures, renders).
//!
//! Formats with a single owner stay with it: the capture directory in
//! qhm-acquire, the calibration file in qhm-imaging, the material model in
//! qhm-model.

pub mod exr;
pub mod image;
pub mod rectified;

pub use image::RgbImage;

use std::path::PathBuf;

/// Why a file of one of these formats could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    /// The file system refused.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The TOML could not be parsed or written.
    #[error("{path}: {message}")]
    Toml { path: PathBuf, message: String },
    /// The EXR library rejected a file.
    #[error("{path}: EXR: {message}")]
    Exr { path: PathBuf, message: String },
    /// Well-formed, but not a valid file of the format (version, sizes, values).
    #[error("{path}: invalid: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl FormatError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        FormatError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        FormatError::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}
