//! The rectified dataset (written here, read by the model fitter):
//!
//! ```text
//! CAPTURE_DIR/rectified/index.toml   format "qhm-rectified", version 1, [grid], [[stripe]], [[lamp]]
//! CAPTURE_DIR/rectified/stripes/NNNNNN.exr, lamps/NNNNNN.exr
//! ```
//! EXR: RGB f32, outgoing radiance at each texel centre, NaN where not valid;
//! for stripes only the laser's channel is meaningful (others 0). Row j = 0 is
//! the EXR's first row; texel (i, j) centre = origin + (i + 0.5, j + 0.5) texel_mm.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::exr_io;
use crate::image::ImageF;
use crate::rectify::Grid;
use crate::{Error, Result};

pub const FORMAT: &str = "qhm-rectified";
pub const VERSION: u32 = 1;

/// `[grid]` of index.toml.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridEntry {
    pub width: usize,
    pub height: usize,
    pub texel_mm: f64,
    pub origin_mm: [f64; 2],
}

impl From<Grid> for GridEntry {
    fn from(g: Grid) -> Self {
        GridEntry {
            width: g.width,
            height: g.height,
            texel_mm: g.texel_mm,
            origin_mm: g.origin_mm,
        }
    }
}

impl From<GridEntry> for Grid {
    fn from(g: GridEntry) -> Self {
        Grid {
            width: g.width,
            height: g.height,
            texel_mm: g.texel_mm,
            origin_mm: g.origin_mm,
        }
    }
}

/// One rectified laser-stripe image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StripeEntry {
    pub file: String,
    /// 1 = entrance-function pass, 2 = vertical-stripe (dipole) pass.
    pub pass: u8,
    /// Laser colour: 0 red, 1 green, 2 blue.
    pub channel: usize,
    pub light_dir: [f64; 3],
    pub view_dir: [f64; 3],
    pub camera: usize,
    pub flux_per_mm: f64,
    pub line_point: [f64; 2],
    pub line_dir: [f64; 2],
}

/// One rectified lamp image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LampEntry {
    pub file: String,
    pub light_dir: [f64; 3],
    pub view_dir: [f64; 3],
    pub camera: usize,
    pub irradiance: [f64; 3],
}

/// index.toml.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Index {
    pub format: String,
    pub version: u32,
    pub grid: GridEntry,
    #[serde(default)]
    pub stripe: Vec<StripeEntry>,
    #[serde(default)]
    pub lamp: Vec<LampEntry>,
    /// What the calibration used held, in brief (the model fit keeps it for its report).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationSummary>,
}

/// `[calibration]` of index.toml (the reader's twin is qhm_model::rectified).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSummary {
    #[serde(default)]
    pub source: String,
    #[serde(default)]
    pub cameras: Vec<CameraSummary>,
    #[serde(default)]
    pub lamps: Vec<LampSummary>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_flux_per_mm: Option<[f64; 3]>,
    /// (nominal, measured) laser plane angle per clamp position, degrees.
    #[serde(default)]
    pub laser_plane_angles_deg: Vec<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turntable_axis: Option<[f64; 3]>,
}

/// One camera of a [`CalibrationSummary`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraSummary {
    pub index: usize,
    pub response: bool,
    pub geometry: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reprojection_rms_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_gain: Option<[f64; 3]>,
}

/// One lamp of a [`CalibrationSummary`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LampSummary {
    pub index: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<[f64; 3]>,
}

impl CalibrationSummary {
    pub fn of(cal: &crate::Calibration) -> Self {
        CalibrationSummary {
            source: cal.source.clone(),
            cameras: cal
                .camera
                .iter()
                .map(|c| CameraSummary {
                    index: c.index,
                    response: !c.response.is_empty(),
                    geometry: c.geometry.is_some(),
                    reprojection_rms_px: c.reprojection_rms_px,
                    colour_gain: c.colour_gain,
                })
                .collect(),
            lamps: cal
                .lamp
                .iter()
                .map(|l| LampSummary {
                    index: l.index,
                    irradiance: l.irradiance,
                })
                .collect(),
            laser_flux_per_mm: cal.laser.as_ref().and_then(|l| l.flux_per_mm),
            laser_plane_angles_deg: cal.laser.as_ref().map_or(Vec::new(), |l| {
                l.plane_angles
                    .iter()
                    .map(|a| a.map(f64::to_degrees))
                    .collect()
            }),
            turntable_axis: cal.turntable.as_ref().map(|t| t.axis),
        }
    }
}

