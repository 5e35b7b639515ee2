//! Test doubles for the Controller: a virtual rig behind [`Io`] and a
//! minimal host. Used by the unit and property tests (`cfg(test)` only).

use crate::io::{Inputs, Io};
use crate::{Controller, axis::AxisParams};
use hardware::{LIGHT_ARC, TURNTABLE};
use protocol::{
    Axis, Command, CommandError, Event, FrameDecoder, HostFrame, LaserColour, MAX_FRAME, McuFrame,
    Reply, encode_frame,
};
use std::vec::Vec;

/// A virtual rig: integrates steps into positions, derives the home switches
/// from them, records every output and flags impossible output states.
#[derive(Debug, Clone)]
pub struct Rig {
    /// Physical position of each axis in steps (0 = the home switch edge).
    pub pos: [i64; 2],
    /// Home switch actuated for positions in `[-width, 0]`.
    pub home_width: i64,
    pub enable: [bool; 2],
    pub galvo: u16,
    pub lasers: [bool; 3],
    pub laser_power: u16,
    pub lamps: u8,
    pub triggers: u8,
    pub trigger_rises: Vec<u8>,
    pub steps: u64,
    pub steps_while_disabled: u64,
    pub two_lasers_seen: bool,
    pub interlock_closed: bool,
    pub estop_pressed: bool,
    pub arc_limit_ok: bool,
}

impl Default for Rig {
    fn default() -> Self {
        Rig {
            pos: [3000, -2000],
            home_width: 200,
            enable: [true; 2],
            galvo: 0,
            lasers: [true; 3],
            laser_power: 4095,
            lamps: 0xff,
            triggers: 0xff,
            trigger_rises: Vec::new(),
            steps: 0,
            steps_while_disabled: 0,
            two_lasers_seen: false,
            interlock_closed: true,
            estop_pressed: false,
            arc_limit_ok: true,
        }
    }
}

impl Rig {
    pub fn laser_on(&self) -> bool {
        self.lasers.iter().any(|&l| l)
    }
}

impl Io for Rig {
    fn step(&mut self, axis: Axis, forward: bool) {
        let i = axis.index();
        self.pos[i] += if forward { 1 } else { -1 };
        self.steps += 1;
        if !self.enable[i] {
            self.steps_while_disabled += 1;
        }
    }
    fn set_motor_enable(&mut self, axis: Axis, enabled: bool) {
        self.enable[axis.index()] = enabled;
    }
    fn set_galvo(&mut self, code: u16) {
        self.galvo = code;
    }
    fn set_laser(&mut self, colour: LaserColour, on: bool) {
        self.lasers[colour.index()] = on;
        if on && self.lasers.iter().filter(|&&l| l).count() > 1 {
            self.two_lasers_seen = true;
        }
    }
    fn set_laser_power(&mut self, code: u16) {
        self.laser_power = code;
    }
    fn set_lamps(&mut self, mask: u8) {
        self.lamps = mask;
    }
    fn set_triggers(&mut self, mask: u8) {
        let rising = mask & !self.triggers;
        if rising != 0 {
            self.trigger_rises.push(rising);
        }
        self.triggers = mask;
    }
    fn inputs(&mut self) -> Inputs {
        let home = |p: i64| (-self.home_width..=0).contains(&p);
        Inputs {
            home: [home(self.pos[0]), home(self.pos[1])],
            arc_limit_ok: self.arc_limit_ok,
            interlock_closed: self.interlock_closed,
            estop_pressed: self.estop_pressed,
        }
    }
}

/// A minimal host: numbers commands, decodes replies and events.
pub struct Host {
    pub seq: u16,
    dec: FrameDecoder,
    pub acks: Vec<(u16, Result<Reply, CommandError>)>,
    /// Every event frame received, duplicates included.
    pub events: Vec<(u16, u64, Event)>,
    /// When the controller last received a frame from this host.
    pub last_heard_us: Option<u64>,
}

impl Default for Host {
    fn default() -> Self {
        Self::new()
    }
}

impl Host {
    pub fn new() -> Self {
        Host {
            seq: 100,
            dec: FrameDecoder::new(),
            acks: Vec::new(),
            events: Vec::new(),
            last_heard_us: None,
        }
    }

    pub fn encode(seq: u16, command: Command) -> Vec<u8> {
        let mut buf = [0u8; MAX_FRAME];
        let n = encode_frame(&HostFrame { seq, command }, &mut buf).unwrap();
        buf[..n].to_vec()
    }

    /// Collect everything the controller has queued.
    pub fn drain(&mut self, c: &mut Controller) {
        let mut buf = [0u8; 512];
        loop {
            let n = c.take_tx(&mut buf);
            if n == 0 {
                break;
            }
            let (acks, events) = (&mut self.acks, &mut self.events);
            // Partial frames (a test took bytes itself) are dropped like a real host does.
            self.dec.push_slice::<McuFrame>(&buf[..n], |r| match r {
                Ok(McuFrame::Ack { seq, result }) => acks.push((seq, result)),
                Ok(McuFrame::Event { eseq, at_us, event }) => events.push((eseq, at_us, event)),
                Err(_) => {}
            });
        }
    }

    /// Send `command` with sequence `seq` at `now`; returns the reply to it.
    pub fn send_seq(
        &mut self,
        c: &mut Controller,
        rig: &mut Rig,
        now: u64,
        seq: u16,
        command: Command,
    ) -> Result<Reply, CommandError> {
        self.last_heard_us = Some(now);
        c.receive(now, &Self::encode(seq, command), rig);
        self.acks.clear();
        self.drain(c);
        let (s, r) = self.acks.last().cloned().expect("no reply");
        assert_eq!(s, seq);
        r
    }

    /// Send the next command.
    pub fn send(
        &mut self,
        c: &mut Controller,
        rig: &mut Rig,
        now: u64,
        command: Command,
    ) -> Result<Reply, CommandError> {
        if !matches!(command, Command::Identify) {
            self.seq = self.seq.wrapping_add(1);
        }
        self.send_seq(c, rig, now, self.seq, command)
    }

    /// Distinct events (duplicates from retransmission removed), in order.
    pub fn distinct_events(&self) -> Vec<Event> {
        let mut seen = std::collections::BTreeSet::new();
        self.events
            .iter()
            .filter(|(eseq, _, _)| seen.insert(*eseq))
            .map(|e| e.2)
            .collect()
    }
}

/// Poll `c` at every deadline it asks for until `until_us`, then at `until_us`.
pub fn run_until(c: &mut Controller, rig: &mut Rig, from_us: u64, until_us: u64) {
    let mut now = from_us;
    loop {
        let next = c.poll(now, rig);
        if next > until_us || now >= until_us {
            break;
        }
        now = next.max(now + 1).min(until_us);
    }
    c.poll(until_us, rig);
}

pub fn params(axis: Axis) -> AxisParams {
    match axis {
        Axis::Turntable => AxisParams::of(TURNTABLE),
        Axis::LightArc => AxisParams::of(LIGHT_ARC),
    }
}
