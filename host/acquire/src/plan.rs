//! The capture plan: the three passes of paper Fig. 4 as an ordered list of
//! steps, with the rig time it will take and a mechanical lower bound.
//!
//! A [`Step`] is one rig configuration (clamp elevation, turntable and light-arc
//! angles, light source) and one exposure of the bracket; it fires the cameras
//! once per laser scan position (a galvo sweep) or once (a lamp image). Steps
//! are the unit of resume, and every frame's name and noise seed derive from
//! (step, scan position, camera), never from time or arrival order.
//!
//! Order (fewest motions): the operator's clamp moves are outermost, then the
//! light arc (the slower axis), then the turntable in serpentine order (so it
//! never swings back across the whole circle), then the electronic switches
//! (laser colour, lamp), then the exposures.
//!
//! f(w_i) compares each oblique stripe with a vertical one on the same line
//! of the sample, seen from the same view: a heterogeneous sample differs
//! from line to line by more than f does. So pass 1 ends at the vertical
//! clamp with a reference row for every turntable angle and line direction
//! its oblique rows use, at the same scan positions, unless pass 2 already
//! sweeps those lines in those views (`PlanConfig::entrance_vertical_rows`).
//! The clamp then stays at the vertical for pass 2 and moves once per
//! position.

use std::f64::consts::PI;

use hardware::{AxisMechanics, GALVO, LIGHT_ARC, NOMINAL_GEOMETRY, TURNTABLE};
use protocol::LaserColour;
use serde::{Deserialize, Serialize};

/// Time the operator needs to move the laser clamp on the arc (estimate), s.
pub const OPERATOR_CLAMP_S: f64 = 60.0;
/// Link round trip charged per command in the estimate, s.
pub const COMMAND_OVERHEAD_S: f64 = 0.004;

/// Which of the paper's three passes a step belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Pass {
    /// Pass 1: laser stripes from many light directions, sparse views (entrance function).
    Entrance,
    /// Pass 2: vertical laser stripes, all views (dipole parameters and exiting function).
    Exiting,
    /// Pass 3: lamp images, all views and lights (local reflectance function).
    Reflectance,
    /// A calibration capture's frames (`crate::cal_plan`; numbered 0).
    Calibration,
}

impl Pass {
    pub fn number(self) -> u8 {
        match self {
            Pass::Entrance => 1,
            Pass::Exiting => 2,
            Pass::Reflectance => 3,
            Pass::Calibration => 0,
        }
    }
}

/// Named sampling densities.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    /// Tiny: the whole capture (with the sim's Monte Carlo) runs inside the test suite.
    Ci,
    /// The demo's: minutes on the simulated rig.
    Default,
    /// Paper Table 1: views 12 x 7, lights 12 x 7, entrance from 4 x 4 sparse views.
    Paper,
}

impl Scale {
    pub const ALL: [Scale; 3] = [Scale::Ci, Scale::Default, Scale::Paper];
    pub fn name(self) -> &'static str {
        match self {
            Scale::Ci => "ci",
            Scale::Default => "default",
            Scale::Paper => "paper",
        }
    }
}

