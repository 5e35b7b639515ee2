//! The renderer's error types: one enum for meshes (what is wrong with the
//! geometry) and one for everything else (files, scenes, images).

use std::path::PathBuf;

/// Why a mesh cannot be rendered.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The mesh file does not exist or cannot be read.
    #[error("cannot read mesh {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file extension is neither `.obj` nor `.ply`.
    #[error("unsupported mesh format {0:?} (expected .obj or .ply)")]
    UnsupportedFormat(PathBuf),
    /// The OBJ parser rejected the file.
    #[error("bad OBJ file {path}: {message}")]
    Obj { path: PathBuf, message: String },
    /// The PLY parser rejected the file.
    #[error("bad PLY file: {0}")]
    Ply(String),
    /// No triangles at all (or only degenerate ones).
    #[error(
        "mesh has no usable faces{}",
        if *degenerate == 0 { String::new() } else { format!(": all {degenerate} have zero area") }
    )]
    NoFaces { degenerate: usize },
    /// A vertex position, normal or UV is NaN or infinite.
    #[error("mesh {what} {index} is not finite (NaN or infinity)")]
    NonFinite { what: &'static str, index: usize },
    /// A face refers to a vertex that does not exist.
    #[error("face {face} refers to vertex {index}, but the mesh has {count} vertices")]
    IndexOutOfRange {
        face: usize,
        index: u32,
        count: usize,
    },
    /// An edge is shared by more than two faces.
    #[error(
        "mesh is not manifold: {edges} edges are shared by more than two faces (first near {at:?} mm)"
    )]
    NonManifold { edges: usize, at: [f32; 3] },
    /// The scale is not positive, or makes the object too small or too large.
    #[error("{0}")]
    Scale(String),
    /// Normal or UV arrays do not match the vertex count.
    #[error("mesh {what} count {got} does not match the {expected} vertices")]
    AttributeCount {
        what: &'static str,
        got: usize,
        expected: usize,
    },
}

/// Everything else that can go wrong while rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Reading a scene or env map, or writing an image, failed.
    #[error("cannot read {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The scene TOML is malformed or holds impossible values.
    #[error("bad scene: {0}")]
    Scene(String),
    /// Unknown built-in scene name.
    #[error("unknown built-in scene {0:?} (known: slab, sphere, teapot, bread)")]
    UnknownBuiltin(String),
    /// Render settings out of range.
    #[error("bad render settings: {0}")]
    Settings(String),
    /// An EXR file could not be read or written.
    #[error("EXR {path}: {message}")]
    Exr { path: PathBuf, message: String },
    /// A PNG file could not be written.
    #[error("PNG {path}: {message}")]
    Png { path: PathBuf, message: String },
    /// The material model is unusable for rendering.
    #[error("material: {0}")]
    Material(String),
}

impl From<qhm_formats::FormatError> for RenderError {
    fn from(e: qhm_formats::FormatError) -> Self {
        use qhm_formats::FormatError as F;
        match e {
            F::Io { path, source } => RenderError::Io { path, source },
            F::Exr { path, message } | F::Invalid { path, message } | F::Toml { path, message } => {
                RenderError::Exr { path, message }
            }
        }
    }
}
