//! The one error type of `qhm-model`: every failure names the file, line or
//! value that caused it.

use std::path::PathBuf;

/// Errors of fitting, loading and saving material models.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A CSV profile is malformed at a given line (1-based).
    #[error("{path}:{line}: {message}")]
    Csv {
        path: String,
        line: usize,
        message: String,
    },
    /// A TOML manifest or index could not be parsed.
    #[error("{path}: {message}")]
    Toml { path: PathBuf, message: String },
    /// An EXR file could not be decoded or encoded.
    #[error("{path}: EXR: {message}")]
    Exr { path: PathBuf, message: String },
    /// A model or dataset is internally inconsistent (sizes, versions, NaNs, ...).
    #[error("{path}: invalid: {message}")]
    Invalid { path: PathBuf, message: String },
    /// A numeric argument is out of its domain.
    #[error("{0}")]
    Domain(String),
    /// A fit had too little usable data.
    #[error("fit: {0}")]
    Fit(String),
}

impl ModelError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        ModelError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        ModelError::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}

impl From<qhm_formats::FormatError> for ModelError {
    fn from(e: qhm_formats::FormatError) -> Self {
        use qhm_formats::FormatError as F;
        match e {
            F::Io { path, source } => ModelError::Io { path, source },
            F::Toml { path, message } => ModelError::Toml { path, message },
            F::Exr { path, message } => ModelError::Exr { path, message },
            F::Invalid { path, message } => ModelError::Invalid { path, message },
        }
    }
}

/// A value as the user would write it: `1e300`, not 301 digits.
pub(crate) fn number(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-4..1e9).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}
