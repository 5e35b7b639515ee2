//! The rectified dataset: what rectification (qhm-imaging) writes and the
//! fit (qhm-model) reads, defined once.
//!
//! ```text
//! CAPTURE_DIR/rectified/index.toml          format "qhm-rectified", version 1, [grid], [[stripe]], [[lamp]], [calibration]
//! CAPTURE_DIR/rectified/stripes/NNNNNN.exr  one laser-stripe image each
//! CAPTURE_DIR/rectified/lamps/NNNNNN.exr    one lamp image each
//! ```
//! Images: RGB f32 EXR of outgoing radiance per texel (W sr^-1 mm^-2 in
//! camera units), NaN where not valid; for stripes only the laser's channel
//! is meaningful (the others 0). Row j = 0 is the EXR's first row; texel
//! (i, j)'s centre is origin + (i + 0.5, j + 0.5) texel_mm in the sample
//! frame. index.toml is written last, so a directory with one is complete.

use std::path::{Component, Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::FormatError;
use crate::exr;
use crate::image::RgbImage;

/// Value of `format`.
pub const FORMAT: &str = "qhm-rectified";
/// The layout this code reads and writes.
pub const VERSION: u32 = 1;
/// The dataset's folder inside a capture directory.
pub const DIR: &str = "rectified";
/// The index's file name inside the dataset.
pub const INDEX: &str = "index.toml";

/// `[grid]`: the reference-plane texel grid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub width: u32,
    pub height: u32,
    pub texel_mm: f64,
    /// Sample-frame xy of texel (0, 0)'s outer corner, mm.
    pub origin_mm: [f64; 2],
}

impl Grid {
    /// Sample-frame xy of texel (i, j)'s centre.
    pub fn centre(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.origin_mm[0] + (i as f64 + 0.5) * self.texel_mm,
            self.origin_mm[1] + (j as f64 + 0.5) * self.texel_mm,
        ]
    }

    /// Whether an image has this grid's size.
    pub fn fits(&self, width: usize, height: usize) -> bool {
        (width, height) == (self.width as usize, self.height as usize)
    }
}

/// `[[stripe]]`: a laser-stripe image (pass 1: entrance function, pass 2:
/// vertical stripes, the dipole).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StripeEntry {
    /// The image, relative to the dataset (`stripes/NNNNNN.exr`).
    pub file: String,
    pub pass: u8,
    /// Laser colour: 0 red, 1 green, 2 blue.
    pub channel: u8,
    /// Unit vector towards the laser, sample frame.
    pub light_dir: [f64; 3],
    /// Unit vector towards the camera, sample frame.
    pub view_dir: [f64; 3],
    pub camera: u32,
    /// W per mm of stripe length (camera units).
    pub flux_per_mm: f64,
    /// A point of the stripe's centre line and its unit direction, sample-frame mm.
    pub line_point: [f64; 2],
    pub line_dir: [f64; 2],
}

impl StripeEntry {
    /// Distance (mm) of a sample-frame point from the stripe's centre line.
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        self.signed_distance(p).abs()
    }

    /// Signed distance (mm) from the centre line, positive along the normal
    /// (line_dir.y, -line_dir.x).
    pub fn signed_distance(&self, p: [f64; 2]) -> f64 {
        let (dx, dy) = (p[0] - self.line_point[0], p[1] - self.line_point[1]);
        dx * self.line_dir[1] - dy * self.line_dir[0]
    }
}

/// `[[lamp]]`: a halogen-lamp image (pass 3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LampEntry {
    /// The image, relative to the dataset (`lamps/NNNNNN.exr`).
    pub file: String,
    pub light_dir: [f64; 3],
    pub view_dir: [f64; 3],
    pub camera: u32,
    /// W/mm² on a surface normal to the lamp, per channel (camera units).
    pub irradiance: [f64; 3],
}

/// `index.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Index {
    pub format: String,
    pub version: u32,
    pub grid: Grid,
    #[serde(default)]
    pub stripe: Vec<StripeEntry>,
    #[serde(default)]
    pub lamp: Vec<LampEntry>,
    /// The calibration the images were rectified with (absent in datasets
    /// rectified before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationSummary>,
}

/// `[calibration]` of index.toml: what the rectification's calibration held,
/// in brief. The fit copies it into fit.json and the report shows it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSummary {
    /// The calibration file's `source` (where its frames came from).
    #[serde(default)]
    pub source: String,
    #[serde(default)]
    pub cameras: Vec<CameraSummary>,
    #[serde(default)]
    pub lamps: Vec<LampSummary>,
    /// Laser flux per mm of stripe at full drive (R, G, B), camera units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_flux_per_mm: Option<[f64; 3]>,
    /// Laser plane angle per clamp position: (nominal, measured), degrees.
    #[serde(default)]
    pub laser_plane_angles_deg: Vec<[f64; 2]>,
    /// The turntable's rotation axis (unit, world frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turntable_axis: Option<[f64; 3]>,
}

