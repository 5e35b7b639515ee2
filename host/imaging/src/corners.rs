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
use rayon::prelude::*;

use crate::{Error, Result};

/// Separable Gaussian blur of a single-channel plane.
pub fn gaussian_blur(src: &[f32], w: usize, h: usize, sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let ks: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| v / ks).collect();
    let tap = |i: isize, n: usize| (i - r).clamp(0, n as isize - 1) as usize;
    let mut tmp = vec![0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        // The row with its edge pixels repeated r times each side, so the
        // taps need no bounds.
        let padded: Vec<f32> = (0..w + 2 * r as usize)
            .map(|i| src[y * w + tap(i as isize, w)])
            .collect();
        for (t, win) in row.iter_mut().zip(padded.windows(k.len())) {
            *t = k.iter().zip(win).map(|(kv, v)| kv * v).sum();
        }
    });
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (j, kv) in k.iter().enumerate() {
            let yy = tap(y as isize + j as isize, h);
            for (o, t) in row.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                *o += kv * t;
            }
        }
    });
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

/// Least-squares fit of a corner model to the raw pixels around `p`:
/// I(u) = m + a tanh(d1 / w) tanh(d2 / w), d_k = n_k . (u - c), n_k the unit
/// normal of edge k at angle phi_k. Both edges are straight through the corner
/// (a projected board), so every pixel of the window, not only those with a
/// strong gradient, informs c; image noise that is flat on average leaves c
/// unbiased (the gradient-orthogonality refinement is pulled towards its start
/// point by noise gradients). `e1`, `e2` are the (predicted) image vectors to
/// the neighbouring corners along the board's two axes: the window is the
/// parallelogram |s|, |t| <= `reach` of u - p = s e1 + t e2. Returns None when
/// the fit fails or moves the corner by more than a third of the window.
pub fn fit_saddle(
    gray: &[f32],
    w: usize,
    h: usize,
    p: DVec2,
    e1: DVec2,
    e2: DVec2,
    reach: f64,
) -> Option<DVec2> {
    let det = e1.x * e2.y - e1.y * e2.x;
    if !(det.abs() > 1e-6) {
        return None;
    }
    // Window pixels: the parallelogram's bounding box, filtered.
    let corners = [e1 + e2, e1 - e2, -e1 + e2, -e1 - e2].map(|v| v * reach);
    let ext = corners.iter().fold(DVec2::ZERO, |a, v| a.max(v.abs()));
    let (x0, x1) = (
        (p.x - ext.x).floor() as isize,
        (p.x + ext.x).ceil() as isize,
    );
    let (y0, y1) = (
        (p.y - ext.y).floor() as isize,
        (p.y + ext.y).ceil() as isize,
    );
    if x0 < 0 || y0 < 0 || x1 >= w as isize || y1 >= h as isize {
        return None;
    }
    let mut px: Vec<(DVec2, f64)> = Vec::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = DVec2::new(x as f64, y as f64) - p;
            let s = (d.x * e2.y - d.y * e2.x) / det;
            let t = (e1.x * d.y - e1.y * d.x) / det;
            if s.abs() <= reach && t.abs() <= reach {
                px.push((d, gray[y as usize * w + x as usize] as f64));
            }
        }
    }
    if px.len() < 16 {
        return None;
    }
    // Parameters relative to p: [cx, cy, phi1, phi2, m, a, ln w].
    let normal_angle = |e: DVec2| (-e.x).atan2(e.y); // normal of an edge along e
    let mut q = [
        0.0,
        0.0,
        normal_angle(e1),
        normal_angle(e2),
        0.0,
        0.0,
        0.0f64,
    ];
    // What the model needs of a parameter vector, computed once per vector.
    struct Geom {
        c: DVec2,
        n1: DVec2,
        n2: DVec2,
        ww: f64,
    }
    let geom = |q: &[f64; 7]| Geom {
        c: DVec2::new(q[0], q[1]),
        n1: DVec2::new(q[2].cos(), q[2].sin()),
        n2: DVec2::new(q[3].cos(), q[3].sin()),
        ww: q[6].exp(),
    };
    let model = |g: &Geom, d: DVec2| {
        let (d1, d2) = ((d - g.c).dot(g.n1), (d - g.c).dot(g.n2));
        (tanh(d1 / g.ww), tanh(d2 / g.ww), d1, d2)
    };
    // m and a by linear least squares for the initial geometry.
    let lin = |q: &[f64; 7]| {
        let (mut s1, mut st, mut stt, mut sv, mut stv) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let g = geom(q);
        for &(d, v) in &px {
            let (t1, t2, ..) = model(&g, d);
            let t = t1 * t2;
            s1 += 1.0;
            st += t;
            stt += t * t;
            sv += v;
            stv += t * v;
        }
        let den = s1 * stt - st * st;
        if den.abs() < 1e-12 {
            return None;
        }
        let a = (s1 * stv - st * sv) / den;
        Some(((sv - a * st) / s1, a))
    };
    let (m0, a0) = lin(&q)?;
    q[4] = m0;
    q[5] = a0;
    // The cost at q, keeping the model at every pixel: the Jacobian at an
    // accepted q reuses it (the tanh's exponentials are most of the fit's
    // time).
    let cost = |q: &[f64; 7], at: &mut Vec<(f64, f64, f64, f64)>| {
        let g = geom(q);
        at.clear();
        let mut sum = 0.0;
        for &(d, v) in &px {
            let m = model(&g, d);
            at.push(m);
            let (t1, t2, ..) = m;
            let r = q[4] + q[5] * t1 * t2 - v;
            sum += r * r;
        }
        sum
    };
    let (mut at_q, mut at_trial) = (Vec::with_capacity(px.len()), Vec::with_capacity(px.len()));
    let mut c0 = cost(&q, &mut at_q);
    let mut lambda = 1e-3;
    for _ in 0..50 {
        let mut jtj = [0.0; 49];
        let mut jtr = [0.0; 7];
        let g = geom(&q);
        let (c, n1, n2, ww) = (g.c, g.n1, g.n2, g.ww);
        let (p1, p2) = (n1.perp(), n2.perp()); // (-sin, cos)
        let a = q[5];
        for (&(d, v), &(t1, t2, d1, d2)) in px.iter().zip(&at_q) {
            let (g1, g2) = ((1.0 - t1 * t1) / ww, (1.0 - t2 * t2) / ww);
            let dc = -(n1 * (g1 * t2) + n2 * (t1 * g2)) * a;
            let j = [
                dc.x,
                dc.y,
                a * g1 * t2 * (d - c).dot(p1),
                a * t1 * g2 * (d - c).dot(p2),
                1.0,
                t1 * t2,
                -a * (g1 * d1 * t2 + t1 * g2 * d2),
            ];
            let r = q[4] + a * t1 * t2 - v;
            for i in 0..7 {
                jtr[i] += j[i] * r;
                for k in i..7 {
                    jtj[i * 7 + k] += j[i] * j[k];
                }
            }
        }
        for i in 0..7 {
            for k in 0..i {
                jtj[i * 7 + k] = jtj[k * 7 + i];
            }
        }
        let mut improved = false;
        let neg: Vec<f64> = jtr.iter().map(|x| -x).collect();
        for _ in 0..8 {
            let mut aug = jtj;
            for i in 0..7 {
                aug[i * 7 + i] += lambda * jtj[i * 7 + i].max(1e-12);
            }
            let Some(step) = crate::linalg::cholesky_solve(&aug, &neg, 7) else {
                lambda *= 10.0;
                continue;
            };
            let mut nq = q;
            for i in 0..7 {
                nq[i] += step[i];
            }
            nq[6] = nq[6].clamp(-3.0, 2.5);
            let c1 = cost(&nq, &mut at_trial);
            if c1 < c0 {
                std::mem::swap(&mut at_q, &mut at_trial);
                let done = (c0 - c1) < 1e-10 * c0 || step[0].hypot(step[1]) < 1e-4;
                q = nq;
                c0 = c1;
                lambda = (lambda * 0.3).max(1e-9);
                improved = !done;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let c = DVec2::new(q[0], q[1]);
    let limit = reach / 3.0 * e1.length().min(e2.length());
    (c.length() <= limit && c.is_finite()).then_some(p + c)
}

/// tanh by one `exp`: libm's `tanh` (through `expm1`) took a third of the
/// calibration's corner fits, this a fifth of that; within 1e-16 absolute,
/// which is all the fit sees of it.
#[inline]
fn tanh(x: f64) -> f64 {
    if x.abs() > 19.0 {
        return x.signum();
    }
    let e = (2.0 * x).exp();
    (e - 1.0) / (e + 1.0)
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
    detect_board(gray, w, h, predicted, &[], &[], square_px)
}

/// As [`detect_checkerboard`], with the predicted centres of the board's
/// squares and whether each is the bright one (`squares`, may be empty). A
/// checkerboard is periodic and the nominal geometry can be off by a square:
/// among the offsets that line up nearly as many corners as the best, the
/// one whose squares have the predicted colours wins (a shift by one square
/// swaps them; one by two loses two rows of corners). `axes[i]` are the
/// predicted image vectors from corner i to its neighbours along the board's
/// two axes (empty: taken from the nearest predicted corners, which picks a
/// diagonal instead of an axis when the board is seen at a grazing angle).
pub fn detect_board(
    gray: &[f32],
    w: usize,
    h: usize,
    predicted: &[DVec2],
    axes: &[(DVec2, DVec2)],
    squares: &[(DVec2, bool)],
    square_px: f64,
) -> Result<Vec<Option<DVec2>>> {
    if !axes.is_empty() && axes.len() != predicted.len() {
        return Err(Error::Input(format!(
            "{} axes for {} predicted corners",
            axes.len(),
            predicted.len()
        )));
    }
    if gray.len() != w * h || w < 16 || h < 16 {
        return Err(Error::Input(format!(
            "image {w}x{h} with {} values",
            gray.len()
        )));
    }
    if !(square_px >= 5.0) {
        return Err(Error::Corners(format!(
            "squares of {square_px:.1} px are too small to find"
        )));
    }
    let sigma = (square_px / 8.0).clamp(0.8, 3.0);
    let min_dist = (square_px / 3.0) as usize;
    let saddles: Vec<DVec2> = find_saddles(gray, w, h, sigma, 0.05, min_dist.max(2))
        .into_iter()
        .filter(|p| is_x_junction(gray, w, h, *p, (0.35 * square_px).max(2.0)))
        .collect();
    if saddles.is_empty() {
        return Err(Error::Corners("no saddle points in the image".into()));
    }
    // Vote for the offset: pair each of the five predicted centre-most corners
    // (one of them may not have been found) with each saddle.
    let tol = 0.3 * square_px;
    let centre: DVec2 = predicted.iter().copied().sum::<DVec2>() / predicted.len().max(1) as f64;
    let mut anchors = predicted.to_vec();
    anchors.sort_by(|a, b| (*a - centre).length().total_cmp(&(*b - centre).length()));
    anchors.truncate(5);
    if anchors.is_empty() {
        return Err(Error::Input("no predicted corners".into()));
    }
    let saddle_grid = PointGrid::new(&saddles, tol);
    let nearest = |p: DVec2| saddle_grid.nearest(p);
    // Candidate offsets, each more than 0.5 px from every one kept before it.
    let mut offsets = PointGrid::new(&[], 0.5);
    for a in &anchors {
        for s in &saddles {
            let off = *s - *a;
            if off.length() <= 4.0 * square_px + 0.2 * w as f64 && !offsets.any_within(off) {
                offsets.push(off);
            }
        }
    }
    let mut votes: Vec<(usize, DVec2)> = offsets
        .points
        .into_par_iter()
        .map(|off| {
            let n = predicted
                .iter()
                .filter(|p| nearest(**p + off).is_some())
                .count();
            (n, off)
        })
        .collect();
    votes.sort_by(|a, b| b.0.cmp(&a.0));
    let top = votes.first().map_or(0, |v| v.0);
    if top < predicted.len() / 2 {
        return Err(Error::Corners(format!(
            "only {top} of {} corners line up with the prediction",
            predicted.len()
        )));
    }
    let mut best = votes[0];
    if !squares.is_empty() {
        // Colour agreement of the squares: mean over squares of +-(value - mid).
        let smooth = gaussian_blur(gray, w, h, (square_px / 6.0).max(0.7));
        let parity = |off: DVec2| -> f64 {
            let vals: Vec<(f64, bool)> = squares
                .iter()
                .filter_map(|(c, bright)| {
                    let q = *c + off;
                    (q.x >= 0.0 && q.y >= 0.0 && q.x <= (w - 1) as f64 && q.y <= (h - 1) as f64)
                        .then(|| {
                            (
                                crate::image::bilinear_plane(&smooth, w, h, q.x, q.y) as f64,
                                *bright,
                            )
                        })
                })
                .collect();
            if vals.is_empty() {
                return 0.0;
            }
            let mid = vals.iter().map(|v| v.0).sum::<f64>() / vals.len() as f64;
            vals.iter()
                .map(|(v, b)| if *b { v - mid } else { mid - v })
                .sum::<f64>()
                / squares.len() as f64
        };
        let mut cands: Vec<(usize, DVec2)> = Vec::new();
        for v in votes.iter().filter(|v| v.0 as f64 >= 0.75 * top as f64) {
            if cands.iter().all(|c| (c.1 - v.1).length() > tol) {
                cands.push(*v);
            }
        }
        best = cands
            .iter()
            .copied()
            .max_by(|a, b| {
                let sa = a.0 as f64 * parity(a.1).max(0.0);
                let sb = b.0 as f64 * parity(b.1).max(0.0);
                sa.total_cmp(&sb)
            })
            .unwrap_or(best);
    }
    // Second association through the image-to-image homography of the first
    // matches: it absorbs the prediction's perspective and scale errors.
    let first: Vec<(DVec2, DVec2)> = predicted
        .iter()
        .filter_map(|p| nearest(*p + best.1).map(|s| (*p, s)))
        .collect();
    let hm = (first.len() >= 8)
        .then(|| {
            let (a, b): (Vec<DVec2>, Vec<DVec2>) = first.iter().copied().unzip();
            crate::zhang::homography(&a, &b).ok()
        })
        .flatten();
    let hmap = |p: DVec2| hm.map_or(p + best.1, |h| crate::zhang::apply(&h, p));
    let blurred = gaussian_blur(gray, w, h, 0.7);
    let radius = ((square_px * 0.3) as usize).clamp(2, 12);
    // Local board axes at each corner: given, or from the predicted neighbours.
    let axes = |i: usize| -> Option<(DVec2, DVec2)> {
        if let Some(a) = axes.get(i) {
            return Some(*a);
        }
        let p = predicted[i];
        let mut near: Vec<DVec2> = predicted
            .iter()
            .map(|q| *q - p)
            .filter(|d| d.length() > 0.3 * square_px)
            .collect();
        near.sort_by(|a, b| a.length().total_cmp(&b.length()));
        let e1 = *near.first()?;
        let e2 = *near
            .iter()
            .find(|d| (d.normalize().dot(e1.normalize())).abs() < 0.8)?;
        Some((e1, e2))
    };
    let found: Vec<Option<DVec2>> = (0..predicted.len())
        .into_par_iter()
        .map(|i| {
            let s = nearest(hmap(predicted[i]))?;
            let g = refine_corner(&blurred, w, h, s, radius).unwrap_or(s);
            let (e1, e2) = axes(i)?;
            fit_saddle(gray, w, h, g, e1, e2, 0.6)
        })
        .collect();
    Ok(reject_outliers(predicted, found))
}

/// Points binned in square cells as wide as the query radius, so that a query
/// looks at nine cells instead of every point (the association compares every
/// candidate offset's predicted corners with every saddle).
struct PointGrid {
    radius: f64,
    points: Vec<DVec2>,
    cells: std::collections::HashMap<(i64, i64), Vec<usize>>,
}

impl PointGrid {
    fn new(points: &[DVec2], radius: f64) -> PointGrid {
        let mut grid = PointGrid {
            radius,
            points: Vec::with_capacity(points.len()),
            cells: std::collections::HashMap::new(),
        };
        for p in points {
            grid.push(*p);
        }
        grid
    }

    fn cell(&self, p: DVec2) -> (i64, i64) {
        let c = (p / self.radius).floor();
        (c.x as i64, c.y as i64)
    }

    fn push(&mut self, p: DVec2) {
        let key = self.cell(p);
        self.cells.entry(key).or_default().push(self.points.len());
        self.points.push(p);
    }

    /// Indices of the points in the nine cells around `p`: all within the radius.
    fn around(&self, p: DVec2) -> impl Iterator<Item = usize> + '_ {
        let (cx, cy) = self.cell(p);
        (-1..=1)
            .flat_map(move |dy| {
                (-1..=1).map(move |dx| (cx.saturating_add(dx), cy.saturating_add(dy)))
            })
            .flat_map(|key| self.cells.get(&key).into_iter().flatten().copied())
    }

    /// The point nearest `p` closer than the radius; of equally near ones the
    /// first pushed (as a linear scan's `min_by` would pick).
    fn nearest(&self, p: DVec2) -> Option<DVec2> {
        let mut best: Option<(f64, usize)> = None;
        for i in self.around(p) {
            let d = (self.points[i] - p).length();
            if d < self.radius && best.is_none_or(|(bd, bi)| d < bd || (d == bd && i < bi)) {
                best = Some((d, i));
            }
        }
        best.map(|(_, i)| self.points[i])
    }

    /// Whether a point lies within the radius of `p`, bound included.
    fn any_within(&self, p: DVec2) -> bool {
        self.around(p)
            .any(|i| (self.points[i] - p).length() <= self.radius)
    }
}

/// Drop corners that a homography through all the others does not explain
/// (wrong saddle, fit gone astray): residual above 4 times the median and 0.5 px.
pub fn reject_outliers(predicted: &[DVec2], mut found: Vec<Option<DVec2>>) -> Vec<Option<DVec2>> {
    for _ in 0..3 {
        let idx: Vec<usize> = (0..found.len()).filter(|&i| found[i].is_some()).collect();
        if idx.len() < 8 {
            return found;
        }
        let a: Vec<DVec2> = idx.iter().map(|&i| predicted[i]).collect();
        let b: Vec<DVec2> = idx.iter().filter_map(|&i| found[i]).collect();
        let Ok(hm) = crate::zhang::homography(&a, &b) else {
            return found;
        };
        let res: Vec<f64> = a
            .iter()
            .zip(&b)
            .map(|(p, f)| (crate::zhang::apply(&hm, *p) - *f).length())
            .collect();
        let mut sorted = res.clone();
        sorted.sort_by(f64::total_cmp);
        let limit = (4.0 * sorted[sorted.len() / 2]).max(0.5);
        let mut dropped = false;
        for (&i, r) in idx.iter().zip(&res) {
            if *r > limit {
                found[i] = None;
                dropped = true;
            }
        }
        if !dropped {
            break;
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraModel, Intrinsics};
    use crate::synthetic_calibration::{Checkerboard, render_checkerboard};
    use glam::{DMat3, DVec3};

    #[test]
    fn point_grid_answers_as_a_linear_scan_does() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        let mut pt = || DVec2::new(rng.random_range(-40.0..40.0), rng.random_range(-40.0..40.0));
        let points: Vec<DVec2> = (0..300).map(|_| pt()).collect();
        let radius = 3.0;
        let grid = PointGrid::new(&points, radius);
        let mut hits = 0;
        for _ in 0..2000 {
            let p = pt();
            let scan = points
                .iter()
                .copied()
                .filter(|s| (*s - p).length() < radius)
                .min_by(|a, b| (*a - p).length().total_cmp(&(*b - p).length()));
            assert_eq!(grid.nearest(p), scan, "at {p}");
            let within = points.iter().any(|s| (*s - p).length() <= radius);
            assert_eq!(grid.any_within(p), within, "at {p}");
            hits += scan.is_some() as usize;
        }
        assert!(
            hits > 500,
            "{hits} queries found a point: the test shows little"
        );
        assert_eq!(grid.nearest(DVec2::new(f64::INFINITY, 0.0)), None);
        assert_eq!(grid.nearest(DVec2::NAN), None);
    }

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

    /// The lowest camera of the rig (12.9 deg elevation) at 2x binning: squares
    /// 6 px tall and 28 px wide, the board turned so one axis runs nearly along
    /// the line of sight.
    #[test]
    fn corners_of_a_grazing_board() {
        let intr = Intrinsics {
            fx: 2560.0,
            fy: 2560.0,
            cx: 255.5,
            cy: 191.5,
            k1: 0.0,
            k2: 0.0,
        };
        let e = 12.86f64.to_radians();
        let eye = DVec3::new(e.cos(), 0.0, e.sin()) * 450.0;
        let cam = CameraModel::look_at(eye, DVec3::ZERO, DVec3::Z, intr);
        let board = Checkerboard {
            squares_x: 12,
            squares_y: 12,
            square_mm: 5.0,
        };
        for theta in [0.2f64, 1.25, 2.29, 3.34] {
            let rot = DMat3::from_rotation_z(theta);
            let img = render_checkerboard(&cam, 512, 384, &board, rot, DVec3::ZERO, 0.5, 3);
            let truth: Vec<DVec2> = board
                .corners()
                .iter()
                .map(|c| cam.project(rot * *c).unwrap())
                .collect();
            let predicted: Vec<DVec2> = truth.iter().map(|t| *t + DVec2::new(3.0, -1.0)).collect();
            let axes: Vec<(DVec2, DVec2)> = board
                .corners()
                .iter()
                .map(|c| {
                    let p = cam.project(rot * *c).unwrap();
                    let ex = cam.project(rot * (*c + DVec3::X * 5.0)).unwrap() - p;
                    let ey = cam.project(rot * (*c + DVec3::Y * 5.0)).unwrap() - p;
                    (ex, ey)
                })
                .collect();
            let squares: Vec<(DVec2, bool)> = (0..144)
                .map(|k| {
                    let c = DVec3::new(
                        (k % 12) as f64 * 5.0 - 27.5,
                        (k / 12) as f64 * 5.0 - 27.5,
                        0.0,
                    );
                    let bright = board.albedo(c.x, c.y).unwrap() > 0.5;
                    (
                        cam.project(rot * c).unwrap() + DVec2::new(3.0, -1.0),
                        bright,
                    )
                })
                .collect();
            let found = detect_board(
                &img.channel_f32(0),
                512,
                384,
                &predicted,
                &axes,
                &squares,
                6.0,
            )
            .unwrap();
            let (mut sq, mut n) = (0.0, 0);
            for (f, t) in found.iter().zip(&truth) {
                if let Some(f) = f {
                    sq += (*f - *t).length_squared();
                    n += 1;
                }
            }
            let rms = (sq / n.max(1) as f64).sqrt();
            eprintln!("theta {theta}: {n} corners, rms {rms:.3} px");
            assert!(
                n > 90 && rms < 0.1,
                "theta {theta}: {n} corners, RMS {rms} px"
            );
        }
    }

    #[test]
    fn blank_image_is_an_error() {
        let g = vec![0.5f32; 64 * 64];
        assert!(detect_checkerboard(&g, 64, 64, &[DVec2::new(30.0, 30.0)], 10.0).is_err());
    }
}
