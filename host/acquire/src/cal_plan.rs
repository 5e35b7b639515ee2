//! The calibration capture: every frame the calibration procedures need
//! (docs/imaging.md), as a plan of ordinary [`Step`]s that `run_capture`
//! executes into a capture directory like any other (journal, `--resume`,
//! progress), on a real rig or the simulated one alike.
//!
//! Steps, in the order that asks the operator least (a target is put on the
//! turntable once, the laser clamp moves once per elevation):
//!
//! 1. colour pattern under the target lamp: the response brackets (every
//!    camera, many exposures), then the colour bracket (finer binning);
//! 2. checkerboard on the turntable at every board angle, then on the spacer
//!    of known thickness at the same angles (finer binning);
//! 3. reference white: each lamp (the reference camera), then the laser
//!    stripe of each colour with the clamp vertical (flux);
//! 4. two-height target under the laser at every clamp elevation, light arc
//!    and turntable turned by `plane_arc` (the laser-plane camera).
//!
//! Each step carries a [`CalStep`]: what must be on the turntable, the
//! binning, and which procedure its frames feed. A step is one exposure of a
//! bracket, as in the capture plan.

use std::f64::consts::PI;

use hardware::NOMINAL_GEOMETRY;
use protocol::LaserColour;
use serde::{Deserialize, Serialize};

use crate::plan::{Light, Pass, Plan, PlanConfig, PlanError, Scale, Step, Timing};

/// Time the operator needs to put a target on the turntable (estimate), s.
pub const OPERATOR_TARGET_S: f64 = 60.0;

/// Calibration targets, as the operator is asked for them.
pub const COLOUR_PATTERN: &str = "colour-pattern";
pub const CHECKERBOARD: &str = "checkerboard";
pub const WHITE: &str = "white";
pub const TWO_HEIGHT: &str = "two-height";

/// The checkerboard raised on the spacer block of `mm` thickness.
pub fn checkerboard_on_spacer(mm: f64) -> String {
    format!("checkerboard on the {mm} mm spacer")
}

/// Parses [`checkerboard_on_spacer`]'s name back to the thickness, mm.
pub fn spacer_of(target: &str) -> Option<f64> {
    target
        .strip_prefix("checkerboard on the ")?
        .strip_suffix(" mm spacer")?
        .parse()
        .ok()
}

/// Which procedure a calibration step's frames feed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Procedure {
    /// Camera response (Mitsunaga-Nayar) from exposure brackets.
    Response,
    /// Zhang's intrinsics, distortion and poses, and the turntable axis.
    Geometry,
    /// Relative colour of the cameras.
    Colour,
    /// Lamp irradiance.
    Lamp,
    /// Laser-plane angle at a clamp elevation.
    LaserPlane,
    /// Laser flux per mm of stripe.
    LaserFlux,
}

/// The calibration part of a [`Step`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalStep {
    pub procedure: Procedure,
    /// What the operator must have put on the turntable.
    pub target: String,
    /// Height of the target's top surface above the turntable, mm.
    pub height_mm: f64,
    /// Sensor binning of the frames.
    pub binning: u32,
}

/// What the calibration capture takes. Angles in radians, times in seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalPlanConfig {
    /// Binning of the response, lamp and laser frames.
    pub binning: u32,
    /// Binning of the checkerboard and colour-pattern frames (corners and
    /// patch edges need pixels).
    pub fine_binning: u32,
    /// Cameras calibrated.
    pub cameras: Vec<u8>,
    /// The camera the others' colour is relative to, and that measures the
    /// lamps and the laser flux.
    pub reference_camera: u8,
    /// The camera that measures the laser-plane angles.
    pub plane_camera: u8,
    /// The lamp lighting the colour pattern and the checkerboard.
    pub target_lamp: u8,
    pub response_exposures: Vec<f64>,
    pub colour_exposures: Vec<f64>,
    /// Turntable angles of the checkerboard views (on the turntable and on the spacer).
    pub board_turntable: Vec<f64>,
    pub board_exposure: f64,
    /// Thickness of the spacer block, mm.
    pub spacer_mm: f64,
    /// Lamps measured on the reference white.
    pub lamps: Vec<u8>,
    pub lamp_exposures: Vec<f64>,
    /// Laser bracket (the stripe on white clips above ~0.1 ms at full power;
    /// it starts at 10 us, the shortest exposure many GenICam cameras take).
    pub laser_exposures: Vec<f64>,
    /// Clamp elevations of the laser-plane measurement.
    pub plane_elevations: Vec<f64>,
    /// Light-arc and turntable angle of the laser-plane measurement: the
    /// stripe crosses the image rows and runs along the target's step.
    pub plane_arc: f64,
}

