//! A small reader (and, for synthetic tests, writer) of the rectified
//! dataset that acquisition hands to the fit: `CAPTURE_DIR/rectified/index.toml`
//! plus RGB f32 EXR images of outgoing radiance (W sr^-1 mm^-2) per texel,
//! NaN where not valid. The contract is written out in docs/model-format.md.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::ModelError;
use crate::exrio::read_rgb;
use crate::model::Texture;

pub const FORMAT: &str = "qhm-rectified";
pub const VERSION: u32 = 1;

/// The reference-plane texel grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}

/// A laser-stripe image (pass 1: entrance function, pass 2: vertical, dipole).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StripeEntry {
    pub file: String,
    pub pass: u8,
    /// 0 red, 1 green, 2 blue.
    pub channel: u8,
    pub light_dir: [f64; 3],
    pub view_dir: [f64; 3],
    pub camera: u32,
    /// W per mm of stripe length.
    pub flux_per_mm: f64,
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

/// A halogen-lamp image (pass 3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LampEntry {
    pub file: String,
    pub light_dir: [f64; 3],
    pub view_dir: [f64; 3],
    pub camera: u32,
    /// W/mm² on a surface normal to the lamp.
    pub irradiance: [f64; 3],
}

/// `rectified/index.toml`.
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

/// An opened, validated rectified dataset.
#[derive(Clone, Debug)]
pub struct Rectified {
    /// The `rectified/` directory.
    pub root: PathBuf,
    pub index: Index,
}

fn unit3(v: &[f64; 3]) -> bool {
    ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 1e-3
}

impl Rectified {
    /// Opens `capture_dir/rectified/index.toml` and checks every entry.
    pub fn open(capture_dir: &Path) -> Result<Self, ModelError> {
        let root = capture_dir.join("rectified");
        let ipath = root.join("index.toml");
        let text = std::fs::read_to_string(&ipath).map_err(|e| ModelError::io(&ipath, e))?;
        let index: Index = toml::from_str(&text).map_err(|e| ModelError::Toml {
            path: ipath.clone(),
            message: e.to_string(),
        })?;
        let bad = |m: String| ModelError::invalid(&ipath, m);
        if index.format != FORMAT {
            return Err(bad(format!(
                "format is `{}`, expected `{FORMAT}`",
                index.format
            )));
        }
        if index.version != VERSION {
            return Err(bad(format!(
                "unsupported version {}; this qhm reads {VERSION}",
                index.version
            )));
        }
        let g = &index.grid;
        if g.width == 0 || g.height == 0 || !(g.texel_mm.is_finite() && g.texel_mm > 0.0) {
            return Err(bad(format!(
                "grid {}×{} texels of {} mm is empty",
                g.width, g.height, g.texel_mm
            )));
        }
        for (k, s) in index.stripe.iter().enumerate() {
            let what = format!("stripe {k} ({})", s.file);
            if !(s.pass == 1 || s.pass == 2) {
                return Err(bad(format!("{what}: pass {} is not 1 or 2", s.pass)));
            }
            if s.channel > 2 {
                return Err(bad(format!(
                    "{what}: channel {} is not 0, 1 or 2",
                    s.channel
                )));
            }
            if !unit3(&s.light_dir) || !unit3(&s.view_dir) {
                return Err(bad(format!(
                    "{what}: light_dir and view_dir must be unit vectors"
                )));
            }
            let ld = (s.line_dir[0].powi(2) + s.line_dir[1].powi(2)).sqrt();
            if (ld - 1.0).abs() > 1e-3 {
                return Err(bad(format!(
                    "{what}: line_dir {:?} is not a unit vector",
                    s.line_dir
                )));
            }
            if !(s.flux_per_mm.is_finite() && s.flux_per_mm > 0.0) {
                return Err(bad(format!(
                    "{what}: flux_per_mm = {} must be > 0",
                    s.flux_per_mm
                )));
            }
            if !(s.line_point.iter().all(|x| x.is_finite())) {
                return Err(bad(format!("{what}: line_point is not finite")));
            }
        }
        for (k, l) in index.lamp.iter().enumerate() {
            let what = format!("lamp {k} ({})", l.file);
            if !unit3(&l.light_dir) || !unit3(&l.view_dir) {
                return Err(bad(format!(
                    "{what}: light_dir and view_dir must be unit vectors"
                )));
            }
            if !l.irradiance.iter().all(|e| e.is_finite() && *e > 0.0) {
                return Err(bad(format!(
                    "{what}: irradiance {:?} must be > 0",
                    l.irradiance
                )));
            }
        }
        Ok(Rectified { root, index })
    }

