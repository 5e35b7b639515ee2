//! The report's images: colour maps and per-row scales from percentiles,
//! textures and mosaics as PNG, data URIs, colour bars and labelled tiles.

use std::fmt::Write as _;

use super::esc;
use super::plots::tick;
use crate::model::Texture;

/// A colour map: value in 0..1 to sRGB.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Map {
    /// Perceptually uniform, dark to light (viridis).
    Viridis,
    /// Diverging about the middle, blue - grey - red (coolwarm).
    CoolWarm,
    /// Grey with display gamma 2.2 (for RGB images).
    Grey,
}

impl Map {
    fn stops(self) -> &'static [[u8; 3]] {
        match self {
            Map::Viridis => &[
                [68, 1, 84],
                [71, 44, 122],
                [59, 81, 139],
                [44, 113, 142],
                [33, 144, 141],
                [39, 173, 129],
                [92, 200, 99],
                [170, 220, 50],
                [253, 231, 37],
            ],
            Map::CoolWarm => &[
                [59, 76, 192],
                [124, 159, 249],
                [192, 212, 245],
                [221, 221, 221],
                [242, 203, 183],
                [238, 132, 104],
                [180, 4, 38],
            ],
            Map::Grey => &[[0, 0, 0], [255, 255, 255]],
        }
    }
    fn at(self, t: f64) -> [u8; 3] {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        if self == Map::Grey {
            let v = (t.powf(1.0 / 2.2) * 255.0).round() as u8;
            return [v; 3];
        }
        let s = self.stops();
        let x = t * (s.len() - 1) as f64;
        let k = (x.floor() as usize).min(s.len() - 2);
        let f = x - k as f64;
        std::array::from_fn(|c| (s[k][c] as f64 * (1.0 - f) + s[k + 1][c] as f64 * f).round() as u8)
    }
}

/// The colour of a texel with a channel that is not a number (not measured).
pub(super) const INVALID: [u8; 3] = [255, 0, 255];

/// A caption's note when some texels of `maps` are not valid.
pub(super) fn invalid_note(maps: &[&Texture]) -> String {
    let n: usize = maps
        .iter()
        .map(|t| {
            t.data
                .iter()
                .filter(|p| p.iter().any(|x| !x.is_finite()))
                .count()
        })
        .sum();
    if n == 0 {
        String::new()
    } else {
        format!("; magenta: {n} texels not valid (NaN in a channel)")
    }
}

/// How one row of images turns values into colours.
#[derive(Clone, Copy, Debug)]
pub(super) struct Scale {
    map: Map,
    lo: f64,
    hi: f64,
    /// RGB kept per channel (Grey map) instead of the mean of the channels.
    rgb: bool,
}

impl Scale {
    fn t(&self, v: f64) -> f64 {
        (v - self.lo) / (self.hi - self.lo)
    }
    fn pixel(&self, v: [f32; 3]) -> [u8; 3] {
        if v.iter().any(|x| !x.is_finite()) {
            return INVALID;
        }
        if self.rgb {
            return std::array::from_fn(|c| self.map.at(self.t(v[c] as f64))[0]);
        }
        let m = (v[0] as f64 + v[1] as f64 + v[2] as f64) / 3.0;
        self.map.at(self.t(m))
    }
}

/// The `p`-quantile (0..1) of the finite values, by selection; None if none.
pub(super) fn quantile(values: &mut [f64], p: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let k = ((values.len() - 1) as f64 * p).round() as usize;
    let (_, v, _) = values.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    Some(*v)
}

/// At most ~1M values of `maps`, as `f` of each texel (strided for big models).
pub(super) fn values(maps: &[&Texture], f: impl Fn([f32; 3]) -> Vec<f64>) -> Vec<f64> {
    let n: usize = maps.iter().map(|t| t.data.len()).sum();
    let stride = (n / 1_000_000).max(1);
    maps.iter()
        .flat_map(|t| t.data.iter().step_by(stride))
        .flat_map(|v| f(*v))
        .filter(|v| v.is_finite())
        .collect()
}

