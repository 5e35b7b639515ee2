//! The simulated world: quasi-homogeneous samples, Monte Carlo light
//! transport, camera sensors, calibration targets (issue 3).
//!
//! Main types:
//! - [`SceneDesc`]: what sits on the turntable (a sample slab or a
//!   calibration target), from a preset or a TOML file.
//! - [`RigTruth`]: the rig as it really is (nominal geometry from `hardware`
//!   plus seeded errors calibration must find).
//! - [`World`]: scene + rig + [`SimQuality`]; [`World::render_pose`] turns an
//!   [`Illumination`] into per-camera linear radiance ([`PoseRadiance`]),
//!   the expensive step, done once per rig pose.
//! - [`Sensor`]: [`Sensor::expose`] turns radiance into an 8-bit [`Frame`]
//!   (response curve, noise, saturation), cheap, once per exposure.
//!
//! Units: mm, mm^-1, radians; radiance in W sr^-1 m^-2, linear RGB f32.
//! The world never uses a diffusion approximation (DESIGN.md principle 2).
//!
//! ```no_run
//! use sim_light::*;
//! let mut world = World::new(SceneDesc::preset("bread")?, RigTruth::perturbed(1), SimQuality::ci())?;
//! world.set_laser_mount(std::f64::consts::FRAC_PI_2);
//! let illum = Illumination { laser: Some(LaserOn { channel: 0, power: 1.0 }), ..Illumination::default() };
//! let radiance = world.render_pose(&illum, 0xFE, 42)?;
//! let frame = world.sensor(3).expose(radiance.image(3).unwrap(), 0.005, 1.0, 7);
//! # Ok::<(), sim_light::Error>(())
//! ```

pub mod bench;
pub mod cells;
pub mod cellwalk;
pub mod entrance;
pub mod lanes;
pub mod medium;
pub mod microfacet;
pub mod object;
pub mod rig;
pub mod rng;
pub mod sample;
pub mod sensor;
pub mod surface;
pub mod walk;
mod world;

pub use rig::{CameraTruth, LampTruth, LaserGeometry, LaserTruth, RigTruth};
pub use sample::{
    COLOUR_PATTERN, Coefficients, InclusionDesc, MaterialDesc, POLISHED_ROUGHNESS, Relief,
    SCENE_PRESETS, SampleDesc, SceneDesc, SurfaceDesc, TargetDesc, VolumeDesc, colour_patch_at,
    material_preset,
};
pub use sensor::{Frame, FrameMeta, Response, Sensor};
pub use walk::{ExitGrid, Source, Tally};
pub use world::{Illumination, LaserOn, PoseRadiance, RadianceImage, SimQuality, World};

/// Errors of the simulated world.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A sample or target file is not valid TOML or has the wrong shape
    /// (the message carries toml's line, column and field).
    #[error("sample description: {0}")]
    Toml(String),
    /// A field holds a value out of range.
    #[error("sample description: field `{field}`: {reason}")]
    InvalidField { field: String, reason: String },
    /// No preset of that name.
    #[error("unknown sample or target preset {0:?} (known: {known})", known = SCENE_PRESETS.join(", "))]
    UnknownPreset(String),
    /// A quality scale name that does not exist.
    #[error("unknown quality {0:?} (known: ci, preview, default, final)")]
    UnknownQuality(String),
    /// Reading a description file failed.
    #[error("{path:?} is neither a preset ({known}) nor a readable file", known = SCENE_PRESETS.join(", "))]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// An illumination or rig setting out of range.
    #[error("invalid illumination: {0}")]
    InvalidIllumination(String),
}
