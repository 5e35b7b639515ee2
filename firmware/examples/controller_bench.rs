//! Host-side cost of the Controller's work, to judge the MCU budget:
//! `cargo run -p firmware --release --example controller_bench`.
//!
//! Measures (on the host CPU, so only relative to the 375 µs step period of
//! the rig's fastest axis): a command round (decode + admit + execute + reply
//! encoding + take_tx), and one poll that emits a step during a long move.
//!
//! Measured 2026-11-23 on the shared 2-core build machine (x86_64, busy):
//!   command round Status: 1.19 µs
//!   command round  Lamps: 0.53 µs
//!   move of 15279 steps: 15580 polls, 0.043 µs per poll, 0.044 µs per step

use firmware::{Controller, Inputs, Io};
use protocol::{Axis, Command, HostFrame, LaserColour, MAX_FRAME, MoveTarget, encode_frame};
use std::time::Instant;

struct NullRig {
    steps: u64,
}

impl Io for NullRig {
    fn step(&mut self, _: Axis, _: bool) {
        self.steps += 1;
    }
    fn set_motor_enable(&mut self, _: Axis, _: bool) {}
    fn set_galvo(&mut self, _: u16) {}
    fn set_laser(&mut self, _: LaserColour, _: bool) {}
    fn set_laser_power(&mut self, _: u16) {}
    fn set_lamps(&mut self, _: u8) {}
    fn set_triggers(&mut self, _: u8) {}
    fn inputs(&mut self) -> Inputs {
        Inputs::SAFE
    }
}

fn frame(seq: u16, command: Command) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    let n = encode_frame(&HostFrame { seq, command }, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn main() {
    let mut c = Controller::new(1, false);
    let mut rig = NullRig { steps: 0 };
    let mut out = [0u8; 1024];
    c.receive(0, &frame(0, Command::Identify), &mut rig);
    c.take_tx(&mut out);

    // Command rounds: Status (largest reply) and Lamps (smallest).
    for (name, command) in [
        ("Status", Command::Status),
        ("Lamps", Command::Lamps { mask: 3 }),
    ] {
        let n = 60_000u16;
        let frames: Vec<_> = (1..=n).map(|s| frame(s, command.clone())).collect();
        let mut c = Controller::new(1, false);
        c.receive(0, &frame(0, Command::Identify), &mut rig);
        c.take_tx(&mut out);
        let t0 = Instant::now();
        for (i, f) in frames.iter().enumerate() {
            c.receive(i as u64, f, &mut rig);
            while c.take_tx(&mut out) > 0 {}
        }
        let per = t0.elapsed().as_secs_f64() / n as f64;
        println!("command round {name:>6}: {:.2} µs", per * 1e6);
    }

    // Steps: a 10-turn-equivalent of relative moves polled at every deadline.
    c.receive(1, &frame(1, Command::Heartbeat { event_ack: 1 }), &mut rig);
    c.receive(
        2,
        &frame(
            2,
            Command::Move {
                axis: Axis::Turntable,
                target: MoveTarget::Relative(6_000_000),
                speed_urad_s: 0,
                accel_urad_s2: 0,
            },
        ),
        &mut rig,
    );
    let mut now = 2;
    let mut polls = 0u64;
    let t0 = Instant::now();
    while c.status(now).axes[0].moving && c.fault().is_none() {
        now = c.poll(now, &mut rig).max(now + 1);
        polls += 1;
        if polls.is_multiple_of(200) {
            let seq = 2 + (polls / 200) as u16;
            c.receive(
                now,
                &frame(seq, Command::Heartbeat { event_ack: 0 }),
                &mut rig,
            );
        }
        c.take_tx(&mut out);
    }
    let el = t0.elapsed().as_secs_f64();
    println!(
        "move of {} steps: {} polls, {:.3} µs per poll, {:.3} µs per step (host CPU)",
        rig.steps,
        polls,
        el / polls as f64 * 1e6,
        el / rig.steps as f64 * 1e6
    );
}
