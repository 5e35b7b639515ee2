//! The workspace's one EXR reader and writer: RGB f32, the first layer,
//! row 0 = the file's first row, NaN kept as NaN.

use std::path::Path;

use exr::prelude::{RgbaChannels, Vec2, read_first_rgba_layer_from_file, write_rgb_file};

use crate::FormatError;
use crate::image::RgbImage;

fn exr_error(path: &Path) -> impl FnOnce(exr::error::Error) -> FormatError + '_ {
    move |e| FormatError::Exr {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Reads the first RGB(A) layer of an EXR file as f32 (alpha ignored).
pub fn read_rgb(path: &Path) -> Result<RgbImage, FormatError> {
    if path.is_dir() {
        return Err(FormatError::invalid(path, "a directory, not an EXR file"));
    }
    if !path.is_file() {
        return Err(FormatError::invalid(path, "missing file"));
    }
    let image = read_first_rgba_layer_from_file(
        path,
        |size: Vec2<usize>, _: &RgbaChannels| {
            RgbImage::filled(size.width(), size.height(), [0.0; 3])
        },
        |t: &mut RgbImage, pos: Vec2<usize>, (r, g, b, _a): (f32, f32, f32, f32)| {
            let w = t.width;
            t.data[pos.y() * w + pos.x()] = [r, g, b];
        },
    )
    .map_err(exr_error(path))?;
    Ok(image.layer_data.channel_data.pixels)
}

/// Writes an image as an RGB f32 EXR file.
pub fn write_rgb(path: &Path, image: &RgbImage) -> Result<(), FormatError> {
    write_rgb_pixels(path, image.width, image.height, &image.data)
}

/// Writes `width` x `height` row-major RGB pixels as an RGB f32 EXR file
/// (for image types of other crates with the same layout).
pub fn write_rgb_pixels(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[[f32; 3]],
) -> Result<(), FormatError> {
    if pixels.len() != width * height {
        return Err(FormatError::invalid(
            path,
            format!("{} pixels for a {width}x{height} image", pixels.len()),
        ));
    }
    write_rgb_file(path, width, height, |x, y| {
        let p = pixels[y * width + x];
        (p[0], p[1], p[2])
    })
    .map_err(exr_error(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_values_and_nan() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.exr");
        let mut t = RgbImage::filled(3, 2, [0.25, -1.5, 3.0e-7]);
        t.data[4] = [f32::NAN, 1.0, 2.0];
        write_rgb(&p, &t).unwrap();
        let u = read_rgb(&p).unwrap();
        assert_eq!((u.width, u.height), (3, 2));
        assert_eq!(u.data[0], t.data[0]);
        assert!(u.data[4][0].is_nan() && u.data[4][2] == 2.0);
        let missing = read_rgb(&dir.path().join("missing.exr")).unwrap_err();
        assert!(missing.to_string().contains("missing file"), "{missing}");
        std::fs::write(dir.path().join("bad.exr"), b"not an exr").unwrap();
        assert!(read_rgb(&dir.path().join("bad.exr")).is_err());
        assert!(write_rgb_pixels(&p, 2, 2, &[[0.0; 3]; 3]).is_err());
    }
}