impl std::str::FromStr for Scale {
    type Err = PlanError;
    fn from_str(s: &str) -> Result<Self, PlanError> {
        match s {
            "ci" => Ok(Scale::Ci),
            "default" => Ok(Scale::Default),
            "paper" => Ok(Scale::Paper),
            _ => Err(PlanError::UnknownScale(s.to_string())),
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PlanError {
    /// The scale name is none of ci, default, paper.
    #[error("unknown scale {0:?} (expected ci, default or paper)")]
    UnknownScale(String),
    /// A sampling parameter is out of range.
    #[error("bad plan parameter {field}: {why}")]
    Bad { field: &'static str, why: String },
}

/// Sampling of the three passes. Angles in radians, times in seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanConfig {
    pub scale: Scale,
    /// Laser colours measured (all three are mounted; selecting one is electronic).
    pub laser_colours: Vec<LaserColour>,
    /// Pass 1: laser clamp elevations on the light arc (must include the vertical, pi/2).
    pub clamp_elevations: Vec<f64>,
    /// Pass 1: light-arc rotations (evenly over the circle).
    pub entrance_arc_rotations: u32,
    /// Pass 1: turntable positions of the sparse views (evenly over the circle).
    pub entrance_turntable: u32,
    /// Pass 1: cameras of the sparse views.
    pub entrance_cameras: Vec<u8>,
    /// Pass 2: turntable positions (the light arc follows so the stripe direction is fixed).
    pub exiting_turntable: u32,
    /// Pass 3: light-arc rotations.
    pub reflectance_arc_rotations: u32,
    /// Pass 3: turntable positions.
    pub reflectance_turntable: u32,
    /// Passes 2 and 3: cameras.
    pub cameras: Vec<u8>,
    /// Pass 3: lamps.
    pub lamps: Vec<u8>,
    /// Laser scan positions per sweep, evenly over +-`scan_half_width_mm` on the plane.
    pub scan_positions: u16,
    /// Pass 1's scan positions, when not `scan_positions`. f(w_i) sums
    /// stripes over the sample, so a heterogeneous sample wants many lines;
    /// each feeds only a band flux, so the simulated rig renders them with
    /// fewer photons (`SimQuality::entrance_laser_photons`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub entrance_scan_positions: Option<u16>,
    pub scan_half_width_mm: f64,
    /// Exposure brackets, s. A pixel saturated in every exposure is lost
    /// with the texels it falls in, and those are the brightest (a cell
    /// wall's glint, a translucent material's hot spot), so the shortest
    /// lamp exposure must hold them: losing them biases the LRF low.
    pub laser_exposures: Vec<f64>,
    pub lamp_exposures: Vec<f64>,
    /// Sensor gain, dB.
    pub gain_db: f64,
    /// Laser drive, per mille of full power.
    pub laser_power_permille: u16,
    /// Sensor binning (1 = full 1024 x 768).
    pub binning: u32,
    /// Texel resolution of the rectified images (for the stages after capture).
    pub rectified_size: u32,
    /// Trigger pulse width, us.
    pub pulse_us: u32,
    /// A calibration capture: its steps come from here (`crate::cal_plan`),
    /// and the pass fields above are not used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<crate::cal_plan::CalPlanConfig>,
}

const DEG: f64 = PI / 180.0;

impl PlanConfig {
    /// The named scale's sampling.
    pub fn for_scale(scale: Scale) -> PlanConfig {
        let all_cams: Vec<u8> = NOMINAL_GEOMETRY
            .used_cameras()
            .map(|(i, _)| i as u8)
            .collect();
        let all_lamps: Vec<u8> = NOMINAL_GEOMETRY
            .used_lamps()
            .map(|(i, _)| i as u8)
            .collect();
        let base = PlanConfig {
            scale,
            laser_colours: LaserColour::ALL.to_vec(),
            clamp_elevations: NOMINAL_GEOMETRY.laser.positions.to_vec(),
            entrance_arc_rotations: 12,
            entrance_turntable: 4,
            entrance_cameras: vec![1, 3, 5, 7],
            exiting_turntable: 12,
            reflectance_arc_rotations: 12,
            reflectance_turntable: 12,
            cameras: all_cams,
            lamps: all_lamps,
            scan_positions: 32,
            entrance_scan_positions: None,
            scan_half_width_mm: 12.0,
            laser_exposures: vec![0.0000625, 0.0005, 0.002, 0.008, 0.032, 0.128],
            lamp_exposures: vec![0.001, 0.004, 0.016, 0.064],
            gain_db: 0.0,
            laser_power_permille: 1000,
            binning: 1,
            rectified_size: 256,
            pulse_us: 1000,
            calibration: None,
        };
        match scale {
            Scale::Paper => base,
            Scale::Default => PlanConfig {
                clamp_elevations: vec![30.0 * DEG, 60.0 * DEG, 90.0 * DEG],
                entrance_arc_rotations: 4,
                entrance_turntable: 2,
                entrance_cameras: vec![3, 7],
                exiting_turntable: 4,
                reflectance_arc_rotations: 4,
                reflectance_turntable: 4,
                scan_positions: 6,
                // One line per mm: a two-material sample's f(w_i), each
                // direction on its own, is within 1.6 % of the true
                // exitance ratio with 24, 3.6 % with 12 (docs/capture.md).
                entrance_scan_positions: Some(24),
                laser_exposures: vec![0.0000625, 0.0005, 0.004, 0.032],
                lamp_exposures: vec![0.001, 0.008, 0.064],
                binning: 4,
                rectified_size: 64,
                ..base
            },
            Scale::Ci => PlanConfig {
                clamp_elevations: vec![45.0 * DEG, 90.0 * DEG],
                entrance_arc_rotations: 2,
                entrance_turntable: 1,
                // Camera 3 sees the vertical stripes of pass 2 in the same
                // view, so f(w_i) compares like with like; camera 7 sees
                // the vertical laser's mirror reflection.
                entrance_cameras: vec![3, 7],
                exiting_turntable: 2,
                reflectance_arc_rotations: 1,
                reflectance_turntable: 2,
                cameras: vec![3, 5, 7],
                lamps: vec![2, 5],
                scan_positions: 3,
                // Three stripes 6 mm apart keep 10 mm of window on both
                // sides of each: f(w_i) compares whole bands.
                scan_half_width_mm: 6.0,
                laser_exposures: vec![0.0000625, 0.0005, 0.004, 0.032],
                lamp_exposures: vec![0.001, 0.008, 0.064],
                binning: 4,
                rectified_size: 48,
                ..base
            },
        }
    }

    /// Checks every field against the rig in hardware/; returns the first problem.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |field, why: &str| {
            Err(PlanError::Bad {
                field,
                why: why.to_string(),
            })
        };
        if self.laser_colours.is_empty() {
            return bad("laser_colours", "empty");
        }
        if self.clamp_elevations.is_empty()
            || !self.clamp_elevations.iter().any(|&e| is_vertical(e))
        {
            return bad("clamp_elevations", "must include the vertical (90 deg)");
        }
        if self
            .clamp_elevations
            .iter()
            .any(|e| !(5.0 * DEG..=90.0 * DEG + 1e-9).contains(e))
        {
            return bad("clamp_elevations", "must lie in 5..=90 deg");
        }
        for (field, n) in [
            ("entrance_arc_rotations", self.entrance_arc_rotations),
            ("entrance_turntable", self.entrance_turntable),
            ("exiting_turntable", self.exiting_turntable),
            ("reflectance_arc_rotations", self.reflectance_arc_rotations),
            ("reflectance_turntable", self.reflectance_turntable),
        ] {
            if n == 0 || n > 360 {
                return bad(field, "must be 1..=360");
            }
        }
        for (field, cams) in [
            ("entrance_cameras", &self.entrance_cameras),
            ("cameras", &self.cameras),
        ] {
            if cams.is_empty() || cams.iter().any(|&c| c >= 8) {
                return bad(field, "must list camera indices 0..8");
            }
        }
        if self.lamps.is_empty() || self.lamps.iter().any(|&l| l >= 8) {
            return bad("lamps", "must list lamp indices 0..8");
        }
        if self.scan_positions == 0 {
            return bad("scan_positions", "must be at least 1");
        }
        if self.entrance_scan_positions == Some(0) {
            return bad("entrance_scan_positions", "must be at least 1");
        }
        if !(0.0..=30.0).contains(&self.scan_half_width_mm) {
            return bad("scan_half_width_mm", "must be 0..=30 mm");
        }
        for (field, ex) in [
            ("laser_exposures", &self.laser_exposures),
            ("lamp_exposures", &self.lamp_exposures),
        ] {
            if ex.is_empty() || ex.iter().any(|&e| !(1e-5..=10.0).contains(&e)) {
                return bad(field, "must list exposures in 10 us..=10 s");
            }
        }
        if !(0.0..=48.0).contains(&self.gain_db) {
            return bad("gain_db", "must be 0..=48 dB");
        }
        if self.laser_power_permille == 0 || self.laser_power_permille > 1000 {
            return bad("laser_power_permille", "must be 1..=1000");
        }
        if ![1, 2, 4, 8, 16].contains(&self.binning) {
            return bad("binning", "must be 1, 2, 4, 8 or 16");
        }
        if self.rectified_size == 0 || self.rectified_size > 4096 {
            return bad("rectified_size", "must be 1..=4096");
        }
        if self.pulse_us == 0 || self.pulse_us > 100_000 {
            return bad("pulse_us", "must be 1..=100000 us");
        }
        for (field, ex) in [
            ("laser_exposures", &self.laser_exposures),
            ("lamp_exposures", &self.lamp_exposures),
        ] {
            if ex.windows(2).any(|w| w[1] <= w[0]) {
                return bad(field, "must be strictly increasing");
            }
        }
        Ok(())
    }

    /// Pass 1's clamp elevations off the vertical.
    pub fn oblique_elevations(&self) -> Vec<f64> {
        self.clamp_elevations
            .iter()
            .copied()
            .filter(|&e| !is_vertical(e))
            .collect()
    }

    /// Pass 1's scan positions per sweep.
    pub fn entrance_positions(&self) -> u16 {
        self.entrance_scan_positions.unwrap_or(self.scan_positions)
    }

    /// The (light-arc, turntable) rows pass 1 images at the vertical clamp:
    /// with no oblique position, every row (the vertical is
    /// all it measures); otherwise one per turntable angle and line
    /// direction of the oblique rows (the line lies across the light's
    /// azimuth, so arcs half a turn apart sweep the same lines), unless pass
    /// 2 sweeps the same lines there, in every entrance view.
    pub fn entrance_vertical_rows(&self) -> Vec<(f64, f64)> {
        let arcs = circle(self.entrance_arc_rotations, true);
        let turntable = circle(self.entrance_turntable, false);
        let all = || {
            arcs.iter()
                .flat_map(|&a| turntable.iter().map(move |&t| (a, t)))
                .collect()
        };
        if self.oblique_elevations().is_empty() {
            return all();
        }
        let same_lines = |a: f64, b: f64| ((a - b) / PI - ((a - b) / PI).round()).abs() < 1e-9;
        let pass_2_sweeps_them = self.entrance_positions() == self.scan_positions
            && self
                .entrance_cameras
                .iter()
                .all(|c| self.cameras.contains(c));
        let exiting = circle(self.exiting_turntable, false);
        let in_pass_2 = |arc: f64, tt: f64| {
            pass_2_sweeps_them
                && exiting
                    .iter()
                    .any(|&t| (t - tt).abs() < 1e-9 && same_lines(exiting_arc(t, self), arc))
        };
        let mut rows: Vec<(f64, f64)> = Vec::new();
        for &a in &arcs {
            for &t in &turntable {
                let seen = rows.iter().any(|&(ra, rt)| rt == t && same_lines(ra, a));
                if !seen && !in_pass_2(a, t) {
                    rows.push((a, t));
                }
            }
        }
        rows
    }

    /// Frame size the cameras deliver at this binning.
    pub fn frame_size(&self) -> (u32, u32) {
        let s = NOMINAL_GEOMETRY.sensor;
        (s.width / self.binning, s.height / self.binning)
    }
}

/// The light source of a step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Light {
    /// A galvo sweep of the selected laser: one trigger per galvo angle (mechanical, rad).
    Laser {
        colour: LaserColour,
        galvo: Vec<f64>,
    },
    /// One lamp on, one trigger.
    Lamp { lamp: u8 },
}

