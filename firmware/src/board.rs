//! The Nucleo-F446RE board layer: owned drivers for every pin of
//! `hardware::PIN_MAP`, and the [`Io`] implementation the Controller acts through.
//!
//! Every line that claims a pin names its signal as `// Signal::X` next to
//! `p.PXn`; `tests/tests/pinmap.rs` checks these against `hardware::PIN_MAP`.
//! Input wiring (see hardware/WIRING.md): home switches and the e-stop are
//! active low with pull-ups; the arc limit loop (NC switches in series to
//! GND) reads low while intact; the interlock loop drives the pin high while
//! closed.

use crate::debounce::Debouncer;
use crate::io::{Inputs, Io};
use embassy_stm32::dac::{Dac, DacChannel, Value};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::mode::Blocking;
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Peripherals, bind_interrupts, peripherals};
use embassy_time::Instant;
use protocol::{Axis, LaserColour};
use static_cell::StaticCell;

bind_interrupts!(pub struct Irqs {
    USART2 => usart::BufferedInterruptHandler<peripherals::USART2>;
});

/// Link speed on the ST-LINK virtual COM port.
pub const BAUD: u32 = 115_200;
/// Independent watchdog timeout: the control loop pets it every iteration
/// (at least once per ms); a hang longer than this resets to safe outputs.
pub const WATCHDOG_US: u32 = 500_000;
/// STEP pulse width: DRV8825/A4988 drivers need >= 1.9 µs (1 µs for the A4988).
const STEP_PULSE_CYCLES: u32 = 180 * 3; // 3 µs at 180 MHz
/// DIR setup time before the STEP edge (>= 650 ns).
const DIR_SETUP_CYCLES: u32 = 180; // 1 µs at 180 MHz

/// One stepper driver's three lines.
pub struct Stepper {
    step: Output<'static>,
    dir: Output<'static>,
    /// Active low on DRV8825/A4988 (nENABLE).
    enable_n: Output<'static>,
    forward: bool,
}

impl Stepper {
    fn step(&mut self, forward: bool) {
        if forward != self.forward {
            self.dir
                .set_level(if forward { Level::High } else { Level::Low });
            self.forward = forward;
            cortex_m::asm::delay(DIR_SETUP_CYCLES);
        }
        self.step.set_high();
        cortex_m::asm::delay(STEP_PULSE_CYCLES);
        self.step.set_low();
    }
}

