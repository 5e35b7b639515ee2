//! Checkerboard corners to sub-pixel in rendered 8-bit images.
//!
//! 1. Saddle points: on a Gaussian-smoothed image, a checkerboard corner is a
//!    saddle of intensity, where s = Ixy^2 - Ixx Iyy is large; local maxima
//!    of s above a fraction of the strongest are candidates.
//! 2. Association: the corners predicted from the nominal geometry are moved
//!    by the single image offset that lines up the most of them with
//!    candidates (a checkerboard is periodic, so the offset matching every
//!    corner wins over one shifted by a square, which loses a row).
//! 3. Sub-pixel: the gradient-orthogonality refinement (the gradient at any
//!    point near a corner is orthogonal to the vector to the corner), iterated.

use glam::DVec2;

use crate::{Error, Result};

/// Separable Gaussian blur of a single-channel plane.
pub fn gaussian_blur(src: &[f32], w: usize, h: usize, sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let ks: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| v / ks).collect();
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let xx = (x as isize + j as isize - r).clamp(0, w as isize - 1) as usize;
                s += kv * src[y * w + xx];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let yy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
                s += kv * tmp[yy * w + x];
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// Saddle candidates: local maxima of Ixy^2 - Ixx Iyy (on a blurred image) above
/// `rel_threshold` times the largest, at least `min_dist` pixels apart.
pub fn find_saddles(
    gray: &[f32],
    w: usize,
    h: usize,
    sigma: f64,
    rel_threshold: f32,
    min_dist: usize,
) -> Vec<DVec2> {
    let g = gaussian_blur(gray, w, h, sigma);
    let mut s = vec![0f32; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let at = |dx: isize, dy: isize| {
                g[((y as isize + dy) as usize) * w + (x as isize + dx) as usize]
            };
            let ixx = at(1, 0) - 2.0 * at(0, 0) + at(-1, 0);
            let iyy = at(0, 1) - 2.0 * at(0, 0) + at(0, -1);
            let ixy = 0.25 * (at(1, 1) - at(1, -1) - at(-1, 1) + at(-1, -1));
            s[y * w + x] = (ixy * ixy - ixx * iyy).max(0.0);
        }
    }
    let max = s.iter().cloned().fold(0.0, f32::max);
    let thr = max * rel_threshold;
    let d = min_dist as isize;
    let mut out = Vec::new();
    for y in d as usize..h.saturating_sub(d as usize) {
        for x in d as usize..w.saturating_sub(d as usize) {
            let v = s[y * w + x];
            if v <= thr || v == 0.0 {
                continue;
            }
            let mut is_max = true;
            'nb: for dy in -d..=d {
                for dx in -d..=d {
                    let u = s[(y as isize + dy) as usize * w + (x as isize + dx) as usize];
                    if u > v || (u == v && (dy, dx) < (0, 0)) {
                        is_max = false;
                        break 'nb;
                    }
                }
            }
            if is_max {
                out.push(DVec2::new(x as f64, y as f64));
            }
        }
    }
    out
}

