//! RGB f32 EXR files (the rectified dataset and HDR images), NaN kept as NaN.

use std::path::Path;

use crate::image::ImageF;
use crate::{Error, Result};

/// Write a 1- or 3-channel image as RGB f32 EXR (one channel is copied to all three).
pub fn write_rgb(path: &Path, img: &ImageF) -> Result<()> {
    if img.channels != 1 && img.channels != 3 {
        return Err(Error::Input(format!(
            "EXR wants 1 or 3 channels, got {}",
            img.channels
        )));
    }
    let ch = img.channels;
    exr::prelude::write_rgb_file(path, img.width, img.height, |x, y| {
        let i = (y * img.width + x) * ch;
        if ch == 1 {
            (img.data[i], img.data[i], img.data[i])
        } else {
            (img.data[i], img.data[i + 1], img.data[i + 2])
        }
    })
    .map_err(|e| Error::Exr {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// Read the first RGB(A) layer of an EXR file as a 3-channel f32 image.
pub fn read_rgb(path: &Path) -> Result<ImageF> {
    let img = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |res, _| ImageF::zeros(res.width(), res.height(), 3),
        |im: &mut ImageF, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = (pos.y() * im.width + pos.x()) * 3;
            im.data[i] = r;
            im.data[i + 1] = g;
            im.data[i + 2] = b;
        },
    )
    .map_err(|e| Error::Exr {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    Ok(img.layer_data.channel_data.pixels)
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
        std::fs::write(dir.path().join("bad.exr"), b"not an exr").unwrap();
        assert!(read_rgb(&dir.path().join("bad.exr")).is_err());
    }
}