/// Every rig output and input, owned.
pub struct RigIo {
    steppers: [Stepper; 2],
    galvo: DacChannel<'static, Blocking>,
    laser_power: DacChannel<'static, Blocking>,
    lasers: [Output<'static>; 3],
    lamps: [Output<'static>; 8],
    triggers: [Output<'static>; 8],
    home: [Input<'static>; 2],
    arc_limit: Input<'static>,
    interlock: Input<'static>,
    estop: Input<'static>,
    debounce: Debouncer,
}

/// The board: rig I/O, the host link, the watchdog.
pub struct Board {
    pub rig: RigIo,
    pub uart: BufferedUart<'static>,
    pub watchdog: IndependentWatchdog<'static, IWDG>,
}

fn out(pin: embassy_stm32::Peri<'static, impl embassy_stm32::gpio::Pin>) -> Output<'static> {
    Output::new(pin, Level::Low, Speed::Low)
}

/// Take the peripherals apart into the board's drivers. All outputs start
/// at their safe level (low: lasers, lamps and triggers off, drivers
/// disabled through their active-low enable driven high right below).
pub fn init(p: Peripherals) -> Board {
    let mut tt_enable_n = out(p.PB4); // Signal::TurntableEnable
    let mut arc_enable_n = out(p.PA10); // Signal::ArcEnable
    tt_enable_n.set_high();
    arc_enable_n.set_high();
    let steppers = [
        Stepper {
            step: Output::new(p.PA8, Level::Low, Speed::VeryHigh), // Signal::TurntableStep
            dir: out(p.PB10),                                      // Signal::TurntableDir
            enable_n: tt_enable_n,
            forward: false,
        },
        Stepper {
            step: Output::new(p.PB5, Level::Low, Speed::VeryHigh), // Signal::ArcStep
            dir: out(p.PB3),                                       // Signal::ArcDir
            enable_n: arc_enable_n,
            forward: false,
        },
    ];
    let dac = Dac::new_blocking(
        p.DAC1, p.PA4, // Signal::GalvoDac
        p.PA5, // Signal::LaserPowerDac
    );
    let (mut galvo, mut laser_power) = dac.split();
    galvo.set(Value::Bit12Right(crate::galvo::DAC_MID));
    laser_power.set(Value::Bit12Right(0));
    let lasers = [
        out(p.PC0), // Signal::LaserRedEnable
        out(p.PC1), // Signal::LaserGreenEnable
        out(p.PC2), // Signal::LaserBlueEnable
    ];
    let lamps = [
        out(p.PB8),  // Signal::Lamp(0)
        out(p.PB9),  // Signal::Lamp(1)
        out(p.PB12), // Signal::Lamp(2)
        out(p.PB13), // Signal::Lamp(3)
        out(p.PB14), // Signal::Lamp(4)
        out(p.PB15), // Signal::Lamp(5)
        out(p.PB1),  // Signal::Lamp(6)
        out(p.PB2),  // Signal::Lamp(7)
    ];
    let triggers = [
        out(p.PC5),  // Signal::CameraTrigger(0)
        out(p.PC6),  // Signal::CameraTrigger(1)
        out(p.PC8),  // Signal::CameraTrigger(2)
        out(p.PC9),  // Signal::CameraTrigger(3)
        out(p.PC10), // Signal::CameraTrigger(4)
        out(p.PC11), // Signal::CameraTrigger(5)
        out(p.PC12), // Signal::CameraTrigger(6)
        out(p.PD2),  // Signal::CameraTrigger(7)
    ];
    let home = [
        Input::new(p.PA6, Pull::Up), // Signal::TurntableHome
        Input::new(p.PA7, Pull::Up), // Signal::ArcHome
    ];
    let arc_limit = Input::new(p.PA1, Pull::Up); // Signal::ArcLimit
    let interlock = Input::new(p.PB6, Pull::Down); // Signal::Interlock
    let estop = Input::new(p.PC13, Pull::Up); // Signal::EStop

    static TX_BUF: StaticCell<[u8; 512]> = StaticCell::new();
    static RX_BUF: StaticCell<[u8; 512]> = StaticCell::new();
    let mut config = usart::Config::default();
    config.baudrate = BAUD;
    let uart = BufferedUart::new(
        p.USART2,
        p.PA3, // Signal::UsartRx
        p.PA2, // Signal::UsartTx
        TX_BUF.init([0; 512]),
        RX_BUF.init([0; 512]),
        Irqs,
        config,
    )
    // The configuration is a constant one the F446 supports.
    .unwrap_or_else(|_| defmt::panic!("USART2 configuration rejected"));

    let mut watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_US);
    watchdog.unleash();

    Board {
        rig: RigIo {
            steppers,
            galvo,
            laser_power,
            lasers,
            lamps,
            triggers,
            home,
            arc_limit,
            interlock,
            estop,
            debounce: Debouncer::new(),
        },
        uart,
        watchdog,
    }
}

/// Whether the last reset came from the independent watchdog; clears the flags.
pub fn take_watchdog_reset() -> bool {
    let rcc = embassy_stm32::pac::RCC;
    let wdg = rcc.csr().read().wdgrstf();
    rcc.csr().modify(|w| w.set_rmvf(true));
    wdg
}

fn set_mask(lines: &mut [Output<'static>; 8], mask: u8) {
    for (i, line) in lines.iter_mut().enumerate() {
        line.set_level(if mask & (1 << i) != 0 {
            Level::High
        } else {
            Level::Low
        });
    }
}

impl Io for RigIo {
    fn step(&mut self, axis: Axis, forward: bool) {
        self.steppers[axis.index()].step(forward);
    }

    fn set_motor_enable(&mut self, axis: Axis, enabled: bool) {
        let s = &mut self.steppers[axis.index()];
        s.enable_n
            .set_level(if enabled { Level::Low } else { Level::High });
    }

    fn set_galvo(&mut self, code: u16) {
        self.galvo
            .set(Value::Bit12Right(code.min(crate::galvo::DAC_MAX)));
    }

    fn set_laser(&mut self, colour: LaserColour, on: bool) {
        self.lasers[colour.index()].set_level(if on { Level::High } else { Level::Low });
    }

    fn set_laser_power(&mut self, code: u16) {
        self.laser_power
            .set(Value::Bit12Right(code.min(crate::galvo::DAC_MAX)));
    }

    fn set_lamps(&mut self, mask: u8) {
        set_mask(&mut self.lamps, mask);
    }

    fn set_triggers(&mut self, mask: u8) {
        set_mask(&mut self.triggers, mask);
    }

    fn inputs(&mut self) -> Inputs {
        let raw = Inputs {
            home: [self.home[0].is_low(), self.home[1].is_low()],
            arc_limit_ok: self.arc_limit.is_low(),
            interlock_closed: self.interlock.is_high(),
            estop_pressed: self.estop.is_low(),
        };
        self.debounce.update(Instant::now().as_micros(), raw)
    }
}