/// Gradient-orthogonality sub-pixel refinement of a corner near `p` using a
/// Gaussian-weighted window of `radius` pixels. None if it walks away.
pub fn refine_corner(gray: &[f32], w: usize, h: usize, p: DVec2, radius: usize) -> Option<DVec2> {
    let r = radius as isize;
    let mut q = p;
    for _ in 0..30 {
        let (cx, cy) = (q.x.round() as isize, q.y.round() as isize);
        if cx - r - 1 < 0 || cy - r - 1 < 0 || cx + r + 1 >= w as isize || cy + r + 1 >= h as isize
        {
            return None;
        }
        let (mut a, mut b, mut c, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let sig2 = (radius as f64 * 0.6).powi(2);
        for dy in -r..=r {
            for dx in -r..=r {
                let (x, y) = ((cx + dx) as usize, (cy + dy) as usize);
                let gx = 0.5 * (gray[y * w + x + 1] - gray[y * w + x - 1]) as f64;
                let gy = 0.5 * (gray[(y + 1) * w + x] - gray[(y - 1) * w + x]) as f64;
                let wt = (-((dx * dx + dy * dy) as f64) / (2.0 * sig2)).exp();
                let (px, py) = (x as f64, y as f64);
                a += wt * gx * gx;
                b += wt * gx * gy;
                c += wt * gy * gy;
                bx += wt * (gx * gx * px + gx * gy * py);
                by += wt * (gx * gy * px + gy * gy * py);
            }
        }
        let det = a * c - b * b;
        if det.abs() < 1e-9 {
            return None;
        }
        let nq = DVec2::new((c * bx - b * by) / det, (a * by - b * bx) / det);
        if (nq - p).length() > radius as f64 {
            return None;
        }
        let step = (nq - q).length();
        q = nq;
        if step < 1e-3 {
            break;
        }
    }
    Some(q)
}

/// An inner checkerboard corner: on a circle around it the intensity crosses its
/// mean four times and is point-symmetric. The board's outer edge against the
/// background makes T-junctions and L-corners, which fail one or the other.
pub fn is_x_junction(gray: &[f32], w: usize, h: usize, p: DVec2, radius: f64) -> bool {
    const N: usize = 32;
    let mut v = [0f32; N];
    for (k, vk) in v.iter_mut().enumerate() {
        let a = 2.0 * std::f64::consts::PI * k as f64 / N as f64;
        let (x, y) = (p.x + radius * a.cos(), p.y + radius * a.sin());
        if x < 0.0 || y < 0.0 || x > (w - 1) as f64 || y > (h - 1) as f64 {
            return false;
        }
        *vk = crate::image::bilinear_plane(gray, w, h, x, y);
    }
    let mean = v.iter().sum::<f32>() / N as f32;
    let (lo, hi) = v
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    if hi - lo < 20.0 {
        return false;
    }
    let crossings = (0..N)
        .filter(|&k| (v[k] > mean) != (v[(k + 1) % N] > mean))
        .count();
    let asym = (0..N / 2).map(|k| (v[k] - v[k + N / 2]).abs()).sum::<f32>() / (N / 2) as f32;
    crossings == 4 && asym < 0.25 * (hi - lo)
}

/// Find the board's corners given their predicted pixel positions (from the
/// nominal geometry) and the board square's size in pixels. Returns, for each
/// prediction, the refined corner if found.
pub fn detect_checkerboard(
    gray: &[f32],
    w: usize,
    h: usize,
    predicted: &[DVec2],
    square_px: f64,
) -> Result<Vec<Option<DVec2>>> {
    if gray.len() != w * h || w < 16 || h < 16 {
        return Err(Error::Input(format!(
            "image {w}x{h} with {} values",
            gray.len()
        )));
    }
    if !(square_px >= 6.0) {
        return Err(Error::Corners(format!(
            "squares of {square_px:.1} px are too small to find"
        )));
    }
    let sigma = (square_px / 8.0).clamp(1.0, 3.0);
    let min_dist = (square_px / 3.0) as usize;
    let saddles: Vec<DVec2> = find_saddles(gray, w, h, sigma, 0.05, min_dist.max(2))
        .into_iter()
        .filter(|p| is_x_junction(gray, w, h, *p, 0.35 * square_px))
        .collect();
    if saddles.is_empty() {
        return Err(Error::Corners("no saddle points in the image".into()));
    }
    // Vote for the offset: pair the predicted centre-most corner with each saddle.
    let tol = 0.3 * square_px;
    let centre: DVec2 = predicted.iter().copied().sum::<DVec2>() / predicted.len().max(1) as f64;
    let anchor = predicted
        .iter()
        .copied()
        .min_by(|a, b| (*a - centre).length().total_cmp(&(*b - centre).length()))
        .ok_or_else(|| Error::Input("no predicted corners".into()))?;
    let nearest = |p: DVec2| -> Option<DVec2> {
        saddles
            .iter()
            .copied()
            .filter(|s| (*s - p).length() < tol)
            .min_by(|a, b| (*a - p).length().total_cmp(&(*b - p).length()))
    };
    let mut best = (0usize, DVec2::ZERO);
    for s in &saddles {
        let off = *s - anchor;
        if off.length() > 4.0 * square_px + 0.2 * w as f64 {
            continue;
        }
        let n = predicted
            .iter()
            .filter(|p| nearest(**p + off).is_some())
            .count();
        if n > best.0 {
            best = (n, off);
        }
    }
    if best.0 < predicted.len() / 2 {
        return Err(Error::Corners(format!(
            "only {} of {} corners line up with the prediction",
            best.0,
            predicted.len()
        )));
    }
    let blurred = gaussian_blur(gray, w, h, 0.7);
    let radius = ((square_px * 0.3) as usize).clamp(3, 12);
    Ok(predicted
        .iter()
        .map(|p| nearest(*p + best.1).and_then(|s| refine_corner(&blurred, w, h, s, radius)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraModel, Intrinsics};
    use crate::synth::{Checkerboard, render_checkerboard};
    use glam::{DMat3, DVec3};

    #[test]
    fn corners_found_to_subpixel_despite_a_shifted_prediction() {
        let intr = Intrinsics {
            fx: 5120.0,
            fy: 5120.0,
            cx: 255.5,
            cy: 191.5,
            k1: 0.0,
            k2: 0.0,
        };
        let cam = CameraModel::look_at(DVec3::new(250.0, 30.0, 380.0), DVec3::ZERO, DVec3::X, intr);
        let board = Checkerboard {
            squares_x: 5,
            squares_y: 4,
            square_mm: 5.0,
        };
        let img = render_checkerboard(
            &cam,
            512,
            384,
            &board,
            DMat3::from_rotation_z(0.3),
            DVec3::ZERO,
            1.0,
            1,
        );
        let truth: Vec<DVec2> = board
            .corners()
            .iter()
            .map(|c| cam.project(DMat3::from_rotation_z(0.3) * *c).unwrap())
            .collect();
        // A prediction off by 0.6 of a square: the voting must still associate correctly.
        let predicted: Vec<DVec2> = truth.iter().map(|t| *t + DVec2::new(22.0, -12.0)).collect();
        let found = detect_checkerboard(&img.channel_f32(0), 512, 384, &predicted, 45.0).unwrap();
        let mut sq = 0.0;
        for (f, t) in found.iter().zip(&truth) {
            let f = f.expect("every corner found");
            sq += (f - *t).length_squared();
        }
        let rms = (sq / truth.len() as f64).sqrt();
        assert!(rms < 0.1, "corner RMS {rms} px");
    }

    #[test]
    fn blank_image_is_an_error() {
        let g = vec![0.5f32; 64 * 64];
        assert!(detect_checkerboard(&g, 64, 64, &[DVec2::new(30.0, 30.0)], 10.0).is_err());
    }
}