/// One rig configuration and one exposure; see the module docs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Step {
    pub index: u32,
    pub pass: Pass,
    /// Elevation the laser clamp must be at (None: the clamp does not matter).
    pub clamp_elevation: Option<f64>,
    pub turntable: f64,
    pub light_arc: f64,
    pub light: Light,
    pub exposure_index: u8,
    pub exposure_s: f64,
    pub cameras: Vec<u8>,
    /// A calibration step: its target, binning and procedure (`crate::cal_plan`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<crate::cal_plan::CalStep>,
}

impl Step {
    /// Sensor binning of this step's frames.
    pub fn binning(&self, config: &PlanConfig) -> u32 {
        self.calibration
            .as_ref()
            .map_or(config.binning, |c| c.binning)
    }
    /// Triggers this step fires.
    pub fn triggers(&self) -> usize {
        match &self.light {
            Light::Laser { galvo, .. } => galvo.len(),
            Light::Lamp { .. } => 1,
        }
    }
    /// Frames this step produces.
    pub fn frames(&self) -> usize {
        self.triggers() * self.cameras.len()
    }
    /// Camera trigger-line mask.
    pub fn camera_mask(&self) -> u8 {
        self.cameras.iter().fold(0u8, |m, &c| m | (1 << c))
    }
    /// Tag of the frame at scan position `k`: carried through the cameras and
    /// used (with the camera index) as the simulated sensor's noise seed.
    pub fn frame_tag(&self, k: usize) -> u64 {
        ((self.index as u64) << 16) | k as u64
    }
    /// Path of a frame relative to the capture directory.
    pub fn frame_path(&self, k: usize, camera: u8) -> String {
        format!(
            "frames/p{}/s{:06}_k{:03}_c{}.png",
            self.pass.number(),
            self.index,
            k,
            camera
        )
    }
}

