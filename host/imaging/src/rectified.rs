//! Writing the rectified dataset. Its format (index.toml and the EXR
//! images, read by the model fitter) is defined once, in
//! qhm_formats::rectified; this module fills it from rectified [`ImageF`]s
//! and a [`Calibration`].

use std::path::{Path, PathBuf};

pub use qhm_formats::rectified::{
    CalibrationSummary, CameraSummary, FORMAT, Grid as GridEntry, Index, LampEntry, LampSummary,
    StripeEntry, VERSION, lamp_file, read_index, stripe_file, write_index,
};

use crate::calibration::Calibration;
use crate::exr_io;
use crate::image::ImageF;
use crate::rectify::Grid;
use crate::{Error, Result};

impl From<Grid> for GridEntry {
    fn from(g: Grid) -> Self {
        GridEntry {
            width: g.width as u32,
            height: g.height as u32,
            texel_mm: g.texel_mm,
            origin_mm: g.origin_mm,
        }
    }
}

impl From<GridEntry> for Grid {
    fn from(g: GridEntry) -> Self {
        Grid {
            width: g.width as usize,
            height: g.height as usize,
            texel_mm: g.texel_mm,
            origin_mm: g.origin_mm,
        }
    }
}

/// What `cal` holds, in brief, for the index's `[calibration]`.
pub fn calibration_summary(cal: &Calibration) -> CalibrationSummary {
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

/// The on-disk grid of a checked working grid.
pub(crate) fn grid_entry(grid: Grid) -> Result<GridEntry> {
    // validate() bounds the size far below u32::MAX.
    grid.validate()?;
    Ok(grid.into())
}

/// Checks a rectified image against the dataset's grid.
pub(crate) fn check_size(img: &ImageF, grid: &GridEntry) -> Result<()> {
    if !grid.fits(img.width, img.height) {
        return Err(Error::Input(format!(
            "rectified image {}x{} does not match the grid {}x{}",
            img.width, img.height, grid.width, grid.height
        )));
    }
    Ok(())
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
        let grid = grid_entry(grid)?;
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
            index: Index::new(grid),
        })
    }

    /// Records the calibration the images are rectified with.
    pub fn set_calibration(&mut self, cal: CalibrationSummary) {
        self.index.calibration = Some(cal);
    }

    /// Add a stripe image; `entry.file` is filled in.
    pub fn add_stripe(&mut self, img: &ImageF, mut entry: StripeEntry) -> Result<()> {
        check_size(img, &self.index.grid)?;
        entry.file = stripe_file(self.index.stripe.len());
        exr_io::write_rgb(&self.root.join(&entry.file), img)?;
        self.index.stripe.push(entry);
        Ok(())
    }

    /// Add a lamp image; `entry.file` is filled in.
    pub fn add_lamp(&mut self, img: &ImageF, mut entry: LampEntry) -> Result<()> {
        check_size(img, &self.index.grid)?;
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

/// Read one image of the dataset (a `file` of an entry), checked against the grid.
pub fn read_image(root: &Path, idx: &Index, file: &str) -> Result<ImageF> {
    Ok(exr_io::from_rgb(qhm_formats::rectified::read_image(
        root, idx, file,
    )?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stripe() -> StripeEntry {
        StripeEntry {
            file: String::new(),
            pass: 2,
            channel: 0,
            light_dir: [0.0, 0.0, 1.0],
            view_dir: [0.6, 0.0, 0.8],
            camera: 5,
            flux_per_mm: 1.2e-4,
            line_point: [0.1, -0.2],
            line_dir: [0.0, 1.0],
        }
    }

    #[test]
    fn write_then_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("rectified");
        let grid = Grid::centred(8, 0.5);
        let mut w = Writer::create(&root, grid).unwrap();
        let mut img = ImageF::zeros(8, 8, 3);
        img.set(2, 3, 0, 1.5);
        img.set(0, 0, 0, f32::NAN);
        w.add_stripe(&img, stripe()).unwrap();
        let mut cal = Calibration::default();
        cal.source = "test".into();
        cal.camera_mut(5).colour_gain = Some([1.0, 0.99, 1.01]);
        w.set_calibration(calibration_summary(&cal));
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
        assert!(w.add_stripe(&ImageF::zeros(4, 4, 3), stripe()).is_err());
        w.finish().unwrap();
        let idx = read_index(&root).unwrap();
        assert_eq!(idx.stripe.len(), 1);
        let summary = idx.calibration.as_ref().unwrap();
        assert_eq!(summary.source, "test");
        assert_eq!(summary.cameras[0].colour_gain, Some([1.0, 0.99, 1.01]));
        assert!(!summary.cameras[0].geometry);
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
