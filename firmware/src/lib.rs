//! The rig controller.
//!
//! `Controller` owns all rig logic (motion profiles, homing, limits, galvo
//! sweeps, lasers, lamps, triggers, safety) and is hardware independent: it is
//! driven by protocol bytes and a microsecond clock, and acts through the
//! [`io::Io`] trait. The STM32 binary (feature `stm32`) and the emulated MCU
//! in `sim` run the same Controller.
#![no_std]

pub mod io;
