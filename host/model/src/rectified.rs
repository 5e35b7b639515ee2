//! The rectified dataset that acquisition hands to the fit, opened with the
//! model's error type. Its format (`CAPTURE_DIR/rectified/index.toml` plus
//! RGB f32 EXR images) is defined once, in qhm_formats::rectified; the
//! contract is written out in docs/model-format.md.

use std::path::{Path, PathBuf};

pub use qhm_formats::rectified::{
    CalibrationSummary, CameraSummary, FORMAT, Grid, Index, LampEntry, LampSummary, StripeEntry,
    VERSION, lamp_file, stripe_file,
};

use crate::ModelError;
use crate::model::Texture;

/// An opened, validated rectified dataset.
#[derive(Clone, Debug)]
pub struct Rectified {
    /// The `rectified/` directory.
    pub root: PathBuf,
    pub index: Index,
}

impl Rectified {
    /// Opens `capture_dir/rectified/index.toml` and checks every entry.
    pub fn open(capture_dir: &Path) -> Result<Self, ModelError> {
        let d = qhm_formats::rectified::Dataset::open(capture_dir)?;
        Ok(Rectified {
            root: d.root,
            index: d.index,
        })
    }

    /// Reads an image named in the index and checks its size against the grid.
    pub fn read_image(&self, file: &str) -> Result<Texture, ModelError> {
        Ok(qhm_formats::rectified::read_image(
            &self.root,
            &self.index,
            file,
        )?)
    }

    /// Writes an index into `capture_dir/rectified/` (for synthetic datasets and tests).
    pub fn write_index(capture_dir: &Path, index: &Index) -> Result<(), ModelError> {
        let root = capture_dir.join(qhm_formats::rectified::DIR);
        std::fs::create_dir_all(&root).map_err(|e| ModelError::io(&root, e))?;
        Ok(qhm_formats::rectified::write_index(&root, index)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic_dataset::{SynthSpec, write_synthetic};

    #[test]
    fn a_synthetic_capture_opens_and_a_damaged_one_is_an_error() {
        let d = tempfile::tempdir().unwrap();
        let mut spec = SynthSpec::small(crate::DipoleParams {
            alpha_prime: [0.99; 3],
            sigma_t_prime: [1.0; 3],
            eta: 1.3,
            model: crate::subsurface::ProfileModel::Dipole,
        });
        spec.width = 8;
        spec.height = 8;
        spec.scan_offsets_mm = vec![0.3];
        write_synthetic(d.path(), &spec).unwrap();
        let r = Rectified::open(d.path()).unwrap();
        assert_eq!(r.index.grid.width, 8);
        let t = r.read_image(&r.index.stripe[0].file).unwrap();
        assert_eq!((t.width, t.height), (8, 8));
        crate::write_rgb(
            &r.root.join(&r.index.lamp[1].file),
            &Texture::filled(4, 8, [0.0; 3]),
        )
        .unwrap();
        let e = r.read_image(&r.index.lamp[1].file).unwrap_err().to_string();
        assert!(e.contains("the grid is 8×8"), "{e}");
        // The fit reports an error instead of panicking.
        std::fs::remove_file(r.root.join(&r.index.lamp[0].file)).unwrap();
        assert!(crate::fit::fit_capture(d.path(), &crate::fit::FitOptions::default()).is_err());
        let p = r.root.join("index.toml");
        let text = std::fs::read_to_string(&p).unwrap();
        std::fs::write(&p, text.replacen("version = 1", "version = 2", 1)).unwrap();
        let e = Rectified::open(d.path()).unwrap_err().to_string();
        assert!(e.contains("unsupported version 2"), "{e}");
    }
}
