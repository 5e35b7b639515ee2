//! Rendering arbitrary meshes with an acquired material model.
