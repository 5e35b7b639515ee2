//! Imaging pipeline end to end on files: a textured reference plane rendered
//! through a known distorted camera at a turntable angle, written as an 8-bit
//! PNG exposure bracket through a known response; `rectify_capture` must give
//! a rectified dataset whose texels align with their true positions within
//! 0.5 texel, carry NaN where the bracket is clipped everywhere, and whose
//! index follows the contract.

use glam::{DVec2, DVec3};
use qhm_imaging::calibration::{Calibration, LampCal};
use qhm_imaging::camera::{CameraModel, Intrinsics};
use qhm_imaging::pipeline::{RectifyOptions, Shot, ShotLight, rectify_capture};
use qhm_imaging::rectified::{read_image, read_index};
use qhm_imaging::rectify::{Grid, sample_to_world};
use qhm_imaging::response::ResponseCurve;
use qhm_imaging::{hdr::MergeOptions, synthetic_calibration};

/// Radiance texture on the sample plane (sample frame, mm): smooth, with a
/// bright square that clips every exposure.
fn texture(p: DVec2) -> f64 {
    if p.x > 9.0 && p.x < 12.0 && p.y > 9.0 && p.y < 12.0 {
        return 1e4;
    }
    10.0 + 4.0 * (0.35 * p.x).sin() + 4.0 * (0.3 * p.y).cos()
}

fn gradient(p: DVec2) -> DVec2 {
    DVec2::new(
        4.0 * 0.35 * (0.35 * p.x).cos(),
        -4.0 * 0.3 * (0.3 * p.y).sin(),
    )
}

