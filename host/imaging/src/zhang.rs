//! Camera calibration by Zhang's method (Zhang 1999, the paper's choice):
//! homographies by normalised DLT, closed-form intrinsics from the image of the
//! absolute conic, extrinsics per view, then Levenberg-Marquardt refinement of
//! all parameters including radial distortion (k1, k2).
//!
//! Views of a single plane in one orientation (a flat board rotated on the
//! turntable) leave the intrinsics under-determined; then the closed form
//! falls back to a principal point at the image centre and square pixels,
//! with only the focal length solved (see docs/imaging.md). A view of the
//! board raised by a known height over another view (`Raised`: the board on
//! a spacer block) shares that view's plane orientation and lies a known
//! distance along its normal; the change of image scale with that known depth
//! change separates focal length and distance, which a fronto-parallel board
//! at one height cannot.

use glam::{DMat3, DVec2, DVec3};

use crate::camera::{CameraModel, Intrinsics, rodrigues, rodrigues_inv};
use crate::linalg;
use crate::lm;
use crate::{Error, Result};

/// Corresponding points of one view: board plane (mm, z = 0) and image (px).
#[derive(Debug, Clone)]
pub struct PlanarView {
    pub object: Vec<DVec2>,
    pub image: Vec<DVec2>,
    /// This view's board lies on a spacer over the board of another view.
    pub raised: Option<Raised>,
}

/// A view of the board raised by a known height over the board of view `base`
/// (the same turntable pose): its points are at `Rz(phi) (x, y) + (dx, dy)`,
/// z = `height_mm` in `base`'s board frame. The in-plane shift and turn
/// (the board placed by hand on the spacer) are estimated; the height is known.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Raised {
    /// Index (in the views passed to `calibrate`) of a view at height 0.
    pub base: usize,
    /// The spacer's thickness, mm (the board's normal offset).
    pub height_mm: f64,
}

/// Result of a calibration.
#[derive(Debug, Clone)]
pub struct Calibrated {
    pub intrinsics: Intrinsics,
    /// Board -> camera pose of each view (Rodrigues, translation mm); a raised
    /// view's board frame is its own (origin on the raised board).
    pub poses: Vec<(DVec3, DVec3)>,
    /// Reprojection RMS over all points, px.
    pub rms: f64,
    /// Whether the closed form had to assume the principal point (degenerate views).
    pub principal_point_assumed: bool,
}

impl Calibrated {
    /// The camera of view `k` as a CameraModel whose "world" is that view's board frame.
    pub fn camera(&self, k: usize) -> CameraModel {
        let (r, t) = self.poses[k];
        CameraModel {
            intrinsics: self.intrinsics,
            rotation: r.to_array(),
            translation: t.to_array(),
        }
    }
}

/// Normalising similarity (centroid to 0, mean distance sqrt 2) of 2D points.
fn normaliser(pts: &[DVec2]) -> DMat3 {
    let c = pts.iter().copied().sum::<DVec2>() / pts.len() as f64;
    let d = pts.iter().map(|p| (*p - c).length()).sum::<f64>() / pts.len() as f64;
    let s = std::f64::consts::SQRT_2 / d.max(1e-12);
    DMat3::from_cols(
        DVec3::new(s, 0.0, 0.0),
        DVec3::new(0.0, s, 0.0),
        DVec3::new(-s * c.x, -s * c.y, 1.0),
    )
}

pub(crate) fn apply(h: &DMat3, p: DVec2) -> DVec2 {
    let q = *h * DVec3::new(p.x, p.y, 1.0);
    DVec2::new(q.x / q.z, q.y / q.z)
}