/// The whole capture: configuration and ordered steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub config: PlanConfig,
    pub steps: Vec<Step>,
}

/// The clamp elevation of pass 2 (within the plan's tolerance).
fn is_vertical(elevation: f64) -> bool {
    (elevation - PI / 2.0).abs() < 1e-6
}

/// `n` angles evenly over the circle: for the arc symmetric about 0 and half
/// a step inside +-pi (its soft limits are +-(pi + 0.1), and its end switch
/// is just beyond: never run up to them), for the turntable from 0.
fn circle(n: u32, centred: bool) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let a = 2.0 * PI * i as f64 / n as f64;
            if centred { a - PI + PI / n as f64 } else { a }
        })
        .collect()
}

/// Galvo angles (mechanical, rad) putting the stripe at `n` positions over
/// +-half_width on the plane, for a laser clamped at `elevation`: evenly
/// spaced in angle, as the MCU's `GalvoSweep` steps. The mirror turns the beam
/// by twice its angle; a beam from distance D at elevation e moves its hit
/// point by about D * delta / sin(e) for a turn delta.
pub fn galvo_angles(n: u16, half_width_mm: f64, elevation: f64) -> Vec<f64> {
    let d = NOMINAL_GEOMETRY.laser.distance;
    let max = (0.5 * (half_width_mm * elevation.sin() / d).atan()).min(GALVO.max_angle);
    // Whole microradians, as the wire carries them.
    let urad = |a: f64| (a * 1e6).round() / 1e6;
    (0..n)
        .map(|k| {
            if n == 1 {
                0.0
            } else {
                urad(-max + 2.0 * max * k as f64 / (n - 1) as f64)
            }
        })
        .collect()
}

/// Pass 2's light-arc angle at turntable angle `tt`: it follows the
/// turntable, so the stripe crosses the sample the same way in every view.
fn exiting_arc(tt: f64, c: &PlanConfig) -> f64 {
    tt - PI + PI / c.exiting_turntable as f64
}