/// Writes a rectified dataset incrementally; `finish` writes index.toml last,
/// so a directory with an index is complete.
pub struct Writer {
    root: PathBuf,
    index: Index,
}

impl Writer {
    /// Start `root` (CAPTURE_DIR/rectified); refuses a directory that already has an index.
    pub fn create(root: &Path, grid: Grid) -> Result<Self> {
        grid.validate()?;
        if root.join("index.toml").exists() {
            return Err(Error::Format {
                path: root.join("index.toml"),
                msg: "a rectified dataset is already there; pass --force to rectify again".into(),
            });
        }
        for sub in ["stripes", "lamps"] {
            std::fs::create_dir_all(root.join(sub)).map_err(|source| Error::Io {
                path: root.join(sub),
                source,
            })?;
        }
        Ok(Writer {
            root: root.to_path_buf(),
            index: Index {
                format: FORMAT.into(),
                version: VERSION,
                grid: grid.into(),
                stripe: Vec::new(),
                lamp: Vec::new(),
                calibration: None,
            },
        })
    }

    /// Records the calibration the images are rectified with.
    pub fn set_calibration(&mut self, cal: CalibrationSummary) {
        self.index.calibration = Some(cal);
    }

    fn check(&self, img: &ImageF) -> Result<()> {
        if img.width != self.index.grid.width || img.height != self.index.grid.height {
            return Err(Error::Input(format!(
                "rectified image {}x{} does not match the grid {}x{}",
                img.width, img.height, self.index.grid.width, self.index.grid.height
            )));
        }
        Ok(())
    }

    /// Add a stripe image; `entry.file` is filled in.
    pub fn add_stripe(&mut self, img: &ImageF, mut entry: StripeEntry) -> Result<()> {
        self.check(img)?;
        entry.file = stripe_file(self.index.stripe.len());
        exr_io::write_rgb(&self.root.join(&entry.file), img)?;
        self.index.stripe.push(entry);
        Ok(())
    }

    /// Add a lamp image; `entry.file` is filled in.
    pub fn add_lamp(&mut self, img: &ImageF, mut entry: LampEntry) -> Result<()> {
        self.check(img)?;
        entry.file = lamp_file(self.index.lamp.len());
        exr_io::write_rgb(&self.root.join(&entry.file), img)?;
        self.index.lamp.push(entry);
        Ok(())
    }

    pub fn finish(self) -> Result<Index> {
        write_index(&self.root, &self.index)?;
        Ok(self.index)
    }
}

/// The file of the `n`-th stripe image of a dataset (0-based).
pub fn stripe_file(n: usize) -> String {
    format!("stripes/{n:06}.exr")
}

/// The file of the `n`-th lamp image of a dataset (0-based).
pub fn lamp_file(n: usize) -> String {
    format!("lamps/{n:06}.exr")
}

/// Writes `root/index.toml` atomically (a temporary file, then a rename).
pub fn write_index(root: &Path, index: &Index) -> Result<()> {
    let p = root.join("index.toml");
    let text = toml::to_string_pretty(index).map_err(|e| Error::Format {
        path: p.clone(),
        msg: e.to_string(),
    })?;
    let tmp = root.join("index.toml.tmp");
    std::fs::write(&tmp, text).map_err(|source| Error::Io {
        path: tmp.clone(),
        source,
    })?;
    std::fs::rename(&tmp, &p).map_err(|source| Error::Io { path: p, source })
}