impl CalPlanConfig {
    /// The calibration capture at a scale: binned 4 (2 for the checkerboard
    /// and colour pattern) for ci and default, full resolution for paper.
    pub fn for_scale(scale: Scale) -> CalPlanConfig {
        let g = NOMINAL_GEOMETRY;
        let (binning, fine_binning) = match scale {
            Scale::Ci | Scale::Default => (4, 2),
            Scale::Paper => (1, 1),
        };
        let cameras: Vec<u8> = g.used_cameras().map(|(i, _)| i as u8).collect();
        CalPlanConfig {
            binning,
            fine_binning,
            reference_camera: *cameras.last().unwrap_or(&7),
            plane_camera: 4,
            cameras,
            target_lamp: 7,
            response_exposures: vec![0.002, 0.005, 0.0125, 0.03, 0.075, 0.2],
            colour_exposures: vec![0.005, 0.02, 0.08],
            board_turntable: (0..6).map(|i| i as f64 * PI / 3.0 + 0.2).collect(),
            board_exposure: 0.03,
            spacer_mm: 20.0,
            lamps: g.used_lamps().map(|(i, _)| i as u8).collect(),
            lamp_exposures: vec![0.01, 0.04, 0.16, 0.64],
            laser_exposures: vec![1e-5, 4e-5, 1.6e-4, 6.4e-4, 2.56e-3],
            plane_elevations: g.laser.positions.to_vec(),
            plane_arc: 30.0 * PI / 180.0,
        }
    }

    /// The [`PlanConfig`] of a calibration capture at `scale`: the capture
    /// settings (gain, laser power, trigger pulse) of the scale's plan, the
    /// steps from this.
    pub fn plan_config(scale: Scale) -> PlanConfig {
        PlanConfig {
            calibration: Some(CalPlanConfig::for_scale(scale)),
            ..PlanConfig::for_scale(scale)
        }
    }

