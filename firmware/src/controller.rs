//! The Controller: every decision of the rig, driven by link bytes and a µs clock.
//!
//! `receive` decodes host frames, admits them through
//! `protocol::seq::CommandSequencer` (exactly once; retransmissions answered
//! from the cached reply), executes them and queues the reply. `poll` does what
//! is due: step pulses, homing, sweeps, trigger pulses, safety checks and event
//! (re)transmission, and says when it must run next. Outputs reach the board
//! only through [`Io`], and only when they change.
//!
//! Safety (DESIGN.md principle 4), re-evaluated on every `receive` and `poll`:
//! the laser emits only while armed, the interlock is closed, the host was
//! heard within [`HEARTBEAT_TIMEOUT_US`] and no fault is latched. A stale
//! heartbeat while armed or moving, the arc limit switch opening, or a failed
//! homing latch a fault: lasers and lamps off, sweeps aborted, motors
//! decelerate. E-stop (input or command) stops everything at once. A fault
//! stays latched until `ClearFault`, refused while its cause persists.

use crate::axis::{AxisOutcome, AxisParams, AxisState};
use crate::galvo::{self, DAC_MAX, GALVO_MAX_URAD, SweepAction, SweepRun};
use crate::io::{Inputs, Io};
use crate::tx::{TX_CAPACITY, TxQueue};
use crate::{BOARD_NAME, FIRMWARE_VERSION};
use hardware::{LIGHT_ARC, TURNTABLE};
use protocol::seq::{Admission, CommandSequencer, EventQueue, seq_after};
use protocol::{
    Axis, Command, CommandError, Event, FaultCause, FrameDecoder, HostFrame, Identity, LaserColour,
    LaserStatus, Limits, MAX_FRAME, McuFrame, MoveTarget, PROTOCOL_VERSION, Reply, SCHEMA_HASH,
    Status, encode_frame,
};

/// The laser needs the host heard at most this long ago; longer while armed
/// or moving is a fault. Any valid host frame counts (a retransmission too):
/// each proves the host alive, and on a damaged line a command that is still
/// being retried cannot let a `Heartbeat` go first. An idle host sends
/// `Heartbeat`s to be heard.
pub const HEARTBEAT_TIMEOUT_US: u64 = 250_000;
/// Unacknowledged events are re-sent this often.
pub const EVENT_RESEND_US: u64 = 50_000;
/// Longest camera trigger pulse a `Trigger` command may ask for.
pub const MAX_PULSE_US: u32 = 1_000_000;
/// Inputs are re-read at least this often even when nothing else is due.
pub const INPUT_POLL_US: u64 = 1_000;
/// Unacknowledged events kept for retransmission.
pub const EVENT_QUEUE: usize = 32;
/// Oldest unacknowledged events re-sent per period (about 3 KB/s at most,
/// a quarter of a 115200 baud link).
pub const RESEND_BURST: usize = 8;
/// Number of lamp and camera trigger lines.
pub const LINES: usize = 8;

/// What the board outputs are currently driven to (writes happen on change only).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Outputs {
    motor_enable: [bool; 2],
    galvo: u16,
    laser: Option<LaserColour>,
    laser_power: u16,
    lamps: u8,
    triggers: u8,
}

impl Outputs {
    const SAFE: Outputs = Outputs {
        motor_enable: [false, false],
        galvo: galvo::DAC_MID,
        laser: None,
        laser_power: 0,
        lamps: 0,
        triggers: 0,
    };
}

/// The rig controller (see the module documentation).
pub struct Controller {
    boot_id: u32,
    decoder: FrameDecoder,
    sequencer: CommandSequencer,
    /// The encoded reply to the last executed command, for retransmissions.
    cached_reply: heapless::Vec<u8, MAX_FRAME>,
    events: EventQueue<EVENT_QUEUE>,
    /// Newest event already transmitted at least once.
    last_sent_eseq: u16,
    resend_at: u64,
    tx: TxQueue,
    /// `tx.pushed()` once the Reset ack is queued.
    reset_mark: Option<u64>,

