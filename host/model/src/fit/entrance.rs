//! Step 4 of the fit: the mesostructure entrance function f(w_i) from the
//! band fluxes of the pass-1 (oblique) stripes relative to the vertical ones.

use std::collections::BTreeMap;

use rayon::prelude::*;

use super::FitOptions;
use super::bins::DistanceBins;
use super::stripes::{
    NEAR_VERTICAL_COS, SAME_LIGHT_DIR, SPECULAR_VIEW_COS, VERTICAL_KEY, ascending_runs,
    cos_to_mirror, dir_key, f32v,
};
use crate::ModelError;
use crate::fresnel;
use crate::model::{EntranceFunction, Texture};
use crate::rectified::{Grid, Rectified, StripeEntry};

/// f(w_i) per channel at the measured laser directions, then resampled to the
/// regular (θ, φ) table by the 4 nearest measured directions (inverse-square
/// angular weights): the paper's interpolation from the four nearest laser
/// directions. Returns the table and the measured samples.
#[allow(clippy::type_complexity)]
pub(super) fn fit_entrance(
    data: &Rectified,
    opts: &FitOptions,
    notes: &mut Vec<String>,
) -> Result<(EntranceFunction, Vec<([f32; 3], [f32; 3])>), ModelError> {
    // Mean per-stripe exitance flux / incident flux, keyed by (light, view, channel).
    if !data.index.stripe.iter().any(|s| s.pass == 1) {
        notes.push(
            "no pass-1 images: entrance function set to the smooth-surface Fresnel ratio".into(),
        );
        return Ok((
            EntranceFunction::fresnel(opts.eta, opts.n_theta),
            Vec::new(),
        ));
    }
    // Pass 1 and, as more vertical references, pass 2. The whole stripe
    // counts, its core included (the near field's share of the light changes
    // with the angle of incidence), so views that see the laser's specular
    // reflection on the core are left out; views are made comparable through
    // the exitance per radiance, so a light whose vertical reference lacks
    // its view (the top camera sees the vertical laser's mirror reflection)
    // is still compared.
    let used: Vec<&StripeEntry> = data
        .index
        .stripe
        .iter()
        .filter(|s| {
            (s.pass == 1 || is_vertical(s.light_dir)) && cos_to_mirror(s) <= SPECULAR_VIEW_COS
        })
        .collect();
    if used.is_empty() {
        return Err(ModelError::Fit(
            "entrance function: every stripe image sees the laser's specular reflection".into(),
        ));
    }
    let fresnel_average = fresnel::fresnel_hemispherical_average(opts.eta);
    let light_keys = cluster_light_directions(used.iter().map(|s| s.light_dir));
    // Each image's outgoing flux per mm of stripe over the band |d| <= reach
    // around its line: the mean radiance at each signed distance (so the
    // length of line inside the window does not matter) summed over the
    // band. One reach for all images (0.9 x the median extent), so a stripe
    // near the window's edge does not lose more of its profile than the
    // vertical reference.
    let grid = &data.index.grid;
    let extents: Vec<f64> = used.iter().map(|s| band_extent(s, grid)).collect();
    let reach = {
        let mut sorted = extents.clone();
        sorted.sort_by(f64::total_cmp);
        0.9 * sorted[sorted.len() / 2]
    };
    let fluxes: Vec<Option<f64>> = used
        .par_iter()
        .zip(&extents)
        .map(|(s, &e)| -> Result<Option<f64>, ModelError> {
            if e < reach {
                return Ok(None);
            }
            let img = data.read_image(&s.file)?;
            let k = fresnel::exitance_per_radiance(s.view_dir[2], opts.eta, fresnel_average);
            Ok(Some(k * band_flux(&img, s, grid, reach) / s.flux_per_mm))
        })
        .collect::<Result<_, _>>()?;
    let short = fluxes.iter().filter(|f| f.is_none()).count();
    if short > 0 {
        notes.push(format!(
            "entrance function: {short} of {} stripe images left out: their line is within {reach:.1} mm of the window's edge",
            used.len()
        ));
    }
    let images: Vec<BandFlux> = used
        .iter()
        .zip(light_keys)
        .zip(fluxes)
        .filter_map(|((s, light), flux)| {
            Some(BandFlux {
                light,
                light_dir: s.light_dir,
                view: dir_key(s.view_dir),
                stripe: s,
                flux: flux?,
            })
        })
        .collect();
    // The vertical's flux per channel, averaged over its views: the
    // reference of a view that has no vertical stripe of its own.
    let mean_reference: [f64; 3] = std::array::from_fn(|c| {
        let mut per_view: BTreeMap<[i64; 3], (f64, usize)> = BTreeMap::new();
        for b in images
            .iter()
            .filter(|b| b.light == VERTICAL_KEY && b.stripe.channel as usize == c)
        {
            let e = per_view.entry(b.view).or_default();
            e.0 += b.flux;
            e.1 += 1;
        }
        per_view.values().map(|(f, n)| f / *n as f64).sum::<f64>() / per_view.len() as f64
    });
    // Each direction is its stripes' mean.
    let mut lights: BTreeMap<[i64; 3], [f64; 3]> = BTreeMap::new();
    for b in &images {
        let sum = lights.entry(b.light).or_default();
        for (s, d) in sum.iter_mut().zip(b.light_dir) {
            *s += d;
        }
    }
    for d in lights.values_mut() {
        let norm = d.iter().map(|v| v * v).sum::<f64>().sqrt();
        *d = d.map(|v| v / norm);
    }
    let mut measured: Vec<Measured> = Vec::new();
    for (lk, ld) in &lights {
        // Near-vertical directions (the vertical stripe from another arc or
        // turntable angle, tilted by the rig's small errors) are the
        // reference itself, f = 1, not oblique samples.
        if *lk == VERTICAL_KEY || ld[2] > NEAR_VERTICAL_COS {
            continue;
        }
        let (mut value, mut se) = ([f64::NAN; 3], [f64::NAN; 3]);
        for c in 0..3u8 {
            // Each oblique stripe against the vertical stripe of its view
            // whose line lies nearest its own (the same stretch of a
            // heterogeneous sample), or, where the light has no view with a
            // vertical stripe, the vertical's mean over views.
            let oblique: Vec<&BandFlux> = images
                .iter()
                .filter(|b| b.light == *lk && b.stripe.channel == c)
                .collect();
            let paired: Vec<(f64, Option<f64>)> = oblique
                .iter()
                .map(|b| (b.flux, nearest_vertical(&images, b)))
                .collect();
            let same_view = paired.iter().any(|(_, r)| r.is_some());
            let pairs: Vec<(f64, f64)> = paired
                .into_iter()
                .filter(|(_, r)| !same_view || r.is_some())
                .map(|(f, r)| (f, r.unwrap_or(mean_reference[c as usize])))
                .collect();
            (value[c as usize], se[c as usize]) = ratio_with_error(&pairs);
        }
        if value.iter().any(|v| !v.is_finite()) {
            // Its stripes all lie near the window's edge, or no vertical
            // reference shares a view: the table interpolates from the others.
            notes.push(format!(
                "entrance function: light direction {ld:.3?} left out (no usable stripe or vertical reference in some channel)"
            ));
            continue;
        }
        measured.push(Measured {
            dir: *ld,
            value,
            se,
        });
    }
    pool_azimuths(&mut measured, notes);
    let mut samples: Vec<([f32; 3], [f32; 3])> = vec![([0.0, 0.0, 1.0], [1.0; 3])];
    samples.extend(
        measured
            .iter()
            .map(|m| (f32v(m.dir), m.value.map(|v| v as f32))),
    );
    let n_theta = opts.n_theta.max(2);
    let n_phi = opts.n_phi.max(1);
    let mut table = EntranceFunction {
        n_theta,
        n_phi,
        values: vec![[0.0; 3]; n_theta * n_phi],
    };
    for k in 0..n_theta {
        for m in 0..n_phi {
            let (t, p) = (table.theta(k), table.phi(m));
            let d = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
            let mut near: Vec<(f32, [f32; 3])> = samples
                .iter()
                .map(|(s, v)| {
                    (
                        (s[0] * d[0] + s[1] * d[1] + s[2] * d[2])
                            .clamp(-1.0, 1.0)
                            .acos(),
                        *v,
                    )
                })
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            near.truncate(4);
            table.values[k * n_phi + m] = if near[0].0 < 1e-4 {
                near[0].1
            } else {
                let ws: Vec<f32> = near.iter().map(|x| 1.0 / (x.0 * x.0)).collect();
                let sum: f32 = ws.iter().sum();
                std::array::from_fn(|c| {
                    near.iter().zip(&ws).map(|(x, w)| x.1[c] * w).sum::<f32>() / sum
                })
            };
        }
    }
    Ok((table, samples))
}