    /// Checks every field; returns the first problem.
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |field, why: &str| {
            Err(PlanError::Bad {
                field,
                why: why.to_string(),
            })
        };
        for (field, b) in [
            ("binning", self.binning),
            ("fine_binning", self.fine_binning),
        ] {
            if ![1, 2, 4, 8, 16].contains(&b) {
                return bad(field, "must be 1, 2, 4, 8 or 16");
            }
        }
        if self.cameras.is_empty() || self.cameras.iter().any(|&c| c >= 8) {
            return bad("cameras", "must list camera indices 0..8");
        }
        for (field, c) in [
            ("reference_camera", self.reference_camera),
            ("plane_camera", self.plane_camera),
        ] {
            if !self.cameras.contains(&c) {
                return bad(field, "must be one of the cameras");
            }
        }
        if self.target_lamp >= 8 || self.lamps.iter().any(|&l| l >= 8) {
            return bad("lamps", "must be lamp indices 0..8");
        }
        for (field, ex) in [
            ("response_exposures", &self.response_exposures),
            ("colour_exposures", &self.colour_exposures),
            ("lamp_exposures", &self.lamp_exposures),
            ("laser_exposures", &self.laser_exposures),
        ] {
            if ex.len() < 2 || ex.iter().any(|&e| !(1e-6..=10.0).contains(&e)) {
                return bad(field, "must list at least 2 exposures in 1 us..=10 s");
            }
            if ex.windows(2).any(|w| w[1] <= w[0]) {
                return bad(field, "must be strictly increasing");
            }
        }
        if !(1e-6..=10.0).contains(&self.board_exposure) {
            return bad("board_exposure", "must be 1 us..=10 s");
        }
        if self.board_turntable.len() < 2 {
            return bad("board_turntable", "needs at least 2 views");
        }
        if !(self.spacer_mm > 0.0 && self.spacer_mm <= 100.0) {
            return bad("spacer_mm", "must be in (0, 100] mm");
        }
        if self.plane_elevations.is_empty()
            || self
                .plane_elevations
                .iter()
                .any(|e| !(5.0f64.to_radians()..=PI / 2.0 + 1e-9).contains(e))
        {
            return bad("plane_elevations", "must lie in 5..=90 deg");
        }
        if !(0.0..=PI / 2.0).contains(&self.plane_arc) {
            return bad("plane_arc", "must be 0..=90 deg");
        }
        Ok(())
    }

    /// The steps, in order, indexed; see the module docs.
    pub fn steps(&self) -> Result<Vec<Step>, PlanError> {
        self.validate()?;
        let mut steps = Vec::new();
        let mut push = |procedure,
                        target: &str,
                        height_mm,
                        binning,
                        (clamp, tt, arc): (Option<f64>, f64, f64),
                        light: Light,
                        exposures: &[f64],
                        cameras: &[u8]| {
            for (ei, &e) in exposures.iter().enumerate() {
                steps.push(Step {
                    index: steps.len() as u32,
                    pass: Pass::Calibration,
                    clamp_elevation: clamp,
                    turntable: tt,
                    light_arc: arc,
                    light: light.clone(),
                    exposure_index: ei as u8,
                    exposure_s: e,
                    cameras: cameras.to_vec(),
                    calibration: Some(CalStep {
                        procedure,
                        target: target.to_string(),
                        height_mm,
                        binning,
                    }),
                });
            }
        };
        let lamp = Light::Lamp {
            lamp: self.target_lamp,
        };
        let home = (None, 0.0, 0.0);
        let (b, fine) = (self.binning, self.fine_binning);
        let cams = &self.cameras;
        let one = |c: u8| vec![c];
        // 1. Colour pattern.
        for (procedure, binning, exposures) in [
            (Procedure::Response, b, &self.response_exposures),
            (Procedure::Colour, fine, &self.colour_exposures),
        ] {
            let light = lamp.clone();
            push(
                procedure,
                COLOUR_PATTERN,
                0.0,
                binning,
                home,
                light,
                exposures,
                cams,
            );
        }
        // 2. Checkerboard, on the turntable then on the spacer.
        let spacer = checkerboard_on_spacer(self.spacer_mm);
        for (target, height) in [(CHECKERBOARD, 0.0), (spacer.as_str(), self.spacer_mm)] {
            for &tt in &self.board_turntable {
                push(
                    Procedure::Geometry,
                    target,
                    height,
                    fine,
                    (None, tt, 0.0),
                    lamp.clone(),
                    std::slice::from_ref(&self.board_exposure),
                    cams,
                );
            }
        }
        // 3. Reference white: lamps, then the vertical stripe of each laser.
        let reference = one(self.reference_camera);
        for &l in &self.lamps {
            push(
                Procedure::Lamp,
                WHITE,
                0.0,
                b,
                home,
                Light::Lamp { lamp: l },
                &self.lamp_exposures,
                &reference,
            );
        }
        for colour in LaserColour::ALL {
            push(
                Procedure::LaserFlux,
                WHITE,
                0.0,
                b,
                (Some(PI / 2.0), 0.0, 0.0),
                Light::Laser {
                    colour,
                    galvo: vec![0.0],
                },
                &self.laser_exposures,
                &reference,
            );
        }
        // 4. Two-height target, the clamp from the vertical down.
        let mut elevations = self.plane_elevations.clone();
        elevations.sort_by(|a, b| b.total_cmp(a));
        elevations.dedup();
        for elev in elevations {
            push(
                Procedure::LaserPlane,
                TWO_HEIGHT,
                0.0,
                b,
                (Some(elev), self.plane_arc, self.plane_arc),
                Light::Laser {
                    colour: LaserColour::ALL[0],
                    galvo: vec![0.0],
                },
                &self.laser_exposures,
                &one(self.plane_camera),
            );
        }
        Ok(steps)
    }
}

