//! Pin map of the reference board (Nucleo-F446RE). The firmware's board layer
//! uses exactly these pins; a test in `tests/` checks that it does.

/// What a pin does on the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signal {
    TurntableStep,
    TurntableDir,
    TurntableEnable,
    TurntableHome,
    ArcStep,
    ArcDir,
    ArcEnable,
    ArcHome,
    /// Light-arc end-of-travel switches (both ends wired in series, normally closed).
    ArcLimit,
    /// DAC channel 1 to the galvo driver's analogue input.
    GalvoDac,
    /// DAC channel 2 to the laser drivers' analogue power input.
    LaserPowerDac,
    LaserRedEnable,
    LaserGreenEnable,
    LaserBlueEnable,
    Lamp(u8),
    CameraTrigger(u8),
    /// Laser-safety interlock loop (enclosure door), closed = high.
    Interlock,
    /// Emergency stop, active low (the Nucleo's blue user button B1 on the bench).
    EStop,
    /// ST-LINK virtual COM port.
    UsartTx,
    UsartRx,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PinAssignment {
    pub signal: Signal,
    /// STM32 pin name as embassy-stm32 names the peripheral (`PA8`).
    pub pin: &'static str,
    /// Arduino/morpho header position on the Nucleo board, for wiring.
    pub header: &'static str,
}

/// The board the pin map is for.
pub const BOARD: &str = "nucleo-f446re";

const fn p(signal: Signal, pin: &'static str, header: &'static str) -> PinAssignment {
    PinAssignment {
        signal,
        pin,
        header,
    }
}

/// Every signal and its pin. Step pins are plain GPIO toggled from a timer
/// task; the two DAC outputs are the F446's only DAC pins.
pub const PIN_MAP: &[PinAssignment] = &[
    p(Signal::UsartTx, "PA2", "ST-LINK VCP"),
    p(Signal::UsartRx, "PA3", "ST-LINK VCP"),
    p(Signal::GalvoDac, "PA4", "A2"),
    p(Signal::LaserPowerDac, "PA5", "D13"),
    p(Signal::TurntableStep, "PA8", "D7"),
    p(Signal::TurntableDir, "PB10", "D6"),
    p(Signal::TurntableEnable, "PB4", "D5"),
    p(Signal::TurntableHome, "PA6", "D12"),
    p(Signal::ArcStep, "PB5", "D4"),
    p(Signal::ArcDir, "PB3", "D3"),
    p(Signal::ArcEnable, "PA10", "D2"),
    p(Signal::ArcHome, "PA7", "D11"),
    p(Signal::ArcLimit, "PA1", "A1"),
    p(Signal::LaserRedEnable, "PC0", "A5"),
    p(Signal::LaserGreenEnable, "PC1", "A4"),
    p(Signal::LaserBlueEnable, "PC2", "CN7-35"),
    p(Signal::Lamp(0), "PB8", "D15"),
    p(Signal::Lamp(1), "PB9", "D14"),
    p(Signal::Lamp(2), "PB12", "CN10-16"),
    p(Signal::Lamp(3), "PB13", "CN10-30"),
    p(Signal::Lamp(4), "PB14", "CN10-28"),
    p(Signal::Lamp(5), "PB15", "CN10-26"),
    p(Signal::Lamp(6), "PB1", "CN10-24"),
    p(Signal::Lamp(7), "PB2", "CN10-22"),
    p(Signal::CameraTrigger(0), "PC5", "CN10-6"),
    p(Signal::CameraTrigger(1), "PC6", "CN10-4"),
    p(Signal::CameraTrigger(2), "PC8", "CN10-2"),
    p(Signal::CameraTrigger(3), "PC9", "CN10-1"),
    p(Signal::CameraTrigger(4), "PC10", "CN7-1"),
    p(Signal::CameraTrigger(5), "PC11", "CN7-2"),
    p(Signal::CameraTrigger(6), "PC12", "CN7-3"),
    p(Signal::CameraTrigger(7), "PD2", "CN7-4"),
    p(Signal::Interlock, "PB6", "D10"),
    p(Signal::EStop, "PC13", "B1 USER"),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_pin_used_twice() {
        for (i, a) in PIN_MAP.iter().enumerate() {
            for b in &PIN_MAP[i + 1..] {
                assert_ne!(
                    a.pin, b.pin,
                    "{:?} and {:?} share a pin",
                    a.signal, b.signal
                );
                assert_ne!(a.signal, b.signal);
            }
        }
    }
}