    axes: [AxisState; 2],
    galvo_urad: i32,
    sweep: Option<SweepRun>,
    laser_selected: LaserColour,
    laser_permille: u16,
    armed: bool,
    lamps: u8,
    /// Time each trigger line goes low again (0 = low).
    trigger_off_us: [u64; LINES],

    /// When a valid host frame last arrived (the heartbeat's clock).
    last_heard_us: Option<u64>,
    /// Since when the heartbeat has been required (armed or moving), if it is.
    watch_since: Option<u64>,
    inputs: Inputs,
    fault: Option<FaultCause>,

    out: Outputs,
    outputs_ready: bool,
    now_us: u64,
    frames_dropped: u32,
}

impl Controller {
    /// A freshly booted controller: all outputs at their safe defaults after the first poll.
    pub fn new(boot_id: u32, watchdog_reset: bool) -> Self {
        let mut c = Controller {
            boot_id,
            decoder: FrameDecoder::new(),
            sequencer: CommandSequencer::new(),
            cached_reply: heapless::Vec::new(),
            events: EventQueue::new(),
            last_sent_eseq: 0,
            resend_at: 0,
            tx: TxQueue::new(),
            reset_mark: None,
            axes: [
                AxisState::new(Axis::Turntable, TURNTABLE),
                AxisState::new(Axis::LightArc, LIGHT_ARC),
            ],
            galvo_urad: 0,
            sweep: None,
            laser_selected: LaserColour::Red,
            laser_permille: 0,
            armed: false,
            lamps: 0,
            trigger_off_us: [0; LINES],
            last_heard_us: None,
            watch_since: None,
            inputs: Inputs::SAFE,
            fault: None,
            out: Outputs::SAFE,
            outputs_ready: false,
            now_us: 0,
            frames_dropped: 0,
        };
        c.events.push(
            0,
            Event::Booted {
                boot_id,
                watchdog: watchdog_reset,
            },
        );
        if watchdog_reset {
            c.fault = Some(FaultCause::Watchdog);
            c.events.push(
                0,
                Event::Fault {
                    cause: FaultCause::Watchdog,
                },
            );
        }
        c
    }

    /// Feed bytes received from the host link at time `now_us`.
    pub fn receive(&mut self, now_us: u64, bytes: &[u8], io: &mut impl Io) {
        self.advance_clock(now_us);
        if self.reset_mark.is_some() {
            return;
        }
        // Bring inputs and outputs up to date before acting on commands.
        self.service(io);
        for &b in bytes {
            match self.decoder.push::<HostFrame>(b) {
                None => {}
                Some(Err(_)) => self.frames_dropped = self.frames_dropped.wrapping_add(1),
                Some(Ok(frame)) => {
                    self.last_heard_us = Some(self.now_us);
                    self.handle_frame(frame);
                    self.service(io);
                    if self.reset_mark.is_some() {
                        break;
                    }
                }
            }
        }
    }

    /// Do everything due at or before `now_us`; returns when to poll next.
    pub fn poll(&mut self, now_us: u64, io: &mut impl Io) -> u64 {
        self.advance_clock(now_us);
        self.service(io);
        self.next_deadline()
    }

    /// Move queued outgoing bytes (complete frames where they fit) into `out`.
    pub fn take_tx(&mut self, out: &mut [u8]) -> usize {
        self.tx.take(out)
    }

    /// True once a `Reset` was acknowledged and its ack fully taken by `take_tx`.
    pub fn reset_requested(&self) -> bool {
        self.reset_mark.is_some_and(|m| self.tx.taken() >= m)
    }

    /// Current status (the same struct the Status command returns).
    pub fn status(&self, now_us: u64) -> Status {
        Status {
            uptime_us: now_us.max(self.now_us),
            boot_id: self.boot_id,
            axes: [self.axes[0].status(), self.axes[1].status()],
            galvo_urad: self.galvo_urad,
            sweep_step: self.sweep.map(|s| s.step.min(s.sweep.steps - 1)),
            laser: LaserStatus {
                selected: self.laser_selected,
                power_permille: self.laser_permille,
                armed: self.armed,
                emitting: self.laser_emitting(),
            },
            lamps: self.lamps,
            interlock_closed: self.inputs.interlock_closed,
            estop_pressed: self.inputs.estop_pressed,
            fault: self.fault,
            last_eseq: self.events.last_eseq(),
            events_dropped: self.events.dropped(),
            last_seq: self.sequencer.last().unwrap_or(0),
        }
    }

