//! Step 5 of the fit: the mesostructure exiting function f_v(x, w_o) per
//! pass-2 view, and the window of texels every view and channel measures.

use std::collections::BTreeMap;
use std::f64::consts::PI;

use rayon::prelude::*;

use super::global::EnteringStripe;
use super::stripes::{dir_key, f32v};
use crate::ModelError;
use crate::model::{ExitingFunction, Texture};
use crate::profile::ChannelFit;
use crate::rectified::{Grid, Rectified, StripeEntry};

/// f_v of every pass-2 view of `data`, cropped to the texels every view and
/// channel reaches: the function and that window, [i0, j0, width, height].
/// `step` is called once per view.
pub(super) fn fit_exiting(
    data: &Rectified,
    channels: &[ChannelFit],
    tables: &[EnteringStripe; 3],
    notes: &mut Vec<String>,
    step: &(dyn Fn() + Sync),
) -> Result<(ExitingFunction, [u32; 4]), ModelError> {
    let grid = data.index.grid;
    let (w, h) = (grid.width as usize, grid.height as usize);
    let mut views: BTreeMap<[i64; 3], [f64; 3]> = BTreeMap::new();
    for s in data.index.stripe.iter().filter(|s| s.pass == 2) {
        views.entry(dir_key(s.view_dir)).or_insert(s.view_dir);
    }
    // From the core out to every valid texel: the measured profile follows
    // the data wherever it goes, and a texel's sum weighs each stripe by its
    // signal, so far, faint stripes count little.
    let fv_range: [[f64; 2]; 3] = std::array::from_fn(|c| [0.0, channels[c].fit.range_mm[1]]);
    let fv_raw: Vec<Vec<[f64; 3]>> = views
        .keys()
        .collect::<Vec<_>>()
        .par_iter()
        .map(|key| -> Result<Vec<[f64; 3]>, ModelError> {
            let images: Vec<(&StripeEntry, Texture)> = data
                .index
                .stripe
                .iter()
                .filter(|s| s.pass == 2 && dir_key(s.view_dir) == **key)
                .map(|s| Ok((s, data.read_image(&s.file)?)))
                .collect::<Result<_, ModelError>>()?;
            let out = exiting_view(&images, &grid, &fv_range, channels, tables);
            step();
            Ok(out)
        })
        .collect::<Result<_, _>>()?;
    let window = measured_window(&fv_raw, w, h);
    let Some(window) = window else {
        return Err(ModelError::Fit(format!(
            "f_v: no texel is reached by the pass-2 stripes (within {:.2} mm) in every view and channel",
            fv_range[0][1].min(fv_range[1][1]).min(fv_range[2][1])
        )));
    };
    let [i0, j0, ww, wh] = window.map(|x| x as usize);
    if (ww, wh) != (w, h) {
        notes.push(format!(
            "f_v: pass-2 stripes reach texels {i0}..{} x {j0}..{} of the {w}x{h} window in every view and channel; the model covers those",
            i0 + ww,
            j0 + wh
        ));
    }
    let crop = |t: &Texture| Texture {
        width: ww,
        height: wh,
        data: (0..ww * wh)
            .map(|p| t.get(i0 + p % ww, j0 + p / ww))
            .collect(),
    };
    let exiting = ExitingFunction::new(
        views.values().map(|&v| f32v(v)).collect(),
        fv_raw
            .iter()
            .map(|m| {
                crop(&Texture {
                    width: w,
                    height: h,
                    data: m.iter().map(|v| v.map(|x| x as f32)).collect(),
                })
            })
            .collect(),
    );
    Ok((exiting, window))
}

