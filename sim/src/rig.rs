//! The emulated MCU: the firmware's `Controller` on virtual time and virtual
//! peripherals.
//!
//! [`EmulatedRig`] owns a Controller, the [`Peripherals`] it drives and a
//! virtual clock (µs since the emulator started, the "world clock"). Time only
//! moves in [`EmulatedRig::advance`] / [`EmulatedRig::advance_to`], which poll
//! the Controller at every deadline it asks for (each motor step, each sweep
//! phase) and at least every `poll_interval_us` (the board's input scan), so a
//! test that advances by hand is exactly repeatable. Real-time and
//! faster-than-real-time running is the link drivers' job ([`crate::link`]).
//!
//! A reset (the `Reset` command, [`EmulatedRig::reset_mcu`] for fault
//! injection, or a watchdog) replaces the Controller with a fresh one that has
//! a new boot id and its own clock starting at 0, as a rebooted MCU would; the
//! peripherals' outputs go to their power-on (safe) levels, and the axes stay
//! where they physically are.

use firmware::Controller;
use protocol::Status;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde::{Deserialize, Serialize};
use tokio::sync::mpsc::{UnboundedReceiver, unbounded_channel};

use crate::SimError;
use crate::peripherals::{PeripheralSnapshot, Peripherals, PhysicalConfig, RigState, TriggerEvent};

/// How the emulated MCU behaves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RigConfig {
    /// Seed of the boot ids.
    pub seed: u64,
    /// The physical rig (start angles, switch places).
    pub physical: PhysicalConfig,
    /// Longest time between two Controller polls, µs (the board's input
    /// scan: how late an interlock or e-stop change can be seen).
    pub poll_interval_us: u64,
}

impl Default for RigConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            physical: PhysicalConfig::default(),
            poll_interval_us: 1_000,
        }
    }
}

impl RigConfig {
    /// A default rig whose seeds (boot ids, start angles) derive from `seed`.
    pub fn seeded(seed: u64) -> Self {
        Self {
            seed,
            physical: PhysicalConfig {
                seed: seed ^ 0x005e_ed0f_a7e5,
                ..PhysicalConfig::default()
            },
            ..Self::default()
        }
    }

    pub fn validate(&self) -> Result<(), SimError> {
        if self.poll_interval_us == 0 || self.poll_interval_us > 100_000 {
            return Err(SimError::BadConfig(format!(
                "poll_interval_us = {} must be in 1..=100000",
                self.poll_interval_us
            )));
        }
        let w = self.physical.home_width_rad;
        if !(w > 0.0 && w < 1.0) {
            return Err(SimError::BadConfig(format!(
                "physical.home_width_rad = {w} must be in (0, 1) rad"
            )));
        }
        let m = self.physical.arc_limit_margin_rad;
        if !(m.is_finite() && (0.0..1.0).contains(&m)) {
            return Err(SimError::BadConfig(format!(
                "physical.arc_limit_margin_rad = {m} must be in [0, 1) rad"
            )));
        }
        for a in self.physical.start_rad.iter().flatten() {
            if !a.is_finite() {
                return Err(SimError::BadConfig(
                    "physical.start_rad must be finite".into(),
                ));
            }
        }
        Ok(())
    }
}

/// The emulated MCU with its peripherals and clock.
pub struct EmulatedRig {
    cfg: RigConfig,
    controller: Controller,
    io: Peripherals,
    /// World clock, µs.
    now_us: u64,
    /// World time the current Controller booted (its clock is `now - boot_at`).
    boot_at_us: u64,
    /// World time of the next Controller poll.
    next_poll_us: u64,
    boot_rng: Pcg64,
    boot_id: u32,
    boots: u32,
    /// Bytes the MCU's UART started sending, with the world time it did.
    tx: Vec<(u64, u8)>,
    /// Time one byte occupies the UART, µs (0 = unpaced: take all at once).
    uart_byte_us: f64,
    /// When the UART finishes its last byte, µs.
    uart_free_us: f64,
    /// World time of the previous Controller call: bytes still queued in
    /// the Controller were queued then at the latest.
    last_call_us: u64,
}

