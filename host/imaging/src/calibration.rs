//! The calibration file: one versioned TOML document that every
//! `qhm calibrate <step>` updates in place (its own section only) and that HDR
//! and rectification read. Layout in docs/imaging.md.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::camera::CameraModel;
use crate::response::ResponseCurve;
use crate::{Error, Result};

/// Value of `format`.
pub const FORMAT: &str = "qhm-calibration";
/// Version of the layout this code reads and writes.
pub const VERSION: u32 = 1;

/// Everything calibration found about the rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    pub format: String,
    pub version: u32,
    /// Where the calibration frames came from (informational).
    #[serde(default)]
    pub source: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turntable: Option<Turntable>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser: Option<LaserCal>,
    #[serde(default)]
    pub camera: Vec<CameraCal>,
    #[serde(default)]
    pub lamp: Vec<LampCal>,
}

/// The turntable's rotation axis (unit, world frame, through the origin).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Turntable {
    pub axis: [f64; 3],
}

/// One camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraCal {
    pub index: usize,
    /// Inverse response per channel (R, G, B).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub response: Vec<ResponseCurve>,
    /// Factor per channel taking this camera's linear values to the reference camera's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_gain: Option<[f64; 3]>,
    /// Intrinsics, distortion and world -> camera pose; pixel centres on integers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<CameraModel>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reprojection_rms_px: Option<f64>,
}

/// One lamp.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LampCal {
    pub index: usize,
    /// Unit vector towards the lamp at light-arc angle 0, world frame.
    pub direction: [f64; 3],
    /// Irradiance on a surface normal to the lamp, per channel, camera units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<[f64; 3]>,
}

/// The laser unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserCal {
    /// Angle between the laser plane and the XY plane at each clamp position
    /// measured, radians: (nominal clamp elevation, measured angle).
    #[serde(default)]
    pub plane_angles: Vec<[f64; 2]>,
    /// Flux per mm of stripe per laser channel (R, G, B) at full drive, camera units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flux_per_mm: Option<[f64; 3]>,
}

impl Default for Calibration {
    fn default() -> Self {
        Calibration {
            format: FORMAT.into(),
            version: VERSION,
            source: String::new(),
            turntable: None,
            laser: None,
            camera: Vec::new(),
            lamp: Vec::new(),
        }
    }
}

impl Calibration {
    /// Read and check a calibration file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.into(),
            source,
        })?;
        Self::from_toml(&text).map_err(|msg| Error::Format {
            path: path.into(),
            msg,
        })
    }

    /// Parse and check; the error names what is wrong.
    pub fn from_toml(text: &str) -> std::result::Result<Self, String> {
        let c: Calibration = toml::from_str(text).map_err(|e| e.to_string())?;
        if c.format != FORMAT {
            return Err(format!("format is {:?}, not {FORMAT:?}", c.format));
        }
        if c.version != VERSION {
            return Err(format!(
                "version {} is not supported (this qhm reads {VERSION})",
                c.version
            ));
        }
        for cam in &c.camera {
            for r in &cam.response {
                r.validate()
                    .map_err(|e| format!("camera {}: {e}", cam.index))?;
            }
            if !cam.response.is_empty() && cam.response.len() != 3 {
                return Err(format!(
                    "camera {}: {} response curves, want 3",
                    cam.index,
                    cam.response.len()
                ));
            }
            if let Some(g) = &cam.geometry {
                let k = &g.intrinsics;
                if !(k.fx > 0.0 && k.fy > 0.0) {
                    return Err(format!(
                        "camera {}: focal lengths must be positive",
                        cam.index
                    ));
                }
            }
        }
        Ok(c)
    }

    /// Load `path` if it exists, else start empty.
    pub fn load_or_default(path: &Path) -> Result<Self> {
        if path.exists() {
            Self::load(path)
        } else {
            Ok(Self::default())
        }
    }

    /// Write atomically (temporary file, then rename).
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = toml::to_string_pretty(self).map_err(|e| Error::Format {
            path: path.into(),
            msg: e.to_string(),
        })?;
        let tmp = path.with_extension("toml.tmp");
        std::fs::write(&tmp, text).map_err(|source| Error::Io {
            path: tmp.clone(),
            source,
        })?;
        std::fs::rename(&tmp, path).map_err(|source| Error::Io {
            path: path.into(),
            source,
        })
    }

    /// The entry of camera `index`, created if missing.
    pub fn camera_mut(&mut self, index: usize) -> &mut CameraCal {
        if let Some(i) = self.camera.iter().position(|c| c.index == index) {
            return &mut self.camera[i];
        }
        self.camera.push(CameraCal {
            index,
            response: Vec::new(),
            colour_gain: None,
            geometry: None,
            reprojection_rms_px: None,
        });
        self.camera.sort_by_key(|c| c.index);
        let i = self
            .camera
            .iter()
            .position(|c| c.index == index)
            .unwrap_or(0);
        &mut self.camera[i]
    }

    pub fn camera(&self, index: usize) -> Option<&CameraCal> {
        self.camera.iter().find(|c| c.index == index)
    }

    /// Turntable axis, +z when not calibrated.
    pub fn axis(&self) -> DVec3 {
        self.turntable
            .as_ref()
            .map_or(DVec3::Z, |t| DVec3::from(t.axis).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;

    #[test]
    fn round_trip_and_refusals() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("calibration.toml");
        let mut c = Calibration::default();
        c.source = "test".into();
        c.turntable = Some(Turntable {
            axis: [0.0, 0.001, 1.0],
        });
        let cam = c.camera_mut(3);
        cam.response = vec![ResponseCurve::linear_camera(); 3];
        cam.colour_gain = Some([1.0, 0.9, 1.1]);
        cam.geometry = Some(CameraModel::look_at(
            DVec3::new(300.0, 0.0, 300.0),
            DVec3::ZERO,
            DVec3::X,
            Intrinsics {
                fx: 5000.0,
                fy: 5000.0,
                cx: 511.5,
                cy: 383.5,
                k1: -0.1,
                k2: 0.0,
            },
        ));
        c.lamp.push(LampCal {
            index: 2,
            direction: [-0.9, 0.0, 0.43],
            irradiance: Some([1.0, 0.8, 0.6]),
        });
        c.laser = Some(LaserCal {
            plane_angles: vec![[1.2, 1.1985]],
            flux_per_mm: Some([1e-4, 2e-4, 3e-4]),
        });
        c.save(&p).unwrap();
        assert_eq!(Calibration::load(&p).unwrap(), c);

        let text = std::fs::read_to_string(&p).unwrap();
        let bad = text.replace("version = 1", "version = 99");
        assert!(
            Calibration::from_toml(&bad)
                .unwrap_err()
                .contains("version 99")
        );
        let bad = text.replace("qhm-calibration", "something-else");
        assert!(Calibration::from_toml(&bad).is_err());
        assert!(Calibration::from_toml("not toml [").is_err());
        std::fs::write(&p, "format = 3").unwrap();
        assert!(Calibration::load(&p).is_err());
    }
}