    /// Whether the laser is emitting right now (the enable line driven on).
    pub fn laser_emitting(&self) -> bool {
        self.out.laser.is_some()
    }

    /// Frames dropped for bad CRC, COBS, length or content since boot.
    pub fn frames_dropped(&self) -> u32 {
        self.frames_dropped
    }

    /// Bytes dropped because the transmit queue was full (the host recovers
    /// them by retransmitting; events are re-sent anyway).
    pub fn tx_overflows(&self) -> u32 {
        self.tx.overflows()
    }

    /// The fault latched, if any.
    pub fn fault(&self) -> Option<FaultCause> {
        self.fault
    }

    /// The constants advertised in `Identity`.
    pub fn limits() -> Limits {
        let (t, a) = (AxisParams::of(TURNTABLE), AxisParams::of(LIGHT_ARC));
        let urad = |x: f64| (x * 1e6) as i64;
        Limits {
            steps_per_rev: [t.steps_per_rev, a.steps_per_rev],
            max_speed_urad_s: [
                urad(TURNTABLE.max_speed) as u32,
                urad(LIGHT_ARC.max_speed) as u32,
            ],
            max_accel_urad_s2: [
                urad(TURNTABLE.max_accel) as u32,
                urad(LIGHT_ARC.max_accel) as u32,
            ],
            soft_min_urad: [
                urad(t.mech.rad_from_steps(t.soft_min as i64)) as i32,
                urad(a.mech.rad_from_steps(a.soft_min as i64)) as i32,
            ],
            soft_max_urad: [
                urad(t.mech.rad_from_steps(t.soft_max as i64)) as i32,
                urad(a.mech.rad_from_steps(a.soft_max as i64)) as i32,
            ],
            galvo_max_urad: GALVO_MAX_URAD,
            heartbeat_timeout_us: HEARTBEAT_TIMEOUT_US as u32,
            lamps: LINES as u8,
            cameras: LINES as u8,
        }
    }

    fn advance_clock(&mut self, now_us: u64) {
        // The clock never runs backwards, whatever the caller passes.
        self.now_us = self.now_us.max(now_us);
    }

    fn heartbeat_fresh(&self) -> bool {
        self.last_heard_us
            .is_some_and(|t| self.now_us.saturating_sub(t) <= HEARTBEAT_TIMEOUT_US)
    }

    fn motion_active(&self) -> bool {
        self.axes.iter().any(|a| a.active())
    }

    // ---- commands ------------------------------------------------------

    fn handle_frame(&mut self, frame: HostFrame) {
        let seq = frame.seq;
        match self.sequencer.admit(&frame) {
            Admission::Retransmission => {
                if self.cached_reply.is_empty() {
                    // Unreachable in practice (every executed command caches its
                    // reply); never execute twice, only an Identify is answered.
                    if matches!(frame.command, Command::Identify) {
                        let result = self.execute(frame.command);
                        self.reply(seq, result, true);
                    }
                } else {
                    let cached = self.cached_reply.clone();
                    self.tx.push_frame(&cached);
                }
            }
            Admission::Refuse(e) => self.reply(seq, Err(e), false),
            Admission::Execute => {
                let is_reset = matches!(frame.command, Command::Reset);
                let result = self.execute(frame.command);
                self.reply(seq, result, true);
                if is_reset {
                    self.safe_outputs_now();
                    self.reset_mark = Some(self.tx.pushed());
                }
            }
        }
    }

    fn reply(&mut self, seq: u16, result: Result<Reply, CommandError>, cache: bool) {
        let mut buf = [0u8; MAX_FRAME];
        // Every reply fits MAX_FRAME (protocol's largest_messages_fit test).
        if let Ok(n) = encode_frame(&McuFrame::Ack { seq, result }, &mut buf) {
            self.tx.push_frame(&buf[..n]);
            if cache {
                self.cached_reply.clear();
                let _ = self.cached_reply.extend_from_slice(&buf[..n]);
            }
        }
    }