/// Rig time of a calibration plan: the capture estimate and its lower bound
/// (`Plan::timing`), with the operator's target changes added to both.
pub fn timing(plan: &Plan) -> Timing {
    let mut t = plan.timing();
    let mut last: Option<&str> = None;
    for s in &plan.steps {
        if let Some(c) = &s.calibration
            && last != Some(c.target.as_str())
        {
            last = Some(c.target.as_str());
            t.operator_s += OPERATOR_TARGET_S;
            t.lower_operator_s += OPERATOR_TARGET_S;
        }
    }
    t
}

/// Targets in the order the operator is asked for them.
pub fn targets(plan: &Plan) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for c in plan.steps.iter().filter_map(|s| s.calibration.as_ref()) {
        if out.last() != Some(&c.target) {
            out.push(c.target.clone());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_builds_and_orders_targets() {
        for scale in Scale::ALL {
            let plan = Plan::new(CalPlanConfig::plan_config(scale)).unwrap();
            let c = CalPlanConfig::for_scale(scale);
            assert_eq!(
                targets(&plan),
                [
                    COLOUR_PATTERN.to_string(),
                    CHECKERBOARD.into(),
                    checkerboard_on_spacer(c.spacer_mm),
                    WHITE.into(),
                    TWO_HEIGHT.into()
                ]
            );
            assert!(
                plan.steps
                    .iter()
                    .enumerate()
                    .all(|(i, s)| s.index as usize == i)
            );
            let frames = |p: Procedure| -> usize {
                (plan.steps.iter())
                    .filter(|s| s.calibration.as_ref().unwrap().procedure == p)
                    .map(Step::frames)
                    .sum()
            };
            let n = c.cameras.len();
            assert_eq!(frames(Procedure::Response), n * c.response_exposures.len());
            assert_eq!(frames(Procedure::Geometry), 2 * n * c.board_turntable.len());
            assert_eq!(
                frames(Procedure::LaserPlane),
                c.plane_elevations.len() * c.laser_exposures.len()
            );
            // The clamp moves once per elevation: flux and the first plane
            // elevation share the vertical.
            let mut moves = 0;
            let mut clamp = None;
            for s in &plan.steps {
                if s.clamp_elevation.is_some() && s.clamp_elevation != clamp {
                    moves += 1;
                    clamp = s.clamp_elevation;
                }
            }
            assert_eq!(moves, c.plane_elevations.len());
            let t = timing(&plan);
            assert!(
                t.ratio() >= 1.0 && t.ratio() < 2.0,
                "{scale:?}: {}",
                t.ratio()
            );
            assert_eq!(
                t.operator_s,
                plan.timing().operator_s + 5.0 * OPERATOR_TARGET_S
            );
        }
    }

    #[test]
    fn the_plan_survives_the_manifest() {
        let config = CalPlanConfig::plan_config(Scale::Default);
        let text = toml::to_string(&config).unwrap();
        let back: PlanConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, config);
        assert_eq!(Plan::new(back).unwrap(), Plan::new(config).unwrap());
        // A capture plan's manifest has no calibration table.
        let capture = PlanConfig::for_scale(Scale::Ci);
        assert!(!toml::to_string(&capture).unwrap().contains("calibration"));
    }

    #[test]
    fn spacer_names_round_trip_and_bad_configs_are_refused() {
        assert_eq!(spacer_of(&checkerboard_on_spacer(20.0)), Some(20.0));
        assert_eq!(spacer_of(&checkerboard_on_spacer(12.5)), Some(12.5));
        assert_eq!(spacer_of(CHECKERBOARD), None);
        let mut c = CalPlanConfig::for_scale(Scale::Ci);
        c.plane_camera = 0;
        assert!(c.steps().is_err());
        let mut c = CalPlanConfig::for_scale(Scale::Ci);
        c.laser_exposures = vec![1e-3, 1e-4];
        assert!(c.steps().is_err());
        let mut c = CalPlanConfig::for_scale(Scale::Ci);
        c.fine_binning = 3;
        assert!(c.steps().is_err());
    }
}