/// Serpentine order: even rows forward, odd rows backward.
fn serpentine(v: &[f64], row: usize) -> Vec<f64> {
    if row % 2 == 0 {
        v.to_vec()
    } else {
        v.iter().rev().copied().collect()
    }
}

impl Plan {
    pub fn new(config: PlanConfig) -> Result<Plan, PlanError> {
        config.validate()?;
        if let Some(cal) = &config.calibration {
            let steps = cal.steps()?;
            return Ok(Plan { config, steps });
        }
        let mut steps = Vec::new();
        let c = &config;
        let mut push = |pass, clamp, tt, arc, light: Light, exposures: &[f64], cams: &[u8]| {
            for (ei, &e) in exposures.iter().enumerate() {
                steps.push(Step {
                    index: 0,
                    pass,
                    clamp_elevation: clamp,
                    turntable: tt,
                    light_arc: arc,
                    light: light.clone(),
                    exposure_index: ei as u8,
                    exposure_s: e,
                    cameras: cams.to_vec(),
                    calibration: None,
                });
            }
        };
        // Pass 1: ascending elevations, ending at the vertical with the rows
        // its reference needs (module docs).
        let mut clamps = c.clamp_elevations.clone();
        clamps.sort_by(f64::total_cmp);
        clamps.dedup();
        let vertical_rows = c.entrance_vertical_rows();
        let mut row = 0;
        for (ci, &clamp) in clamps.iter().enumerate() {
            let galvo = galvo_angles(c.entrance_positions(), c.scan_half_width_mm, clamp);
            for arc in serpentine(&circle(c.entrance_arc_rotations, true), ci) {
                let tts: Vec<f64> = serpentine(&circle(c.entrance_turntable, false), row)
                    .into_iter()
                    .filter(|&tt| !is_vertical(clamp) || vertical_rows.contains(&(arc, tt)))
                    .collect();
                if tts.is_empty() {
                    continue;
                }
                for tt in tts {
                    for &colour in &c.laser_colours {
                        let light = Light::Laser {
                            colour,
                            galvo: galvo.clone(),
                        };
                        push(
                            Pass::Entrance,
                            Some(clamp),
                            tt,
                            arc,
                            light,
                            &c.laser_exposures,
                            &c.entrance_cameras,
                        );
                    }
                }
                row += 1;
            }
        }
        // Pass 2: the arc follows the turntable so the stripe crosses the sample
        // along the same direction in every view.
        let galvo = galvo_angles(c.scan_positions, c.scan_half_width_mm, PI / 2.0);
        for tt in circle(c.exiting_turntable, false) {
            for &colour in &c.laser_colours {
                let light = Light::Laser {
                    colour,
                    galvo: galvo.clone(),
                };
                push(
                    Pass::Exiting,
                    Some(PI / 2.0),
                    tt,
                    exiting_arc(tt, c),
                    light,
                    &c.laser_exposures,
                    &c.cameras,
                );
            }
        }
        // Pass 3: arc outermost (slow), turntable serpentine, lamps switched.
        // Pass 2 ended with both axes high, so pass 3 starts from the top.
        for (row, arc) in serpentine(&circle(c.reflectance_arc_rotations, true), 1)
            .into_iter()
            .enumerate()
        {
            for tt in serpentine(&circle(c.reflectance_turntable, false), row + 1) {
                for &lamp in &c.lamps {
                    push(
                        Pass::Reflectance,
                        None,
                        tt,
                        arc,
                        Light::Lamp { lamp },
                        &c.lamp_exposures,
                        &c.cameras,
                    );
                }
            }
        }
        for (i, s) in steps.iter_mut().enumerate() {
            s.index = i as u32;
        }
        Ok(Plan { config, steps })
    }

    pub fn frames(&self) -> usize {
        self.steps.iter().map(Step::frames).sum()
    }

    pub fn triggers(&self) -> usize {
        self.steps.iter().map(Step::triggers).sum()
    }

    /// Upper bound of the disk the frames need (8-bit RGB PNG, stored
    /// uncompressed in the worst case), bytes.
    pub fn disk_bytes(&self) -> u64 {
        let (w, h) = self.config.frame_size();
        // PNG worst case: raw rows plus a filter byte per row and container overhead.
        let per_frame = (w as u64 * 3 + 1) * h as u64 + 1024;
        per_frame * self.frames() as u64
    }

