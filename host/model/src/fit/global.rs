//! Steps 1-3 of the fit, per colour channel: I(d) from the vertical
//! (pass-2) stripe images, R = 2 ∫ I(d) dd, then a' and s'_t by the
//! profile fit: the global dipole term.

use std::collections::BTreeMap;

use rayon::prelude::*;

use super::FitOptions;
use super::bins::DistanceBins;
use super::stripes::{SPECULAR_VIEW_COS, ascending_runs, core_mm, cos_to_mirror, dir_key};
use crate::ModelError;
use crate::fresnel::normal_transmittance;
use crate::profile::{ChannelFit, Profile, ProfileFit, fit_profile};
use crate::rectified::{Rectified, StripeEntry};
use crate::scaled_stripe::ScaledStripe;
use crate::subsurface::ProfileModel;

/// A channel's I_D(d) as the capture sees it: per incident flux of a
/// normal stripe, T(0) times the per-entered profile of the fit's model
/// (see [`crate::profile`]), tabulated out to `d_max`.
pub(super) struct EnteringStripe {
    table: ScaledStripe,
    sigma_t_prime: f64,
    t_in: f64,
}

impl EnteringStripe {
    pub(super) fn new(
        model: ProfileModel,
        alpha_prime: f64,
        sigma_t_prime: f64,
        eta: f64,
        d_max: f64,
    ) -> Self {
        EnteringStripe {
            table: model.stripe_table(alpha_prime, eta, sigma_t_prime * d_max),
            sigma_t_prime,
            t_in: normal_transmittance(eta),
        }
    }
    pub(super) fn stripe(&self, d: f64) -> f64 {
        self.t_in * self.table.eval(d, self.sigma_t_prime)
    }
    /// The mean of [`Self::stripe`] across a texel `w` wide centred at `d`:
    /// what an area-mean texel measures.
    pub(super) fn texel_mean(&self, d: f64, w: f64) -> f64 {
        self.t_in * self.table.bin_mean(d, w, self.sigma_t_prime)
    }
    /// ∫_{d0}^∞ of [`Self::stripe`] (d = d0 + L t/(1 - t), L = 1/s'_t).
    pub(super) fn tail(&self, d0: f64) -> f64 {
        let l = 1.0 / self.sigma_t_prime;
        let f = |t: f64| {
            if t >= 1.0 {
                return 0.0;
            }
            let u = 1.0 - t;
            self.stripe(d0 + l * t / u) * l / (u * u)
        };
        crate::quad::integrate(f, 0.0, 1.0, 1e-6, 1e-300, 200)
    }
}

/// One view's pass-2 bins: fine ones for the profile, texel-wide ones for R.
struct ViewBins {
    cos: f64,
    /// No image of this view left the stripe's core out.
    whole_core: bool,
    fine: DistanceBins,
    coarse: DistanceBins,
}

/// R = 2 ∫ I(d) dd from I(d) binned at `bin` mm (None: no valid texel).
/// Measured bins count as they are; unmeasured bins below the last measured
/// one (the stripe's near field, masked) come from the dipole `dp` when
/// given; beyond the last bin the measured tail goes on at its own
/// exponential decay, fitted over the outer third of the measured distances.
/// The sample's edges and depth shape that far tail, and the dipole's
/// semi-infinite tail would overstate it (and feed back through a' into a
/// still longer tail).
fn reflectance_from_profile(means: &[Option<f64>], bin: f64, dp: Option<&EnteringStripe>) -> f64 {
    let centre = |k: usize| (k as f64 + 0.5) * bin;
    let measured: Vec<usize> = (0..means.len()).filter(|&k| means[k].is_some()).collect();
    let (Some(&first), Some(&last)) = (measured.first(), measured.last()) else {
        return 0.0;
    };
    let inside: f64 = (0..=last)
        .map(|k| match means[k] {
            Some(i) => i,
            None => dp.map_or(0.0, |dp| dp.stripe(centre(k))),
        })
        .sum::<f64>()
        * bin;
    // ln I = a - κ d over the outer third, least squares.
    let from = centre(last) - (centre(last) - centre(first)) / 3.0;
    let pts: Vec<(f64, f64)> = measured
        .iter()
        .filter(|&&k| centre(k) >= from)
        .filter_map(|&k| means[k].filter(|&i| i > 0.0).map(|i| (centre(k), i.ln())))
        .collect();
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let kappa = -sxy / sxx;
    let d_end = (last + 1) as f64 * bin;
    let tail = if pts.len() >= 4 && kappa > 1e-3 {
        (my - kappa * (d_end - mx)).exp() / kappa
    } else if let Some(dp) = dp {
        // No usable decay (too few or noisy points): the model's own tail.
        dp.tail(d_end)
    } else {
        0.0
    };
    2.0 * (inside + tail)
}

