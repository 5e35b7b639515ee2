//! The board layer as the Controller sees it: outputs it drives and inputs it
//! reads. The STM32 binary implements it on GPIO/DAC pins; the emulated MCU in
//! `sim` implements it on virtual peripherals. Nothing here decides anything.

use protocol::{Axis, LaserColour};

/// Levels of the rig's input lines, already debounced and made active-high.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Inputs {
    /// Home switch of each axis (index `Axis::index()`), true while actuated.
    pub home: [bool; 2],
    /// True while the light arc's end-of-travel switch loop is intact.
    pub arc_limit_ok: bool,
    /// True while the laser-safety interlock loop is closed.
    pub interlock_closed: bool,
    /// True while the emergency stop is pressed.
    pub estop_pressed: bool,
}

impl Inputs {
    /// Everything safe, no switch actuated.
    pub const SAFE: Inputs = Inputs {
        home: [false, false],
        arc_limit_ok: true,
        interlock_closed: true,
        estop_pressed: false,
    };
}

/// Outputs and inputs of the rig.
pub trait Io {
    /// Emit one step pulse on `axis` in the given direction (the board sets DIR,
    /// then pulses STEP; timing of the pulse edge itself is the board's job).
    fn step(&mut self, axis: Axis, forward: bool);
    /// Motor driver enable.
    fn set_motor_enable(&mut self, axis: Axis, enabled: bool);
    /// Galvo DAC code (0..=4095, 2048 = 0 rad).
    fn set_galvo(&mut self, code: u16);
    /// Laser enable line of one colour. The Controller never enables two at once.
    fn set_laser(&mut self, colour: LaserColour, on: bool);
    /// Laser power DAC code (0..=4095).
    fn set_laser_power(&mut self, code: u16);
    /// Lamp outputs, one bit per lamp.
    fn set_lamps(&mut self, mask: u8);
    /// Camera trigger lines, one bit per camera (level, not pulse).
    fn set_triggers(&mut self, mask: u8);
    /// Current input levels.
    fn inputs(&mut self) -> Inputs;
}