    /// Estimated rig time and the mechanical lower bound.
    pub fn timing(&self) -> Timing {
        let fps = NOMINAL_GEOMETRY.sensor.frame_rate;
        let frame_time = |e: f64| e.max(1.0 / fps);
        let mut t = Timing::default();
        // Homing both axes once, concurrently: fast approach over at most a
        // full turn would be the worst case; we are usually near home, so
        // charge the back-off and slow re-approach plus a quarter turn.
        t.homing_s = [TURNTABLE, LIGHT_ARC]
            .iter()
            .map(|a| {
                0.5 * PI / a.home_fast_speed
                    + 2.0 * a.home_backoff / a.home_slow_speed
                    + a.settle_time
            })
            .fold(0.0, f64::max);
        let mut tt = 0.0;
        let mut arc = 0.0;
        let mut clamp: Option<f64> = None;
        let mut colour = None;
        let mut lamp = None;
        let (mut tt_lo, mut tt_hi, mut arc_lo, mut arc_hi) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for s in &self.steps {
            if let Some(e) = s.clamp_elevation
                && clamp.is_none_or(|c| (c - e).abs() > 1e-9)
            {
                clamp = Some(e);
                t.operator_s += OPERATOR_CLAMP_S;
                t.lower_operator_s += OPERATOR_CLAMP_S;
            }
            let mv = |a: &AxisMechanics, from: f64, to: f64| {
                if (from - to).abs() < 1e-12 {
                    (0.0, 0.0)
                } else {
                    (
                        a.move_time(to - from, a.max_speed, a.max_accel),
                        a.settle_time,
                    )
                }
            };
            let (m_tt, s_tt) = mv(&TURNTABLE, tt, s.turntable);
            let (m_arc, s_arc) = mv(&LIGHT_ARC, arc, s.light_arc);
            if m_tt > 0.0 || m_arc > 0.0 {
                // Both axes move at once; the exposure waits for both to settle.
                t.motion_s += (m_tt + s_tt).max(m_arc + s_arc) + COMMAND_OVERHEAD_S * 3.0;
                t.moves += 1;
            }
            tt = s.turntable;
            arc = s.light_arc;
            tt_lo = tt_lo.min(tt);
            tt_hi = tt_hi.max(tt);
            arc_lo = arc_lo.min(arc);
            arc_hi = arc_hi.max(arc);
            let exposures = s.triggers() as f64 * frame_time(s.exposure_s);
            t.lower_exposure_s += exposures;
            match &s.light {
                Light::Laser { colour: c, galvo } => {
                    if colour != Some(*c) || lamp.is_some() {
                        t.switching_s += 4.0 * COMMAND_OVERHEAD_S;
                    }
                    colour = Some(*c);
                    lamp = None;
                    // Configure cameras, arm, sweep, wait for the frames.
                    t.exposure_s += exposures + galvo.len() as f64 * GALVO.settle_time;
                    t.switching_s += 3.0 * COMMAND_OVERHEAD_S;
                }
                Light::Lamp { lamp: l } => {
                    if lamp != Some(*l) {
                        t.switching_s += COMMAND_OVERHEAD_S;
                    }
                    if colour.is_some() {
                        t.switching_s += COMMAND_OVERHEAD_S;
                    }
                    colour = None;
                    lamp = Some(*l);
                    t.exposure_s += exposures;
                    t.switching_s += 3.0 * COMMAND_OVERHEAD_S;
                }
            }
        }
        // Unavoidable motion: each axis must at least travel from home over
        // the span of angles it visits, in one uninterrupted move.
        let span = |a: &AxisMechanics, lo: f64, hi: f64| {
            let d = (hi - lo) + lo.abs().min(hi.abs());
            a.move_time(d, a.max_speed, a.max_accel)
        };
        t.lower_motion_s = span(&TURNTABLE, tt_lo, tt_hi).max(span(&LIGHT_ARC, arc_lo, arc_hi));
        t
    }
}

/// Rig-time figures of a plan, seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub homing_s: f64,
    /// Axis moves with their settling.
    pub motion_s: f64,
    pub moves: usize,
    /// Exposures at the camera frame rate, galvo settling.
    pub exposure_s: f64,
    /// Laser/lamp switching and camera configuration commands.
    pub switching_s: f64,
    /// The operator moving the laser clamp.
    pub operator_s: f64,
    /// Lower bound parts: every trigger at the frame rate, the unavoidable
    /// travel of the busier axis, and the clamp moves.
    pub lower_exposure_s: f64,
    pub lower_motion_s: f64,
    pub lower_operator_s: f64,
}

impl Timing {
    pub fn estimate_s(&self) -> f64 {
        self.homing_s + self.motion_s + self.exposure_s + self.switching_s + self.operator_s
    }
    pub fn lower_bound_s(&self) -> f64 {
        self.lower_exposure_s + self.lower_motion_s + self.lower_operator_s
    }
    pub fn ratio(&self) -> f64 {
        self.estimate_s() / self.lower_bound_s()
    }
}

/// What `qhm capture plan` prints.
#[derive(Debug, Clone, Serialize)]
pub struct PlanSummary {
    pub scale: Scale,
    pub steps: usize,
    pub frames_per_pass: [usize; 3],
    pub frames: usize,
    pub triggers: usize,
    pub frame_size: (u32, u32),
    /// Camera frame rate the estimate assumes, Hz.
    pub frame_rate_hz: f64,
    pub disk_bytes: u64,
    pub timing: Timing,
    pub estimate_s: f64,
    pub lower_bound_s: f64,
    pub ratio: f64,
}

