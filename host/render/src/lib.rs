//! Rendering arbitrary meshes with an acquired quasi-homogeneous material
//! model (Tong et al. 2005, section 5 and eq. 4).
//!
//! - [`Scene`]: a [`Mesh`] (OBJ, PLY, or built-in: slab, sphere, teapot,
//!   bread) with its [`bvh::Bvh`], a pinhole [`Camera`], [`Light`]s and an
//!   [`EnvMap`]; [`SceneFile`] reads the scene TOML.
//! - [`Material`]: the four parts of eq. 4 as the renderer sees them,
//!   implemented ([`materials`]) by `qhm_model::MaterialModel` and by
//!   [`Homogeneous`].
//! - [`render_scene`] with [`RenderSettings`] ([`settings`]): pass 1
//!   ([`prepare`]: Poisson-disk surface samples and their f-attenuated
//!   irradiance from [`points`], the Jensen-Buhler octree from [`octree`],
//!   texture synthesis from [`texture_synthesis`]), then per-pixel shading
//!   ([`render`]), with the smooth boundary's entry and exit shapes
//!   ([`boundary`]).
//! - Mesh files: [`obj`] and [`ply`] read a [`mesh_input::MeshInput`], which
//!   [`Mesh::build`] validates.
//! - [`Image`]: EXR and tone-mapped PNG output; [`export`]: pbrt-v4 and
//!   Mitsuba 3 snippets of the homogeneous part.

pub mod boundary;
pub mod builtin;
pub mod bvh;
pub mod camera;
pub mod compare;
pub mod curvature;
pub mod distrib;
mod error;
pub mod export;
pub mod film;
pub mod interreflection;
pub mod light;
pub mod material;
pub mod materials;
pub mod mesh;
pub mod mesh_input;
pub mod obj;
pub mod octree;
pub mod ply;
pub mod points;
pub mod prepare;
pub mod render;
pub mod scene;
pub mod settings;
pub mod tangent_field;
mod teapot_data;
pub mod texture_synthesis;
pub mod watertight;

pub use camera::Camera;
pub use error::{MeshError, RenderError};
pub use film::Image;
pub use light::{EnvMap, Light};
pub use material::Material;
pub use materials::Homogeneous;
pub use mesh::Mesh;
pub use render::{render_scene, render_scene_camera, render_scene_stats};
pub use scene::{Scene, SceneFile};
pub use settings::{Mode, RenderSettings, RenderStats};