impl std::fmt::Debug for EmulatedRig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EmulatedRig")
            .field("now_us", &self.now_us)
            .field("boot_id", &self.boot_id)
            .field("boots", &self.boots)
            .field("state", &self.io.rig_state())
            .finish_non_exhaustive()
    }
}

impl EmulatedRig {
    /// Power on: the Controller boots (boot id drawn from the seed) at time 0.
    pub fn new(cfg: RigConfig) -> Result<Self, SimError> {
        cfg.validate()?;
        let mut boot_rng = Pcg64::seed_from_u64(cfg.seed);
        let boot_id = boot_rng.random::<u32>() | 1;
        let io = Peripherals::new(cfg.physical.clone());
        let mut rig = Self {
            controller: Controller::new(boot_id, false),
            io,
            now_us: 0,
            boot_at_us: 0,
            next_poll_us: 0,
            boot_rng,
            boot_id,
            boots: 1,
            tx: Vec::new(),
            uart_byte_us: 0.0,
            uart_free_us: 0.0,
            last_call_us: 0,
            cfg,
        };
        rig.poll();
        Ok(rig)
    }

    pub fn config(&self) -> &RigConfig {
        &self.cfg
    }

    /// World clock, µs since power-on.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// The current Controller's clock, µs since its boot.
    pub fn mcu_now_us(&self) -> u64 {
        self.now_us - self.boot_at_us
    }

    pub fn boot_id(&self) -> u32 {
        self.boot_id
    }

    /// How many times the MCU booted (1 after power-on).
    pub fn boots(&self) -> u32 {
        self.boots
    }

    /// Pace the MCU's output at a UART's rate (8N1; 0 = unpaced). The
    /// Controller's transmit queue then fills and overflows as on the board
    /// when the host does not keep up (e.g. never acknowledges events).
    pub fn set_uart_baud(&mut self, baud: u32) {
        self.uart_byte_us = if baud == 0 { 0.0 } else { 10.0e6 / baud as f64 };
    }

    /// Bytes from the host arrive at the MCU's UART now.
    pub fn receive(&mut self, bytes: &[u8]) {
        let t = self.mcu_now_us();
        self.io.set_now(self.now_us);
        self.drain_tx();
        self.controller.receive(t, bytes, &mut self.io);
        self.last_call_us = self.now_us;
        self.drain_tx();
        // A command may have started something: poll at once.
        self.next_poll_us = self.now_us;
        self.poll_due();
    }

    /// Run the MCU for `dt_us` of virtual time.
    pub fn advance(&mut self, dt_us: u64) {
        self.advance_to(self.now_us.saturating_add(dt_us));
    }

    /// Run the MCU until the world clock reads `t_us` (no-op if it is past).
    pub fn advance_to(&mut self, t_us: u64) {
        while self.next_poll_us <= t_us {
            self.now_us = self.now_us.max(self.next_poll_us);
            self.poll();
        }
        self.now_us = self.now_us.max(t_us);
        self.io.set_now(self.now_us);
    }

    /// World time of the next Controller poll.
    pub fn next_poll_us(&self) -> u64 {
        self.next_poll_us
    }

    fn poll_due(&mut self) {
        if self.next_poll_us <= self.now_us {
            self.poll();
        }
    }

    fn poll(&mut self) {
        let t = self.mcu_now_us();
        self.io.set_now(self.now_us);
        self.drain_tx();
        let deadline = self.controller.poll(t, &mut self.io);
        self.last_call_us = self.now_us;
        // Never poll twice at the same instant (a Controller that keeps asking
        // for "now" would hang the emulator), never sleep past the input scan.
        self.next_poll_us = deadline
            .saturating_add(self.boot_at_us)
            .max(self.now_us + 1)
            .min(self.now_us + self.cfg.poll_interval_us);
        // May reboot, which schedules the new Controller's first poll now.
        self.drain_tx();
    }