    fn execute(&mut self, command: Command) -> Result<Reply, CommandError> {
        let now = self.now_us;
        if let Some(cause) = self.fault {
            let allowed = matches!(
                command,
                Command::Identify
                    | Command::Heartbeat { .. }
                    | Command::AckEvents { .. }
                    | Command::Status
                    | Command::ClearFault
                    | Command::EStop
                    | Command::Reset
            );
            if !allowed {
                return Err(CommandError::Faulted(cause));
            }
        }
        match command {
            Command::Identify => Ok(Reply::Identity(Identity {
                protocol_version: PROTOCOL_VERSION,
                schema_hash: SCHEMA_HASH,
                firmware_version: FIRMWARE_VERSION,
                board: heapless::String::try_from(BOARD_NAME).unwrap_or_default(),
                boot_id: self.boot_id,
                limits: Self::limits(),
            })),
            Command::Heartbeat { event_ack } => {
                // Being heard was noted in `receive`, for every frame.
                self.events.ack(event_ack);
                Ok(Reply::Ok)
            }
            Command::AckEvents { upto } => {
                self.events.ack(upto);
                Ok(Reply::Ok)
            }
            Command::Status => Ok(Reply::Status(self.status(now))),
            Command::Home { axis } => {
                let a = &mut self.axes[axis.index()];
                if a.active() {
                    return Err(CommandError::Busy(axis));
                }
                let switch = self.inputs.home[axis.index()];
                a.start_homing(now, switch);
                Ok(Reply::Ok)
            }
            Command::Move {
                axis,
                target,
                speed_urad_s,
                accel_urad_s2,
            } => {
                let a = &mut self.axes[axis.index()];
                if a.active() {
                    return Err(CommandError::Busy(axis));
                }
                let goal = match target {
                    MoveTarget::Absolute(urad) => {
                        if !a.homed {
                            return Err(CommandError::NotHomed(axis));
                        }
                        a.p.steps_from_urad(urad)
                    }
                    MoveTarget::Relative(urad) => a.position as i64 + a.p.steps_from_urad(urad),
                };
                if goal < a.p.soft_min as i64 || goal > a.p.soft_max as i64 {
                    return Err(CommandError::OutOfLimits(axis));
                }
                let speed = a.p.rate_from_urad(speed_urad_s, a.p.max_speed);
                let accel = a.p.rate_from_urad(accel_urad_s2, a.p.max_accel);
                if goal as i32 == a.position {
                    let (position_steps, homed) = (a.position, a.homed);
                    self.events.push(
                        now,
                        Event::MotionDone {
                            axis,
                            position_steps,
                            homed,
                        },
                    );
                } else {
                    a.start_move(now, goal as i32, speed, accel);
                }
                Ok(Reply::Ok)
            }
            Command::GalvoSet { angle_urad } => {
                if self.sweep.is_some() {
                    return Err(CommandError::SweepRunning);
                }
                if angle_urad.unsigned_abs() > GALVO_MAX_URAD as u32 {
                    return Err(CommandError::BadArgument);
                }
                self.galvo_urad = angle_urad;
                Ok(Reply::Ok)
            }
            Command::GalvoSweep(sweep) => {
                if self.sweep.is_some() {
                    return Err(CommandError::SweepRunning);
                }
                galvo::check_sweep(&sweep)?;
                self.galvo_urad = galvo::sweep_angle(&sweep, 0);
                self.sweep = Some(SweepRun::new(now, sweep));
                Ok(Reply::Ok)
            }
            Command::LaserSelect { colour } => {
                self.laser_selected = colour;
                Ok(Reply::Ok)
            }
            Command::LaserPower { permille } => {
                if permille > 1000 {
                    return Err(CommandError::BadArgument);
                }
                self.laser_permille = permille;
                Ok(Reply::Ok)
            }
            Command::LaserArm { armed } => {
                self.armed = armed;
                Ok(Reply::Ok)
            }
            Command::Lamps { mask } => {
                self.lamps = mask;
                Ok(Reply::Ok)
            }
            Command::Trigger { mask, pulse_us } => {
                if mask == 0 || pulse_us == 0 || pulse_us > MAX_PULSE_US {
                    return Err(CommandError::BadArgument);
                }
                self.fire_triggers(now, mask, pulse_us);
                Ok(Reply::Ok)
            }
            Command::Abort => {
                self.abort_sweep();
                for a in &mut self.axes {
                    a.stop();
                }
                Ok(Reply::Ok)
            }
            Command::EStop => {
                self.estop();
                Ok(Reply::Ok)
            }
            Command::ClearFault => match self.fault {
                None => Ok(Reply::Ok),
                Some(cause) if self.cause_active(cause) => Err(CommandError::CauseActive(cause)),
                Some(_) => {
                    self.fault = None;
                    self.watch_since = None;
                    Ok(Reply::Ok)
                }
            },
            Command::Reset => Ok(Reply::Ok),
        }
    }

