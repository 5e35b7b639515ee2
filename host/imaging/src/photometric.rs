//! Photometric and laser calibration (paper 4.1): relative colour of cameras
//! and lamps, lamp irradiance and laser flux from the diffuse reference white,
//! and the laser-plane angle from a stripe on two planes of known heights.
//!
//! All radiances here are in the cameras' linear units after HDR (one global
//! scale per camera, fixed by the colour calibration), so ratios such as
//! "outgoing over incoming flux" that the fitter forms are scale-free.

use std::f64::consts::PI;

use glam::DVec2;

use crate::rectify::StripeLine;
use crate::{Error, Result};

/// Relative colour gains of cameras: for each camera, the per-channel factor
/// that maps its linear values onto the reference camera's, from mean values
/// of the same patches of the colour pattern (`patch_means[camera][patch]`,
/// RGB, NaN for patches not seen). Least squares per channel through the origin.
pub fn colour_gains(patch_means: &[Vec<[f64; 3]>], reference: usize) -> Result<Vec<[f64; 3]>> {
    let r = patch_means
        .get(reference)
        .ok_or_else(|| Error::Input(format!("reference camera {reference} not measured")))?;
    patch_means
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let mut g = [0.0; 3];
            for c in 0..3 {
                // gain = sum(ref * m) / sum(m * m): m * gain ~ ref
                let (mut num, mut den) = (0.0, 0.0);
                for (a, b) in r.iter().zip(m) {
                    if a[c].is_finite() && b[c].is_finite() && b[c] > 0.0 {
                        num += a[c] * b[c];
                        den += b[c] * b[c];
                    }
                }
                if den <= 0.0 {
                    return Err(Error::Input(format!(
                        "camera {k} channel {c}: no usable patches"
                    )));
                }
                g[c] = num / den;
            }
            Ok(g)
        })
        .collect()
}

/// Irradiance on a surface normal to a lamp from the radiance of the
/// Lambertian reference white (albedo `rho`) lit by it at incidence cos `cos_i`:
/// L = rho E cos_i / pi  =>  E = pi L / (rho cos_i).
pub fn lamp_irradiance(white_radiance: [f64; 3], rho: f64, cos_i: f64) -> Result<[f64; 3]> {
    if !(rho > 0.0 && cos_i > 1e-3) {
        return Err(Error::Input(format!("albedo {rho}, cos incidence {cos_i}")));
    }
    Ok(white_radiance.map(|l| PI * l / (rho * cos_i)))
}

/// Laser flux per mm of stripe from a rectified image of the stripe on the
/// reference white: the white re-emits rho of the incoming flux with radiance
/// L over the hemisphere, so Phi_in = pi sum(L dA) / rho over the stripe's
/// neighbourhood. `texels` are the radiances of the texels within the window,
/// `texel_area` mm^2, `length_mm` the stripe length inside the window.
pub fn laser_flux_per_mm(texels: &[f32], texel_area: f64, rho: f64, length_mm: f64) -> Result<f64> {
    if !(rho > 0.0 && length_mm > 0.0 && texel_area > 0.0) {
        return Err(Error::Input(format!(
            "albedo {rho}, length {length_mm} mm, texel area {texel_area}"
        )));
    }
    let sum: f64 = texels
        .iter()
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .sum();
    Ok(PI * sum * texel_area / (rho * length_mm))
}

/// The laser plane's angle to the XY plane (paper 4.1) from the stripe's
/// lines on two parallel planes at heights `z_low` < `z_high` (each line
/// found on an image rectified onto its own plane). The stripe moves by the
/// perpendicular offset d between the lines when the surface rises by dh;
/// the plane then makes atan(dh / d) with XY. Returns radians in (0, pi/2].
pub fn laser_plane_angle(
    low: &StripeLine,
    high: &StripeLine,
    z_low: f64,
    z_high: f64,
) -> Result<f64> {
    let dh = z_high - z_low;
    if !(dh > 0.0) {
        return Err(Error::Input(format!(
            "plane heights {z_low} and {z_high} mm: need z_high > z_low"
        )));
    }
    if low.dir.dot(high.dir).abs() < (2f64.to_radians()).cos() {
        return Err(Error::Input(
            "stripe lines on the two planes are not parallel".into(),
        ));
    }
    let d = low.distance(high.point);
    Ok(dh.atan2(d))
}

/// Sub-pixel centres of a stripe running along y of a rectified image: for
/// every texel row whose y passes `keep`, the centroid in x of channel `c`
/// above a fifth of the row's peak, within 1.5 mm of the peak. Rows whose peak
/// is below a tenth of the brightest are skipped. Returns (x, y) points, mm.
pub fn stripe_centres(
    rect: &crate::image::ImageF,
    c: usize,
    grid: &crate::rectify::Grid,
    keep: impl Fn(f64) -> bool,
) -> Vec<DVec2> {
    // (row, column of the peak, peak value) of the kept rows with a finite texel.
    let peaks: Vec<(usize, usize, f32)> = (0..rect.height)
        .filter(|&j| keep(grid.texel_centre(0, j).y))
        .filter_map(|j| {
            (0..rect.width)
                .map(|i| (i, rect.get(i, j, c)))
                .filter(|(_, v)| v.is_finite())
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(i, v)| (j, i, v))
        })
        .collect();
    let brightest = peaks.iter().fold(0f32, |a, &(.., v)| a.max(v));
    let reach = (1.5 / grid.texel_mm).ceil() as isize;
    let mut out = Vec::new();
    for &(j, ip, vp) in &peaks {
        if !(vp > 0.1 * brightest) {
            continue;
        }
        let floor = 0.2 * vp;
        let (mut sw, mut sx) = (0.0, 0.0);
        let mut complete = true;
        for di in -reach..=reach {
            let i = ip as isize + di;
            if i < 0 || i >= rect.width as isize {
                complete = false;
                continue;
            }
            let v = rect.get(i as usize, j, c);
            if !v.is_finite() {
                complete = false;
                continue;
            }
            let w = (v - floor).max(0.0) as f64;
            sw += w;
            sx += w * grid.texel_centre(i as usize, j).x;
        }
        if complete && sw > 0.0 {
            out.push(DVec2::new(sx / sw, grid.texel_centre(0, j).y));
        }
    }
    out
}