impl Plan {
    pub fn summary(&self) -> PlanSummary {
        let timing = self.timing();
        let mut per_pass = [0usize; 3];
        for s in &self.steps {
            if let Some(p) = (s.pass.number() as usize).checked_sub(1) {
                per_pass[p] += s.frames();
            }
        }
        PlanSummary {
            scale: self.config.scale,
            steps: self.steps.len(),
            frames_per_pass: per_pass,
            frames: self.frames(),
            triggers: self.triggers(),
            frame_size: self.config.frame_size(),
            frame_rate_hz: NOMINAL_GEOMETRY.sensor.frame_rate,
            disk_bytes: self.disk_bytes(),
            timing,
            estimate_s: timing.estimate_s(),
            lower_bound_s: timing.lower_bound_s(),
            ratio: timing.ratio(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scales_validate_and_count() {
        for scale in Scale::ALL {
            let plan = Plan::new(PlanConfig::for_scale(scale)).unwrap();
            let c = &plan.config;
            let p1_rows = c.oblique_elevations().len()
                * c.entrance_arc_rotations as usize
                * c.entrance_turntable as usize
                + c.entrance_vertical_rows().len();
            let p1 = p1_rows
                * c.laser_colours.len()
                * c.laser_exposures.len()
                * c.entrance_positions() as usize
                * c.entrance_cameras.len();
            let p2 = c.exiting_turntable as usize
                * c.laser_colours.len()
                * c.laser_exposures.len()
                * c.scan_positions as usize
                * c.cameras.len();
            let p3 = (c.reflectance_arc_rotations * c.reflectance_turntable) as usize
                * c.lamps.len()
                * c.lamp_exposures.len()
                * c.cameras.len();
            assert_eq!(plan.summary().frames_per_pass, [p1, p2, p3]);
            let t = plan.timing();
            assert!(
                t.ratio() >= 1.0,
                "{scale:?}: estimate below the lower bound"
            );
            assert!(t.ratio() < 2.0, "{scale:?}: ratio {}", t.ratio());
        }
    }

    #[test]
    fn paper_scale_matches_table_1() {
        let c = PlanConfig::for_scale(Scale::Paper);
        assert_eq!(c.reflectance_turntable as usize * c.cameras.len(), 12 * 7);
        assert_eq!(c.reflectance_arc_rotations as usize * c.lamps.len(), 12 * 7);
        assert_eq!(
            c.entrance_turntable as usize * c.entrance_cameras.len(),
            4 * 4
        );
        assert_eq!(c.rectified_size, 256);
    }

    #[test]
    fn order_minimises_motion() {
        let plan = Plan::new(PlanConfig::for_scale(Scale::Default)).unwrap();
        let steps = &plan.steps;
        // The clamp changes once per elevation, the last time into pass 2.
        let mut clamp_changes = 0;
        let mut arc_moves = 0;
        for w in steps.windows(2) {
            if let (Some(a), Some(b)) = (w[0].clamp_elevation, w[1].clamp_elevation)
                && a != b
            {
                clamp_changes += 1;
            }
            if w[0].light_arc != w[1].light_arc {
                arc_moves += 1;
            }
            // The turntable never swings back across more than one sampling interval
            // inside a pass (serpentine order).
            if w[0].pass == w[1].pass && w[0].light_arc == w[1].light_arc {
                let n = match w[0].pass {
                    Pass::Entrance => plan.config.entrance_turntable,
                    Pass::Exiting => plan.config.exiting_turntable,
                    Pass::Reflectance => plan.config.reflectance_turntable,
                    Pass::Calibration => unreachable!("a capture plan"),
                };
                assert!((w[0].turntable - w[1].turntable).abs() <= 2.0 * PI / n as f64 + 1e-9);
            }
        }
        assert_eq!(clamp_changes, plan.config.clamp_elevations.len() - 1);
        let c = &plan.config;
        // The slow axis moves at most once per arc row; serpentine order lets
        // consecutive rows (clamp positions, passes) share their end angle.
        let rows = (c.clamp_elevations.len() - 1) * c.entrance_arc_rotations as usize
            + c.exiting_turntable as usize
            + c.reflectance_arc_rotations as usize;
        assert!(
            arc_moves < rows - 1,
            "{arc_moves} arc moves for {rows} rows"
        );
        // Default scale: 8 oblique pass-1 rows at each of two clamp
        // positions sharing 1 end, 2 vertical reference rows (arcs) sharing
        // the other, 1 move into pass 2, 3 in pass 2, pass 3 starting where
        // pass 2 ended, 3 in pass 3.
        assert_eq!(arc_moves, 6 + 1 + 1 + 3 + 3);
        let p2 = steps.iter().find(|s| s.pass == Pass::Exiting).unwrap();
        let last_p1 = steps
            .iter()
            .rev()
            .find(|s| s.pass == Pass::Entrance)
            .unwrap();
        assert_eq!(last_p1.clamp_elevation, p2.clamp_elevation);
    }

    /// The oblique stripes' lines, and those of the vertical stripes in
    /// the same view: (turntable, line direction mod pi, galvo angles).
    fn lines(plan: &Plan) -> (Vec<(f64, f64, Vec<f64>)>, Vec<(f64, f64, Vec<f64>)>) {
        let (mut oblique, mut vertical) = (Vec::new(), Vec::new());
        let entrance_cams = &plan.config.entrance_cameras;
        for s in &plan.steps {
            let Light::Laser { galvo, .. } = &s.light else {
                continue;
            };
            let line = (
                s.turntable,
                (s.light_arc - s.turntable).rem_euclid(PI),
                galvo.clone(),
            );
            match s.clamp_elevation {
                Some(e) if !is_vertical(e) => oblique.push(line),
                _ if entrance_cams.iter().all(|c| s.cameras.contains(c)) => vertical.push(line),
                _ => {}
            }
        }
        (oblique, vertical)
    }

    #[test]
    fn every_oblique_line_has_a_vertical_one_in_its_views() {
        let same = |a: &(f64, f64, Vec<f64>), b: &(f64, f64, Vec<f64>)| {
            (a.0 - b.0).abs() < 1e-9
                && ((a.1 - b.1).abs() < 1e-9 || (PI - (a.1 - b.1).abs()).abs() < 1e-9)
                && a.2.len() == b.2.len()
        };
        for scale in Scale::ALL {
            let plan = Plan::new(PlanConfig::for_scale(scale)).unwrap();
            let (oblique, vertical) = lines(&plan);
            assert!(!oblique.is_empty());
            for o in &oblique {
                assert!(vertical.iter().any(|v| same(o, v)), "{scale:?}: {o:?}");
            }
        }
        // Pass 2 sweeps ci's lines in its views, so pass 1 images no vertical;
        // the default scale's 24 lines need 2 directions x 2 turntable angles.
        let vertical_rows = |scale| PlanConfig::for_scale(scale).entrance_vertical_rows().len();
        assert_eq!(vertical_rows(Scale::Ci), 0);
        assert_eq!(vertical_rows(Scale::Default), 4);
        assert_eq!(vertical_rows(Scale::Paper), 4 * 5);
        // An entrance camera pass 2 does not use: ci's row too.
        let mut c = PlanConfig::for_scale(Scale::Ci);
        c.cameras = vec![3, 5];
        assert_eq!(c.entrance_vertical_rows().len(), 1);
        // No oblique position: every row.
        let mut c = PlanConfig::for_scale(Scale::Ci);
        c.clamp_elevations = vec![PI / 2.0];
        assert_eq!(
            c.entrance_vertical_rows().len(),
            (c.entrance_arc_rotations * c.entrance_turntable) as usize
        );
    }

    #[test]
    fn angles_stay_inside_soft_limits() {
        let plan = Plan::new(PlanConfig::for_scale(Scale::Paper)).unwrap();
        for s in &plan.steps {
            assert!((TURNTABLE.soft_min..=TURNTABLE.soft_max).contains(&s.turntable));
            assert!((LIGHT_ARC.soft_min..=LIGHT_ARC.soft_max).contains(&s.light_arc));
            if let Light::Laser { galvo, .. } = &s.light {
                assert!(galvo.iter().all(|g| g.abs() <= GALVO.max_angle));
                assert!(galvo.windows(2).all(|w| w[1] > w[0]));
            }
        }
    }

    #[test]
    fn bad_configs_are_refused() {
        let mut c = PlanConfig::for_scale(Scale::Ci);
        c.clamp_elevations = vec![0.5];
        assert!(matches!(
            Plan::new(c),
            Err(PlanError::Bad {
                field: "clamp_elevations",
                ..
            })
        ));
        let mut c = PlanConfig::for_scale(Scale::Ci);
        c.cameras = vec![9];
        assert!(Plan::new(c).is_err());
        let mut c = PlanConfig::for_scale(Scale::Ci);
        c.laser_exposures = vec![0.01, 0.005];
        assert!(Plan::new(c).is_err());
        assert!("huge".parse::<Scale>().is_err());
    }

    #[test]
    fn frame_tags_and_paths_are_unique() {
        let plan = Plan::new(PlanConfig::for_scale(Scale::Default)).unwrap();
        let mut seen = std::collections::HashSet::new();
        for s in &plan.steps {
            for k in 0..s.triggers() {
                for &c in &s.cameras {
                    assert!(seen.insert(s.frame_path(k, c)));
                }
            }
        }
        assert_eq!(seen.len(), plan.frames());
    }
}
