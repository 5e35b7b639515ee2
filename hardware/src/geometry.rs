//! Nominal placement of cameras, lamps and the laser unit (paper Fig. 3).
//!
//! These are the values the rig was built to. The real (or simulated) rig
//! differs from them by small errors that calibration finds.

use core::f64::consts::PI;

const DEG: f64 = PI / 180.0;

/// A camera on the stationary arc, looking at the origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraMount {
    /// Elevation above the reference plane, radians (pi/2 = straight down onto the sample).
    pub elevation: f64,
    /// Azimuth of the camera arc, radians.
    pub azimuth: f64,
    /// Distance from the origin to the centre of projection, mm.
    pub distance: f64,
    /// Whether captures use it (the lowest sees the sample edge-on).
    pub used: bool,
}

/// A halogen lamp on the light arc; nearly directional at the sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LampMount {
    pub elevation: f64,
    pub distance: f64,
    pub used: bool,
}

/// The laser unit: where it may be clamped on the light arc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserMount {
    /// Distance from the galvo mirror to the origin, mm.
    pub distance: f64,
    /// Elevations at which the unit can be clamped, radians; pass 1 uses them
    /// all, pass 2 only the vertical one.
    pub positions: [f64; 5],
    /// Length of the stripe the line lens draws on the reference plane, mm.
    pub stripe_length: f64,
}

/// Sensor of every camera on the arc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSpec {
    pub width: u32,
    pub height: u32,
    /// Focal length in pixels.
    pub focal_px: f64,
    /// Frames per second at full resolution (Dragonfly: 3.75 Hz).
    pub frame_rate: f64,
    /// Bits per channel.
    pub bits: u32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigGeometry {
    pub cameras: [CameraMount; 8],
    pub lamps: [LampMount; 8],
    pub laser: LaserMount,
    pub sensor: SensorSpec,
    /// Light-arc azimuth at arc angle 0 (the arc faces the cameras across the sample).
    pub light_arc_azimuth0: f64,
    /// Radius of the turntable's flat top, mm.
    pub turntable_radius: f64,
}

const fn camera(k: usize) -> CameraMount {
    CameraMount {
        elevation: k as f64 * (90.0 / 7.0) * DEG,
        azimuth: 0.0,
        distance: 450.0,
        used: k > 0,
    }
}

const fn lamp(k: usize) -> LampMount {
    LampMount {
        elevation: k as f64 * 12.0 * DEG,
        distance: 650.0,
        used: k > 0,
    }
}

/// The rig as built.
pub const NOMINAL_GEOMETRY: RigGeometry = RigGeometry {
    cameras: [
        camera(0),
        camera(1),
        camera(2),
        camera(3),
        camera(4),
        camera(5),
        camera(6),
        camera(7),
    ],
    lamps: [
        lamp(0),
        lamp(1),
        lamp(2),
        lamp(3),
        lamp(4),
        lamp(5),
        lamp(6),
        lamp(7),
    ],
    laser: LaserMount {
        distance: 600.0,
        positions: [90.0 * DEG, 75.0 * DEG, 60.0 * DEG, 45.0 * DEG, 30.0 * DEG],
        stripe_length: 70.0,
    },
    sensor: SensorSpec {
        width: 1024,
        height: 768,
        focal_px: 5120.0,
        frame_rate: 3.75,
        bits: 8,
    },
    light_arc_azimuth0: PI,
    turntable_radius: 100.0,
};

impl RigGeometry {
    /// Cameras the capture passes use.
    pub fn used_cameras(&self) -> impl Iterator<Item = (usize, &CameraMount)> {
        self.cameras.iter().enumerate().filter(|(_, c)| c.used)
    }
    /// Lamps the capture passes use.
    pub fn used_lamps(&self) -> impl Iterator<Item = (usize, &LampMount)> {
        self.lamps.iter().enumerate().filter(|(_, l)| l.used)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seven_of_eight_used() {
        assert_eq!(NOMINAL_GEOMETRY.used_cameras().count(), 7);
        assert_eq!(NOMINAL_GEOMETRY.used_lamps().count(), 7);
        assert!((NOMINAL_GEOMETRY.cameras[7].elevation - PI / 2.0).abs() < 1e-12);
    }
}