/// f at one measured light direction, per channel, with its standard error.
#[derive(Debug, Clone, PartialEq)]
struct Measured {
    dir: [f64; 3],
    value: [f64; 3],
    se: [f64; 3],
}

/// Σ oblique / Σ reference over a direction's stripe pairs, and the ratio
/// estimator's standard error, sqrt(n / (n - 1) Σ (f_i - R r_i)²) / Σ r_i:
/// on a heterogeneous sample each pair lies on its own stretch of the
/// sample, and their scatter is what the sum averages out. NaN error for
/// fewer than two pairs.
fn ratio_with_error(pairs: &[(f64, f64)]) -> (f64, f64) {
    let (num, den) = pairs
        .iter()
        .fold((0.0, 0.0), |(n, d), (f, r)| (n + f, d + r));
    let ratio = num / den;
    let n = pairs.len() as f64;
    let ss: f64 = pairs.iter().map(|(f, r)| (f - ratio * r).powi(2)).sum();
    let se = if pairs.len() >= 2 {
        (n / (n - 1.0) * ss).sqrt() / den
    } else {
        f64::NAN
    };
    (ratio, se)
}

/// Directions whose elevations agree within `SAME_ELEVATION` are one ring.
const SAME_ELEVATION: f64 = 2.0 * std::f64::consts::PI / 180.0;

