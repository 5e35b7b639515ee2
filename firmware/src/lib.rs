//! The rig controller.
//!
//! [`Controller`] owns all rig logic (motion profiles, homing, limits, galvo
//! sweeps, lasers, lamps, triggers, safety) and is hardware independent: it is
//! driven by protocol bytes and a microsecond clock, and acts through the
//! [`io::Io`] trait. The STM32 binary (feature `stm32`, `src/bin/firmware.rs`
//! with `src/board.rs`) and the emulated MCU in `sim` run the same Controller.
//!
//! - [`profile`]: trapezoidal step schedules.
//! - [`axis`]: limits in steps, moves and homing of one stepper axis.
//! - [`galvo`]: angle <-> DAC code, sweep schedules.
//! - [`tx`]: the outgoing frame queue.
#![no_std]

#[cfg(test)]
extern crate std;

pub mod axis;
#[cfg(feature = "stm32")]
pub mod board;
pub mod controller;
pub mod debounce;
pub mod galvo;
pub mod io;
pub mod profile;
pub mod tx;

#[cfg(test)]
mod controller_tests;
#[cfg(test)]
mod proptests;
#[cfg(test)]
mod testkit;

pub use controller::Controller;
pub use io::{Inputs, Io};

/// Firmware version (major, minor, patch), reported in `Identity`.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];

/// Board name reported in `Identity`.
pub const BOARD_NAME: &str = hardware::BOARD;