/// Read and check `root/index.toml`.
pub fn read_index(root: &Path) -> Result<Index> {
    let p = root.join("index.toml");
    let text = std::fs::read_to_string(&p).map_err(|source| Error::Io {
        path: p.clone(),
        source,
    })?;
    let idx: Index = toml::from_str(&text).map_err(|e| Error::Format {
        path: p.clone(),
        msg: e.to_string(),
    })?;
    if idx.format != FORMAT || idx.version != VERSION {
        return Err(Error::Format {
            path: p,
            msg: format!(
                "format {:?} version {}, want {FORMAT:?} version {VERSION}",
                idx.format, idx.version
            ),
        });
    }
    Grid::from(idx.grid).validate()?;
    Ok(idx)
}

/// Read one image of the dataset (a `file` of an entry), checked against the grid.
pub fn read_image(root: &Path, idx: &Index, file: &str) -> Result<ImageF> {
    if file.contains("..") || Path::new(file).is_absolute() {
        return Err(Error::Format {
            path: root.join("index.toml"),
            msg: format!("file {file:?} leaves the dataset"),
        });
    }
    let img = exr_io::read_rgb(&root.join(file))?;
    if img.width != idx.grid.width || img.height != idx.grid.height {
        return Err(Error::Format {
            path: root.join(file),
            msg: format!(
                "{}x{} image in a {}x{} grid",
                img.width, img.height, idx.grid.width, idx.grid.height
            ),
        });
    }
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn write_then_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("rectified");
        let grid = Grid::centred(8, 0.5);
        let mut w = Writer::create(&root, grid).unwrap();
        let mut img = ImageF::zeros(8, 8, 3);
        img.set(2, 3, 0, 1.5);
        img.set(0, 0, 0, f32::NAN);
        let entry = StripeEntry {
            file: String::new(),
            pass: 2,
            channel: 0,
            light_dir: [0.0, 0.0, 1.0],
            view_dir: [0.5, 0.0, 0.866],
            camera: 5,
            flux_per_mm: 1.2e-4,
            line_point: [0.1, -0.2],
            line_dir: [0.0, 1.0],
        };
        w.add_stripe(&img, entry.clone()).unwrap();
        let cal = CalibrationSummary {
            source: "test".into(),
            cameras: vec![CameraSummary {
                index: 5,
                response: true,
                geometry: true,
                reprojection_rms_px: Some(0.2),
                colour_gain: Some([1.0, 0.99, 1.01]),
            }],
            lamps: vec![LampSummary {
                index: 7,
                irradiance: Some([2.0; 3]),
            }],
            laser_flux_per_mm: Some([1.0, 2.0, 3.0]),
            laser_plane_angles_deg: vec![[60.0, 59.9]],
            turntable_axis: None,
        };
        w.set_calibration(cal.clone());
        w.add_lamp(
            &img,
            LampEntry {
                file: String::new(),
                light_dir: [0.0, 0.0, 1.0],
                view_dir: [0.0, 0.0, 1.0],
                camera: 7,
                irradiance: [1.0; 3],
            },
        )
        .unwrap();
        assert!(
            w.add_lamp(
                &ImageF::zeros(4, 4, 3),
                LampEntry {
                    file: String::new(),
                    light_dir: [0.0; 3],
                    view_dir: [0.0; 3],
                    camera: 0,
                    irradiance: [0.0; 3]
                }
            )
            .is_err()
        );
        w.finish().unwrap();
        let idx = read_index(&root).unwrap();
        assert_eq!(idx.stripe.len(), 1);
        assert_eq!(idx.calibration.as_ref(), Some(&cal));
        assert_eq!(idx.stripe[0].file, "stripes/000000.exr");
        assert_eq!(idx.grid.origin_mm, [-2.0, -2.0]);
        let back = read_image(&root, &idx, &idx.stripe[0].file).unwrap();
        assert_eq!(back.get(2, 3, 0), 1.5);
        assert!(back.get(0, 0, 0).is_nan());
        assert!(read_image(&root, &idx, "../x.exr").is_err());
        assert!(
            Writer::create(&root, grid).is_err(),
            "an existing dataset is not overwritten"
        );
    }
}