/// What one light direction's f can be off by whatever the sample, as a
/// share of f: the rig's own direction-to-direction errors (the laser's
/// aim and power per arc rotation). Homogeneous captures at the default
/// scale read f within 0.6-1.6 % of the truth direction by direction, at
/// stripe-to-stripe errors of a few tenths of a per cent.
const RIG_FLOOR: f64 = 0.005;

/// Per channel and per ring of directions at one elevation: where the
/// azimuths' f agree within their errors (the stripes' standard error and
/// [`RIG_FLOOR`]; χ² of their deviations from the weighted mean at most its
/// 99th percentile), f does not depend on the
/// azimuth as far as the capture can tell, and each takes the ring's
/// weighted mean; the scatter between them is the sample's stretches under
/// the lines, not the material. Where they do not (an anisotropic sample,
/// or a rig error beyond the floor), each keeps its own, and a note says so.
fn pool_azimuths(measured: &mut [Measured], notes: &mut Vec<String>) {
    let theta = |m: &Measured| m.dir[2].clamp(-1.0, 1.0).acos();
    let thetas: Vec<f64> = measured.iter().map(theta).collect();
    let rings = ascending_runs(&thetas, SAME_ELEVATION);
    let mut pooled = Vec::new();
    for ring in rings.iter().filter(|r| r.len() >= 2) {
        let mut channels = String::new();
        for c in 0..3 {
            let (v, w): (Vec<f64>, Vec<f64>) = ring
                .iter()
                .map(|&i| {
                    let (v, se) = (measured[i].value[c], measured[i].se[c]);
                    (v, 1.0 / (se * se + (RIG_FLOOR * v).powi(2)))
                })
                .unzip();
            if !w.iter().all(|w| w.is_finite() && *w > 0.0) {
                continue;
            }
            let mean = v.iter().zip(&w).map(|(v, w)| v * w).sum::<f64>() / w.iter().sum::<f64>();
            let chi2: f64 = v.iter().zip(&w).map(|(v, w)| w * (v - mean).powi(2)).sum();
            let dof = ring.len() - 1;
            if chi2 <= chi2_99(dof) {
                for &i in ring {
                    measured[i].value[c] = mean;
                }
                channels.push(['R', 'G', 'B'][c]);
            } else {
                notes.push(format!(
                    "entrance function: channel {c} at {:.1} deg: the azimuths' f differ beyond their errors (chi2 {chi2:.1} over {dof} degrees of freedom), each kept",
                    thetas[ring[0]].to_degrees()
                ));
            }
        }
        if !channels.is_empty() {
            pooled.push(format!(
                "{:.1} deg ({} directions, {channels})",
                thetas[ring[0]].to_degrees(),
                ring.len()
            ));
        }
    }
    if !pooled.is_empty() {
        notes.push(format!(
            "entrance function: the azimuths at {} agree within their errors and hold their weighted mean",
            pooled.join(", ")
        ));
    }
}

/// The 99th percentile of χ² with `dof` degrees of freedom (Wilson and
/// Hilferty's cube-root normal approximation, within 1 % from 1 up).
fn chi2_99(dof: usize) -> f64 {
    let k = dof as f64;
    let z = 2.326_347_874;
    k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3)
}

/// A light within 2 degrees of the normal is the vertical reference.
fn is_vertical(d: [f64; 3]) -> bool {
    d[2] > (2f64).to_radians().cos()
}