    /// Reads an image named in the index and checks its size against the grid.
    pub fn read_image(&self, file: &str) -> Result<Texture, ModelError> {
        let rel = Path::new(file);
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| matches!(c, std::path::Component::ParentDir))
        {
            return Err(ModelError::invalid(
                self.root.join("index.toml"),
                format!("file `{file}` leaves the rectified directory"),
            ));
        }
        let p = self.root.join(rel);
        let t = read_rgb(&p)?;
        let g = &self.index.grid;
        if (t.width, t.height) != (g.width as usize, g.height as usize) {
            return Err(ModelError::invalid(
                &p,
                format!(
                    "{}×{} texels, the grid is {}×{}",
                    t.width, t.height, g.width, g.height
                ),
            ));
        }
        Ok(t)
    }

    /// Writes an index (for synthetic datasets and tests).
    pub fn write_index(capture_dir: &Path, index: &Index) -> Result<(), ModelError> {
        let root = capture_dir.join("rectified");
        std::fs::create_dir_all(&root).map_err(|e| ModelError::io(&root, e))?;
        let p = root.join("index.toml");
        let text = toml::to_string(index).map_err(|e| ModelError::Toml {
            path: p.clone(),
            message: e.to_string(),
        })?;
        std::fs::write(&p, text).map_err(|e| ModelError::io(&p, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{SynthSpec, write_synthetic};

    fn capture() -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        let mut spec = SynthSpec::small(crate::DipoleParams {
            alpha_prime: [0.99; 3],
            sigma_t_prime: [1.0; 3],
            eta: 1.3,
            model: crate::profile::ProfileModel::Dipole,
        });
        spec.width = 8;
        spec.height = 8;
        spec.scan_offsets_mm = vec![0.3];
        write_synthetic(d.path(), &spec).unwrap();
        d
    }

    fn edit(dir: &Path, from: &str, to: &str) -> String {
        let p = dir.join("rectified/index.toml");
        let t = std::fs::read_to_string(&p).unwrap();
        assert!(t.contains(from), "index lacks `{from}`");
        std::fs::write(&p, t.replacen(from, to, 1)).unwrap();
        Rectified::open(dir)
            .map(|_| String::new())
            .unwrap_or_else(|e| e.to_string())
    }

    #[test]
    fn open_validates_the_index() {
        let d = capture();
        let r = Rectified::open(d.path()).unwrap();
        assert_eq!(r.index.grid.width, 8);
        let t = r.read_image(&r.index.stripe[0].file).unwrap();
        assert_eq!((t.width, t.height), (8, 8));
        assert!(edit(d.path(), "version = 1", "version = 2").contains("unsupported version 2"));
        let d = capture();
        assert!(edit(d.path(), "channel = 0", "channel = 5").contains("channel 5"));
        let d = capture();
        assert!(edit(d.path(), "pass = 2", "pass = 3").contains("pass 3"));
        let d = capture();
        assert!(
            edit(d.path(), "line_dir = [0.0, 1.0]", "line_dir = [0.0, 2.0]").contains("line_dir")
        );
        let d = capture();
        assert!(
            edit(d.path(), "format = \"qhm-rectified\"", "format = \"x\"")
                .contains("format is `x`")
        );
        let d = capture();
        let e = edit(d.path(), "width = 8", "width = ");
        assert!(e.contains("index.toml"), "{e}");
    }

    #[test]
    fn images_must_exist_match_the_grid_and_stay_inside() {
        let d = capture();
        let r = Rectified::open(d.path()).unwrap();
        std::fs::remove_file(r.root.join(&r.index.lamp[0].file)).unwrap();
        assert!(
            r.read_image(&r.index.lamp[0].file)
                .unwrap_err()
                .to_string()
                .contains("missing file")
        );
        crate::write_rgb(
            &r.root.join(&r.index.lamp[1].file),
            &Texture::filled(4, 8, [0.0; 3]),
        )
        .unwrap();
        assert!(
            r.read_image(&r.index.lamp[1].file)
                .unwrap_err()
                .to_string()
                .contains("the grid is 8×8")
        );
        assert!(
            r.read_image("../x.exr")
                .unwrap_err()
                .to_string()
                .contains("leaves")
        );
        // The fit reports an error instead of panicking.
        assert!(crate::fit::fit_capture(d.path(), &crate::fit::FitOptions::default()).is_err());
    }
}