    fn cause_active(&self, cause: FaultCause) -> bool {
        match cause {
            FaultCause::EStop => self.inputs.estop_pressed,
            FaultCause::LimitHit(_) => !self.inputs.arc_limit_ok,
            FaultCause::HeartbeatLost | FaultCause::HomingFailed(_) | FaultCause::Watchdog => false,
        }
    }

    fn fire_triggers(&mut self, now: u64, mask: u8, pulse_us: u32) {
        for (i, off) in self.trigger_off_us.iter_mut().enumerate() {
            if mask & (1 << i) != 0 {
                *off = (*off).max(now.saturating_add(pulse_us as u64));
            }
        }
        self.events.push(
            now,
            Event::TriggerFired {
                mask,
                at_us: now,
                pulse_us,
            },
        );
    }

    fn abort_sweep(&mut self) {
        if self.sweep.take().is_some() {
            self.events
                .push(self.now_us, Event::SweepDone { completed: false });
        }
    }

    // ---- faults ----------------------------------------------------------

    /// Latch `cause`: lasers and lamps off, sweep aborted, motors decelerate.
    fn raise(&mut self, cause: FaultCause) {
        self.fault = Some(cause);
        self.armed = false;
        self.lamps = 0;
        self.abort_sweep();
        for a in &mut self.axes {
            a.stop();
        }
        self.events.push(self.now_us, Event::Fault { cause });
    }

    /// Everything off and stopped at once, fault latched.
    fn estop(&mut self) {
        let now = self.now_us;
        for i in 0..2 {
            if self.axes[i].active() {
                self.axes[i].halt();
                let a = &self.axes[i];
                self.events.push(
                    now,
                    Event::MotionDone {
                        axis: a.axis,
                        position_steps: a.position,
                        homed: false,
                    },
                );
            }
        }
        self.trigger_off_us = [0; LINES];
        if self.fault != Some(FaultCause::EStop) {
            self.raise(FaultCause::EStop);
        }
    }

    /// Force every output safe immediately (before a reset).
    fn safe_outputs_now(&mut self) {
        self.armed = false;
        self.lamps = 0;
        self.sweep = None;
        self.trigger_off_us = [0; LINES];
        for a in &mut self.axes {
            a.halt();
        }
    }

    // ---- the periodic work ------------------------------------------------

    fn service(&mut self, io: &mut impl Io) {
        let now = self.now_us;
        if !self.outputs_ready {
            self.write_all_outputs(io);
            self.outputs_ready = true;
        }
        if self.reset_mark.is_some() {
            self.safe_outputs_now();
            self.drive_outputs(io);
            return;
        }
        self.check_inputs(io.inputs());
        self.check_heartbeat();
        self.run_axes(io);
        self.run_sweep(io);
        self.drive_outputs(io);
        self.send_events(now);
    }

    fn check_inputs(&mut self, inputs: Inputs) {
        let now = self.now_us;
        if inputs.interlock_closed != self.inputs.interlock_closed {
            self.events.push(
                now,
                Event::Interlock {
                    closed: inputs.interlock_closed,
                },
            );
        }
        self.inputs = inputs;
        if inputs.estop_pressed && self.fault != Some(FaultCause::EStop) {
            self.estop();
        } else if !inputs.arc_limit_ok && self.fault.is_none() {
            self.raise(FaultCause::LimitHit(Axis::LightArc));
        }
    }