/// Weights of views at the direction cosines `cos` (summing to 1) that turn
/// their R into the exitance over the whole hemisphere. Each view's R is its
/// radiance times `per_radiance` (the exitance per radiance of the model's
/// emergent distribution, π / S(μ)); the exitance is π ∫ L d(μ²) =
/// ∫ R(μ) S(μ) d(μ²), with R(μ) piecewise linear in μ² between the
/// elevations (views within 0.02 in cosine are one elevation, each of its
/// views an equal share) and held beyond the outermost. A plain mean over
/// views gives a grazing view, whose R depends most on the assumed
/// distribution, as much weight as one near the normal; where the sample's
/// emergent distribution is the model's, every view's R is the same and so
/// is the result.
fn elevation_weights(cos: &[f64], per_radiance: &dyn Fn(&[f64]) -> Vec<f64>) -> Vec<f64> {
    let groups = elevations(cos);
    let nodes: Vec<f64> = groups.iter().map(|(c, _)| c * c).collect();
    // Midpoint rule over x = μ² with the hat functions of the nodes.
    const STEPS: usize = 400;
    let xs: Vec<f64> = (0..STEPS)
        .map(|k| (k as f64 + 0.5) / STEPS as f64)
        .collect();
    let mus: Vec<f64> = xs.iter().map(|x| x.sqrt()).collect();
    let k = per_radiance(&mus);
    let mut node_weight = vec![0.0; nodes.len()];
    for (&x, k) in xs.iter().zip(k) {
        let shape = std::f64::consts::PI / k;
        match nodes.iter().position(|&n| n > x) {
            Some(0) => node_weight[0] += shape,
            None => node_weight[nodes.len() - 1] += shape,
            Some(j) => {
                let t = (x - nodes[j - 1]) / (nodes[j] - nodes[j - 1]);
                node_weight[j - 1] += (1.0 - t) * shape;
                node_weight[j] += t * shape;
            }
        }
    }
    let total: f64 = node_weight.iter().sum();
    let mut weights = vec![0.0; cos.len()];
    for ((_, members), w) in groups.iter().zip(node_weight) {
        for &i in members {
            weights[i] = w / total / members.len() as f64;
        }
    }
    weights
}

/// The views' elevations, ascending: (mean direction cosine, the views
/// within 0.02 of the lowest).
fn elevations(cos: &[f64]) -> Vec<(f64, Vec<usize>)> {
    ascending_runs(cos, 0.02)
        .into_iter()
        .map(|members| {
            let mean = members.iter().map(|&j| cos[j]).sum::<f64>() / members.len() as f64;
            (mean, members)
        })
        .collect()
}

/// A note when the elevations' mean R differ by more than 10 %: the
/// sample sends its light out otherwise than the model's distribution.
fn elevation_spread_note(
    channel: u8,
    for_r: &[(f64, Vec<Option<f64>>)],
    bin: f64,
    dp: Option<&EnteringStripe>,
    r: f64,
) -> Option<String> {
    let cos: Vec<f64> = for_r.iter().map(|(c, _)| *c).collect();
    let per: Vec<(f64, f64)> = elevations(&cos)
        .iter()
        .map(|(c, members)| {
            let sum: f64 = members
                .iter()
                .map(|&i| reflectance_from_profile(&for_r[i].1, bin, dp))
                .sum();
            (*c, sum / members.len() as f64)
        })
        .collect();
    let lo = per.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let hi = per.iter().map(|p| p.1).fold(0.0, f64::max);
    (per.len() > 1 && lo > 0.0 && hi > 1.1 * lo).then(|| {
        let list: Vec<String> = per
            .iter()
            .map(|(c, v)| format!("{:.0} deg {v:.4}", c.clamp(-1.0, 1.0).acos().to_degrees()))
            .collect();
        format!(
            "channel {channel}: R read at each view elevation ({}) spreads by {:.0} %: the sample's light leaves at other angles than the model's; R = {r:.4} weighs them over the hemisphere",
            list.join(", "),
            100.0 * (hi / lo - 1.0)
        )
    })
}

