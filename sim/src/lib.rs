//! The rig without hardware: an emulated MCU running the firmware's
//! `Controller`, virtual serial links, fault injection.
//!
//! The host cannot tell this rig from the real one (DESIGN.md principles 1
//! and 3): the same Controller code decides everything, the same protocol
//! bytes cross a serial line, only the board layer is virtual.
//!
//! Main types, from the inside out:
//! - [`Peripherals`]: the virtual board (`firmware::io::Io`): motors that
//!   integrate steps, home and limit switches at their physical places, galvo,
//!   lasers, lamps, trigger lines; records laser and trigger history and
//!   publishes [`TriggerEvent`]s with the physical [`RigState`].
//! - [`EmulatedRig`]: Controller + peripherals + virtual clock, advanced by
//!   hand ([`EmulatedRig::advance`]) for deterministic tests; MCU resets.
//! - [`SimPort`]: the rig behind a modelled serial line ([`Wire`]: baud rate,
//!   seeded drop/corrupt/duplicate/delay faults) plus disconnect and
//!   reset-in-the-middle faults ([`FaultConfig`]); still virtual time.
//! - [`spawn_in_process`]: real time (times `speed`) behind a
//!   `tokio::io::duplex` stream, with a [`RigHandle`] on the rig.
//! - [`serve_pty`] / [`serve_pty_until_ctrl_c`]: the same on a
//!   pseudo-terminal that another process opens as a serial port.
//! - [`RawHost`]: a minimal raw-frame host on virtual time, for tests and
//!   benchmarks that must not depend on the real link client.
//!
//! Clocks: [`TriggerEvent::at_us`] and [`EmulatedRig::now_us`] are the world
//! clock (µs since the emulator started); the Controller's own clock (in its
//! events) restarts at 0 on every MCU reset.

pub mod fault;
pub mod link;
pub mod peripherals;
pub mod port;
pub mod pty;
pub mod raw;
pub mod rig;

pub use fault::{ByteFaults, FaultConfig, ResetFault, Wire, WireStats};
pub use link::{RigHandle, VirtualClock, spawn_in_process};
pub use peripherals::{
    AxisPhysics, LaserChange, PeripheralSnapshot, Peripherals, PhysicalConfig, RigState,
    TriggerEvent,
};
pub use port::{DEFAULT_BAUD, LinkConfig, SimPort};
pub use pty::{PtyServer, serve_pty, serve_pty_until_ctrl_c};
pub use raw::{RawError, RawHost, ReceivedEvent};
pub use rig::{EmulatedRig, RigConfig};

use serde::{Deserialize, Serialize};

/// Errors of the simulated rig.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A configuration value is out of range.
    #[error("bad simulator configuration: {0}")]
    BadConfig(String),
    /// A pseudo-terminal call failed.
    #[error("pseudo-terminal: {0} failed: {1}")]
    Pty(&'static str, nix::Error),
    /// An I/O error (thread spawn, output).
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// `spawn_in_process` was called outside a tokio runtime.
    #[error("the in-process link needs a tokio runtime")]
    NoRuntime,
}

/// Everything a running simulated rig needs: the rig, its line, and how fast
/// virtual time runs. Serde, so the CLI and tests can read it from TOML/JSON;
/// missing fields take their defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SimConfig {
    pub rig: RigConfig,
    pub link: LinkConfig,
    /// Virtual seconds per wall second (1.0 = real time).
    pub speed: f64,
    /// Lockstep with the host: the rig's clock never runs more than this
    /// many virtual µs past the last byte the host wrote. A host that is
    /// late (descheduled on a loaded machine, its heartbeat due) then holds
    /// the rig back instead of missing its heartbeat; below the MCU's
    /// heartbeat timeout it never misses one. A host that stops writing
    /// stops the rig, so `None` (free-running) is what tests of a lost
    /// heartbeat use. See [`link`].
    pub host_lead_us: Option<u64>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            rig: RigConfig::default(),
            link: LinkConfig::default(),
            speed: 1.0,
            host_lead_us: None,
        }
    }
}

impl SimConfig {
    /// Defaults with every seed derived from `seed`.
    pub fn seeded(seed: u64) -> Self {
        let mut link = LinkConfig::default();
        link.faults.seed = seed ^ 0x000f_a017;
        Self {
            rig: RigConfig::seeded(seed),
            link,
            speed: 1.0,
            host_lead_us: None,
        }
    }

    pub fn validate(&self) -> Result<(), SimError> {
        if !(self.speed.is_finite() && self.speed > 0.0 && self.speed <= 1000.0) {
            return Err(SimError::BadConfig(format!(
                "speed = {} must be in (0, 1000]",
                self.speed
            )));
        }
        if let Some(lead) = self.host_lead_us
            && !(1..firmware::controller::HEARTBEAT_TIMEOUT_US).contains(&lead)
        {
            return Err(SimError::BadConfig(format!(
                "host_lead_us = {lead} must be in 1..{} (below the MCU's heartbeat timeout)",
                firmware::controller::HEARTBEAT_TIMEOUT_US
            )));
        }
        self.rig.validate()?;
        self.link.faults.validate()
    }
}