/// One camera of a [`CalibrationSummary`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraSummary {
    pub index: usize,
    /// Whether its response curves were calibrated.
    #[serde(default)]
    pub response: bool,
    /// Whether its intrinsics and pose were calibrated.
    #[serde(default)]
    pub geometry: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reprojection_rms_px: Option<f64>,
    /// Factor per channel to the reference camera's linear values.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_gain: Option<[f64; 3]>,
}

/// One lamp of a [`CalibrationSummary`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LampSummary {
    pub index: usize,
    /// Irradiance normal to the lamp per channel, camera units.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub irradiance: Option<[f64; 3]>,
}

impl Index {
    /// An empty index of this format and version over `grid`.
    pub fn new(grid: Grid) -> Index {
        Index {
            format: FORMAT.into(),
            version: VERSION,
            grid,
            stripe: Vec::new(),
            lamp: Vec::new(),
            calibration: None,
        }
    }

    /// Checks format, version, grid and every entry; the message names the
    /// first entry and field that is wrong.
    pub fn validate(&self) -> Result<(), String> {
        if self.format != FORMAT {
            return Err(format!("format is `{}`, expected `{FORMAT}`", self.format));
        }
        if self.version != VERSION {
            return Err(format!(
                "unsupported version {}; this qhm reads {VERSION}",
                self.version
            ));
        }
        let g = &self.grid;
        if g.width == 0 || g.height == 0 || !(g.texel_mm.is_finite() && g.texel_mm > 0.0) {
            return Err(format!(
                "grid {}×{} texels of {} mm is empty",
                g.width, g.height, g.texel_mm
            ));
        }
        if !g.origin_mm.iter().all(|x| x.is_finite()) {
            return Err(format!("grid origin {:?} is not finite", g.origin_mm));
        }
        for (k, s) in self.stripe.iter().enumerate() {
            let what = format!("stripe {k} ({})", s.file);
            if !(s.pass == 1 || s.pass == 2) {
                return Err(format!("{what}: pass {} is not 1 or 2", s.pass));
            }
            if s.channel > 2 {
                return Err(format!("{what}: channel {} is not 0, 1 or 2", s.channel));
            }
            if !unit3(&s.light_dir) || !unit3(&s.view_dir) {
                return Err(format!(
                    "{what}: light_dir and view_dir must be unit vectors"
                ));
            }
            let ld = (s.line_dir[0].powi(2) + s.line_dir[1].powi(2)).sqrt();
            if (ld - 1.0).abs() > 1e-3 {
                return Err(format!(
                    "{what}: line_dir {:?} is not a unit vector",
                    s.line_dir
                ));
            }
            if !(s.flux_per_mm.is_finite() && s.flux_per_mm > 0.0) {
                return Err(format!(
                    "{what}: flux_per_mm = {} must be > 0 (was the laser flux calibrated?)",
                    s.flux_per_mm
                ));
            }
            if !(s.line_point.iter().all(|x| x.is_finite())) {
                return Err(format!("{what}: line_point is not finite"));
            }
        }
        for (k, l) in self.lamp.iter().enumerate() {
            let what = format!("lamp {k} ({})", l.file);
            if !unit3(&l.light_dir) || !unit3(&l.view_dir) {
                return Err(format!(
                    "{what}: light_dir and view_dir must be unit vectors"
                ));
            }
            if !l.irradiance.iter().all(|e| e.is_finite() && *e > 0.0) {
                return Err(format!(
                    "{what}: irradiance {:?} must be > 0 (was the lamp calibrated?)",
                    l.irradiance
                ));
            }
        }
        Ok(())
    }
}

fn unit3(v: &[f64; 3]) -> bool {
    ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 1e-3
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
pub fn write_index(root: &Path, index: &Index) -> Result<(), FormatError> {
    let p = root.join(INDEX);
    let text = toml::to_string_pretty(index).map_err(|e| FormatError::Toml {
        path: p.clone(),
        message: e.to_string(),
    })?;
    let tmp = root.join("index.toml.tmp");
    std::fs::write(&tmp, text).map_err(|e| FormatError::io(&tmp, e))?;
    std::fs::rename(&tmp, &p).map_err(|e| FormatError::io(&p, e))
}

/// Reads `root/index.toml` and checks it ([`Index::validate`]).
pub fn read_index(root: &Path) -> Result<Index, FormatError> {
    let p = root.join(INDEX);
    let text = std::fs::read_to_string(&p).map_err(|e| FormatError::io(&p, e))?;
    let index: Index = toml::from_str(&text).map_err(|e| FormatError::Toml {
        path: p.clone(),
        message: e.to_string(),
    })?;
    index.validate().map_err(|m| FormatError::invalid(&p, m))?;
    Ok(index)
}

/// `root/file` for a `file` of an entry, refused if it leaves the dataset.
pub fn image_path(root: &Path, file: &str) -> Result<PathBuf, FormatError> {
    let rel = Path::new(file);
    if rel.is_absolute() || rel.components().any(|c| matches!(c, Component::ParentDir)) {
        return Err(FormatError::invalid(
            root.join(INDEX),
            format!("file `{file}` leaves the rectified directory"),
        ));
    }
    Ok(root.join(rel))
}

/// Reads one image of the dataset (a `file` of an entry), checked against the grid.
pub fn read_image(root: &Path, index: &Index, file: &str) -> Result<RgbImage, FormatError> {
    let p = image_path(root, file)?;
    let t = exr::read_rgb(&p)?;
    let g = &index.grid;
    if !g.fits(t.width, t.height) {
        return Err(FormatError::invalid(
            &p,
            format!(
                "{}×{} texels, the grid is {}×{}",
                t.width, t.height, g.width, g.height
            ),
        ));
    }
    Ok(t)
}

/// An opened, validated rectified dataset.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The dataset's directory (CAPTURE_DIR/rectified).
    pub root: PathBuf,
    pub index: Index,
}

