//! The Controller fed an arbitrary script: raw link bytes, well-formed
//! commands built from the input, time steps and input changes. The
//! invariant (issue 2, DESIGN.md principle 4): the laser never emits unless
//! the interlock is closed, the e-stop released, a valid host frame (any
//! command, a retransmission too) arrived within 250 ms and no fault is latched, and never two colours at once.
//! Also: homed axes stay inside their soft limits, and no step is emitted
//! while the e-stop is pressed or its fault latched.
//! Any violation panics, which libFuzzer reports with the reproducing input.
//!
//! The harness mirrors the controller's frame decoding and sequencing on the
//! same bytes, so it knows exactly when a valid frame arrived, even one the
//! fuzzer smuggled in through raw link bytes.
#![no_main]

use firmware::axis::AxisParams;
use firmware::controller::HEARTBEAT_TIMEOUT_US;
use firmware::{Controller, Inputs, Io};
use libfuzzer_sys::fuzz_target;
use protocol::seq::{Admission, CommandSequencer};
use protocol::{
    Axis, Command, FaultCause, FrameDecoder, HostFrame, LaserColour, MAX_FRAME, MoveTarget, Sweep,
    encode_frame,
};

#[derive(Default)]
struct Rig {
    pos: [i64; 2],
    steps: u64,
    lasers: [bool; 3],
    inputs: Option<Inputs>,
}

impl Io for Rig {
    fn step(&mut self, axis: Axis, forward: bool) {
        self.pos[axis.index()] += if forward { 1 } else { -1 };
        self.steps += 1;
    }
    fn set_motor_enable(&mut self, _: Axis, _: bool) {}
    fn set_galvo(&mut self, _: u16) {}
    fn set_laser(&mut self, colour: LaserColour, on: bool) {
        self.lasers[colour.index()] = on;
        assert!(
            self.lasers.iter().filter(|&&l| l).count() <= 1,
            "two lasers on at once"
        );
    }
    fn set_laser_power(&mut self, _: u16) {}
    fn set_lamps(&mut self, _: u8) {}
    fn set_triggers(&mut self, _: u8) {}
    fn inputs(&mut self) -> Inputs {
        let mut i = self.inputs.unwrap_or(Inputs::SAFE);
        i.home = [
            (-100..=0).contains(&self.pos[0]),
            (-100..=0).contains(&self.pos[1]),
        ];
        i
    }
}

/// The controller plus a mirror of its link state.
struct Harness {
    c: Controller,
    rig: Rig,
    now: u64,
    seq: u16,
    mirror_dec: FrameDecoder,
    mirror_seq: CommandSequencer,
    mirror_reset: bool,
    last_hb: Option<u64>,
}

impl Harness {
    fn feed(&mut self, bytes: &[u8]) {
        if !self.mirror_reset {
            for &b in bytes {
                if let Some(Ok(frame)) = self.mirror_dec.push::<HostFrame>(b) {
                    self.last_hb = Some(self.now);
                    if self.mirror_seq.admit(&frame) == Admission::Execute
                        && matches!(frame.command, Command::Reset)
                    {
                        self.mirror_reset = true;
                        break;
                    }
                }
            }
        }
        self.c.receive(self.now, bytes, &mut self.rig);
        let mut sink = [0u8; 256];
        while self.c.take_tx(&mut sink) > 0 {}
    }

    fn send(&mut self, command: Command) {
        if !matches!(command, Command::Identify) {
            self.seq = self.seq.wrapping_add(1);
        }
        let mut buf = [0u8; MAX_FRAME + 1];
        // leading delimiter: flush whatever raw bytes left in the decoder
        let n = encode_frame(
            &HostFrame {
                seq: self.seq,
                command,
            },
            &mut buf[1..],
        )
        .expect("commands fit a frame");
        self.feed(&buf[..n + 1].to_vec());
    }

    fn poll(&mut self) -> u64 {
        let next = self.c.poll(self.now, &mut self.rig);
        self.check();
        next
    }