/// Homography mapping `from` to `to` (>= 4 points) by the normalised DLT.
pub fn homography(from: &[DVec2], to: &[DVec2]) -> Result<DMat3> {
    if from.len() != to.len() || from.len() < 4 {
        return Err(Error::Input(format!(
            "homography needs >= 4 pairs, got {}",
            from.len().min(to.len())
        )));
    }
    let (tf, tt) = (normaliser(from), normaliser(to));
    let mut rows = Vec::with_capacity(2 * from.len());
    for (a, b) in from.iter().zip(to) {
        let (p, q) = (apply(&tf, *a), apply(&tt, *b));
        rows.push(vec![
            p.x,
            p.y,
            1.0,
            0.0,
            0.0,
            0.0,
            -q.x * p.x,
            -q.x * p.y,
            -q.x,
        ]);
        rows.push(vec![
            0.0,
            0.0,
            0.0,
            p.x,
            p.y,
            1.0,
            -q.y * p.x,
            -q.y * p.y,
            -q.y,
        ]);
    }
    let h = linalg::null_vector(&rows, 9);
    let hn = DMat3::from_cols(
        DVec3::new(h[0], h[3], h[6]),
        DVec3::new(h[1], h[4], h[7]),
        DVec3::new(h[2], h[5], h[8]),
    );
    let hm = tt.inverse() * hn * tf;
    if !hm.is_finite() || hm.determinant().abs() < 1e-300 {
        return Err(Error::Numeric(
            "degenerate homography (collinear points?)".into(),
        ));
    }
    Ok(hm * (1.0 / hm.z_axis.z))
}

fn v_ij(h: &DMat3, i: usize, j: usize) -> Vec<f64> {
    let (hi, hj) = (h.col(i), h.col(j));
    vec![
        hi.x * hj.x,
        hi.x * hj.y + hi.y * hj.x,
        hi.y * hj.y,
        hi.z * hj.x + hi.x * hj.z,
        hi.z * hj.y + hi.y * hj.z,
        hi.z * hj.z,
    ]
}

