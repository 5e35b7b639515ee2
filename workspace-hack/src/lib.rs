//! No code: this crate exists for its dependency features (see .config/hakari.toml).