impl Dataset {
    /// Opens the dataset of the capture in `capture_dir`.
    pub fn open(capture_dir: &Path) -> Result<Dataset, FormatError> {
        let root = capture_dir.join(DIR);
        let index = read_index(&root)?;
        Ok(Dataset { root, index })
    }

    /// Reads an image named in the index, checked against the grid.
    pub fn read_image(&self, file: &str) -> Result<RgbImage, FormatError> {
        read_image(&self.root, &self.index, file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn index() -> Index {
        let mut idx = Index::new(Grid {
            width: 4,
            height: 4,
            texel_mm: 0.5,
            origin_mm: [-1.0, -1.0],
        });
        idx.stripe.push(StripeEntry {
            file: stripe_file(0),
            pass: 2,
            channel: 1,
            light_dir: [0.0, 0.0, 1.0],
            view_dir: [0.6, 0.0, 0.8],
            camera: 5,
            flux_per_mm: 1.2e-4,
            line_point: [0.1, -0.2],
            line_dir: [0.0, 1.0],
        });
        idx.lamp.push(LampEntry {
            file: lamp_file(0),
            light_dir: [0.0, 0.0, 1.0],
            view_dir: [0.0, 0.0, 1.0],
            camera: 7,
            irradiance: [1.0; 3],
        });
        idx.calibration = Some(CalibrationSummary {
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
        });
        idx
    }

    fn write(idx: &Index) -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().join(DIR);
        std::fs::create_dir_all(root.join("stripes")).unwrap();
        std::fs::create_dir_all(root.join("lamps")).unwrap();
        write_index(&root, idx).unwrap();
        let img = RgbImage::filled(4, 4, [0.5, f32::NAN, 2.0]);
        exr::write_rgb(&root.join(stripe_file(0)), &img).unwrap();
        exr::write_rgb(&root.join(lamp_file(0)), &RgbImage::filled(3, 4, [1.0; 3])).unwrap();
        d
    }

    /// The error opening the dataset after replacing `from` by `to` in its index.
    fn edited(idx: &Index, from: &str, to: &str) -> String {
        let d = write(idx);
        let p = d.path().join(DIR).join(INDEX);
        let t = std::fs::read_to_string(&p).unwrap();
        assert!(t.contains(from), "index lacks `{from}`:\n{t}");
        std::fs::write(&p, t.replacen(from, to, 1)).unwrap();
        Dataset::open(d.path()).map_or_else(|e| e.to_string(), |_| String::new())
    }

    #[test]
    fn write_then_read_back() {
        let idx = index();
        let d = write(&idx);
        let data = Dataset::open(d.path()).unwrap();
        assert_eq!(data.index, idx);
        let img = data.read_image(&idx.stripe[0].file).unwrap();
        assert_eq!(img.get(1, 2)[0], 0.5);
        assert!(img.get(1, 2)[1].is_nan());
        let e = data.read_image(&idx.lamp[0].file).unwrap_err().to_string();
        assert!(e.contains("the grid is 4×4"), "{e}");
        let e = data.read_image("../x.exr").unwrap_err().to_string();
        assert!(e.contains("leaves"), "{e}");
        let e = data
            .read_image("stripes/000009.exr")
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing file"), "{e}");
    }

    #[test]
    fn open_refuses_what_the_fit_cannot_use() {
        let idx = index();
        for (from, to, want) in [
            ("version = 1", "version = 2", "unsupported version 2"),
            (
                "format = \"qhm-rectified\"",
                "format = \"x\"",
                "format is `x`",
            ),
            ("channel = 1", "channel = 5", "channel 5"),
            ("pass = 2", "pass = 3", "pass 3"),
            ("width = 4", "width = 0", "is empty"),
            ("width = 4", "width = ", "index.toml"),
        ] {
            let e = edited(&idx, from, to);
            assert!(e.contains(want), "{from} -> {to}: {e}");
        }
        let mut bad = idx.clone();
        bad.stripe[0].flux_per_mm = f64::NAN;
        assert!(bad.validate().unwrap_err().contains("flux_per_mm"));
        let mut bad = idx.clone();
        bad.stripe[0].line_dir = [0.0, 2.0];
        assert!(bad.validate().unwrap_err().contains("line_dir"));
        let mut bad = idx;
        bad.lamp[0].irradiance[1] = 0.0;
        assert!(bad.validate().unwrap_err().contains("irradiance"));
    }
}