/// Closed-form intrinsics from homographies (zero skew imposed); None if degenerate.
fn closed_form(hs: &[DMat3]) -> Option<Intrinsics> {
    let mut rows = Vec::new();
    for h in hs {
        let v12 = v_ij(h, 0, 1);
        let v11 = v_ij(h, 0, 0);
        let v22 = v_ij(h, 1, 1);
        rows.push(v12);
        rows.push(v11.iter().zip(&v22).map(|(a, b)| a - b).collect());
    }
    // Zero skew: B12 = 0, weighted strongly.
    rows.push(vec![0.0, 1e3, 0.0, 0.0, 0.0, 0.0]);
    if rows.len() < 6 {
        return None;
    }
    // Conditioning: the entries of b span many orders of magnitude; scale columns.
    let scale: Vec<f64> = (0..6)
        .map(|k| {
            rows.iter()
                .map(|r| r[k] * r[k])
                .sum::<f64>()
                .sqrt()
                .max(1e-300)
        })
        .collect();
    let scaled: Vec<Vec<f64>> = rows
        .iter()
        .map(|r| r.iter().zip(&scale).map(|(a, s)| a / s).collect())
        .collect();
    let bs = linalg::null_vector(&scaled, 6);
    let b: Vec<f64> = bs.iter().zip(&scale).map(|(a, s)| a / s).collect();
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if den.abs() < 1e-300 || b11.abs() < 1e-300 {
        return None;
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    let alpha2 = lambda / b11;
    let beta2 = lambda * b11 / den;
    if !(alpha2 > 0.0 && beta2 > 0.0) {
        return None;
    }
    let (alpha, beta) = (alpha2.sqrt(), beta2.sqrt());
    let gamma = -b12 * alpha * alpha * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    Some(Intrinsics {
        fx: alpha,
        fy: beta,
        cx: u0,
        cy: v0,
        k1: 0.0,
        k2: 0.0,
    })
}

/// Focal length alone (square pixels, principal point given) from homographies:
/// orthogonality and equal norms of K^-1 h1, K^-1 h2 are linear in 1/f^2.
fn focal_only(hs: &[DMat3], cx: f64, cy: f64) -> Option<f64> {
    let mut num = 0.0;
    let mut den = 0.0;
    for h in hs {
        // Shift the principal point to the origin: h' = T h.
        let t = DMat3::from_cols(DVec3::X, DVec3::Y, DVec3::new(-cx, -cy, 1.0));
        let hp = t * *h;
        let (a, b) = (hp.col(0), hp.col(1));
        // With w = 1/f^2: (a.x b.x + a.y b.y) w + a.z b.z = 0,
        // (a.x^2 + a.y^2 - b.x^2 - b.y^2) w + a.z^2 - b.z^2 = 0.
        for (p, q) in [
            (a.x * b.x + a.y * b.y, a.z * b.z),
            (
                a.x * a.x + a.y * a.y - b.x * b.x - b.y * b.y,
                a.z * a.z - b.z * b.z,
            ),
        ] {
            num += -p * q;
            den += p * p;
        }
    }
    let w = num / den;
    (w > 0.0).then(|| 1.0 / w.sqrt())
}

/// Board -> camera pose from a homography and intrinsics.
fn pose_from_h(h: &DMat3, k: &Intrinsics) -> (DVec3, DVec3) {
    let kinv = DMat3::from_cols(
        DVec3::new(1.0 / k.fx, 0.0, 0.0),
        DVec3::new(0.0, 1.0 / k.fy, 0.0),
        DVec3::new(-k.cx / k.fx, -k.cy / k.fy, 1.0),
    );
    let (h1, h2, h3) = (kinv * h.col(0), kinv * h.col(1), kinv * h.col(2));
    let mut l = 1.0 / h1.length();
    if (l * h3).z < 0.0 {
        l = -l; // the board is in front of the camera
    }
    let r1 = (l * h1).normalize();
    let r2 = (l * h2 - r1 * r1.dot(l * h2)).normalize();
    let r3 = r1.cross(r2);
    (rodrigues_inv(DMat3::from_cols(r1, r2, r3)), l * h3)
}

/// Options of the calibration.
#[derive(Debug, Clone, Copy)]
pub struct ZhangOptions {
    pub image_width: usize,
    pub image_height: usize,
    /// Refine distortion (k1, k2).
    pub distortion: bool,
    /// Keep fx = fy and the principal point at the image centre (flat single-plane views).
    pub fix_principal_point: bool,
    /// Prior on the distance from the camera centre to the board origin,
    /// (mm, standard deviation mm): the rig's mechanics. With a single board
    /// plane it fixes the focal length / distance trade-off of near-frontal views
    /// (raised views fix it from the data; the prior applies to unraised views).
    /// It is weighed against the corners by their scatter (the reprojection RMS
    /// of a first fit), so oblique views, whose perspective does determine the
    /// focal length, are not overruled by it.
    pub centre_distance: Option<(f64, f64)>,
    /// Focal length to start from when the views cannot give one (fronto-parallel).
    pub initial_focal: Option<f64>,
    /// With `fix_principal_point`: let the principal point move from the image
    /// centre under a prior of this standard deviation (px) instead of holding
    /// it there. The flat board cannot find it, but a held-wrong principal
    /// point biases the focal length of oblique views.
    pub principal_sd: Option<f64>,
    /// With `fix_principal_point` and `principal_sd`: fit fy apart from fx.
    /// A board turned in its own plane shows the pixels' aspect ratio (its
    /// squares' image sides swap between the image axes); a sensor whose
    /// fy differs from fx by 0.2 % otherwise pulls the focal, the principal
    /// point and the distortion off (top camera: 15 mm off laterally).
    pub fit_aspect: bool,
}

/// Calibrate one camera from views of a planar target.
pub fn calibrate(views: &[PlanarView], opts: ZhangOptions) -> Result<Calibrated> {
    if views.is_empty() {
        return Err(Error::Input("no views".into()));
    }
    for v in views {
        if v.object.len() != v.image.len() || v.object.len() < 6 {
            return Err(Error::Input(format!(
                "a view with {} object / {} image points",
                v.object.len(),
                v.image.len()
            )));
        }
        if let Some(r) = v.raised {
            if r.base >= views.len() || views[r.base].raised.is_some() {
                return Err(Error::Input(format!(
                    "a raised view's base {} is not an unraised view",
                    r.base
                )));
            }
            if !(r.height_mm.is_finite() && r.height_mm != 0.0) {
                return Err(Error::Input(format!(
                    "a raised view's height must be finite and non-zero, got {}",
                    r.height_mm
                )));
            }
        }
    }
    let hs: Vec<DMat3> = views
        .iter()
        .map(|v| homography(&v.object, &v.image))
        .collect::<Result<_>>()?;
    let (cx0, cy0) = (
        (opts.image_width as f64 - 1.0) / 2.0,
        (opts.image_height as f64 - 1.0) / 2.0,
    );
    let plausible = |k: &Intrinsics| {
        k.fx.is_finite()
            && (k.fx / k.fy - 1.0).abs() < 0.05
            && k.cx > 0.0
            && k.cx < opts.image_width as f64
            && k.cy > 0.0
            && k.cy < opts.image_height as f64
    };
    let mut assumed = opts.fix_principal_point;
    let init = match (!opts.fix_principal_point)
        .then(|| closed_form(&hs))
        .flatten()
    {
        Some(k) if plausible(&k) => k,
        _ => {
            assumed = true;
            let f = focal_only(&hs, cx0, cy0)
                .filter(|f| {
                    opts.initial_focal
                        .is_none_or(|f0| (f / f0 - 1.0).abs() < 0.2)
                })
                .or(opts.initial_focal)
                .ok_or_else(|| {
                    Error::Numeric("views determine no focal length (fronto-parallel?)".into())
                })?;
            Intrinsics {
                fx: f,
                fy: f,
                cx: cx0,
                cy: cy0,
                k1: 0.0,
                k2: 0.0,
            }
        }
    };
    let poses: Vec<(DVec3, DVec3)> = hs.iter().map(|h| pose_from_h(h, &init)).collect();

    // Parameters: [fx, fy, cx, cy, k1, k2], then per view 6 (Rodrigues,
    // translation) or, raised, 3 (phi, dx, dy) relative to its base view.
    let mut p = vec![init.fx, init.fy, init.cx, init.cy, 0.0, 0.0];
    let mut offset = Vec::with_capacity(views.len());
    for (v, (r, t)) in views.iter().zip(&poses) {
        offset.push(p.len());
        match v.raised {
            None => p.extend_from_slice(&[r.x, r.y, r.z, t.x, t.y, t.z]),
            Some(rs) => {
                // In-plane turn and shift of the raised board in the base board's frame.
                let (rb, tb) = poses[rs.base];
                let rb = rodrigues(rb);
                let rel = rb.transpose() * rodrigues(*r);
                let d = rb.transpose() * (*t - tb);
                p.extend_from_slice(&[rel.x_axis.y.atan2(rel.x_axis.x), d.x, d.y]);
            }
        }
    }
    let base_pose = |p: &[f64], vi: usize| -> (DMat3, DVec3) {
        let q = &p[offset[vi]..offset[vi] + 6];
        (
            rodrigues(DVec3::new(q[0], q[1], q[2])),
            DVec3::new(q[3], q[4], q[5]),
        )
    };
    // Board -> camera rotation and translation of view vi.
    let pose = |p: &[f64], vi: usize| -> (DMat3, DVec3) {
        match views[vi].raised {
            None => base_pose(p, vi),
            Some(rs) => {
                let (rb, tb) = base_pose(p, rs.base);
                let q = &p[offset[vi]..offset[vi] + 3];
                (
                    rb * DMat3::from_rotation_z(q[0]),
                    rb * DVec3::new(q[1], q[2], rs.height_mm) + tb,
                )
            }
        }
    };
    let unraised: Vec<usize> = (0..views.len())
        .filter(|&vi| views[vi].raised.is_none())
        .collect();
    let pp_prior = opts.principal_sd.filter(|sd| assumed && *sd > 0.0);
    let m_points: usize = views.iter().map(|v| 2 * v.object.len()).sum();
    let m = m_points
        + if opts.centre_distance.is_some() {
            unraised.len()
        } else {
            0
        }
        + if pp_prior.is_some() { 2 } else { 0 };
    let unpack = |p: &[f64]| -> Intrinsics {
        let (fy, cx, cy) = if pp_prior.is_some() {
            (if opts.fit_aspect { p[1] } else { p[0] }, p[2], p[3])
        } else if assumed {
            (p[0], cx0, cy0)
        } else {
            (p[1], p[2], p[3])
        };
        let (k1, k2) = if opts.distortion {
            (p[4], p[5])
        } else {
            (0.0, 0.0)
        };
        Intrinsics {
            fx: p[0],
            fy,
            cx,
            cy,
            k1,
            k2,
        }
    };
    // Residuals with the priors weighed by w, the pixels of residual per
    // standard deviation of the prior (the corners' scatter).
    let (offset, unraised) = (&offset, &unraised);
    let residuals_w = |w: f64| {
        move |p: &[f64], out: &mut [f64]| {
            let k = unpack(p);
            let mut i = 0;
            for (vi, v) in views.iter().enumerate() {
                let (r, t) = pose(p, vi);
                for (o, im) in v.object.iter().zip(&v.image) {
                    let pc = r * DVec3::new(o.x, o.y, 0.0) + t;
                    let px = k.distort_to_pixel(DVec2::new(pc.x / pc.z, pc.y / pc.z));
                    out[i] = px.x - im.x;
                    out[i + 1] = px.y - im.y;
                    i += 2;
                }
            }
            if let Some((d, sd)) = opts.centre_distance {
                for &vi in unraised {
                    let q = &p[offset[vi]..offset[vi] + 6];
                    out[i] = w * (DVec3::new(q[3], q[4], q[5]).length() - d) / sd;
                    i += 1;
                }
            }
            if let Some(sd) = pp_prior {
                out[i] = w * (p[2] - cx0) / sd;
                out[i + 1] = w * (p[3] - cy0) / sd;
            }
        }
    };
    let steps: Vec<f64> = p
        .iter()
        .enumerate()
        .map(|(i, v)| {
            if i == 4 || i == 5 {
                1e-7
            } else {
                1e-7 * v.abs().max(1.0)
            }
        })
        .collect();
    let residuals = residuals_w(1.0);
    lm::minimise(&mut p, m, &steps, 200, residuals);
    let mut r = vec![0.0; m];
    residuals(&p, &mut r);
    if opts.centre_distance.is_some() || pp_prior.is_some() {
        // Refit with the prior weighed by the corners' measured scatter
        // (per coordinate), never more than one pixel per standard deviation.
        let point_cost: f64 = r[..m_points].iter().map(|x| x * x).sum();
        let scatter = (point_cost / m_points as f64).sqrt().clamp(1e-3, 1.0);
        let residuals = residuals_w(scatter);
        lm::minimise(&mut p, m, &steps, 200, residuals);
        residuals(&p, &mut r);
    }
    let point_cost: f64 = r[..m_points].iter().map(|x| x * x).sum();
    let intrinsics = unpack(&p);
    let poses = (0..views.len())
        .map(|vi| {
            let (r, t) = pose(&p, vi);
            (rodrigues_inv(r), t)
        })
        .collect();
    Ok(Calibrated {
        intrinsics,
        poses,
        rms: (point_cost / (m_points / 2) as f64).sqrt(),
        principal_point_assumed: assumed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::corners::detect_checkerboard;
    use crate::synthetic_calibration::{Checkerboard, render_checkerboard};

    fn truth() -> Intrinsics {
        Intrinsics {
            fx: 5150.0,
            fy: 5140.0,
            cx: 520.0,
            cy: 380.0,
            k1: -0.4,
            k2: 2.0,
        }
    }

    #[test]
    fn homography_maps_points_exactly() {
        let from = [
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(0.0, 1.0),
            DVec2::new(0.3, 0.6),
        ];
        let hm = DMat3::from_cols(
            DVec3::new(2.0, 0.1, 1e-3),
            DVec3::new(0.2, 3.0, 2e-3),
            DVec3::new(5.0, 7.0, 1.0),
        );
        let to: Vec<DVec2> = from.iter().map(|p| apply(&hm, *p)).collect();
        let h = homography(&from, &to).unwrap();
        for (a, b) in from.iter().zip(&to) {
            assert!((apply(&h, *a) - *b).length() < 1e-9);
        }
        assert!(homography(&from[..3], &to[..3]).is_err());
    }

    /// Tilted board views rendered through a known camera, corners detected in
    /// the 8-bit images, then calibrated: focal within 0.5%, RMS < 0.3 px.
    #[test]
    fn zhang_recovers_a_rendered_camera() {
        let k = truth();
        let (w, h) = (1024usize, 768usize);
        let board = Checkerboard {
            squares_x: 12,
            squares_y: 9,
            square_mm: 5.0,
        };
        let cam_world =
            CameraModel::look_at(DVec3::new(300.0, 0.0, 340.0), DVec3::ZERO, DVec3::X, k);
        let mut views = Vec::new();
        for (i, (tilt, turn)) in [(0.0, 0.0), (0.35, 0.5), (0.3, 2.0), (0.4, 3.6), (0.25, 5.0)]
            .iter()
            .enumerate()
        {
            let rot = DMat3::from_rotation_z(*turn) * DMat3::from_rotation_x(*tilt);
            let img =
                render_checkerboard(&cam_world, w, h, &board, rot, DVec3::ZERO, 1.0, i as u64);
            // Predictions from a camera 1% off in focal and slightly rotated: the nominal geometry.
            let mut nominal = cam_world;
            nominal.intrinsics.fx *= 1.01;
            nominal.intrinsics.fy *= 1.01;
            nominal.intrinsics.k1 = 0.0;
            nominal.intrinsics.k2 = 0.0;
            nominal.rotation[1] += 0.002;
            let obj3 = board.corners();
            let pred: Vec<DVec2> = obj3
                .iter()
                .map(|c| nominal.project(rot * *c).unwrap())
                .collect();
            let found = detect_checkerboard(&img.channel_f32(0), w, h, &pred, 5.0 * 5120.0 / 450.0)
                .unwrap();
            let (mut object, mut image) = (Vec::new(), Vec::new());
            for (o, f) in obj3.iter().zip(found) {
                if let Some(f) = f {
                    object.push(o.truncate());
                    image.push(f);
                }
            }
            assert!(
                object.len() as f64 > 0.9 * obj3.len() as f64,
                "view {i}: {} corners",
                object.len()
            );
            views.push(PlanarView {
                object,
                image,
                raised: None,
            });
        }
        let opts = ZhangOptions {
            image_width: w,
            image_height: h,
            distortion: true,
            fix_principal_point: false,
            centre_distance: None,
            initial_focal: None,
            principal_sd: None,
            fit_aspect: false,
        };
        let cal = calibrate(&views, opts).unwrap();
        let fe = (cal.intrinsics.fx / k.fx - 1.0)
            .abs()
            .max((cal.intrinsics.fy / k.fy - 1.0).abs());
        assert!(fe < 0.005, "focal error {fe}: {:?}", cal.intrinsics);
        assert!(cal.rms < 0.3, "reprojection RMS {}", cal.rms);
        assert!(!cal.principal_point_assumed);
    }
    /// A camera looking straight down at the flat board turned on the
    /// turntable (the rig's top camera), 6 mm further than the 450 mm the
    /// distance prior assumes, fy 0.2 % over fx, corners with 0.05 px noise: at one height its
    /// focal length is the prior's (1.3 % off); with the board also on a 20 mm
    /// spacer (placed by hand: shifted and turned in its plane) the image
    /// scale's change with the known depth change gives it within 0.5 %.
    #[test]
    fn raised_board_fixes_a_top_down_focal() {
        use rand::SeedableRng;
        let k = Intrinsics {
            fx: 2565.0,
            fy: 2570.0,
            cx: 257.0,
            cy: 190.5,
            k1: -0.05,
            k2: 0.0,
        };
        let cam = CameraModel::look_at(
            DVec3::new(0.5, -0.3, 456.0),
            DVec3::new(1.5, -2.0, 0.0),
            DVec3::Y,
            k,
        );
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let board: Vec<DVec2> = (-5..=5)
            .flat_map(|j| (-5..=5).map(move |i| DVec2::new(i as f64 * 5.0, j as f64 * 5.0)))
            .collect();
        let mut view = |theta: f64, shift: DVec3, turn: f64| {
            let r = DMat3::from_rotation_z(theta) * DMat3::from_rotation_z(turn);
            let mut v = PlanarView {
                object: Vec::new(),
                image: Vec::new(),
                raised: None,
            };
            for o in &board {
                let w = DMat3::from_rotation_z(theta) * shift + r * DVec3::new(o.x, o.y, 0.0);
                let p = cam.project(w).unwrap();
                let n = DVec2::new(
                    crate::synthetic_calibration::normal(&mut rng),
                    crate::synthetic_calibration::normal(&mut rng),
                );
                v.object.push(*o);
                v.image.push(p + 0.05 * n);
            }
            v
        };
        let thetas: Vec<f64> = (0..6).map(|i| i as f64 * 1.047 + 0.2).collect();
        let low: Vec<PlanarView> = thetas.iter().map(|&t| view(t, DVec3::ZERO, 0.0)).collect();
        let mut both = low.clone();
        for (i, &t) in thetas.iter().enumerate() {
            let mut v = view(t, DVec3::new(0.8, -0.5, 20.0), 0.02);
            v.raised = Some(Raised {
                base: i,
                height_mm: 20.0,
            });
            both.push(v);
        }
        let opts = |prior: bool| ZhangOptions {
            image_width: 512,
            image_height: 384,
            distortion: true,
            fix_principal_point: true,
            centre_distance: prior.then_some((450.0, 1.0)),
            initial_focal: Some(2560.0),
            principal_sd: Some(2.0),
            fit_aspect: true,
        };
        let one = calibrate(&low, opts(true)).unwrap();
        let fe = |c: &Calibrated| {
            (c.intrinsics.fx / k.fx - 1.0)
                .abs()
                .max((c.intrinsics.fy / k.fy - 1.0).abs())
        };
        let fe_one = fe(&one);
        assert!(fe_one > 0.005, "one height: focal error {fe_one}");
        let two = calibrate(&both, opts(false)).unwrap();
        let fe_two = fe(&two);
        assert!(fe_two < 0.005, "two heights: focal error {fe_two}");
        assert!(two.rms < 0.1, "reprojection RMS {}", two.rms);
        // The raised view's pose is its own board frame: 20 mm nearer the camera.
        let (d0, d1) = (two.poses[0].1.length(), two.poses[6].1.length());
        assert!((d0 - d1 - 20.0).abs() < 0.5, "distances {d0} {d1}");
        // A raised view must rest on an unraised one.
        let mut bad = both.clone();
        bad[6].raised = Some(Raised {
            base: 7,
            height_mm: 20.0,
        });
        assert!(calibrate(&bad, opts(false)).is_err());
    }
}
