//! RGB f32 EXR files to and from [`Texture`]s (row 0 = first EXR row).

use std::path::Path;

use exr::prelude::{RgbaChannels, Vec2, read_first_rgba_layer_from_file, write_rgb_file};

use crate::ModelError;
use crate::model::Texture;

/// Reads the first RGB(A) layer of an EXR file as f32 (alpha ignored).
pub fn read_rgb(path: &Path) -> Result<Texture, ModelError> {
    if !path.is_file() {
        return Err(ModelError::invalid(path, "missing file"));
    }
    let image = read_first_rgba_layer_from_file(
        path,
        |size: Vec2<usize>, _: &RgbaChannels| {
            Texture::filled(size.width(), size.height(), [0.0; 3])
        },
        |t: &mut Texture, pos: Vec2<usize>, (r, g, b, _a): (f32, f32, f32, f32)| {
            let w = t.width;
            t.data[pos.y() * w + pos.x()] = [r, g, b];
        },
    )
    .map_err(|e| ModelError::Exr {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    Ok(image.layer_data.channel_data.pixels)
}

/// Writes a texture as an RGB f32 EXR file.
pub fn write_rgb(path: &Path, t: &Texture) -> Result<(), ModelError> {
    write_rgb_file(path, t.width, t.height, |x, y| {
        let p = t.data[y * t.width + x];
        (p[0], p[1], p[2])
    })
    .map_err(|e| ModelError::Exr {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_values_and_nan() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.exr");
        let mut t = Texture::filled(3, 2, [0.25, -1.5, 3.0e-7]);
        t.data[4] = [f32::NAN, 1.0, 2.0];
        write_rgb(&p, &t).unwrap();
        let u = read_rgb(&p).unwrap();
        assert_eq!((u.width, u.height), (3, 2));
        assert_eq!(u.data[0], t.data[0]);
        assert!(u.data[4][0].is_nan() && u.data[4][2] == 2.0);
        assert!(read_rgb(&dir.path().join("missing.exr")).is_err());
        std::fs::write(dir.path().join("bad.exr"), b"not an exr").unwrap();
        assert!(read_rgb(&dir.path().join("bad.exr")).is_err());
    }
}
