//! What can go wrong on the link, as one typed error.

use protocol::{Command, CommandError, FaultCause, Status};

/// Errors of the link client. Every variant is a complete sentence for the
/// CLI; `DeviceReset` carries what the caller needs to resume by hand.
#[derive(Debug, Clone, thiserror::Error)]
pub enum LinkError {
    /// The serial device (or stream factory) could not be opened.
    #[error("cannot open {path}: {reason}")]
    Open { path: String, reason: String },
    /// The peer speaks another protocol version.
    #[error(
        "MCU speaks protocol version {mcu}, this host speaks {host}: update the firmware or the host"
    )]
    VersionMismatch { mcu: u16, host: u16 },
    /// The peer's message table differs from ours.
    #[error(
        "MCU message schema {mcu:#010x} differs from the host's {host:#010x}: update the firmware or the host"
    )]
    SchemaMismatch { mcu: u32, host: u32 },
    /// No answer after `tries` transmissions.
    #[error("no answer from the MCU to {command:?} after {tries} tries")]
    Timeout { command: Command, tries: u32 },
    /// The MCU refused the command.
    #[error("MCU refused {command:?}: {}", describe(error))]
    Refused {
        command: Command,
        error: CommandError,
    },
    /// The MCU answered with a reply of the wrong kind (a peer out of step).
    #[error("MCU answered {command:?} with an unexpected reply")]
    UnexpectedReply { command: Command },
    /// The MCU was reset (power, watchdog, `Reset`): the link re-identified and
    /// re-read its status; `interrupted` is the command in flight, or else the
    /// sweep or move that was running. Nothing was re-issued.
    #[error(
        "the MCU was reset (interrupted: {interrupted:?}); link re-established, rig state must be restored by the caller"
    )]
    DeviceReset {
        interrupted: Option<Command>,
        status: Box<Status>,
    },
    /// The byte stream ended or failed.
    #[error("link to the MCU lost: {reason}")]
    Disconnected { reason: String },
    /// `reconnect()` on a link opened from a one-shot stream.
    #[error("this link was opened from a stream and cannot be reopened")]
    ReconnectUnsupported,
    /// A value given by the caller cannot be expressed on the wire.
    #[error("bad argument: {0}")]
    BadArgument(String),
    /// An event subscriber fell behind and missed events.
    #[error("event subscriber fell behind and missed {0} link events")]
    Lagged(u64),
}

fn describe(e: &CommandError) -> String {
    match e {
        CommandError::NotIdentified => "not identified since boot".into(),
        CommandError::OutOfSequence { expected } => {
            format!("out of sequence (expected {expected})")
        }
        CommandError::Faulted(c) => format!("a fault is latched ({})", fault_name(c)),
        CommandError::NotHomed(a) => format!("{a:?} is not homed"),
        CommandError::OutOfLimits(a) => format!("target outside the soft limits of {a:?}"),
        CommandError::Busy(a) => format!("{a:?} is busy"),
        CommandError::SweepRunning => "a sweep is running".into(),
        CommandError::BadArgument => "argument out of range".into(),
        CommandError::CauseActive(c) => format!("fault cause still active ({})", fault_name(c)),
    }
}

/// Human name of a fault cause.
pub fn fault_name(c: &FaultCause) -> String {
    match c {
        FaultCause::HeartbeatLost => "heartbeat lost".into(),
        FaultCause::LimitHit(a) => format!("limit switch hit on {a:?}"),
        FaultCause::EStop => "emergency stop".into(),
        FaultCause::HomingFailed(a) => format!("homing failed on {a:?}"),
        FaultCause::Watchdog => "watchdog reset".into(),
    }
}