/// f_v of one view over the whole window (NaN where a channel has no
/// stripe data). Each stripe l that reaches texel x gives a ratio
/// r_l = L(x, l) / (flux_l Ī(d(x, l))), with Ī(d) the view's own measured
/// profile (radiance per flux, the mean over its texels at signed distance
/// d in bins an eighth of a texel wide, smoothed [1, 2, 1] and interpolated
/// linearly), and f_v(x) = A Σ_l w_l r_l / Σ_l w_l, with A = Σ L / Σ T(0)
/// I_D flux / π over the fitted range (the formula after paper eq. 6,
/// pooled over the view's texels): A sets the view's level against the
/// dipole, Ī its shape. With I_D in place of Ī each texel's f_v took the
/// model's misfit at its own distances from the few stripes, so it varied
/// with the distance from them: bands parallel to the stripe lines.
/// Distances from 0 (the core is the strongest signal and, at ci and
/// default scale, the only one within the usable range for texels on a
/// stripe) to the fitted range's end count; Ī is the measured profile
/// times the model's, I_D g(d), with g the binned ratio, which is smooth
/// where I_D is steep.
///
/// The weight w_l is the stripe's expected signal flux_l Ī over q(d), the
/// ratios' scatter at that distance beyond the texture's in units of photon
/// noise ([`photon_relative_scatter`]). Photon noise alone gives every
/// distance the same q, and the sum is then Σ L / Σ flux Ī, the paper's
/// f_v. In the core a few hundredths of a millimetre of the fitted line
/// move the ratio along the steep profile by several per cent, the same
/// for every texel of that line: q is higher there, and a texel on a line
/// no longer takes its f_v from that line's core alone. On a homogeneous
/// sample (marble, default scale, true f_v 1) the f_v maps scatter by
/// 4.1-4.9 % about their mean, against 5.0-5.9 % weighed by the signal
/// alone, and the ramps from line to line (up to ±4 % between the outer
/// lines) flatten to within about 2 %.
fn exiting_view(
    images: &[(&StripeEntry, Texture)],
    grid: &Grid,
    fv_range: &[[f64; 2]; 3],
    channels: &[ChannelFit],
    tables: &[EnteringStripe; 3],
) -> Vec<[f64; 3]> {
    let (w, h) = (grid.width as usize, grid.height as usize);
    let tx = grid.texel_mm;
    let mut out = vec![[f64::NAN; 3]; w * h];
    for c in 0..3 {
        let [d0, d1] = fv_range[c];
        let [lo, hi] = channels[c].fit.range_mm;
        // Every (stripe, texel) of this channel within [d0, d1] of the
        // stripe's line, read once, with the model's profile there.
        let mut samples = Vec::new();
        for (s, img) in images.iter().filter(|(s, _)| s.channel as usize == c) {
            for j in 0..h {
                for i in 0..w {
                    let l = img.get(i, j)[c] as f64;
                    let sgn = s.signed_distance(grid.centre(i, j));
                    if l.is_finite() && sgn.abs() >= d0 && sgn.abs() <= d1 {
                        samples.push(Sample {
                            texel: j * w + i,
                            sgn,
                            l,
                            flux: s.flux_per_mm,
                            model: tables[c].texel_mean(sgn.abs(), tx),
                        });
                    }
                }
            }
        }
        // Signed distance bins an eighth of a texel wide: each side of the
        // line has its own profile (a view's line sits a little off the
        // light's, towards the camera, and its blur is not symmetric), and
        // the steep core is followed closely enough that a texel's ratio to
        // it does not depend on where the texel falls within a bin (with
        // texel-wide bins, hatching along the lines at the texel scale).
        let bw = tx / PROFILE_BINS_PER_TEXEL;
        let half = (d1 / bw).ceil() as usize + 1;
        let nb = 2 * half;
        let bin = |sd: f64| (((sd / bw) + half as f64).max(0.0) as usize).min(nb - 1);
        // Per bin: Σ L / flux, Σ d, count; and the level A over the fitted range.
        let (mut sl, mut sm) = (vec![0.0; nb], vec![0.0; nb]);
        let (mut sd, mut n) = (vec![0.0; nb], vec![0.0; nb]);
        let (mut a_num, mut a_den) = (0.0, 0.0);
        for &Sample {
            sgn,
            l,
            flux,
            model,
            ..
        } in &samples
        {
            let d = sgn.abs();
            let b = bin(sgn);
            sl[b] += l / flux;
            sm[b] += model;
            sd[b] += sgn;
            n[b] += 1.0;
            if d >= lo && d <= hi {
                a_num += l;
                a_den += model * flux / PI;
            }
        }
        if !(a_den > 0.0) {
            continue;
        }
        let level = a_num / a_den;
        // The measured profile against the model's, g = Σ L / Σ I_D per bin:
        // smooth where the profile is steep, so it interpolates well.
        let pts: Vec<(f64, f64)> = (0..nb)
            .filter(|&b| n[b] > 0.0 && sm[b] > 0.0)
            .map(|b| (sd[b] / n[b], sl[b] / sm[b]))
            .collect();
        if pts.is_empty() {
            continue;
        }
        // [1, 2, 1] smoothing between measured neighbours.
        let smooth: Vec<(f64, f64)> = (0..pts.len())
            .map(|k| {
                if k == 0 || k + 1 == pts.len() {
                    pts[k]
                } else {
                    (
                        pts[k].0,
                        0.25 * pts[k - 1].1 + 0.5 * pts[k].1 + 0.25 * pts[k + 1].1,
                    )
                }
            })
            .collect();
        // Each sample's expected signal flux Ī, Ī = I_D g; those with none
        // drop out.
        let expected: Vec<(&Sample, f64)> = samples
            .iter()
            .map(|s| (s, s.flux * s.model * piecewise_linear(&smooth, s.sgn)))
            .filter(|&(_, e)| e > 0.0)
            .collect();
        let scatter = photon_relative_scatter(&expected, w * h, d1, tx);
        // Σ w r, Σ w, and the expected signal Σ flux Ī (for the reach).
        let (mut num, mut wsum, mut signal) =
            (vec![0.0; w * h], vec![0.0; w * h], vec![0.0; w * h]);
        for &(s, e) in &expected {
            let wt = if scatter.is_empty() {
                e
            } else {
                e / piecewise_linear(&scatter, s.sgn.abs())
            };
            num[s.texel] += wt * s.l / e;
            wsum[s.texel] += wt;
            signal[s.texel] += e;
        }
        // Where the scans reach: a texel whose expected signal is under
        // REACH of the median texel's is left unmeasured.
        let mut sorted: Vec<f64> = signal.iter().copied().filter(|d| *d > 0.0).collect();
        sorted.sort_by(f64::total_cmp);
        let floor = sorted
            .get(sorted.len() / 2)
            .map_or(f64::INFINITY, |m| REACH * m);
        for p in 0..w * h {
            if wsum[p] > 0.0 && signal[p] >= floor {
                out[p][c] = level * num[p] / wsum[p];
            }
        }
    }
    out
}