/// Sequential scale over the 1st..99th percentile of the channels' mean.
pub(super) fn seq_scale(maps: &[&Texture]) -> Scale {
    let mut v = values(maps, |p| {
        vec![(p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0]
    });
    let lo = quantile(&mut v, 0.01).unwrap_or(0.0);
    let mut hi = quantile(&mut v, 0.99).unwrap_or(1.0);
    if !(hi > lo) {
        hi = lo + lo.abs().max(1e-6) * 0.1;
        return Scale {
            map: Map::Viridis,
            lo: lo - (hi - lo),
            hi,
            rgb: false,
        };
    }
    Scale {
        map: Map::Viridis,
        lo,
        hi,
        rgb: false,
    }
}

/// Diverging scale symmetric about 0 at the 99th percentile of |mean|.
pub(super) fn div_scale(maps: &[&Texture]) -> Scale {
    let mut v = values(maps, |p| {
        vec![((p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0).abs()]
    });
    let peak = quantile(&mut v, 0.99).filter(|p| *p > 0.0).unwrap_or(1e-6);
    Scale {
        map: Map::CoolWarm,
        lo: -peak,
        hi: peak,
        rgb: false,
    }
}

/// RGB scale from 0 to the 99th percentile of all channels.
pub(super) fn rgb_scale(maps: &[&Texture]) -> Scale {
    let mut v = values(maps, |p| p.iter().map(|x| *x as f64).collect());
    let hi = quantile(&mut v, 0.99).filter(|p| *p > 0.0).unwrap_or(1.0);
    Scale {
        map: Map::Grey,
        lo: 0.0,
        hi,
        rgb: true,
    }
}

/// A texture as a PNG, scaled up (nearest) to about `size` pixels.
pub(super) fn texture_png(t: &Texture, scale: &Scale, size: usize) -> Vec<u8> {
    let k = (size / t.width.max(t.height).max(1)).max(1);
    let (w, h) = (t.width * k, t.height * k);
    let mut img = image::RgbImage::new(w as u32, h as u32);
    for y in 0..h {
        for x in 0..w {
            img.put_pixel(
                x as u32,
                y as u32,
                image::Rgb(scale.pixel(t.get(x / k, y / k))),
            );
        }
    }
    png_bytes(&img)
}

pub(super) fn png_bytes(img: &image::RgbImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding into memory");
    out.into_inner()
}

/// Rows of textures, each row with its own scale, tiled into one PNG (paper
/// Fig. 6 beside the page): every tile `size` texels across at most.
pub(super) fn rows_png(rows: &[(&Scale, &[&Texture])], size: usize) -> Vec<u8> {
    let cols = rows.iter().map(|(_, m)| m.len()).max().unwrap_or(0).max(1);
    let first = rows.iter().flat_map(|(_, m)| m.first()).next();
    let (w, h) = first.map_or((1, 1), |t| (t.width.max(1), t.height.max(1)));
    let k = (size / w.max(h)).max(1);
    let gap = 4;
    let mut img = image::RgbImage::from_pixel(
        (cols * (w * k + gap) + gap) as u32,
        (rows.len().max(1) * (h * k + gap) + gap) as u32,
        image::Rgb([255, 255, 255]),
    );
    for (r, (scale, maps)) in rows.iter().enumerate() {
        for (c, t) in maps.iter().enumerate() {
            let (ox, oy) = (c * (w * k + gap) + gap, r * (h * k + gap) + gap);
            for y in 0..(h * k).min(t.height * k) {
                for x in 0..(w * k).min(t.width * k) {
                    img.put_pixel(
                        (ox + x) as u32,
                        (oy + y) as u32,
                        image::Rgb(scale.pixel(t.get(x / k, y / k))),
                    );
                }
            }
        }
    }
    png_bytes(&img)
}

/// Tiles textures into one PNG (for the files beside the page).
pub(super) fn mosaic_png(maps: &[&Texture], scale: &Scale) -> Vec<u8> {
    let cols = (maps.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = maps.len().div_ceil(cols).max(1);
    let (w, h) = (maps[0].width, maps[0].height);
    let k = (128 / w.max(h)).max(1);
    let gap = 2;
    let mut img = image::RgbImage::from_pixel(
        (cols * (w * k + gap) + gap) as u32,
        (rows * (h * k + gap) + gap) as u32,
        image::Rgb([255, 255, 255]),
    );
    for (n, t) in maps.iter().enumerate() {
        let (ox, oy) = (
            (n % cols) * (w * k + gap) + gap,
            (n / cols) * (h * k + gap) + gap,
        );
        for y in 0..h * k {
            for x in 0..w * k {
                img.put_pixel(
                    (ox + x) as u32,
                    (oy + y) as u32,
                    image::Rgb(scale.pixel(t.get(x / k, y / k))),
                );
            }
        }
    }
    png_bytes(&img)
}

pub(super) fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

pub(super) fn data_uri(png: &[u8]) -> String {
    format!("data:image/png;base64,{}", base64(png))
}

/// A colour bar: the map's gradient with tick labels of the values.
pub(super) fn colour_bar(id: &str, scale: &Scale, label: &str) -> String {
    let (w, bw, x0) = (380.0, 300.0, 28.0);
    let mut s = format!(
        "<svg class=\"cbar\" xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"46\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"10\">\
         <defs><linearGradient id=\"{id}\" x1=\"0\" x2=\"1\" y1=\"0\" y2=\"0\">"
    );
    for k in 0..=16 {
        let t = k as f64 / 16.0;
        let [r, g, b] = scale.map.at(t);
        let _ = write!(
            s,
            "<stop offset=\"{t:.4}\" stop-color=\"rgb({r},{g},{b})\"/>"
        );
    }
    let _ = write!(
        s,
        "</linearGradient></defs><rect x=\"{x0}\" y=\"4\" width=\"{bw}\" height=\"12\" fill=\"url(#{id})\" stroke=\"#555\" stroke-width=\"0.5\"/>"
    );
    for k in 0..=4 {
        let v = scale.lo + (scale.hi - scale.lo) * k as f64 / 4.0;
        let x = x0 + bw * k as f64 / 4.0;
        let _ = write!(
            s,
            "<line x1=\"{x}\" x2=\"{x}\" y1=\"16\" y2=\"20\" stroke=\"#333\"/><text x=\"{x}\" y=\"30\" text-anchor=\"middle\">{}</text>",
            tick(v)
        );
    }
    let _ = write!(s, "<text x=\"{x0}\" y=\"43\">{}</text></svg>", esc(label));
    s
}

/// θ and φ of a direction in degrees; φ is left out where θ is 0.
pub(super) fn dir_label(v: [f32; 3]) -> String {
    let th = v[2].clamp(-1.0, 1.0).acos().to_degrees();
    let ph = (v[1].atan2(v[0]).to_degrees().round() as i32).rem_euclid(360);
    if th < 0.05 {
        "θ 0°".into()
    } else if th < 9.95 {
        format!("θ {th:.1}°, φ {ph}°")
    } else {
        format!("θ {th:.0}°, φ {ph}°")
    }
}

/// One labelled image tile.
pub(super) fn tile(png: &[u8], alt: &str, caption: &str) -> String {
    format!(
        "<figure class=\"tile\"><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        data_uri(png),
        esc(alt),
        caption
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_rfc_examples() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }

    #[test]
    fn one_outlier_does_not_set_the_scale() {
        let mut t = Texture::filled(10, 10, [0.01; 3]);
        for (k, p) in t.data.iter_mut().enumerate() {
            *p = [if k % 2 == 0 { 0.01 } else { -0.01 }; 3];
        }
        t.data[0] = [1e3; 3];
        let s = div_scale(&[&t]);
        assert!((s.hi - 0.01).abs() < 1e-9, "{s:?}");
        // The outlier saturates, the rest spans the map.
        assert_eq!(s.pixel([1e3; 3]), Map::CoolWarm.at(1.0));
        assert_eq!(s.pixel([-0.01; 3]), Map::CoolWarm.at(0.0));
    }
}