/// The global term of every channel from the pass-2 stripes of `data`, I(d)
/// binned at `bin` mm out to `diag_max`: each channel's fit and its I_D(d)
/// as the capture sees it. `step` is called once per channel.
pub(super) fn fit_global(
    data: &Rectified,
    opts: &FitOptions,
    bin: f64,
    diag_max: f64,
    notes: &mut Vec<String>,
    step: &(dyn Fn() + Sync),
) -> Result<(Vec<ChannelFit>, [EnteringStripe; 3]), ModelError> {
    let grid = data.index.grid;
    let (w, h) = (grid.width as usize, grid.height as usize);
    let mut channels = Vec::new();
    let mut stripes: [Option<EnteringStripe>; 3] = [None, None, None];
    for c in 0..3u8 {
        let entries: Vec<&StripeEntry> = data
            .index
            .stripe
            .iter()
            .filter(|s| s.pass == 2 && s.channel == c)
            .collect();
        if entries.is_empty() {
            return Err(ModelError::Fit(format!(
                "no pass-2 (vertical stripe) images for channel {c}"
            )));
        }
        // Per view, merged: radiance per incident flux per mm in fine bins
        // for the s'_t fit, and in texel-wide bins for R. A texel is an area
        // mean, so the texels of a texel-wide bin sum to the flux across the
        // line; finer bins leave gaps between texel distances that only the
        // model could fill. Views stay apart because turning radiance into
        // exitance depends on the view and, through the light's angular
        // distribution, on a'.
        let per_image = entries
            .par_iter()
            .map(|s| -> Result<_, ModelError> {
                let img = data.read_image(&s.file)?;
                let k = 1.0 / s.flux_per_mm;
                let skip = if cos_to_mirror(s) > SPECULAR_VIEW_COS {
                    core_mm(&grid)
                } else {
                    0.0
                };
                let mut fine = DistanceBins::new(bin, diag_max);
                let mut coarse = DistanceBins::new(grid.texel_mm, diag_max);
                for j in 0..h {
                    for i in 0..w {
                        let l = img.get(i, j)[c as usize] as f64;
                        let d = s.distance(grid.centre(i, j));
                        if l.is_finite() {
                            fine.add_from(skip, d, k * l);
                            coarse.add_spread(skip, d, k * l);
                        }
                    }
                }
                Ok((
                    dir_key(s.view_dir),
                    s.view_dir[2],
                    skip == 0.0,
                    fine,
                    coarse,
                ))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let mut views: BTreeMap<[i64; 3], ViewBins> = BTreeMap::new();
        for (key, cos, whole_core, fine, coarse) in per_image {
            let merged = match views.remove(&key) {
                Some(v) => ViewBins {
                    cos,
                    whole_core: v.whole_core && whole_core,
                    fine: v.fine.merged(fine),
                    coarse: v.coarse.merged(coarse),
                },
                None => ViewBins {
                    cos,
                    whole_core,
                    fine,
                    coarse,
                },
            };
            views.insert(key, merged);
        }
        let cos_views: Vec<f64> = views.values().map(|v| v.cos).collect();
        // I(d) with each view's radiance turned into exitance: points at the
        // mean distance of their texels (uneven coverage inside a bin does
        // not bias the fit), over all views. Each texel is an area mean, so
        // the model is averaged over a texel's width across the line (at
        // ci, 0.67 mm, this moves s'_t by +0.5..+3 %). For R, the texel-wide
        // bins' means of every view that sees the whole core: each of them
        // measures the whole integral, however its pixels blur the line (a
        // 77-degree view spreads it over a millimetre), where the bins'
        // means over views mixed views that blur differently with views
        // whose core is left out (skin1 at the default scale: R -0.8 % in
        // every channel, though no view alone was below -0.5 %).
        let exitance = |per_radiance: &[f64]| {
            let fine = views
                .values()
                .zip(per_radiance)
                .fold(DistanceBins::new(bin, diag_max), |fine, (v, &k)| {
                    fine.merged(v.fine.scaled(k))
                });
            let whole = views
                .values()
                .zip(per_radiance)
                .filter(|(v, _)| v.whole_core);
            let mut for_r: Vec<(f64, Vec<Option<f64>>)> = whole
                .map(|(v, &k)| (v.cos, v.coarse.scaled(k).means()))
                .collect();
            if for_r.is_empty() {
                // No view sees the whole core: the bins of all views together.
                let merged = views
                    .values()
                    .zip(per_radiance)
                    .map(|(v, &k)| v.coarse.scaled(k))
                    .reduce(DistanceBins::merged)
                    .expect("at least one view");
                for_r.push((1.0, merged.means()));
            }
            (Profile::new(fine.points(), grid.texel_mm), for_r)
        };
        // Each view's R assumes the model's emergent distribution; the views'
        // R weighed by the hemisphere each elevation stands for
        // (`elevation_weights`) is the exitance whatever the distribution.
        let reflectance = |for_r: &[(f64, Vec<Option<f64>>)],
                           dp: Option<&EnteringStripe>,
                           per_radiance: &dyn Fn(&[f64]) -> Vec<f64>| {
            let cos: Vec<f64> = for_r.iter().map(|(c, _)| *c).collect();
            elevation_weights(&cos, per_radiance)
                .iter()
                .zip(for_r)
                .map(|(w, (_, means))| w * reflectance_from_profile(means, grid.texel_mm, dp))
                .sum::<f64>()
        };
        // Until a' is known, the light under the boundary is taken as isotropic.
        let isotropic = |c: &[f64]| ProfileModel::Dipole.exitance_per_radiance(1.0, opts.eta, c);
        let (mut profile, mut means) = exitance(&isotropic(&cos_views));
        if profile.distance_mm.len() < 5 {
            return Err(ModelError::Fit(format!(
                "channel {c}: only {} distance bins have valid texels",
                profile.distance_mm.len()
            )));
        }
        if !(profile.intensity.iter().sum::<f64>() > 0.0) {
            return Err(ModelError::Fit(format!(
                "channel {c}: no outgoing flux in the vertical stripe images"
            )));
        }
        // R and the fit depend on each other through the model's fill of
        // the unmeasured near field and through the radiance-to-exitance
        // conversion: a few rounds converge.
        let mut r = reflectance(&means, None, &isotropic);
        let mut fit = None;
        // The automatic range is chosen once, with the first R.
        let mut range = opts.range;
        for _ in 0..6 {
            let r_used = r.min(1.0);
            let f = fit_profile(&profile, r_used, opts.eta, opts.model, range, opts.norm)
                .map_err(|e| ModelError::Fit(format!("channel {c}: {e}")))?;
            range = Some((f.range_mm[0], f.range_mm[1]));
            let auto = fit
                .as_ref()
                .map_or(f.auto_range, |x: &(f64, ProfileFit, Profile)| {
                    x.1.auto_range
                });
            let f = ProfileFit {
                auto_range: auto,
                ..f
            };
            let dp = EnteringStripe::new(
                opts.model,
                f.alpha_prime,
                f.sigma_t_prime,
                opts.eta,
                diag_max,
            );
            let fitted = |c: &[f64]| opts.model.exitance_per_radiance(f.alpha_prime, opts.eta, c);
            let converted = exitance(&fitted(&cos_views));
            means = converted.1;
            let next = reflectance(&means, Some(&dp), &fitted);
            fit = Some((r_used, f, std::mem::replace(&mut profile, converted.0)));
            stripes[c as usize] = Some(dp);
            // 1e-6 of R moves a' and s'_t by less than 1e-5 of themselves.
            if (next - r).abs() < 1e-6 * r {
                break;
            }
            r = next;
        }
        let (r_used, fit, profile) = fit.expect("at least one iteration");
        notes.extend(elevation_spread_note(
            c,
            &means,
            grid.texel_mm,
            stripes[c as usize].as_ref(),
            r,
        ));
        if r > 1.0 {
            notes.push(format!(
                "channel {c}: measured R = {r:.4} > 1, clamped to 1"
            ));
        }
        channels.push(ChannelFit {
            channel: c as usize,
            reflectance: r_used,
            profile,
            fit,
        });
        step();
    }
    let tables = stripes.map(|s| s.expect("every channel was fitted"));
    Ok((channels, tables))
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    #[test]
    fn elevation_weights_integrate_the_radiance_over_the_hemisphere() {
        // The default scale's whole-core views: four elevations, four azimuths.
        let cos: Vec<f64> = [0.218, 0.431, 0.62, 0.783]
            .iter()
            .flat_map(|&c| [c, c + 0.002, c - 0.001, c + 0.001])
            .collect();
        let smooth = |c: &[f64]| ProfileModel::Dipole.exitance_per_radiance(1.0, 1.45, c);
        let w = elevation_weights(&cos, &smooth);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(w.iter().all(|&x| x > 0.0));
        // Views near the normal stand for more of the exitance than grazing ones.
        assert!(w[12] > 2.0 * w[0], "{w:?}");
        // A sample whose radiance follows the model: every view's R is the
        // exitance, and so is the weighted sum.
        let r: f64 = w.iter().map(|wi| wi * 0.5).sum();
        assert!((r - 0.5).abs() < 1e-12);
        // A Lambertian sample (L = M / pi at every angle), each view's
        // radiance turned into R with the smooth boundary's distribution:
        // the weights give M back within 3 %, the plain mean of the views
        // does not.
        let m = 0.5;
        let per_view: Vec<f64> = smooth(&cos).iter().map(|k| k * m / PI).collect();
        let weighted: f64 = w.iter().zip(&per_view).map(|(a, b)| a * b).sum();
        let mean = per_view.iter().sum::<f64>() / per_view.len() as f64;
        assert!((weighted / m - 1.0).abs() < 0.03, "{weighted}");
        assert!(mean / m - 1.0 > 0.06, "{mean}");
        // One elevation: its views share the weight equally (ci).
        let one = elevation_weights(&[0.62, 0.621], &smooth);
        assert_eq!(one, vec![0.5, 0.5]);
    }

    #[test]
    fn a_note_names_elevations_that_read_different_r() {
        let bin = 0.05;
        let profile = |scale: f64| -> Vec<Option<f64>> {
            (0..100)
                .map(|k| Some(scale * (-(k as f64 + 0.5) * bin).exp()))
                .collect()
        };
        let views = |grazing: f64| {
            vec![
                (0.78, profile(1.0)),
                (0.781, profile(1.0)),
                (0.22, profile(grazing)),
            ]
        };
        let note = elevation_spread_note(1, &views(1.3), bin, None, 2.1).expect("a note");
        assert!(note.contains("spreads by 30 %"), "{note}");
        assert!(note.starts_with("channel 1:"), "{note}");
        assert!(elevation_spread_note(1, &views(1.05), bin, None, 2.0).is_none());
        // One elevation has nothing to compare.
        assert!(elevation_spread_note(1, &views(1.3)[..2], bin, None, 2.0).is_none());
    }

    #[test]
    fn reflectance_continues_an_exponential_tail() {
        // I(d) = e^{-d}: R = 2 ∫ e^{-d} dd = 2, measured only to 5 mm.
        let bin = 0.05;
        let means: Vec<Option<f64>> = (0..100)
            .map(|k| Some((-(k as f64 + 0.5) * bin).exp()))
            .collect();
        let r = reflectance_from_profile(&means, bin, None);
        assert!((r - 2.0).abs() < 2e-3, "{r}");
    }

    #[test]
    fn reflectance_fills_the_near_field_from_the_model() {
        for model in [ProfileModel::Transport, ProfileModel::Dipole] {
            // The model's own profile, the first 0.5 mm masked and measured to 40 mm.
            let dp = EnteringStripe::new(model, 0.99, 2.0, 1.3, 40.0);
            let bin = 0.02;
            let means: Vec<Option<f64>> = (0..2000)
                .map(|k| {
                    let d = (k as f64 + 0.5) * bin;
                    (d > 0.5).then(|| dp.stripe(d))
                })
                .collect();
            let r = reflectance_from_profile(&means, bin, Some(&dp));
            let total = dp.t_in * model.total_reflectance(0.99, 1.3);
            assert!((r / total - 1.0).abs() < 0.01, "{model:?}: {r} vs {total}");
            // Without the model the near field is simply missing.
            assert!(reflectance_from_profile(&means, bin, None) < 0.95 * r);
            // A far third with no positive value (noise around 0): the
            // model's own tail beyond the last bin, by quadrature.
            let short: Vec<Option<f64>> = (0..300)
                .map(|k| {
                    let d = (k as f64 + 0.5) * bin;
                    if d < 4.0 { means[k] } else { Some(0.0) }
                })
                .collect();
            let expect = 2.0 * (short.iter().map(|m| m.unwrap_or(0.0)).sum::<f64>() * bin)
                + 2.0 * dp.tail(300.0 * bin)
                + 2.0
                    * (0..25)
                        .map(|k| dp.stripe((k as f64 + 0.5) * bin))
                        .sum::<f64>()
                    * bin;
            let got = reflectance_from_profile(&short, bin, Some(&dp));
            assert!(
                (got / expect - 1.0).abs() < 1e-6,
                "{model:?}: {got} vs {expect}"
            );
            assert!(dp.tail(300.0 * bin) < 0.05 * total, "{model:?}");
        }
    }
}
