//! The message table: every command the host sends, every reply and event the
//! MCU sends back. This file is the schema: its structs and enums (names,
//! fields, types, variants, in order; not comments or attributes) are hashed
//! into `SCHEMA_HASH` by `build.rs`, and `docs/protocol.md` documents it
//! message by message. Keep it to plain struct and enum definitions with
//! their `impl` blocks (see `schema.rs` for what counts).
//!
//! Wire units are integers so both ends agree bit for bit: angles in
//! microradians (urad), speeds in urad/s, accelerations in urad/s^2, times in
//! microseconds (us), laser power in per mille of full drive.

use serde::{Deserialize, Serialize};

/// A frame from the host to the MCU.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HostFrame {
    /// Command sequence number (wrapping). `Identify` may carry any value and
    /// (re)starts the sequence; every other command must be the last executed
    /// sequence + 1 (new) or equal to it (a retransmission, answered from cache).
    pub seq: u16,
    pub command: Command,
}

/// A frame from the MCU to the host.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum McuFrame {
    /// The answer to the command with this sequence number.
    Ack {
        seq: u16,
        result: Result<Reply, CommandError>,
    },
    /// An unsolicited event with its own sequence number. Re-sent until the
    /// host acknowledges it (`Command::Heartbeat { event_ack }` or `AckEvents`).
    Event { eseq: u16, at_us: u64, event: Event },
}

/// One of the two stepper axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Axis {
    Turntable,
    LightArc,
}

impl Axis {
    pub const ALL: [Axis; 2] = [Axis::Turntable, Axis::LightArc];
    pub const fn index(self) -> usize {
        match self {
            Axis::Turntable => 0,
            Axis::LightArc => 1,
        }
    }
}

/// The three lasers that can be mounted at once (paper: 650/532/473 nm).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LaserColour {
    Red,
    Green,
    Blue,
}

impl LaserColour {
    pub const ALL: [LaserColour; 3] = [LaserColour::Red, LaserColour::Green, LaserColour::Blue];
    pub const fn index(self) -> usize {
        match self {
            LaserColour::Red => 0,
            LaserColour::Green => 1,
            LaserColour::Blue => 2,
        }
    }
}

/// Where a move goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MoveTarget {
    /// Absolute angle from home, urad.
    Absolute(i32),
    /// Relative to the current target, urad.
    Relative(i32),
}

/// A galvo sweep: `steps` stripe positions from `start` to `end` inclusive;
/// at each, wait for the mirror to settle, hold `dwell_us`, and pulse the
/// cameras in `trigger_mask` for `pulse_us` in the middle of the dwell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sweep {
    pub start_urad: i32,
    pub end_urad: i32,
    pub steps: u16,
    pub dwell_us: u32,
    pub trigger_mask: u8,
    pub pulse_us: u32,
}

/// Every command the host can send.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Handshake: answered with `Reply::Identity`. Restarts the sequence.
    Identify,
    /// Keeps the laser permitted (the MCU requires one every 250 ms while the
    /// laser is armed) and acknowledges events up to and including `event_ack`.
    Heartbeat { event_ack: u16 },
    /// Acknowledges events up to and including `upto` without a heartbeat.
    AckEvents { upto: u16 },
    /// Home an axis against its switch (fast approach, back off, slow approach).
    Home { axis: Axis },
    /// Move an axis with a trapezoidal profile limited to the given speed and
    /// acceleration (clamped to the axis' mechanical limits).
    Move {
        axis: Axis,
        target: MoveTarget,
        speed_urad_s: u32,
        accel_urad_s2: u32,
    },
    /// Answered with `Reply::Status`.
    Status,
    /// Set the galvo mirror angle, urad.
    GalvoSet { angle_urad: i32 },
    /// Run a galvo sweep (see `Sweep`).
    GalvoSweep(Sweep),
    /// Choose which of the mounted lasers the arm/power commands drive.
    LaserSelect { colour: LaserColour },
    /// Laser drive level, per mille of full power.
    LaserPower { permille: u16 },
    /// Arm (emit while safe) or disarm the selected laser.
    LaserArm { armed: bool },
    /// Lamps on/off, one bit per lamp.
    Lamps { mask: u8 },
    /// Pulse camera trigger lines now.
    Trigger { mask: u8, pulse_us: u32 },
    /// Stop sweeps and decelerate motors to a stop; lasers and lamps stay as set.
    Abort,
    /// Emergency stop: everything off and stopped at once; latches a fault.
    EStop,
    /// Clear a latched fault (refused while its cause persists).
    ClearFault,
    /// Software reset of the MCU (answered, then the MCU reboots).
    Reset,
}

