//! The fit report of a material model: one self-contained HTML page
//! (`index.html`, no network: plots are inline SVG, images are PNG data
//! URIs), with the plots and mosaics also written beside it as files.
//!
//! The page shows, in order: the global dipole term per channel with the
//! fit's warnings; the laser-stripe profile fit per channel (paper Fig. 5)
//! with its fitted range; f(w_i) against the smooth surface's Fresnel ratio;
//! paper Fig. 6's rows (lamp image, f_v, LRF) at a few (light, view) samples;
//! every f_v view and the first LRF samples, labelled; the calibration the
//! capture was rectified with; and the time of each stage. Every image row is
//! scaled by percentiles of its own values (an outlier texel cannot wash it
//! out) and has a colour bar. A small script checks on load that every image
//! decoded and no script error happened, and says so at the page's foot
//! (`#qhm-check`, its `data-status` JSON read by the page test).
//!
//! This file builds the page; `report/plots.rs` draws the SVG plots and
//! `report/images.rs` the colour-scaled images.

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::ModelError;
use crate::fresnel::normal_transmittance;
use crate::model::{FitDiagnostics, MaterialModel, Texture};
use crate::profile::SIGMA_T_PRIME_MAX;
use crate::rectified::Rectified;

mod images;
mod plots;

pub use plots::{entrance_svg, profile_svg};

use images::{
    Scale, colour_bar, dir_label, div_scale, invalid_note, mosaic_png, rgb_scale, rows_png,
    seq_scale, texture_png, tile,
};
use plots::channel_profile_svg;

const COLOURS: [&str; 3] = ["#d62728", "#2ca02c", "#1f77b4"];
const NAMES: [&str; 3] = ["red 650 nm", "green 532 nm", "blue 473 nm"];

/// Files [`write_report`] produced.
#[derive(Clone, Debug)]
pub struct ReportFiles {
    pub html: PathBuf,
    pub files: Vec<PathBuf>,
}