    /// Move the Controller's output into `tx` as fast as the UART sends it;
    /// honour a requested reset once its reply has been taken.
    fn drain_tx(&mut self) {
        let now = self.now_us;
        if self.uart_byte_us == 0.0 {
            let mut buf = [0u8; 256];
            loop {
                let n = self.controller.take_tx(&mut buf).min(buf.len());
                if n == 0 {
                    break;
                }
                self.tx.extend(buf[..n].iter().map(|&b| (now, b)));
            }
        } else {
            // Byte by byte at the UART's pace, from when each could start
            // (the UART is free and the byte was queued) up to now.
            let mut one = [0u8; 1];
            loop {
                let start = self.uart_free_us.max(self.last_call_us as f64);
                if start > now as f64 {
                    // More may be queued: come back when the UART is free.
                    self.next_poll_us = self.next_poll_us.min(start.ceil() as u64);
                    break;
                }
                if self.controller.take_tx(&mut one) == 0 {
                    break;
                }
                self.tx.push((start.ceil() as u64, one[0]));
                self.uart_free_us = start + self.uart_byte_us;
            }
        }
        if self.controller.reset_requested() {
            self.reboot(false);
        }
    }

    /// Bytes the MCU has sent since the last call.
    pub fn take_tx(&mut self) -> Vec<u8> {
        self.tx.drain(..).map(|(_, b)| b).collect()
    }

    /// Bytes the MCU has sent since the last call, each with the world time it
    /// was handed to the UART.
    pub fn take_tx_timed(&mut self) -> Vec<(u64, u8)> {
        std::mem::take(&mut self.tx)
    }

    /// Reset the MCU now (fault injection; `watchdog` says the watchdog bit
    /// is set in the reset cause). Bytes the old Controller had not handed to
    /// the UART are lost, as they would be (with an unpaced UART everything
    /// was handed over at once, so nothing is).
    pub fn reset_mcu(&mut self, watchdog: bool) {
        let mut buf = [0u8; 256];
        while self.controller.take_tx(&mut buf) > 0 {}
        self.reboot(watchdog);
    }

    fn reboot(&mut self, watchdog: bool) {
        self.io.set_now(self.now_us);
        self.io.reset_outputs();
        let mut boot_id = self.boot_rng.random::<u32>() | 1;
        if boot_id == self.boot_id {
            boot_id = boot_id.wrapping_add(2);
        }
        self.boot_id = boot_id;
        self.boots += 1;
        self.boot_at_us = self.now_us;
        self.controller = Controller::new(boot_id, watchdog);
        self.next_poll_us = self.now_us;
        // The new Controller's first poll (its boot) happens in the normal loop.
    }

    /// What the Controller believes (its `Status` reply).
    pub fn status(&self) -> Status {
        self.controller.status(self.mcu_now_us())
    }

    /// Whether the Controller believes the laser emits.
    pub fn controller_laser_emitting(&self) -> bool {
        self.controller.laser_emitting()
    }

    /// The physical state of the rig now.
    pub fn rig_state(&self) -> RigState {
        self.io.rig_state()
    }

    pub fn snapshot(&self) -> PeripheralSnapshot {
        self.io.snapshot()
    }

    pub fn peripherals(&self) -> &Peripherals {
        &self.io
    }

    /// For tests: change inputs, clear history. The Controller sees input
    /// changes at its next poll (at most `poll_interval_us` later).
    pub fn peripherals_mut(&mut self) -> &mut Peripherals {
        &mut self.io
    }

    pub fn set_interlock(&mut self, closed: bool) {
        self.io.set_now(self.now_us);
        self.io.set_interlock(closed);
    }

    pub fn set_estop(&mut self, pressed: bool) {
        self.io.set_estop(pressed);
    }