/// The scatter of the ratios r = L / (flux Ī) by distance from the line
/// (bins half a texel wide, at least [`MIN_SCATTER_SAMPLES`] each), less
/// the texture's own variance, times the bin's mean expected signal: q(d)
/// with Var(r) = q(d) / signal. Photon noise gives the same q at every
/// distance; an error that does not fall with the signal, as a line's
/// position along the steep core, raises it there. The texture's variance
/// is what two stripes' ratios at the same texel share, the mean over
/// texels of Σ_{l≠m} r_l r_m / (n (n - 1)) less the squared mean ratio. At
/// least [`NOISE_FLOOR`] of a bin's scatter counts. Empty where no bin
/// has a scatter.
fn photon_relative_scatter(
    expected: &[(&Sample, f64)],
    texels: usize,
    d1: f64,
    texel_mm: f64,
) -> Vec<(f64, f64)> {
    let bw = 0.5 * texel_mm;
    let nb = (d1 / bw) as usize + 1;
    // Per bin Σ r, Σ r², Σ signal, count; per texel Σ r, Σ r², count.
    let (mut r1, mut r2, mut se, mut n) =
        (vec![0.0; nb], vec![0.0; nb], vec![0.0; nb], vec![0.0; nb]);
    let (mut t1, mut t2, mut tn) = (vec![0.0; texels], vec![0.0; texels], vec![0.0; texels]);
    for &(s, e) in expected {
        let (b, r, p) = (((s.sgn.abs() / bw) as usize).min(nb - 1), s.l / e, s.texel);
        r1[b] += r;
        r2[b] += r * r;
        se[b] += e;
        n[b] += 1.0;
        t1[p] += r;
        t2[p] += r * r;
        tn[p] += 1.0;
    }
    let (mut shared, mut mean, mut m) = (0.0, 0.0, 0.0);
    for p in (0..texels).filter(|&p| tn[p] >= 2.0) {
        shared += (t1[p] * t1[p] - t2[p]) / (tn[p] * (tn[p] - 1.0));
        mean += t1[p] / tn[p];
        m += 1.0;
    }
    let texture = if m > 0.0 {
        (shared / m - (mean / m).powi(2)).max(0.0)
    } else {
        0.0
    };
    (0..nb)
        .filter(|&b| n[b] >= MIN_SCATTER_SAMPLES)
        .filter_map(|b| {
            let var = r2[b] / n[b] - (r1[b] / n[b]).powi(2);
            let noise = (var - texture).max(NOISE_FLOOR * var);
            (noise > 0.0).then(|| ((b as f64 + 0.5) * bw, noise * se[b] / n[b]))
        })
        .collect()
}