/// What the page shows beyond the model and its fit.json.
#[derive(Clone, Debug, Default)]
pub struct ReportOptions {
    /// Pipeline stage times (name, seconds), shown after the fit's own.
    pub stages: Vec<(String, f64)>,
    /// LRF samples (indices) for the Fig. 6 rows; empty: up to four spread
    /// over the views and lights.
    pub fig6_samples: Vec<usize>,
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), ModelError> {
    std::fs::write(path, bytes).map_err(|e| ModelError::io(path, e))
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The LRF sample whose light and view are nearest to `light` and `view`
/// (summed angles); None without samples.
pub fn nearest_sample(model: &MaterialModel, light: [f32; 3], view: [f32; 3]) -> Option<usize> {
    let angle = |a: [f32; 3], b: [f32; 3]| {
        let n = |v: [f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-12);
        ((a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (n(a) * n(b)))
            .clamp(-1.0, 1.0)
            .acos()
    };
    (0..model.lrf.samples.len()).min_by(|&i, &j| {
        let d = |k: usize| {
            let s = model.lrf.samples[k];
            angle(s.light, light) + angle(s.view, view)
        };
        d(i).total_cmp(&d(j))
    })
}

/// Up to four LRF samples spread over the sorted (view, light) pairs.
fn default_fig6(model: &MaterialModel) -> Vec<usize> {
    let s = &model.lrf.samples;
    let mut order: Vec<usize> = (0..s.len()).collect();
    let key = |i: usize| (s[i].view[2].acos(), s[i].light[2].acos());
    order.sort_by(|&a, &b| {
        key(a)
            .partial_cmp(&key(b))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let n = order.len().min(4);
    if n == 0 {
        return Vec::new();
    }
    let mut out: Vec<usize> = (0..n)
        .map(|k| order[(k * (order.len() - 1)) / (n - 1).max(1)])
        .collect();
    out.dedup();
    out
}

/// The lamp images (radiance per unit irradiance, sr^-1) of LRF samples
/// `idx`: from the rectified capture the model was fitted from when it is
/// still there and matches, else rebuilt from the model (LRF plus the
/// global term the fit subtracted). Returns the images and where they came from.
fn lamp_images(model: &MaterialModel, idx: &[usize]) -> (Vec<Texture>, String) {
    let from_capture = || -> Option<(Vec<Texture>, String)> {
        let dir = model.diagnostics.as_ref()?.capture_dir.as_ref()?;
        let data = Rectified::open(Path::new(dir)).ok()?;
        if data.index.lamp.len() != model.lrf.samples.len() {
            return None;
        }
        let mut out = Vec::new();
        for &k in idx {
            let e = &data.index.lamp[k];
            let s = model.lrf.samples[k];
            let close =
                |a: [f64; 3], b: [f32; 3]| (0..3).all(|c| (a[c] - b[c] as f64).abs() < 1e-3);
            if !close(e.light_dir, s.light) || !close(e.view_dir, s.view) {
                return None;
            }
            let mut t = data.read_image(&e.file).ok()?;
            // The model covers only the window its scans reach.
            if let Some([i0, j0, w, h]) = model.window() {
                let (i0, j0, w, h) = (i0 as usize, j0 as usize, w as usize, h as usize);
                if i0 + w > t.width || j0 + h > t.height {
                    return None;
                }
                t = Texture {
                    width: w,
                    height: h,
                    data: (0..w * h).map(|p| t.get(i0 + p % w, j0 + p / w)).collect(),
                };
            }
            for p in &mut t.data {
                for c in 0..3 {
                    p[c] = (p[c] as f64 / e.irradiance[c]) as f32;
                }
            }
            out.push(t);
        }
        Some((
            out,
            format!("rectified lamp images of {dir}, divided by the lamp's irradiance"),
        ))
    };
    if let Some(r) = from_capture() {
        return r;
    }
    let t_in = normal_transmittance(model.dipole.eta);
    let r0 = model.texel_mm as f64 / PI.sqrt();
    let sub = model.dipole.subsurface();
    let global: [f64; 3] =
        std::array::from_fn(|c| t_in * (sub.total(c) - sub.disc_integral(c, r0)));
    let out = idx
        .iter()
        .map(|&k| {
            let s = model.lrf.samples[k];
            let lrf = &model.lrf.maps[k];
            let f = model.entrance(s.light);
            let cos_i = s.light[2].max(0.0) as f64;
            let (w, h) = (lrf.width, lrf.height);
            let data = (0..w * h)
                .map(|p| {
                    let uv = [
                        ((p % w) as f32 + 0.5) / w as f32,
                        ((p / w) as f32 + 0.5) / h as f32,
                    ];
                    let fv = model.exiting(uv, s.view);
                    std::array::from_fn(|c| {
                        (lrf.data[p][c] as f64
                            + fv[c] as f64 * f[c] as f64 * cos_i * global[c] / PI)
                            as f32
                    })
                })
                .collect();
            Texture {
                width: w,
                height: h,
                data,
            }
        })
        .collect();
    (
        out,
        "rebuilt from the model (LRF + f_v f(w_i) cos θ_i global term / π): the capture is not at hand".into(),
    )
}

/// f_v of `view` as a texture (the model's own lookup).
fn fv_texture(model: &MaterialModel, view: [f32; 3]) -> Texture {
    let (w, h) = (model.exiting.maps[0].width, model.exiting.maps[0].height);
    Texture {
        width: w,
        height: h,
        data: (0..w * h)
            .map(|p| {
                model.exiting(
                    [
                        ((p % w) as f32 + 0.5) / w as f32,
                        ((p / w) as f32 + 0.5) / h as f32,
                    ],
                    view,
                )
            })
            .collect(),
    }
}

// ---------------------------------------------------------------- page

const STYLE: &str = "
body{font-family:Helvetica,Arial,sans-serif;color:#222;max-width:1260px;margin:0 auto;padding:0 24px 40px;line-height:1.4}
h1{font-size:24px;margin:24px 0 4px} h2{font-size:18px;border-bottom:1px solid #ccc;padding-bottom:3px;margin-top:34px}
h3{font-size:14px;margin:16px 0 6px}
.meta{color:#555;font-size:13px;margin:0 0 10px}
table{border-collapse:collapse;font-size:13px;margin:8px 0}
th,td{padding:3px 10px;border-bottom:1px solid #e2e2e2;text-align:right;font-variant-numeric:tabular-nums}
th{background:#f3f3f3} td.l,th.l{text-align:left}
.swatch{display:inline-block;width:10px;height:10px;margin-right:6px;vertical-align:baseline}
.plots{display:flex;flex-wrap:wrap;gap:8px}
.plots svg{border:1px solid #ddd}
.row{display:flex;flex-wrap:wrap;gap:10px;align-items:flex-start}
.rowhead{font-weight:bold;font-size:13px;margin:12px 0 4px}
.tile{margin:0;text-align:center;font-size:11px;color:#444}
.tile img{display:block;width:160px;height:160px;image-rendering:pixelated;border:1px solid #999}
.small .tile img{width:104px;height:104px}
.cbar{display:block;margin:2px 0 6px}
.warn{background:#fff6df;border-left:4px solid #e0a800;padding:6px 12px;font-size:13px}
.warn li{margin:2px 0}
.ok{color:#2a7a2a} .bad{color:#b00020;font-weight:bold}
.bar{background:#5b8bd0;height:11px;display:inline-block}
.note{font-size:12px;color:#555}
#qhm-check{font-size:12px;margin-top:30px;border-top:1px solid #ccc;padding-top:6px}
";

/// Captures script errors from the start and, on load, checks that every
/// image decoded (drawing it into a canvas throws for a broken one);
/// writes the outcome into #qhm-check (text and `data-status` JSON). All
/// synchronous in the load handler, so a headless `--dump-dom` sees it.
const CHECK_SCRIPT: &str = r#"<script>
(function () {
  var errors = [];
  window.addEventListener('error', function (e) {
    var t = e.target;
    errors.push(t && t.tagName ? 'failed to load <' + t.tagName.toLowerCase() + '> ' + (t.alt || '') : String(e.message));
  }, true);
  var ce = console.error;
  console.error = function () { errors.push(Array.prototype.join.call(arguments, ' ')); ce.apply(console, arguments); };
  window.addEventListener('load', function () {
    var imgs = Array.prototype.slice.call(document.images);
    var bad = [];
    var g = document.createElement('canvas').getContext('2d');
    imgs.forEach(function (i) {
      var ok = i.complete && i.naturalWidth > 0;
      if (ok) { try { g.drawImage(i, 0, 0, 1, 1); } catch (e) { ok = false; } }
      if (!ok) bad.push(i.alt || '(no alt)');
    });
    var el = document.getElementById('qhm-check');
    el.setAttribute('data-status', JSON.stringify({ images: imgs.length, broken: bad, errors: errors }));
    el.className = bad.length || errors.length ? 'bad' : 'ok';
    el.textContent = bad.length || errors.length
      ? 'Page check: ' + bad.length + ' of ' + imgs.length + ' images did not decode (' + bad.join(', ') + '); ' + errors.length + ' script errors (' + errors.join('; ') + ').'
      : 'Page check: all ' + imgs.length + ' images decoded; no script errors.';
  });
})();
</script>"#;

/// Warnings of the fit: its notes and what the numbers themselves say.
fn warnings(model: &MaterialModel) -> Vec<String> {
    let mut w = Vec::new();
    let Some(d) = &model.diagnostics else {
        return vec!["no fit diagnostics (fit.json) in the model: fit plots are left out".into()];
    };
    for ch in &d.channels {
        let c = ch.channel.min(2);
        let f = &ch.fit;
        if f.sigma_t_prime >= SIGMA_T_PRIME_MAX * 0.999 {
            w.push(format!(
                "{}: s'_t hit the end of its search interval ({SIGMA_T_PRIME_MAX} /mm): the profile does not fit in range",
                NAMES[c]
            ));
        }
        if f.residual > 0.1 {
            w.push(format!(
                "{}: relative RMS misfit {:.3} over the fit range (above 0.1)",
                NAMES[c], f.residual
            ));
        }
        if f.points < 10 {
            w.push(format!(
                "{}: only {} profile points inside the fit range",
                NAMES[c], f.points
            ));
        }
        if f.alpha_prime > 0.998 {
            w.push(format!(
                "{}: a' = {:.4} is close to 1, where s'_t is ill-conditioned",
                NAMES[c], f.alpha_prime
            ));
        }
    }
    w.extend(d.notes.iter().cloned());
    w
}

fn dipole_section(model: &MaterialModel, html: &mut String) {
    let p = &model.dipole;
    let (ss, sa) = (p.sigma_s_prime(), p.sigma_a());
    let _ = writeln!(
        html,
        "<h2>Global dipole term</h2>\n<p class=\"meta\">eta {}, light transport of the fit: {}. a' and s'_t are per entered flux; R is the measured total diffuse reflectance per incident flux.</p>\n\
         <table><tr><th class=\"l\">channel</th><th>R</th><th>a'</th><th>s'_t (1/mm)</th><th>s'_s (1/mm)</th><th>s_a (1/mm)</th><th>fit range (mm)</th><th>points</th><th>residual</th></tr>",
        p.eta,
        p.model.name()
    );
    let diag = model.diagnostics.as_ref();
    for c in 0..3 {
        let ch = diag.and_then(|d| d.channels.iter().find(|x| x.channel == c));
        let (r, range, pts, res) = ch.map_or_else(
            || ("-".into(), "-".into(), "-".into(), "-".into()),
            |x| {
                (
                    format!("{:.5}", x.reflectance),
                    format!(
                        "{:.2} - {:.2} ({})",
                        x.fit.range_mm[0],
                        x.fit.range_mm[1],
                        if x.fit.auto_range { "auto" } else { "given" }
                    ),
                    x.fit.points.to_string(),
                    format!("{:.2e}", x.fit.residual),
                )
            },
        );
        let _ = writeln!(
            html,
            "<tr><td class=\"l\"><span class=\"swatch\" style=\"background:{}\"></span>{}</td><td>{r}</td><td>{:.5}</td><td>{:.4}</td><td>{:.4}</td><td>{:.5}</td><td>{range}</td><td>{pts}</td><td>{res}</td></tr>",
            COLOURS[c], NAMES[c], p.alpha_prime[c], p.sigma_t_prime[c], ss[c], sa[c]
        );
    }
    html.push_str("</table>\n");
    let w = warnings(model);
    if w.is_empty() {
        html.push_str("<p class=\"ok\">The fit raised no warnings.</p>\n");
    } else {
        html.push_str("<div class=\"warn\"><b>Warnings of the fit</b><ul>\n");
        for n in &w {
            let _ = writeln!(html, "<li>{}</li>", esc(n));
        }
        html.push_str("</ul></div>\n");
    }
}

fn calibration_section(d: Option<&FitDiagnostics>, html: &mut String) {
    html.push_str("<h2>Calibration the capture used</h2>\n");
    let Some(cal) = d.and_then(|d| d.calibration.as_ref()) else {
        html.push_str("<p class=\"note\">Not recorded: the capture was rectified before rectification recorded its calibration, or the model was not fitted from a rectified capture.</p>\n");
        return;
    };
    let _ = writeln!(
        html,
        "<p class=\"meta\">source: {}</p>",
        esc(if cal.source.is_empty() {
            "(not named)"
        } else {
            &cal.source
        })
    );
    let tri = |v: Option<[f64; 3]>, digits: usize| {
        v.map_or("-".into(), |v| {
            format!("{:.d$}, {:.d$}, {:.d$}", v[0], v[1], v[2], d = digits)
        })
    };
    let sci = |v: Option<[f64; 3]>| {
        v.map_or("-".into(), |v| {
            format!("{:.4e}, {:.4e}, {:.4e}", v[0], v[1], v[2])
        })
    };
    html.push_str("<div class=\"row\"><div>");
    if !cal.cameras.is_empty() {
        html.push_str("<h3>Cameras</h3><table><tr><th>camera</th><th>response</th><th>geometry</th><th>reprojection RMS (px)</th><th>colour gain R, G, B</th></tr>\n");
        for c in &cal.cameras {
            let _ = writeln!(
                html,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                c.index,
                if c.response { "yes" } else { "no" },
                if c.geometry { "yes" } else { "no" },
                c.reprojection_rms_px
                    .map_or("-".into(), |r| format!("{r:.3}")),
                tri(c.colour_gain, 4)
            );
        }
        html.push_str("</table>\n");
    }
    html.push_str("</div><div>");
    if !cal.lamps.is_empty() {
        html.push_str("<h3>Lamps</h3><table><tr><th>lamp</th><th>irradiance R, G, B</th></tr>\n");
        for l in &cal.lamps {
            let _ = writeln!(
                html,
                "<tr><td>{}</td><td>{}</td></tr>",
                l.index,
                sci(l.irradiance)
            );
        }
        html.push_str("</table>\n");
    }
    html.push_str("<h3>Laser and turntable</h3><table>\n");
    let _ = writeln!(
        html,
        "<tr><td class=\"l\">laser flux per mm R, G, B</td><td>{}</td></tr>",
        sci(cal.laser_flux_per_mm)
    );
    let angles = cal
        .laser_plane_angles_deg
        .iter()
        .map(|a| format!("{:.1}° → {:.3}°", a[0], a[1]))
        .collect::<Vec<_>>()
        .join(", ");
    let _ = writeln!(
        html,
        "<tr><td class=\"l\">laser plane angle (nominal → measured)</td><td>{}</td></tr>",
        if angles.is_empty() {
            "-".into()
        } else {
            angles
        }
    );
    let _ = writeln!(
        html,
        "<tr><td class=\"l\">turntable axis</td><td>{}</td></tr></table>",
        tri(cal.turntable_axis, 5)
    );
    html.push_str("</div></div>\n");
}

fn times_section(d: Option<&FitDiagnostics>, opts: &ReportOptions, html: &mut String) {
    let fit: Vec<(String, f64)> = d
        .and_then(|d| d.timings.as_ref())
        .map(|t| {
            vec![
                ("dipole term (R, a', s'_t)".to_string(), t.dipole),
                ("entrance function f(w_i)".to_string(), t.entrance),
                ("exiting function f_v".to_string(), t.exiting),
                ("local reflectance function".to_string(), t.lrf),
            ]
        })
        .unwrap_or_default();
    html.push_str("<h2>Stage times</h2>\n");
    if fit.is_empty() && opts.stages.is_empty() {
        html.push_str("<p class=\"note\">Not recorded (the model was fitted before fit.json kept its stage times).</p>\n");
        return;
    }
    let peak = fit
        .iter()
        .chain(&opts.stages)
        .map(|r| r.1)
        .fold(1e-9, f64::max);
    html.push_str(
        "<table><tr><th class=\"l\">stage</th><th>seconds</th><th class=\"l\"></th></tr>\n",
    );
    let group = |title: &str, rows: &[(String, f64)], html: &mut String| {
        if rows.is_empty() {
            return;
        }
        let total: f64 = rows.iter().map(|r| r.1).sum();
        let _ = writeln!(
            html,
            "<tr><th class=\"l\">{}</th><th>{total:.2}</th><th></th></tr>",
            esc(title)
        );
        for (name, s) in rows {
            let _ = writeln!(
                html,
                "<tr><td class=\"l\">&nbsp;&nbsp;{}</td><td>{s:.2}</td><td class=\"l\"><span class=\"bar\" style=\"width:{:.0}px\"></span></td></tr>",
                esc(name),
                (s / peak * 300.0).max(1.0)
            );
        }
    };
    group("pipeline (total)", &opts.stages, html);
    group("inside the fit (total)", &fit, html);
    html.push_str("</table>\n");
}

/// The Fig. 6 rows and the labelled mosaics; returns the beside-page PNGs.
fn image_sections(
    model: &MaterialModel,
    opts: &ReportOptions,
    html: &mut String,
) -> Vec<(&'static str, Vec<u8>)> {
    let mut files = Vec::new();
    let fv_maps: Vec<&Texture> = model.exiting.maps.iter().collect();
    let fv_scale = seq_scale(&fv_maps);
    let lrf_all: Vec<&Texture> = model.lrf.maps.iter().collect();
    let size = 160;

    // Fig. 6: columns are (light, view) samples; rows lamp image, f_v, LRF.
    let idx: Vec<usize> = if opts.fig6_samples.is_empty() {
        default_fig6(model)
    } else {
        opts.fig6_samples
            .iter()
            .copied()
            .filter(|&k| k < model.lrf.samples.len())
            .collect()
    };
    html.push_str("<h2>Components at chosen lights and views (paper Fig. 6)</h2>\n");
    if idx.is_empty() {
        html.push_str(
            "<p class=\"note\">The model has no local reflectance samples (no lamp images).</p>\n",
        );
    } else {
        let (lamps, source) = lamp_images(model, &idx);
        let lamp_refs: Vec<&Texture> = lamps.iter().collect();
        let lamp_scale = rgb_scale(&lamp_refs);
        let fvs: Vec<Texture> = idx
            .iter()
            .map(|&k| fv_texture(model, model.lrf.samples[k].view))
            .collect();
        let lrfs: Vec<&Texture> = idx.iter().map(|&k| &model.lrf.maps[k]).collect();
        let lrf_scale = div_scale(&lrfs);
        let caption = |k: usize| {
            let s = model.lrf.samples[k];
            format!(
                "sample {k}<br>light {}<br>view {}",
                dir_label(s.light),
                dir_label(s.view)
            )
        };
        let _ = writeln!(
            html,
            "<p class=\"meta\">Each column is one (light, view) sample of the LRF. Rows are scaled by percentiles of their own values: the lamp image from 0 to its 99th percentile (RGB, display gamma 2.2), f_v and the LRF by the mean of R, G and B (f_v from its 1st to 99th percentile, the LRF symmetric about 0 at the 99th percentile of |LRF|; negative values are kept). Lamp images: {}.</p>",
            esc(&source)
        );
        let rows: [(&str, &Scale, Vec<&Texture>, &str); 3] = [
            (
                "Lamp image L / E (1/sr)",
                &lamp_scale,
                lamps.iter().collect(),
                "radiance per unit irradiance, R G B (1/sr)",
            ),
            (
                "Mesostructure exiting function f_v",
                &fv_scale,
                fvs.iter().collect(),
                "f_v, mean of R G B (1 = no modulation)",
            ),
            (
                "Local reflectance function",
                &lrf_scale,
                lrfs.clone(),
                "LRF, mean of R G B (1/sr)",
            ),
        ];
        for (r, (head, scale, maps, bar)) in rows.iter().enumerate() {
            let _ = writeln!(
                html,
                "<div class=\"rowhead\">{head}</div><div class=\"row\">"
            );
            for (m, &k) in maps.iter().zip(&idx) {
                html.push_str(&tile(
                    &texture_png(m, scale, size),
                    &format!("{head}, sample {k}"),
                    &caption(k),
                ));
            }
            html.push_str("</div>\n");
            html.push_str(&colour_bar(
                &format!("cbar-fig6-{r}"),
                scale,
                &format!("{bar}{}", invalid_note(maps)),
            ));
        }
        let grid: Vec<(&Scale, &[&Texture])> = rows
            .iter()
            .map(|(_, scale, maps, _)| (*scale, maps.as_slice()))
            .collect();
        files.push(("fig6.png", rows_png(&grid, size)));
    }

    // Every f_v view, labelled.
    let _ = writeln!(
        html,
        "<h2>Exiting function f_v, every view</h2>\n<p class=\"meta\">{} views; mean of R, G and B, scaled from its 1st to its 99th percentile over all views.</p>\n<div class=\"row small\">",
        fv_maps.len()
    );
    for (k, (m, v)) in fv_maps.iter().zip(&model.exiting.views).enumerate() {
        html.push_str(&tile(
            &texture_png(m, &fv_scale, 104),
            &format!("f_v view {k}"),
            &format!("view {k}<br>{}", dir_label(*v)),
        ));
    }
    html.push_str("</div>\n");
    html.push_str(&colour_bar(
        "cbar-fv",
        &fv_scale,
        &format!("f_v, mean of R G B{}", invalid_note(&fv_maps)),
    ));
    files.push(("fv.png", mosaic_png(&fv_maps, &fv_scale)));

    // The first LRF samples, labelled.
    if !lrf_all.is_empty() {
        let n = lrf_all.len().min(24);
        let scale = div_scale(&lrf_all);
        let denoised = model
            .diagnostics
            .as_ref()
            .and_then(|d| d.lrf_denoise.as_ref())
            .map_or_else(
                || " Not denoised.".to_string(),
                |r| format!(" {}.", r.summary()),
            );
        let _ = writeln!(
            html,
            "<h2>Local reflectance function, first {n} of {} samples</h2>\n<p class=\"meta\">Mean of R, G and B, symmetric about 0 at the 99th percentile of |LRF| over all samples (values beyond it saturate).{denoised}</p>\n<div class=\"row small\">",
            lrf_all.len()
        );
        for (k, m) in lrf_all.iter().take(n).enumerate() {
            let s = model.lrf.samples[k];
            html.push_str(&tile(
                &texture_png(m, &scale, 104),
                &format!("LRF sample {k}"),
                &format!(
                    "{k}: light {}<br>view {}",
                    dir_label(s.light),
                    dir_label(s.view)
                ),
            ));
        }
        html.push_str("</div>\n");
        html.push_str(&colour_bar(
            "cbar-lrf",
            &scale,
            &format!("LRF, mean of R G B (1/sr){}", invalid_note(&lrf_all[..n])),
        ));
        files.push(("lrf.png", mosaic_png(&lrf_all[..n], &scale)));
    }
    files
}

/// Writes `index.html` (self-contained) and, beside it, `profile.svg`,
/// `entrance.svg`, `fig6.png` (lamp image, f_v and LRF rows), `fv.png` and
/// `lrf.png` into `out`.
pub fn write_report(
    model: &MaterialModel,
    model_dir: &Path,
    out: &Path,
) -> Result<ReportFiles, ModelError> {
    write_report_with(model, model_dir, out, &ReportOptions::default())
}

/// [`write_report`] with stage times and a choice of Fig. 6 samples.
pub fn write_report_with(
    model: &MaterialModel,
    model_dir: &Path,
    out: &Path,
    opts: &ReportOptions,
) -> Result<ReportFiles, ModelError> {
    std::fs::create_dir_all(out).map_err(|e| ModelError::io(out, e))?;
    let mut files = Vec::new();
    let diag = model.diagnostics.as_ref();
    let mut html = String::new();
    let _ = write!(
        html,
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>qhm model report</title>\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><style>{STYLE}</style>{CHECK_SCRIPT}</head><body>\n\
         <h1>Material model report</h1>\n<p class=\"meta\">{} &middot; {}×{} texels of {} mm &middot; {} f_v views &middot; {} LRF samples{}</p>\n",
        esc(&model_dir.display().to_string()),
        model.width,
        model.height,
        model.texel_mm,
        model.exiting.views.len(),
        model.lrf.samples.len(),
        diag.and_then(|d| d.capture_dir.as_ref())
            .map_or(String::new(), |c| format!(
                " &middot; fitted from {}",
                esc(c)
            ))
    );
    dipole_section(model, &mut html);

    html.push_str("<h2>Laser-stripe profile fit (paper Fig. 5)</h2>\n");
    let panels: Vec<String> = diag
        .map(|d| {
            d.channels
                .iter()
                .filter_map(|ch| channel_profile_svg(model, ch))
                .collect()
        })
        .unwrap_or_default();
    if panels.is_empty() {
        html.push_str(
            "<p class=\"note\">No measured profiles in the model (fit.json is absent).</p>\n",
        );
    } else {
        html.push_str("<p class=\"meta\">Exitance I(d) at distance d from a vertical laser stripe, per unit incident flux per mm of stripe, over all views (dots; faint outside the fit range), and the fitted model's T(0) I_D(d) (line); s'_t is fitted over the shaded range.</p>\n<div class=\"plots\">\n");
        for p in &panels {
            html.push_str(p);
        }
        html.push_str("</div>\n");
    }
    if let Some(svg) = profile_svg(model) {
        let f = out.join("profile.svg");
        write(&f, svg.as_bytes())?;
        files.push(f);
    }

    let entrance = entrance_svg(model);
    html.push_str("<h2>Entrance function f(w_i)</h2>\n<p class=\"meta\">Light entering at incidence theta_i relative to vertical incidence. A flat, smooth surface follows the Fresnel ratio; mesostructure (roughness, fibres, pores) moves f away from it.</p>\n<div class=\"plots\">");
    html.push_str(&entrance);
    html.push_str("</div>\n");
    let f = out.join("entrance.svg");
    write(&f, entrance.as_bytes())?;
    files.push(f);

    for (name, png) in image_sections(model, opts, &mut html) {
        let f = out.join(name);
        write(&f, &png)?;
        files.push(f);
    }
    calibration_section(diag, &mut html);
    times_section(diag, opts, &mut html);
    html.push_str(
        "<p id=\"qhm-check\">Page check pending (needs JavaScript).</p>\n</body></html>\n",
    );
    let f = out.join("index.html");
    write(&f, html.as_bytes())?;
    Ok(ReportFiles { html: f, files })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::{FitOptions, fit_capture};
    use crate::synthetic_dataset::{SynthSpec, write_synthetic};

    #[test]
    fn report_of_a_fitted_model() {
        let truth = crate::DipoleParams {
            alpha_prime: [0.99, 0.97, 0.9],
            sigma_t_prime: [1.0, 1.5, 2.0],
            eta: 1.3,
            model: crate::subsurface::ProfileModel::Dipole,
        };
        let cap = tempfile::tempdir().unwrap();
        let mut spec = SynthSpec::small(truth);
        spec.width = 24;
        spec.height = 24;
        spec.scan_offsets_mm = vec![-3.0, -1.1, 0.7, 2.3];
        write_synthetic(cap.path(), &spec).unwrap();
        // The dipole fits in a fraction of the transport solver's time.
        let fit = FitOptions {
            eta: 1.3,
            model: crate::subsurface::ProfileModel::Dipole,
            ..FitOptions::default()
        };
        let (model, _) = fit_capture(cap.path(), &fit).unwrap();
        let out = tempfile::tempdir().unwrap();
        let opts = ReportOptions {
            stages: vec![("capture".into(), 12.5)],
            ..Default::default()
        };
        let rep = write_report_with(&model, cap.path(), out.path(), &opts).unwrap();
        let html = std::fs::read_to_string(&rep.html).unwrap();
        assert!(html.contains("<title>qhm model report</title>"));
        // Three profile panels, inline; every image inline.
        assert_eq!(
            html.matches("clip-profile-").count(),
            6,
            "two uses per panel"
        );
        assert!(!html.contains("src=\"fv.png\"") && html.contains("data:image/png;base64,"));
        assert!(!html.contains("NaN"));
        // The lamp images come from the capture, the calibration from its index.
        assert!(html.contains("rectified lamp images of"), "lamp source");
        assert!(html.contains("synthetic (qhm_model::synthetic_dataset)"));
        assert!(html.contains("dipole term (R") && html.contains("&nbsp;capture<"));
        // f_v tiles are labelled with their view.
        assert!(
            html.contains("<br>θ 50°, φ 180°</figcaption>"),
            "view labels"
        );
        assert_eq!(html.matches("class=\"cbar\"").count(), 5);
        for f in [
            "profile.svg",
            "entrance.svg",
            "fig6.png",
            "fv.png",
            "lrf.png",
        ] {
            assert!(out.path().join(f).exists(), "{f}");
        }
        let png = image::open(out.path().join("lrf.png")).unwrap();
        assert!(png.width() > 100);
        // A chosen light and view picks the nearest sample.
        let s5 = model.lrf.samples[5];
        assert_eq!(nearest_sample(&model, s5.light, s5.view), Some(5));
        // Without the capture the lamp images are rebuilt from the model.
        let mut m2 = model.clone();
        m2.diagnostics.as_mut().unwrap().capture_dir = None;
        let (rebuilt, src) = lamp_images(&m2, &[0]);
        let (read, _) = lamp_images(&model, &[0]);
        assert!(src.starts_with("rebuilt"));
        let mean =
            |t: &Texture| t.data.iter().map(|p| p[1] as f64).sum::<f64>() / t.data.len() as f64;
        let (a, b) = (mean(&rebuilt[0]), mean(&read[0]));
        assert!((a - b).abs() < 0.05 * b.abs(), "rebuilt {a} vs read {b}");
        // A homogeneous model without diagnostics still reports.
        let m = MaterialModel::homogeneous(truth);
        let out2 = tempfile::tempdir().unwrap();
        let rep = write_report(&m, Path::new("x"), out2.path()).unwrap();
        assert!(!out2.path().join("profile.svg").exists());
        assert!(rep.files.iter().any(|f| f.ends_with("entrance.svg")));
        let html = std::fs::read_to_string(&rep.html).unwrap();
        assert!(html.contains("no fit diagnostics"));
    }
}