/// One key per light direction: [`VERTICAL_KEY`] for the vertical, else
/// that of the cluster it joins, the nearest centre within `SAME_LIGHT_DIR`
/// or a new one (clusters, not a grid, as rounding would split neighbours
/// across a cell boundary). So each direction has all channels and every
/// row that aims the laser that way, and so views from both sides of it.
fn cluster_light_directions(dirs: impl Iterator<Item = [f64; 3]>) -> Vec<[i64; 3]> {
    let mut centres: Vec<[f64; 3]> = Vec::new();
    dirs.map(|d| {
        if is_vertical(d) {
            return VERTICAL_KEY;
        }
        let angle = |c: &[f64; 3]| {
            (c[0] * d[0] + c[1] * d[1] + c[2] * d[2])
                .clamp(-1.0, 1.0)
                .acos()
        };
        let nearest = centres
            .iter()
            .map(|c| (angle(c), *c))
            .filter(|(a, _)| *a < SAME_LIGHT_DIR)
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let centre = match nearest {
            Some((_, c)) => c,
            None => {
                centres.push(d);
                d
            }
        };
        dir_key(centre)
    })
    .collect()
}

/// One stripe image's band flux per incident flux, with its light and view.
struct BandFlux<'a> {
    light: [i64; 3],
    light_dir: [f64; 3],
    view: [i64; 3],
    stripe: &'a StripeEntry,
    flux: f64,
}

/// The band flux of the vertical stripe in `b`'s view and channel whose line
/// is parallel to `b`'s (within 5 degrees) and nearest it.
fn nearest_vertical(images: &[BandFlux], b: &BandFlux) -> Option<f64> {
    let (d, p) = (b.stripe.line_dir, b.stripe.line_point);
    images
        .iter()
        .filter(|r| {
            r.light == VERTICAL_KEY
                && r.view == b.view
                && r.stripe.channel == b.stripe.channel
                && (r.stripe.line_dir[0] * d[0] + r.stripe.line_dir[1] * d[1]).abs()
                    > PARALLEL_LINES_COS
        })
        .map(|r| (r.stripe.distance(p), r.flux))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, flux)| flux)
}

/// Stripe lines within 5 degrees of each other are parallel.
const PARALLEL_LINES_COS: f64 = 0.996_194_698_091_745_5;

/// How far the window reaches from the stripe's line on its nearer side, mm
/// (the signed distance is linear: its extremes sit at corner texels).
fn band_extent(s: &StripeEntry, grid: &Grid) -> f64 {
    let (w, h) = (grid.width as usize - 1, grid.height as usize - 1);
    let (mut lo, mut hi) = (0f64, 0f64);
    for (i, j) in [(0, 0), (w, 0), (0, h), (w, h)] {
        let d = s.signed_distance(grid.centre(i, j));
        lo = lo.min(d);
        hi = hi.max(d);
    }
    hi.min(-lo)
}