    fn check_heartbeat(&mut self) {
        let needed = self.armed || self.motion_active();
        if !needed || self.fault.is_some() {
            self.watch_since = None;
            return;
        }
        let since = *self.watch_since.get_or_insert(self.now_us);
        let last = self.last_heard_us.map_or(since, |t| t.max(since));
        if self.now_us.saturating_sub(last) > HEARTBEAT_TIMEOUT_US {
            self.raise(FaultCause::HeartbeatLost);
        }
    }

    fn run_axes(&mut self, io: &mut impl Io) {
        let now = self.now_us;
        for i in 0..2 {
            let axis = self.axes[i].axis;
            if self.axes[i].active() && !self.out.motor_enable[i] {
                io.set_motor_enable(axis, true);
                self.out.motor_enable[i] = true;
            }
            loop {
                let (stepped, outcome) =
                    self.axes[i].step_once(now, &mut |forward| io.step(axis, forward));
                // Homing reads its switch after every step (the step moved it).
                let outcome = if stepped && outcome.is_none() {
                    self.homing_check(i, io)
                } else {
                    outcome
                };
                match outcome {
                    None if stepped => continue,
                    None => break,
                    Some(AxisOutcome::Done) => {
                        let a = &self.axes[i];
                        let ev = Event::MotionDone {
                            axis,
                            position_steps: a.position,
                            homed: a.homed,
                        };
                        self.events.push(now, ev);
                        if self.fault == Some(FaultCause::LimitHit(axis)) {
                            // Let the operator move the axis off the switch by hand.
                            io.set_motor_enable(axis, false);
                            self.out.motor_enable[i] = false;
                            self.axes[i].homed = false;
                        }
                        break;
                    }
                    Some(AxisOutcome::HomingFailed) => {
                        self.raise(FaultCause::HomingFailed(axis));
                        break;
                    }
                }
            }
        }
        if self.fault == Some(FaultCause::EStop) {
            for (i, axis) in Axis::ALL.into_iter().enumerate() {
                if self.out.motor_enable[i] {
                    io.set_motor_enable(axis, false);
                    self.out.motor_enable[i] = false;
                }
            }
        }
    }

    /// A homing axis that just stepped reads its switch (the step moved it).
    fn homing_check(&mut self, i: usize, io: &mut impl Io) -> Option<AxisOutcome> {
        if !matches!(self.axes[i].mode, crate::axis::Mode::Homing(..)) {
            return None;
        }
        let actuated = io.inputs().home[i];
        self.axes[i].on_switch(self.now_us, actuated)
    }

    fn run_sweep(&mut self, io: &mut impl Io) {
        let now = self.now_us;
        while let Some(run) = self.sweep.as_mut() {
            let Some(action) = run.advance(now) else {
                break;
            };
            match action {
                SweepAction::Trigger { mask, pulse_us } => {
                    self.fire_triggers(now, mask, pulse_us);
                    // Raise the lines now so even a late poll shows the edge.
                    self.drive_triggers(io);
                }
                SweepAction::StepDone { step, angle_urad } => {
                    self.events
                        .push(now, Event::SweepStepDone { step, angle_urad });
                    if let Some(run) = &self.sweep
                        && run.step < run.sweep.steps
                    {
                        self.galvo_urad = galvo::sweep_angle(&run.sweep, run.step);
                    }
                    self.drive_triggers(io);
                }
                SweepAction::Finished => {
                    self.sweep = None;
                    self.events.push(now, Event::SweepDone { completed: true });
                }
            }
        }
    }

    fn laser_permitted(&self) -> bool {
        self.armed
            && self.fault.is_none()
            && self.inputs.interlock_closed
            && !self.inputs.estop_pressed
            && self.heartbeat_fresh()
            && self.reset_mark.is_none()
    }