#[test]
fn rectified_dataset_aligns_within_half_a_texel() {
    let dir = tempfile::tempdir().unwrap();
    let intr = Intrinsics {
        fx: 2560.0,
        fy: 2562.0,
        cx: 257.0,
        cy: 190.0,
        k1: -0.15,
        k2: 0.3,
    };
    let cam = CameraModel::look_at(
        DVec3::new(280.0, 15.0, 360.0),
        DVec3::ZERO,
        DVec3::Z.cross(DVec3::X),
        intr,
    );
    let (w, h) = (512usize, 384usize);
    let theta = 0.9;
    let axis = DVec3::Z;
    let resp = synthetic_calibration::Response::gamma_s_curve(1.0, 0.0);
    let times = [0.0125, 0.05];
    let to_world = sample_to_world(axis, theta);
    let mut frames = Vec::new();
    for (k, t) in times.iter().enumerate() {
        let mut rgb = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                let d = cam.ray(DVec2::new(x as f64, y as f64));
                let o = cam.centre();
                let n = to_world * DVec3::Z;
                let s = -o.dot(n) / d.dot(n);
                let ps = to_world.transpose() * (o + s * d);
                let l = texture(ps.truncate());
                for c in 0..3 {
                    let v = (resp.output(l * t * [1.0, 0.7, 0.4][c]) * 255.0).round() as u8;
                    rgb.push(v);
                }
            }
        }
        let path = dir.path().join(format!("f{k}.png"));
        image::save_buffer(&path, &rgb, w as u32, h as u32, image::ColorType::Rgb8).unwrap();
        frames.push((path, *t));
    }
    // The calibration: the known camera (full resolution = these pixels) and response.
    let mut cal = Calibration::default();
    let inv_poly = {
        // Fit the true inverse response as a polynomial (what MN would give) at 256 points.
        let a: Vec<Vec<f64>> = (0..256)
            .map(|z| (0..6).map(|n| (z as f64 / 255.0).powi(n)).collect())
            .collect();
        let b: Vec<f64> = (0..256).map(|z| resp.exposure_of(z as f64)).collect();
        qhm_imaging::linalg::lstsq_qr(&a, &b).unwrap()
    };
    let c = cal.camera_mut(3);
    c.geometry = Some(cam);
    c.response = vec![ResponseCurve::Polynomial { coeffs: inv_poly }; 3];
    cal.lamp.push(LampCal {
        index: 5,
        direction: [-0.5, 0.0, 0.866],
        irradiance: Some([1.0, 0.9, 0.8]),
    });
    let grid = Grid::centred(64, 0.5);
    let opts = RectifyOptions {
        grid,
        binning: 1,
        sensor_gain: 1.0,
        threshold: 0.3,
        d_min: 0.5,
        d_max: 10.0,
        merge: MergeOptions::default(),
        light_arc_azimuth0: std::f64::consts::PI,
    };
    let shot = Shot {
        light: ShotLight::Lamp { index: 5 },
        turntable: theta,
        light_arc: 0.4,
        camera: 3,
        frames,
    };
    let out = dir.path().join("rectified");
    let idx = rectify_capture(&[shot.clone()], &cal, &opts, &out, &|_, _| {}).unwrap();
    assert_eq!(idx.lamp.len(), 1);

    let idx = read_index(&out).unwrap();
    assert_eq!(
        (
            idx.grid.width,
            idx.grid.height,
            idx.grid.texel_mm,
            idx.grid.origin_mm
        ),
        (64, 64, 0.5, [-16.0, -16.0])
    );
    let e = &idx.lamp[0];
    assert_eq!(e.camera, 3);
    assert_eq!(e.irradiance, [1.0, 0.9, 0.8]);
    // The lamp turned with the light arc, seen from the turned sample.
    let want = sample_to_world(axis, theta).transpose()
        * (glam::DMat3::from_rotation_z(0.4) * DVec3::new(-0.5, 0.0, 0.866));
    assert!((DVec3::from(e.light_dir) - want.normalize()).length() < 1e-9);
    let vd = DVec3::from(e.view_dir);
    assert!(
        (vd - (sample_to_world(axis, theta).transpose() * cam.centre()).normalize()).length()
            < 1e-9
    );

    let img = read_image(&out, &idx, &e.file).unwrap();
    // Alignment: in 8 x 8 texel blocks, the shift d (texels) that explains the
    // value errors e = grad(f) . d best (least squares); 8-bit noise averages out.
    // Linear response, channel gain 1, scale 1: HDR values are the radiance itself.
    let refv = 1.0;
    let mut worst: f64 = 0.0;
    let mut nan = 0;
    for bj in 0..8 {
        for bi in 0..8 {
            let (mut a11, mut a12, mut a22, mut b1, mut b2, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0);
            for j in bj * 8..bj * 8 + 8 {
                for i in bi * 8..bi * 8 + 8 {
                    let p = grid.texel_centre(i, j);
                    let v = img.get(i, j, 0) as f64;
                    if texture(p) > 100.0 {
                        nan += v.is_nan() as usize;
                        continue;
                    }
                    // A texel away from the clipped square (bilinear mixes it in).
                    if (p.x > 8.0 && p.x < 13.0 && p.y > 8.0 && p.y < 13.0) || !v.is_finite() {
                        continue;
                    }
                    let g = gradient(p) * grid.texel_mm; // value change per texel
                    let e = v / refv - texture(p);
                    a11 += g.x * g.x;
                    a12 += g.x * g.y;
                    a22 += g.y * g.y;
                    b1 += g.x * e;
                    b2 += g.y * e;
                    n += 1;
                }
            }
            if n < 32 {
                continue;
            }
            let det = a11 * a22 - a12 * a12;
            let d = DVec2::new(a22 * b1 - a12 * b2, a11 * b2 - a12 * b1) / det;
            worst = worst.max(d.length());
        }
    }
    assert!(worst < 0.5, "misalignment {worst} texel");
    assert!(nan >= 16, "clipped texels must be NaN, got {nan}");
    assert!(
        rectify_capture(&[shot], &cal, &opts, &out, &|_, _| {}).is_err(),
        "an existing dataset is refused"
    );
}