/// Outgoing radiance integrated across the stripe over |d| <= reach, per mm
/// of line: Σ over texel-wide signed-distance bins of the bin's mean
/// radiance (over its finite texels) times the bin width.
fn band_flux(img: &Texture, s: &StripeEntry, grid: &Grid, reach: f64) -> f64 {
    let c = s.channel as usize;
    let mut bins = DistanceBins::new(grid.texel_mm, 2.0 * reach);
    for j in 0..grid.height as usize {
        for i in 0..grid.width as usize {
            let d = s.signed_distance(grid.centre(i, j));
            let l = img.get(i, j)[c] as f64;
            if d.abs() <= reach && l.is_finite() {
                bins.add_spread(0.0, d + reach, l);
            }
        }
    }
    bins.means().into_iter().flatten().sum::<f64>() * grid.texel_mm
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stripe(
        pass: u8,
        light_dir: [f64; 3],
        view_dir: [f64; 3],
        x0: f64,
        dir: [f64; 2],
    ) -> StripeEntry {
        StripeEntry {
            file: String::new(),
            pass,
            channel: 1,
            light_dir,
            view_dir,
            camera: 3,
            flux_per_mm: 1.0,
            line_point: [x0, 0.0],
            line_dir: dir,
        }
    }

    #[test]
    fn light_directions_a_degree_apart_are_one_and_a_plan_s_steps_are_not() {
        let dir = |theta_deg: f64, phi_deg: f64| {
            let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
            [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
        };
        // A sweep's spread about 30 and 60 degrees at azimuth 45, and the
        // paper plan's nearest other direction (azimuth 30 degrees further
        // at 15 degrees from the normal, 7.8 degrees away), and the vertical.
        let dirs = [
            dir(30.4, 45.3),
            dir(59.6, 44.2),
            dir(29.5, 44.6),
            dir(60.3, 45.9),
            dir(15.0, 45.0),
            dir(15.0, 75.0),
            dir(0.5, 10.0),
        ];
        let keys = cluster_light_directions(dirs.into_iter());
        assert_eq!(keys[0], keys[2]);
        assert_eq!(keys[1], keys[3]);
        assert_ne!(keys[0], keys[1]);
        assert_ne!(keys[4], keys[5]);
        assert_eq!(keys[6], VERTICAL_KEY);
    }

    #[test]
    fn an_oblique_stripe_is_paired_with_the_nearest_parallel_vertical_line_of_its_view() {
        let (up, oblique) = ([0.0, 0.0, 1.0], [0.0, 0.707, 0.707]);
        let (view, other_view) = ([0.788, 0.0, 0.616], [-0.788, 0.0, 0.616]);
        let y = [0.0, 1.0];
        let stripes = [
            stripe(2, up, view, 0.0, y),
            stripe(2, up, view, 6.0, y),
            // Nearer, but in another view or across the line.
            stripe(2, up, other_view, 5.5, y),
            stripe(2, up, view, 5.5, [1.0, 0.0]),
            stripe(1, oblique, view, 5.4, y),
        ];
        let images: Vec<BandFlux> = stripes
            .iter()
            .enumerate()
            .map(|(k, s)| BandFlux {
                light: if s.pass == 2 {
                    VERTICAL_KEY
                } else {
                    dir_key(oblique)
                },
                light_dir: s.light_dir,
                view: dir_key(s.view_dir),
                stripe: s,
                flux: k as f64 + 1.0,
            })
            .collect();
        assert_eq!(nearest_vertical(&images, &images[4]), Some(2.0));
        // A view without a vertical stripe has no pair.
        let alone = stripe(1, oblique, [0.0, 0.0, 1.0], 5.4, y);
        let b = BandFlux {
            view: dir_key(alone.view_dir),
            stripe: &alone,
            ..images[4]
        };
        assert_eq!(nearest_vertical(&images, &b), None);
    }

    #[test]
    fn azimuths_that_agree_within_their_errors_share_their_mean() {
        let at = |phi: f64, v: f64, se: f64| {
            let (t, p) = (60f64.to_radians(), phi.to_radians());
            Measured {
                dir: [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()],
                value: [v; 3],
                se: [se; 3],
            }
        };
        let thirty = Measured {
            dir: [0.5, 0.0, 0.866_025_4],
            value: [1.03; 3],
            se: [0.02; 3],
        };
        // a heterogeneous sample: 1.15 to 1.24 at 2 % errors (chi2 9.6 < 11.3)
        let mut m = vec![
            at(45.0, 1.21, 0.02),
            at(135.0, 1.24, 0.02),
            at(225.0, 1.15, 0.02),
            at(315.0, 1.20, 0.02),
            thirty.clone(),
        ];
        let mut notes = Vec::new();
        pool_azimuths(&mut m, &mut notes);
        for k in 0..4 {
            assert_eq!(m[k].value[1], m[0].value[1]);
        }
        assert!((m[0].value[1] - 1.20).abs() < 1e-3, "{:?}", m[0]);
        assert_eq!(m[4], thirty, "a ring of one stays");
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(
            notes[0].contains("60.0 deg (4 directions, RGB) agree"),
            "{notes:?}"
        );
        notes.clear();
        // an anisotropic one: the same values known to 0.5 % and the rig's
        // floor (chi2 69)
        let mut m = vec![
            at(45.0, 1.21, 0.005),
            at(135.0, 1.24, 0.005),
            at(225.0, 1.15, 0.005),
            at(315.0, 1.20, 0.005),
        ];
        pool_azimuths(&mut m, &mut notes);
        assert_eq!(m[2].value[0], 1.15);
        assert_eq!(notes.len(), 3, "{notes:?}");
        assert!(notes[0].contains("differ beyond their errors"), "{notes:?}");
    }

    #[test]
    fn the_ratio_error_follows_the_pairs_scatter_and_chi2_its_table() {
        let (r, se) = ratio_with_error(&[(1.1, 1.0), (0.9, 1.0), (1.0, 1.0)]);
        assert!((r - 1.0).abs() < 1e-12);
        // sqrt(3/2 * 0.02) / 3
        assert!((se - 0.057_735).abs() < 1e-6, "{se}");
        assert!(ratio_with_error(&[(1.0, 1.0)]).1.is_nan());
        for (dof, q) in [
            (1, 6.635),
            (2, 9.210),
            (3, 11.345),
            (7, 18.475),
            (20, 37.566),
        ] {
            assert!(
                (chi2_99(dof) / q - 1.0).abs() < 0.01,
                "{dof}: {}",
                chi2_99(dof)
            );
        }
    }
}