/// Perpendicular offset between two parallel stripes given as centre points
/// (x, y) on two planes (the stripe runs roughly along y): one slope and two
/// intercepts x = a + b y by least squares, then (a_high - a_low) across the
/// common direction, signed positive towards `towards` (sample xy).
pub fn parallel_offset(low: &[DVec2], high: &[DVec2], towards: DVec2) -> Result<f64> {
    if low.len() < 3 || high.len() < 3 {
        return Err(Error::Input(format!(
            "{} and {} stripe centres on the two planes",
            low.len(),
            high.len()
        )));
    }
    let mean = |p: &[DVec2]| p.iter().copied().sum::<DVec2>() / p.len() as f64;
    let (ml, mh) = (mean(low), mean(high));
    let (mut sxy, mut syy) = (0.0, 0.0);
    for (pts, m) in [(low, ml), (high, mh)] {
        for p in pts {
            sxy += (p.y - m.y) * (p.x - m.x);
            syy += (p.y - m.y) * (p.y - m.y);
        }
    }
    if !(syy > 0.0) {
        return Err(Error::Input("stripe centres span no length".into()));
    }
    let b = sxy / syy;
    let (al, ah) = (ml.x - b * ml.y, mh.x - b * mh.y);
    // Unit normal of the direction (b, 1), towards the laser.
    let n = DVec2::new(1.0, -b).normalize();
    let n = if n.dot(towards) < 0.0 { -n } else { n };
    Ok(DVec2::new(ah - al, 0.0).dot(n))
}

/// The direction of the perpendicular offset from `low` to `high` (unit, sample xy):
/// with the angle it gives the plane's normal.
pub fn stripe_shift_direction(low: &StripeLine, high: &StripeLine) -> DVec2 {
    let n = DVec2::new(-low.dir.y, low.dir.x);
    if (high.point - low.point).dot(n) >= 0.0 {
        n
    } else {
        -n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laser_plane_angle_known_answer() {
        // Plane at 60 deg to XY: rising by 10 mm moves the stripe by 10 / tan 60.
        let a = 60f64.to_radians();
        let low = StripeLine {
            point: DVec2::new(0.0, 0.0),
            dir: DVec2::Y,
        };
        let high = StripeLine {
            point: DVec2::new(-10.0 / a.tan(), 5.0),
            dir: DVec2::Y,
        };
        let got = laser_plane_angle(&low, &high, 0.0, 10.0).unwrap();
        assert!((got - a).abs() < 1e-12);
        assert!(stripe_shift_direction(&low, &high).x < 0.0);
        assert!(laser_plane_angle(&low, &high, 10.0, 0.0).is_err());
        let skew = StripeLine {
            point: DVec2::ZERO,
            dir: DVec2::X,
        };
        assert!(laser_plane_angle(&low, &skew, 0.0, 10.0).is_err());
    }

    #[test]
    fn colour_gains_map_cameras_onto_the_reference() {
        let reference: Vec<[f64; 3]> = (0..24)
            .map(|i| [0.1 + i as f64 * 0.03, 0.2, 0.05 + i as f64 * 0.01])
            .collect();
        let other: Vec<[f64; 3]> = reference
            .iter()
            .map(|p| [p[0] / 1.1, p[1] * 1.2, p[2] / 0.9])
            .collect();
        let g = colour_gains(&[reference, other], 0).unwrap();
        assert!(
            (g[1][0] - 1.1).abs() < 1e-12
                && (g[1][1] - 1.0 / 1.2).abs() < 1e-12
                && (g[1][2] - 0.9).abs() < 1e-12
        );
        assert!((g[0][1] - 1.0).abs() < 1e-12);
        assert!(colour_gains(&[vec![[f64::NAN; 3]]], 0).is_err());
    }

    #[test]
    fn white_reference_inversions() {
        let e = lamp_irradiance([0.3, 0.2, 0.1], 0.95, 0.5).unwrap();
        assert!((e[0] - PI * 0.3 / (0.95 * 0.5)).abs() < 1e-12);
        assert!(lamp_irradiance([1.0; 3], 0.0, 1.0).is_err());
        // 1 W/mm over 10 mm on a white of albedo 1: radiance sums to 10 / pi per mm^2.
        let texels = vec![(10.0 / PI) as f32 / 100.0; 100];
        let f = laser_flux_per_mm(&texels, 1.0, 1.0, 10.0).unwrap();
        assert!((f - 1.0).abs() < 1e-6);
    }
}