/// One texel of one stripe image: its index in the window, its signed
/// distance from the stripe's line (mm), L, the stripe's flux per mm, and
/// the model's profile I_D there (averaged over the texel).
struct Sample {
    texel: usize,
    sgn: f64,
    l: f64,
    flux: f64,
    model: f64,
}

/// y at x on the polyline through `pts` (sorted by x, not empty), held
/// beyond its ends.
fn piecewise_linear(pts: &[(f64, f64)], x: f64) -> f64 {
    let k = pts.partition_point(|p| p.0 < x);
    if k == 0 {
        pts[0].1
    } else if k == pts.len() {
        pts[k - 1].1
    } else {
        let (a, b) = (pts[k - 1], pts[k]);
        a.1 + (x - a.0) / (b.0 - a.0) * (b.1 - a.1)
    }
}

/// Texels a distance bin needs before its ratios' scatter weighs them.
const MIN_SCATTER_SAMPLES: f64 = 8.0;

/// The least share of a distance bin's scatter that counts as noise when
/// the texture's (estimated) variance is taken out of it.
const NOISE_FLOOR: f64 = 0.05;

/// Bins per texel of a view's measured profile (over signed distance).
const PROFILE_BINS_PER_TEXEL: f64 = 8.0;

/// A texel counts as reached by a view's stripes when their summed
/// expected signal there is at least this share of the median texel's.
const REACH: f64 = 0.05;

/// The largest block of rows and columns around the window's centre whose
/// texels have f_v in every view and channel: [i0, j0, width, height].
fn measured_window(maps: &[Vec<[f64; 3]>], w: usize, h: usize) -> Option<[u32; 4]> {
    let ok = |i: usize, j: usize| {
        maps.iter()
            .all(|m| m[j * w + i].iter().all(|v| v.is_finite()))
    };
    // Grow a rectangle from the centre while the added row or column is whole.
    let (ci, cj) = (w / 2, h / 2);
    if !ok(ci, cj) {
        return None;
    }
    let (mut i0, mut i1, mut j0, mut j1) = (ci, ci + 1, cj, cj + 1);
    loop {
        let mut grew = false;
        if j0 > 0 && (i0..i1).all(|i| ok(i, j0 - 1)) {
            j0 -= 1;
            grew = true;
        }
        if j1 < h && (i0..i1).all(|i| ok(i, j1)) {
            j1 += 1;
            grew = true;
        }
        if i0 > 0 && (j0..j1).all(|j| ok(i0 - 1, j)) {
            i0 -= 1;
            grew = true;
        }
        if i1 < w && (j0..j1).all(|j| ok(i1, j)) {
            i1 += 1;
            grew = true;
        }
        if !grew {
            break;
        }
    }
    Some([i0 as u32, j0 as u32, (i1 - i0) as u32, (j1 - j0) as u32])
}