    /// Subscribe to camera trigger pulses (see [`TriggerEvent`]). The
    /// receiver works from async code (`recv().await`) and from threads
    /// (`blocking_recv()`, `try_recv()`); drop it to unsubscribe.
    pub fn subscribe_triggers(&mut self) -> UnboundedReceiver<TriggerEvent> {
        let (tx, rx) = unbounded_channel();
        self.io.subscribe(tx);
        rx
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{Command, Event, FrameDecoder, HostFrame, MAX_FRAME, McuFrame, encode_frame};

    fn frames(bytes: &[u8]) -> Vec<McuFrame> {
        let mut dec = FrameDecoder::new();
        let mut out = Vec::new();
        dec.push_slice::<McuFrame>(bytes, |f| out.extend(f.ok()));
        out
    }

    fn send(rig: &mut EmulatedRig, seq: u16, command: Command) {
        let mut buf = [0u8; MAX_FRAME];
        let n = encode_frame(&HostFrame { seq, command }, &mut buf).unwrap();
        rig.receive(&buf[..n]);
    }

    #[test]
    fn boots_with_a_seeded_id_and_announces_it() {
        let mut a = EmulatedRig::new(RigConfig::seeded(3)).unwrap();
        let b = EmulatedRig::new(RigConfig::seeded(3)).unwrap();
        let c = EmulatedRig::new(RigConfig::seeded(4)).unwrap();
        assert_eq!(a.boot_id(), b.boot_id());
        assert_ne!(a.boot_id(), c.boot_id());
        let booted = frames(&a.take_tx());
        let id = a.boot_id();
        assert!(booted.iter().any(|f| matches!(
            f,
            McuFrame::Event { event: Event::Booted { boot_id, watchdog: false }, .. } if *boot_id == id
        )));
    }

    #[test]
    fn idle_controller_is_still_polled_every_input_scan() {
        let mut rig = EmulatedRig::new(RigConfig::default()).unwrap();
        rig.advance(10_000);
        for _ in 0..100 {
            let gap = rig.next_poll_us() - rig.now_us();
            assert!((1..=1_000).contains(&gap), "gap {gap}");
            rig.advance(333);
        }
    }

    #[test]
    fn reset_reboots_with_a_new_id_own_clock_and_safe_outputs() {
        let mut rig = EmulatedRig::new(RigConfig::seeded(5)).unwrap();
        send(&mut rig, 1, Command::Identify);
        send(&mut rig, 2, Command::Lamps { mask: 0xff });
        rig.advance(5_000);
        assert_eq!(rig.rig_state().lamps, 0xff);
        let (id0, t0) = (rig.boot_id(), rig.now_us());
        rig.reset_mcu(false);
        assert_eq!(rig.boots(), 2);
        assert_ne!(rig.boot_id(), id0);
        assert_eq!(rig.rig_state().lamps, 0);
        rig.advance(2_000);
        assert_eq!((rig.now_us(), rig.mcu_now_us()), (t0 + 2_000, 2_000));
        assert_eq!(rig.status().boot_id, rig.boot_id());
        assert!(rig.status().uptime_us <= 2_000);
    }

    #[test]
    fn the_reset_command_is_answered_before_the_reboot() {
        let mut rig = EmulatedRig::new(RigConfig::seeded(6)).unwrap();
        send(&mut rig, 1, Command::Identify);
        rig.take_tx();
        send(&mut rig, 2, Command::Reset);
        let out = frames(&rig.take_tx());
        assert!(
            matches!(
                out[0],
                McuFrame::Ack {
                    seq: 2,
                    result: Ok(_)
                }
            ),
            "{out:?}"
        );
        assert_eq!(rig.boots(), 2);
    }

    #[test]
    fn uart_pacing_spaces_the_output_at_the_baud_rate() {
        let mut rig = EmulatedRig::new(RigConfig::seeded(7)).unwrap();
        rig.set_uart_baud(115_200);
        rig.advance(100_000);
        rig.take_tx();
        send(&mut rig, 1, Command::Identify);
        rig.advance(20_000);
        let tx = rig.take_tx_timed();
        assert!(tx.len() > 30, "identity reply");
        for w in tx.windows(2) {
            let dt = w[1].0 - w[0].0;
            assert!((86..=88).contains(&dt), "{dt} µs between bytes");
        }
    }
}
