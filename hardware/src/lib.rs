//! The qhm capture rig as data (paper section 4.1, Fig. 3).
//!
//! Every crate reads the rig from here: the firmware its mechanics and pin map,
//! the sim the nominal placements it perturbs, the host the geometry it plans
//! and calibrates with. Units: millimetres, radians, seconds, motor steps.
//! `no_std`, no dependencies, so the firmware can use it.
//!
//! Coordinate frame: origin at the turntable centre, z up, the sample's top
//! surface is the reference plane z = 0. Azimuth 0 is the +x axis. The camera
//! arc is stationary in the xz half-plane at azimuth 0; the light arc rotates
//! about z, and at light-arc angle 0 it lies in the half-plane at azimuth pi.
#![no_std]

pub mod geometry;
pub mod mechanics;
pub mod pins;

pub use geometry::{CameraMount, LampMount, LaserMount, NOMINAL_GEOMETRY, RigGeometry};
pub use mechanics::{AxisMechanics, GALVO, LASERS, LIGHT_ARC, LaserSpec, TURNTABLE};
pub use pins::{BOARD, PIN_MAP, PinAssignment, Signal};
