//! Motors, gearing, speed limits, the galvo and the lasers.

use core::f64::consts::PI;

/// One stepper-driven rotation axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMechanics {
    pub name: &'static str,
    /// Full steps per motor revolution.
    pub full_steps_per_rev: u32,
    /// Driver microstepping.
    pub microsteps: u32,
    /// Output revolutions per motor revolution is 1 / gear_ratio.
    pub gear_ratio: u32,
    /// Highest speed the axis may be commanded, rad/s.
    pub max_speed: f64,
    /// Highest acceleration, rad/s^2.
    pub max_accel: f64,
    /// Soft limits in radians from home, inclusive.
    pub soft_min: f64,
    pub soft_max: f64,
    /// Position of the home switch edge, radians from the axis zero.
    pub home_offset: f64,
    /// Homing: approach speed (rad/s), back-off distance (rad), slow re-approach speed (rad/s).
    pub home_fast_speed: f64,
    pub home_backoff: f64,
    pub home_slow_speed: f64,
    /// Time the axis needs to settle after a move before an exposure, s.
    pub settle_time: f64,
}

impl AxisMechanics {
    /// Microsteps per output revolution.
    pub const fn steps_per_rev(&self) -> u32 {
        self.full_steps_per_rev * self.microsteps * self.gear_ratio
    }
    /// Radians per microstep at the output.
    pub fn rad_per_step(&self) -> f64 {
        2.0 * PI / self.steps_per_rev() as f64
    }
    /// Nearest step count for an angle in radians.
    pub fn steps_from_rad(&self, rad: f64) -> i64 {
        let s = rad / self.rad_per_step();
        // round half away from zero without std
        if s >= 0.0 {
            (s + 0.5) as i64
        } else {
            (s - 0.5) as i64
        }
    }
    pub fn rad_from_steps(&self, steps: i64) -> f64 {
        steps as f64 * self.rad_per_step()
    }
    /// Time of a point-to-point trapezoidal (or triangular) move of `distance` radians.
    pub fn move_time(&self, distance: f64, speed: f64, accel: f64) -> f64 {
        let d = if distance < 0.0 { -distance } else { distance };
        if d == 0.0 {
            return 0.0;
        }
        let d_ramp = speed * speed / accel; // accelerate + decelerate
        if d >= d_ramp {
            2.0 * speed / accel + (d - d_ramp) / speed
        } else {
            2.0 * sqrt(d / accel)
        }
    }
}

/// Newton's square root, for no_std callers of `move_time`.
fn sqrt(x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let mut r = if x > 1.0 { x } else { 1.0 };
    for _ in 0..60 {
        r = 0.5 * (r + x / r);
    }
    r
}

/// The turntable carrying the sample. 1.8 degree motor, 16 microsteps, 5:1 belt.
pub const TURNTABLE: AxisMechanics = AxisMechanics {
    name: "turntable",
    full_steps_per_rev: 200,
    microsteps: 16,
    gear_ratio: 5,
    max_speed: PI / 3.0,       // 60 deg/s
    max_accel: 2.0 * PI / 3.0, // 120 deg/s^2
    soft_min: -2.0 * PI - 0.2,
    soft_max: 2.0 * PI + 0.2,
    home_offset: 0.0,
    home_fast_speed: PI / 6.0,
    home_backoff: 0.05,
    home_slow_speed: PI / 90.0,
    settle_time: 0.15,
};

/// The light arc with the lamps and the laser unit. Heavier: 10:1 worm drive.
pub const LIGHT_ARC: AxisMechanics = AxisMechanics {
    name: "light arc",
    full_steps_per_rev: 200,
    microsteps: 16,
    gear_ratio: 10,
    max_speed: PI / 6.0, // 30 deg/s
    max_accel: PI / 3.0, // 60 deg/s^2
    soft_min: -PI - 0.1, // cables allow a little more than half a turn each way
    soft_max: PI + 0.1,
    home_offset: 0.0,
    home_fast_speed: PI / 12.0,
    home_backoff: 0.05,
    home_slow_speed: PI / 180.0,
    settle_time: 0.3,
};

/// The galvo mirror that sweeps the laser stripe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GalvoSpec {
    /// Mechanical angle range, radians, symmetric about 0.
    pub max_angle: f64,
    /// DAC resolution in bits (the F446 DAC is 12 bits).
    pub dac_bits: u32,
    /// Small-step settling time, s.
    pub settle_time: f64,
}

pub const GALVO: GalvoSpec = GalvoSpec {
    max_angle: 0.35,
    dac_bits: 12,
    settle_time: 0.002,
};

/// One of the three interchangeable lasers (paper: 10 mW each).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserSpec {
    pub name: &'static str,
    pub wavelength_nm: f64,
    /// Nominal optical power at full drive, W.
    pub power_w: f64,
    /// The colour channel the laser measures: 0 = R, 1 = G, 2 = B.
    pub channel: usize,
}

pub const LASERS: [LaserSpec; 3] = [
    LaserSpec {
        name: "red",
        wavelength_nm: 650.0,
        power_w: 0.010,
        channel: 0,
    },
    LaserSpec {
        name: "green",
        wavelength_nm: 532.0,
        power_w: 0.010,
        channel: 1,
    },
    LaserSpec {
        name: "blue",
        wavelength_nm: 473.0,
        power_w: 0.010,
        channel: 2,
    },
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_round_trip() {
        for axis in [TURNTABLE, LIGHT_ARC] {
            for s in [-12345i64, -1, 0, 1, 7, 16000] {
                assert_eq!(axis.steps_from_rad(axis.rad_from_steps(s)), s);
            }
        }
    }

    #[test]
    fn move_time_triangular_and_trapezoidal() {
        let a = TURNTABLE;
        // full speed reached: 2 v/a + (d - v^2/a)/v
        let t = a.move_time(PI, a.max_speed, a.max_accel);
        let expect = 2.0 * a.max_speed / a.max_accel
            + (PI - a.max_speed * a.max_speed / a.max_accel) / a.max_speed;
        assert!((t - expect).abs() < 1e-12);
        // tiny move: triangular 2 sqrt(d/a)
        let t = a.move_time(0.01, a.max_speed, a.max_accel);
        assert!((t - 2.0 * (0.01f64 / a.max_accel).sqrt()).abs() < 1e-9);
    }
}
