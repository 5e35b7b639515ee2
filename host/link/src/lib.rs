//! Async host link client to the rig MCU: typed calls, retransmission,
//! heartbeat, reset recovery.
//!
//! [`Link`] is a cloneable handle over one byte stream (a serial device, a
//! pseudo-terminal from the emulator, or an in-process stream). Behind it run
//! one reader task (bytes to frames), one writer task, one heartbeat task and
//! the engine ([`engine`]) that sends one command at a time with sequence
//! numbers, retransmits with an RTT-based timeout ([`rto`]), acknowledges
//! events and delivers them to subscribers ([`LinkEvent`]), and turns an MCU
//! reset into [`LinkError::DeviceReset`] instead of re-issuing anything.
//!
//! Units: the wire speaks microradians and microseconds; the `*_rad` calls
//! take radians, the `*_deg` calls degrees (the CLI's unit).

mod client;
mod config;
mod engine;
mod error;
mod rto;
mod transport;

pub use client::{EventStream, Link, LinkEvent, LinkStats, MotionDone};
pub use config::LinkConfig;
pub use error::{LinkError, fault_name};
pub use rto::RttEstimator;
pub use transport::{
    BAUD_RANGE, BoxStream, ByteStream, Connector, DEFAULT_BAUD, SerialStream, check_baud,
    serial_connector,
};

pub use protocol;
