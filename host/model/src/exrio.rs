//! The model's textures in EXR files, through the workspace's one EXR
//! reader and writer (qhm_formats::exr), with the model's error type.

use std::path::Path;

use crate::ModelError;
use crate::model::Texture;

/// Reads the first RGB(A) layer of an EXR file as f32 (alpha ignored).
pub fn read_rgb(path: &Path) -> Result<Texture, ModelError> {
    Ok(qhm_formats::exr::read_rgb(path)?)
}

/// Writes a texture as an RGB f32 EXR file.
pub fn write_rgb(path: &Path, t: &Texture) -> Result<(), ModelError> {
    Ok(qhm_formats::exr::write_rgb(path, t)?)
}
