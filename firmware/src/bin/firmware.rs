//! The rig firmware for the Nucleo-F446RE: the Controller on real pins.
//!
//! Two tasks: `uart_task` moves bytes between USART2 (ST-LINK virtual COM
//! port) and two pipes; `control_loop` owns the Controller and the rig I/O,
//! feeds it received bytes, polls it at the deadlines it asks for (step
//! pulses, sweep steps, trigger edges, heartbeat expiry, at least every 1 ms
//! for the safety inputs), forwards its replies and pets the watchdog. Every
//! decision is in `firmware::Controller`, tested on the host.
#![no_std]
#![no_main]

use defmt::{info, warn};
use embassy_executor::Spawner;
use embassy_futures::join::join;
use embassy_futures::select::{Either, select};
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::usart::BufferedUart;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_time::{Duration, Instant, Timer};
use embedded_io_async::{Read, Write};
use firmware::board::{self, RigIo};
use firmware::{Controller, Io};
use {defmt_rtt as _, panic_probe as _};

/// Bytes from the host, and bytes to the host.
static RX: Pipe<CriticalSectionRawMutex, 256> = Pipe::new();
static TX: Pipe<CriticalSectionRawMutex, 1024> = Pipe::new();

/// Survives resets (not power cycles): counts boots so every boot gets a new id.
#[unsafe(link_section = ".uninit.qhm_boot")]
static mut BOOT_COUNT: core::mem::MaybeUninit<u32> = core::mem::MaybeUninit::uninit();

#[embassy_executor::task]
async fn uart_task(uart: BufferedUart<'static>) {
    let (mut tx, mut rx) = uart.split();
    let receive = async {
        let mut buf = [0u8; 64];
        loop {
            match rx.read(&mut buf).await {
                Ok(n) => RX.write_all(&buf[..n]).await,
                // Framing/overrun errors: the protocol's CRC and resend recover.
                Err(e) => warn!("uart rx error: {}", e),
            }
        }
    };
    let transmit = async {
        let mut buf = [0u8; 64];
        loop {
            let n = TX.read(&mut buf).await;
            if let Err(e) = tx.write_all(&buf[..n]).await {
                warn!("uart tx error: {}", e);
            }
        }
    };
    join(receive, transmit).await;
}

#[embassy_executor::task]
async fn control_loop(
    mut rig: RigIo,
    mut watchdog: IndependentWatchdog<'static, IWDG>,
    boot_id: u32,
    watchdog_reset: bool,
) {
    // Let the safety debouncer see SETTLE_US of stable reads first, so a
    // closed interlock and a released e-stop are not taken for unsafe at boot.
    let settle = Instant::now() + Duration::from_micros(firmware::debounce::SETTLE_US + 1000);
    while Instant::now() < settle {
        rig.inputs();
        watchdog.pet();
        Timer::after(Duration::from_micros(500)).await;
    }
    let mut controller = Controller::new(boot_id, watchdog_reset);
    let mut rx = [0u8; 64];
    let mut out = [0u8; 256];
    let (mut out_start, mut out_end) = (0, 0);
    loop {
        let next = controller.poll(Instant::now().as_micros(), &mut rig);
        // Forward replies and events without ever blocking the loop.
        loop {
            if out_start == out_end {
                out_end = controller.take_tx(&mut out);
                out_start = 0;
                if out_end == 0 {
                    break;
                }
            }
            match TX.try_write(&out[out_start..out_end]) {
                Ok(n) => out_start += n,
                Err(_) => break,
            }
        }
        watchdog.pet();
        if controller.reset_requested() && out_start == out_end && TX.is_empty() {
            // Let the UART shift out the ack (~15 ms for a frame at 115200 baud).
            Timer::after(Duration::from_millis(20)).await;
            info!("reset requested by the host");
            cortex_m::peripheral::SCB::sys_reset();
        }
        let deadline = Instant::from_micros(next);
        if let Either::First(n) = select(RX.read(&mut rx), Timer::at(deadline)).await {
            controller.receive(Instant::now().as_micros(), &rx[..n], &mut rig);
        }
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let mut config = embassy_stm32::Config::default();
    {
        use embassy_stm32::rcc::*;
        use embassy_stm32::time::Hertz;
        // The ST-LINK feeds an 8 MHz clock into OSC_IN (HSE bypass).
        config.rcc.hse = Some(Hse {
            freq: Hertz(8_000_000),
            mode: HseMode::Bypass,
        });
        config.rcc.pll_src = PllSource::HSE;
        config.rcc.pll = Some(Pll {
            prediv: PllPreDiv::DIV4,   // 8 MHz / 4 = 2 MHz VCO input
            mul: PllMul::MUL180,       // 2 MHz * 180 = 360 MHz VCO
            divp: Some(PllPDiv::DIV2), // 360 MHz / 2 = 180 MHz SYSCLK
            divq: None,
            divr: None,
        });
        config.rcc.sys = Sysclk::PLL1_P;
        config.rcc.ahb_pre = AHBPrescaler::DIV1; // HCLK 180 MHz
        config.rcc.apb1_pre = APBPrescaler::DIV4; // 45 MHz (max 45): USART2, TIM2 at 90 MHz
        config.rcc.apb2_pre = APBPrescaler::DIV2; // 90 MHz (max 90)
    }
    let p = embassy_stm32::init(config);
    let watchdog_reset = board::take_watchdog_reset();
    // SAFETY: single-threaded at this point; the section is never zeroed, so
    // the value left by the previous boot (or power-on noise) is incremented.
    let boot_count = unsafe {
        let c = (*core::ptr::addr_of!(BOOT_COUNT))
            .assume_init()
            .wrapping_add(1);
        core::ptr::addr_of_mut!(BOOT_COUNT).write(core::mem::MaybeUninit::new(c));
        c
    };
    let uid = embassy_stm32::uid::uid();
    let boot_id =
        boot_count ^ u32::from_le_bytes([uid[0], uid[4], uid[8], uid[11]]).rotate_left(16);
    info!(
        "qhm firmware {} boot {:08x} watchdog reset {}",
        firmware::FIRMWARE_VERSION,
        boot_id,
        watchdog_reset
    );
    let b = board::init(p);
    spawner.spawn(uart_task(b.uart).unwrap());
    spawner.spawn(control_loop(b.rig, b.watchdog, boot_id, watchdog_reset).unwrap());
}