/// Successful answers.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reply {
    Ok,
    Identity(Identity),
    Status(Status),
}

/// What the MCU is, sent on `Identify`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Identity {
    pub protocol_version: u16,
    pub schema_hash: u32,
    /// Firmware version (major, minor, patch).
    pub firmware_version: [u8; 3],
    pub board: heapless::String<24>,
    /// Differs on every boot, so the host can tell the MCU was reset.
    pub boot_id: u32,
    /// Capabilities the host reads before choosing a behaviour.
    pub limits: Limits,
}

/// Constants the MCU advertises (Klipper style).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Limits {
    pub steps_per_rev: [u32; 2],
    pub max_speed_urad_s: [u32; 2],
    pub max_accel_urad_s2: [u32; 2],
    pub soft_min_urad: [i32; 2],
    pub soft_max_urad: [i32; 2],
    pub galvo_max_urad: i32,
    pub heartbeat_timeout_us: u32,
    pub lamps: u8,
    pub cameras: u8,
}

/// One axis' state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisStatus {
    pub homed: bool,
    pub moving: bool,
    pub homing: bool,
    /// Current position, steps from home.
    pub position_steps: i32,
    /// Position the axis is going to, steps from home.
    pub target_steps: i32,
}

/// The laser unit's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LaserStatus {
    pub selected: LaserColour,
    pub power_permille: u16,
    pub armed: bool,
    /// Whether light is actually emitted (armed and every safety condition met).
    pub emitting: bool,
}

/// `Reply::Status`: everything the host may need to re-read after a reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    pub uptime_us: u64,
    pub boot_id: u32,
    pub axes: [AxisStatus; 2],
    pub galvo_urad: i32,
    /// Index of the sweep step in progress, if a sweep runs.
    pub sweep_step: Option<u16>,
    pub laser: LaserStatus,
    pub lamps: u8,
    pub interlock_closed: bool,
    pub estop_pressed: bool,
    pub fault: Option<FaultCause>,
    /// Sequence of the newest event raised; the host compares it with what it saw.
    pub last_eseq: u16,
    /// Events dropped because the queue was full (never silently).
    pub events_dropped: u16,
    pub last_seq: u16,
}

/// Why a command was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandError {
    /// No `Identify` since boot: the MCU was reset, the host must re-handshake.
    NotIdentified,
    /// The sequence number is neither the next one nor a retransmission.
    OutOfSequence { expected: u16 },
    /// A fault is latched; only Status, Identify, Heartbeat, ClearFault, EStop, Reset pass.
    Faulted(FaultCause),
    /// The axis must be homed before absolute moves.
    NotHomed(Axis),
    /// The target lies outside the axis' soft limits.
    OutOfLimits(Axis),
    /// The axis is already moving or homing; abort first.
    Busy(Axis),
    /// A sweep is running.
    SweepRunning,
    /// An argument is out of range (zero steps, mask bits beyond 8, ...).
    BadArgument,
    /// ClearFault refused: the cause (e-stop pressed, limit switch) persists.
    CauseActive(FaultCause),
}

/// Why the MCU latched a fault and switched to safe outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultCause {
    /// No host heartbeat within the timeout while the laser was armed or motors moved.
    HeartbeatLost,
    /// An end-of-travel switch opened.
    LimitHit(Axis),
    /// Emergency stop (button or command).
    EStop,
    /// The homing switch was not found within one revolution.
    HomingFailed(Axis),
    /// The watchdog reset the MCU.
    Watchdog,
}

/// Things the MCU reports without being asked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// A move or homing finished; `position_steps` is where the axis stopped.
    MotionDone {
        axis: Axis,
        position_steps: i32,
        homed: bool,
    },
    /// A sweep step's dwell (and its trigger) finished.
    SweepStepDone { step: u16, angle_urad: i32 },
    /// The whole sweep finished (or was aborted, `completed = false`).
    SweepDone { completed: bool },
    /// Trigger lines in `mask` went high at `at_us` (MCU clock) for `pulse_us`.
    TriggerFired { mask: u8, at_us: u64, pulse_us: u32 },
    /// A fault was latched.
    Fault { cause: FaultCause },
    /// The interlock loop opened or closed.
    Interlock { closed: bool },
    /// The MCU booted (after power-on, watchdog or reset).
    Booted { boot_id: u32, watchdog: bool },
}