    fn check(&self) {
        if self.rig.lasers.iter().any(|&l| l) {
            let i = self.rig.inputs.unwrap_or(Inputs::SAFE);
            assert!(i.interlock_closed, "laser on with the interlock open");
            assert!(!i.estop_pressed, "laser on with the e-stop pressed");
            assert!(self.c.fault().is_none(), "laser on with a fault latched");
            let fresh = self
                .last_hb
                .is_some_and(|t| self.now - t <= HEARTBEAT_TIMEOUT_US);
            assert!(
                fresh,
                "laser on without a fresh heartbeat at {} us",
                self.now
            );
        }
        assert_eq!(self.c.laser_emitting(), self.rig.lasers.iter().any(|&l| l));
        let status = self.c.status(self.now);
        for (i, mech) in [hardware::TURNTABLE, hardware::LIGHT_ARC]
            .into_iter()
            .enumerate()
        {
            let p = AxisParams::of(mech);
            let a = status.axes[i];
            assert!(
                !a.homed || (p.soft_min..=p.soft_max).contains(&a.position_steps),
                "homed axis {i} at {} beyond its soft limits",
                a.position_steps
            );
        }
    }

    fn estopped(&self) -> bool {
        self.rig.inputs.is_some_and(|i| i.estop_pressed)
            || self.c.fault() == Some(FaultCause::EStop)
    }
}

/// Reads the script; running out of bytes yields zeros.
struct Script<'a>(&'a [u8]);

impl Script<'_> {
    fn u8(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }
    fn u32(&mut self) -> u32 {
        self.i32() as u32
    }
    fn take(&mut self, n: usize) -> &[u8] {
        let n = n.min(self.0.len());
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        a
    }

    fn command(&mut self) -> Command {
        let axis = if self.u8() & 1 == 0 {
            Axis::Turntable
        } else {
            Axis::LightArc
        };
        let colour = LaserColour::ALL[self.u8() as usize % 3];
        match self.u8() % 18 {
            0 => Command::Identify,
            1 => Command::Heartbeat {
                event_ack: self.u16(),
            },
            2 => Command::AckEvents { upto: self.u16() },
            3 => Command::Home { axis },
            4 | 5 => Command::Move {
                axis,
                target: if self.u8() & 1 == 0 {
                    MoveTarget::Absolute(self.i32() / 256)
                } else {
                    MoveTarget::Relative(self.i32() / 256)
                },
                speed_urad_s: self.u32(),
                accel_urad_s2: self.u32(),
            },
            6 => Command::Status,
            7 => Command::GalvoSet {
                angle_urad: self.i32() / 4096,
            },
            8 => Command::GalvoSweep(Sweep {
                start_urad: self.i32() / 4096,
                end_urad: self.i32() / 4096,
                steps: self.u8() as u16,
                dwell_us: self.u16() as u32,
                trigger_mask: self.u8(),
                pulse_us: self.u16() as u32,
            }),
            9 => Command::LaserSelect { colour },
            10 => Command::LaserPower {
                permille: self.u16() % 1100,
            },
            11 | 12 => Command::LaserArm {
                armed: self.u8() & 1 == 0,
            },
            13 => Command::Lamps { mask: self.u8() },
            14 => Command::Trigger {
                mask: self.u8(),
                pulse_us: self.u16() as u32,
            },
            15 => Command::Abort,
            16 => Command::EStop,
            _ => Command::ClearFault,
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let mut h = Harness {
        c: Controller::new(1, false),
        rig: Rig {
            pos: [300, 200],
            ..Rig::default()
        },
        now: 0,
        seq: 0,
        mirror_dec: FrameDecoder::new(),
        mirror_seq: CommandSequencer::new(),
        mirror_reset: false,
        last_hb: None,
    };
    h.poll();
    h.send(Command::Identify);
    let mut s = Script(data);
    // bounded script: at most 256 operations
    for _ in 0..256 {
        if s.0.is_empty() {
            break;
        }
        let (estopped, steps) = (h.estopped(), h.rig.steps);
        match s.u8() % 8 {
            0 | 1 => {
                let n = s.u8() as usize % 64;
                let bytes = s.take(n).to_vec();
                h.feed(&bytes);
            }
            2 | 3 => {
                let cmd = s.command();
                h.send(cmd);
            }
            4 => {
                // time passes, polled at every deadline (up to ~1 s)
                let end = h.now + s.u16() as u64 * 16;
                while h.now < end {
                    let next = h.poll();
                    h.now = next.clamp(h.now + 1, end);
                }
            }
            5 => {
                // time jumps, one late poll
                h.now += s.u16() as u64 * 64;
            }
            6 => {
                let b = s.u8();
                h.rig.inputs = Some(Inputs {
                    home: [false; 2],
                    interlock_closed: b & 1 == 0,
                    estop_pressed: b & 6 == 6,
                    arc_limit_ok: b & 8 == 0,
                });
            }
            _ => {
                let ack = s.u16();
                h.send(Command::Heartbeat { event_ack: ack });
            }
        }
        h.poll();
        assert!(!estopped || h.rig.steps == steps, "steps after an e-stop");
    }
});
