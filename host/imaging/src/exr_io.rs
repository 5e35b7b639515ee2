//! [`ImageF`]s in the workspace's EXR files (qhm_formats::exr does the
//! reading and writing): RGB f32, NaN kept as NaN.

use std::path::Path;

use qhm_formats::{FormatError, RgbImage, exr};

use crate::image::ImageF;
use crate::{Error, Result};

impl From<FormatError> for Error {
    fn from(e: FormatError) -> Error {
        match e {
            FormatError::Io { path, source } => Error::Io { path, source },
            FormatError::Exr { path, message } => Error::Exr { path, msg: message },
            FormatError::Toml { path, message } | FormatError::Invalid { path, message } => {
                Error::Format { path, msg: message }
            }
        }
    }
}

/// A 1- or 3-channel image as RGB (one channel is copied to all three).
pub fn to_rgb(img: &ImageF) -> Result<RgbImage> {
    let data = match img.channels {
        1 => img.data.iter().map(|&v| [v; 3]).collect(),
        3 => img
            .data
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect(),
        n => {
            return Err(Error::Input(format!("EXR wants 1 or 3 channels, got {n}")));
        }
    };
    Ok(RgbImage {
        width: img.width,
        height: img.height,
        data,
    })
}

/// An RGB image as a 3-channel [`ImageF`].
pub fn from_rgb(img: RgbImage) -> ImageF {
    ImageF {
        width: img.width,
        height: img.height,
        channels: 3,
        data: img.data.into_iter().flatten().collect(),
    }
}

/// Write a 1- or 3-channel image as RGB f32 EXR.
pub fn write_rgb(path: &Path, img: &ImageF) -> Result<()> {
    Ok(exr::write_rgb(path, &to_rgb(img)?)?)
}

/// Read the first RGB(A) layer of an EXR file as a 3-channel f32 image.
pub fn read_rgb(path: &Path) -> Result<ImageF> {
    Ok(from_rgb(exr::read_rgb(path)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_values_and_nan() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.exr");
        let mut im = ImageF::zeros(5, 3, 3);
        for (i, v) in im.data.iter_mut().enumerate() {
            *v = i as f32 * 0.25;
        }
        im.data[7] = f32::NAN;
        write_rgb(&p, &im).unwrap();
        let back = read_rgb(&p).unwrap();
        assert_eq!((back.width, back.height), (5, 3));
        assert!(back.data[7].is_nan());
        for (i, (a, b)) in im.data.iter().zip(&back.data).enumerate() {
            if i != 7 {
                assert_eq!(a, b);
            }
        }
        let grey = ImageF::zeros(2, 2, 1);
        write_rgb(&p, &grey).unwrap();
        assert_eq!(read_rgb(&p).unwrap().channels, 3);
        assert!(write_rgb(&p, &ImageF::zeros(2, 2, 2)).is_err());
        std::fs::write(dir.path().join("bad.exr"), b"not an exr").unwrap();
        assert!(read_rgb(&dir.path().join("bad.exr")).is_err());
    }
}