    fn drive_triggers(&mut self, io: &mut impl Io) {
        let now = self.now_us;
        let mut mask = 0u8;
        for (i, off) in self.trigger_off_us.iter_mut().enumerate() {
            if *off > now {
                mask |= 1 << i;
            } else {
                *off = 0;
            }
        }
        if mask != self.out.triggers {
            io.set_triggers(mask);
            self.out.triggers = mask;
        }
    }

    fn drive_outputs(&mut self, io: &mut impl Io) {
        // Laser first: off before anything else changes, never two colours at once.
        let want = self.laser_permitted().then_some(self.laser_selected);
        if want != self.out.laser {
            if let Some(old) = self.out.laser {
                io.set_laser(old, false);
                self.out.laser = None;
            }
            let power = match want {
                Some(_) => (self.laser_permille as u32 * DAC_MAX as u32 / 1000) as u16,
                None => 0,
            };
            if power != self.out.laser_power {
                io.set_laser_power(power);
                self.out.laser_power = power;
            }
            if let Some(new) = want {
                io.set_laser(new, true);
                self.out.laser = Some(new);
            }
        } else if want.is_some() {
            let power = (self.laser_permille as u32 * DAC_MAX as u32 / 1000) as u16;
            if power != self.out.laser_power {
                io.set_laser_power(power);
                self.out.laser_power = power;
            }
        }
        if self.lamps != self.out.lamps {
            io.set_lamps(self.lamps);
            self.out.lamps = self.lamps;
        }
        let code = galvo::galvo_code(self.galvo_urad);
        if code != self.out.galvo {
            io.set_galvo(code);
            self.out.galvo = code;
        }
        self.drive_triggers(io);
    }

    fn write_all_outputs(&mut self, io: &mut impl Io) {
        for c in LaserColour::ALL {
            io.set_laser(c, false);
        }
        io.set_laser_power(0);
        io.set_lamps(0);
        io.set_triggers(0);
        io.set_galvo(galvo::DAC_MID);
        for a in Axis::ALL {
            io.set_motor_enable(a, false);
        }
        self.out = Outputs::SAFE;
    }

    fn send_events(&mut self, now: u64) {
        let mut buf = [0u8; MAX_FRAME];
        let mut send = |tx: &mut TxQueue, eseq: u16, at_us: u64, event: Event| {
            if let Ok(n) = encode_frame(&McuFrame::Event { eseq, at_us, event }, &mut buf) {
                tx.push_frame(&buf[..n]);
            }
        };
        // Re-send the old ones first, so a new one is not sent twice in one go.
        // At most RESEND_BURST per period, and only while the link keeps up:
        // a host that never acknowledges must not starve the replies.
        if now >= self.resend_at {
            let mut any = false;
            let busy = self.tx.len() > TX_CAPACITY / 2;
            for &(eseq, at_us, event) in self.events.pending().take(RESEND_BURST) {
                if !busy && !seq_after(eseq, self.last_sent_eseq) {
                    send(&mut self.tx, eseq, at_us, event);
                }
                any = true;
            }
            if any {
                self.resend_at = now.saturating_add(EVENT_RESEND_US);
            }
        }
        let mut any_new = false;
        for &(eseq, at_us, event) in self.events.pending() {
            if seq_after(eseq, self.last_sent_eseq) {
                send(&mut self.tx, eseq, at_us, event);
                self.last_sent_eseq = eseq;
                any_new = true;
            }
        }
        if any_new && now >= self.resend_at {
            self.resend_at = now.saturating_add(EVENT_RESEND_US);
        }
    }

    fn next_deadline(&self) -> u64 {
        let now = self.now_us;
        let mut t = now.saturating_add(INPUT_POLL_US);
        for a in &self.axes {
            if let Some(d) = a.next_due() {
                t = t.min(d);
            }
        }
        if let Some(run) = &self.sweep {
            t = t.min(run.next_due());
        }
        for &off in &self.trigger_off_us {
            if off > now {
                t = t.min(off);
            }
        }
        if self.events.pending().next().is_some() {
            t = t.min(self.resend_at.max(now));
        }
        if let Some(hb) = self.last_heard_us
            && self.laser_emitting()
        {
            t = t.min(hb.saturating_add(HEARTBEAT_TIMEOUT_US + 1));
        }
        t.max(now)
    }
}
