//! The fit report of a material model: hand-written SVG plots (the profile
//! fit as paper Fig. 5, the entrance function), PNG mosaics of f_v and LRF
//! slices (paper Fig. 6), and an HTML page tying them together.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::ModelError;
use crate::model::{MaterialModel, Texture};

const COLOURS: [&str; 3] = ["#d62728", "#2ca02c", "#1f77b4"];
const NAMES: [&str; 3] = ["red 650 nm", "green 532 nm", "blue 473 nm"];

/// Files [`write_report`] produced.
#[derive(Clone, Debug)]
pub struct ReportFiles {
    pub html: PathBuf,
    pub files: Vec<PathBuf>,
}

fn write(path: &Path, text: &str) -> Result<(), ModelError> {
    std::fs::write(path, text).map_err(|e| ModelError::io(path, e))
}

/// A plot frame mapping data to an SVG viewport.
struct Frame {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    log_y: bool,
}

impl Frame {
    const W: f64 = 640.0;
    const H: f64 = 400.0;
    const L: f64 = 70.0;
    const R: f64 = 20.0;
    const T: f64 = 30.0;
    const B: f64 = 50.0;
    fn px(&self, x: f64) -> f64 {
        Self::L + (x - self.x0) / (self.x1 - self.x0) * (Self::W - Self::L - Self::R)
    }
    fn py(&self, y: f64) -> f64 {
        let (a, b, v) = if self.log_y {
            (self.y0.log10(), self.y1.log10(), y.max(self.y0).log10())
        } else {
            (self.y0, self.y1, y)
        };
        Self::H - Self::B - (v - a) / (b - a) * (Self::H - Self::T - Self::B)
    }
    fn open(&self, title: &str, xlabel: &str, ylabel: &str) -> String {
        let mut s = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"12\">\n\
             <rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n\
             <text x=\"{cx}\" y=\"18\" text-anchor=\"middle\" font-size=\"14\">{title}</text>\n\
             <text x=\"{cx}\" y=\"{xl}\" text-anchor=\"middle\">{xlabel}</text>\n\
             <text x=\"14\" y=\"{cy}\" text-anchor=\"middle\" transform=\"rotate(-90 14 {cy})\">{ylabel}</text>\n",
            w = Self::W,
            h = Self::H,
            cx = Self::W / 2.0,
            xl = Self::H - 12.0,
            cy = Self::H / 2.0
        );
        let _ = write!(
            s,
            "<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"black\"/>\n",
            Self::L,
            Self::T,
            Self::W - Self::L - Self::R,
            Self::H - Self::T - Self::B
        );
        for k in 0..=5 {
            let x = self.x0 + (self.x1 - self.x0) * k as f64 / 5.0;
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{:.3}</text>",
                self.px(x),
                Self::H - Self::B + 16.0,
                x
            );
        }
        let ticks: Vec<f64> = if self.log_y {
            let (a, b) = (
                self.y0.log10().floor() as i32,
                self.y1.log10().ceil() as i32,
            );
            (a..=b)
                .map(|e| 10f64.powi(e))
                .filter(|v| *v >= self.y0 && *v <= self.y1)
                .collect()
        } else {
            (0..=5)
                .map(|k| self.y0 + (self.y1 - self.y0) * k as f64 / 5.0)
                .collect()
        };
        for y in ticks {
            let label = if self.log_y {
                format!("{y:.0e}")
            } else {
                format!("{y:.3}")
            };
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{label}</text>",
                Self::L - 4.0,
                self.py(y) + 4.0
            );
        }
        s
    }
}

/// The profile fit of every channel: measured I(d), fitted I_D(d), range band.
pub fn profile_svg(model: &MaterialModel) -> Option<String> {
    let diag = model.diagnostics.as_ref()?;
    if diag.channels.is_empty() {
        return None;
    }
    let x1 = diag
        .channels
        .iter()
        .map(|c| c.fit.range_mm[1] * 1.2)
        .fold(1.0, f64::max);
    let pos = diag
        .channels
        .iter()
        .flat_map(|c| c.profile.distance_mm.iter().zip(&c.profile.intensity))
        .filter(|(d, i)| **d <= x1 && **i > 0.0)
        .map(|(_, i)| *i);
    let y1 = pos.clone().fold(0.0, f64::max) * 2.0;
    let y0 = (pos.fold(f64::INFINITY, f64::min)).max(y1 * 1e-8);
    if !(y1 > 0.0 && y0 < y1) {
        return None;
    }
    let f = Frame {
        x0: 0.0,
        x1,
        y0,
        y1,
        log_y: true,
    };
    let mut s = f.open(
        "Laser-stripe profile: measured I(d) (dots), dipole I_D(d) (line), fit range (band)",
        "distance from the stripe d (mm)",
        "I(d) per flux per mm (1/mm)",
    );
    for ch in &diag.channels {
        let c = ch.channel.min(2);
        let [lo, hi] = ch.fit.range_mm;
        let _ = writeln!(
            s,
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"6\" fill=\"{}\" opacity=\"0.5\"/>",
            f.px(lo),
            Frame::H - Frame::B - 8.0 - 7.0 * c as f64,
            f.px(hi.min(x1)) - f.px(lo),
            COLOURS[c]
        );
        for (d, i) in ch.profile.distance_mm.iter().zip(&ch.profile.intensity) {
            if *d <= x1 && *i > 0.0 {
                let _ = writeln!(
                    s,
                    "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"1.6\" fill=\"{}\" opacity=\"0.6\"/>",
                    f.px(*d),
                    f.py(*i),
                    COLOURS[c]
                );
            }
        }
        // The fitted I_D(d) of the fit's own model; measured points are per
        // incident flux: T(0) I_D(d) (qhm_model::profile).
        let (a, st) = (ch.fit.alpha_prime, ch.fit.sigma_t_prime);
        let table = ch
            .fit
            .model
            .stripe_table(a, model.dipole.eta, st * x1 * 1.01);
        let t_in = crate::dipole::normal_transmittance(model.dipole.eta);
        let pts: Vec<String> = (0..=300)
            .map(|k| {
                let d = x1 * k as f64 / 300.0;
                format!("{:.1},{:.1}", f.px(d), f.py(t_in * table.eval(d, st)))
            })
            .collect();
        let _ = writeln!(
            s,
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1.5\"/>",
            pts.join(" "),
            COLOURS[c]
        );
    }
    s.push_str("</svg>\n");
    Some(s)
}

/// f(θ) per channel along a few azimuths, with the measured samples.
pub fn entrance_svg(model: &MaterialModel) -> String {
    let e = &model.entrance;
    let y1 = e
        .values
        .iter()
        .flat_map(|v| v.iter())
        .fold(1.0f32, |a, b| a.max(*b)) as f64
        * 1.1;
    let f = Frame {
        x0: 0.0,
        x1: 90.0,
        y0: 0.0,
        y1,
        log_y: false,
    };
    let mut s = f.open(
        "Mesostructure entrance function f(w_i) (lines: table at phi = 0, 90, 180, 270 deg; dots: measured)",
        "incidence angle theta_i (degrees)",
        "f(w_i)",
    );
    for c in 0..3 {
        for phi_deg in [0.0f32, 90.0, 180.0, 270.0] {
            let phi = phi_deg.to_radians();
            let pts: Vec<String> = (0..=90)
                .map(|t| {
                    let th = (t as f32).to_radians();
                    let v = e.eval([th.sin() * phi.cos(), th.sin() * phi.sin(), th.cos()])[c];
                    format!("{:.1},{:.1}", f.px(t as f64), f.py(v as f64))
                })
                .collect();
            let _ = writeln!(
                s,
                "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1\" opacity=\"0.7\"/>",
                pts.join(" "),
                COLOURS[c]
            );
        }
        if let Some(d) = &model.diagnostics {
            for (dir, v) in &d.entrance_samples {
                let th = dir[2].clamp(-1.0, 1.0).acos().to_degrees() as f64;
                let _ = writeln!(
                    s,
                    "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"3\" fill=\"{}\"/>",
                    f.px(th),
                    f.py(v[c] as f64),
                    COLOURS[c]
                );
            }
        }
    }
    s.push_str("</svg>\n");
    s
}

/// Tiles textures into one 8-bit image, `map` turning a value into 0..1 RGB.
fn mosaic(maps: &[&Texture], map: impl Fn([f32; 3]) -> [f32; 3]) -> image::RgbImage {
    let cols = (maps.len() as f64).sqrt().ceil().max(1.0) as u32;
    let rows = (maps.len() as u32).div_ceil(cols).max(1);
    let (w, h) = (maps[0].width as u32, maps[0].height as u32);
    // Small textures are scaled up so the tiles are visible.
    let scale = (128 / w.max(h)).max(1);
    let gap = 2;
    let mut img = image::RgbImage::from_pixel(
        cols * (w * scale + gap) + gap,
        rows * (h * scale + gap) + gap,
        image::Rgb([40, 40, 40]),
    );
    for (k, t) in maps.iter().enumerate() {
        let (ox, oy) = (
            (k as u32 % cols) * (w * scale + gap) + gap,
            (k as u32 / cols) * (h * scale + gap) + gap,
        );
        for y in 0..h * scale {
            for x in 0..w * scale {
                let v = map(t.get((x / scale) as usize, (y / scale) as usize));
                let p = v.map(|c| (c.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8);
                img.put_pixel(ox + x, oy + y, image::Rgb(p));
            }
        }
    }
    img
}

fn save_png(img: &image::RgbImage, path: &Path) -> Result<(), ModelError> {
    img.save(path)
        .map_err(|e| ModelError::io(path, std::io::Error::other(e.to_string())))
}

/// Writes `index.html`, `profile.svg`, `entrance.svg`, `fv.png` and `lrf.png` into `out`.
pub fn write_report(
    model: &MaterialModel,
    model_dir: &Path,
    out: &Path,
) -> Result<ReportFiles, ModelError> {
    std::fs::create_dir_all(out).map_err(|e| ModelError::io(out, e))?;
    let mut files = Vec::new();
    let mut html = String::new();
    let _ = write!(
        html,
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>qhm model report</title>\
         <style>body{{font-family:sans-serif;max-width:960px;margin:auto}} td,th{{padding:2px 10px;text-align:right}}</style>\
         </head><body>\n<h1>Material model {}</h1>\n",
        html_escape(&model_dir.display().to_string())
    );
    let p = &model.dipole;
    let (ss, sa) = (p.sigma_s_prime(), p.sigma_a());
    html.push_str("<h2>Global dipole term (eta = ");
    let _ = write!(
        html,
        "{})</h2>\n<table><tr><th>channel</th><th>R</th><th>a'</th><th>s'_t (1/mm)</th><th>s'_s (1/mm)</th><th>s_a (1/mm)</th><th>fit range (mm)</th><th>residual</th></tr>\n",
        p.eta
    );
    for c in 0..3 {
        let (r, range, res) = model
            .diagnostics
            .as_ref()
            .and_then(|d| d.channels.iter().find(|x| x.channel == c))
            .map(|x| {
                (
                    format!("{:.5}", x.reflectance),
                    format!("{:.2} - {:.2}", x.fit.range_mm[0], x.fit.range_mm[1]),
                    format!("{:.2e}", x.fit.residual),
                )
            })
            .unwrap_or_else(|| ("-".into(), "-".into(), "-".into()));
        let _ = writeln!(
            html,
            "<tr><td>{}</td><td>{r}</td><td>{:.5}</td><td>{:.4}</td><td>{:.4}</td><td>{:.5}</td><td>{range}</td><td>{res}</td></tr>",
            NAMES[c], p.alpha_prime[c], p.sigma_t_prime[c], ss[c], sa[c]
        );
    }
    html.push_str("</table>\n");
    if let Some(svg) = profile_svg(model) {
        let f = out.join("profile.svg");
        write(&f, &svg)?;
        files.push(f);
        html.push_str("<h2>Profile fit (paper Fig. 5)</h2><img src=\"profile.svg\">\n");
    }
    let f = out.join("entrance.svg");
    write(&f, &entrance_svg(model))?;
    files.push(f);
    html.push_str("<h2>Mesostructure entrance function</h2><img src=\"entrance.svg\">\n");

    let fv: Vec<&Texture> = model.exiting.maps.iter().collect();
    let f = out.join("fv.png");
    save_png(&mosaic(&fv, |v| v.map(|x| x / 2.0)), &f)?;
    files.push(f);
    let _ = write!(
        html,
        "<h2>Mesostructure exiting function f_v (paper Fig. 6, middle)</h2>\
         <p>{} views; 0 = black, 2 = white.</p><img src=\"fv.png\">\n",
        fv.len()
    );
    if !model.lrf.maps.is_empty() {
        let n = model.lrf.maps.len().min(16);
        let lrf: Vec<&Texture> = model.lrf.maps.iter().take(n).collect();
        let peak = lrf
            .iter()
            .flat_map(|t| t.data.iter().flat_map(|v| v.iter()))
            .fold(1e-12f32, |a, b| a.max(b.abs()));
        let f = out.join("lrf.png");
        save_png(&mosaic(&lrf, |v| v.map(|x| 0.5 + 0.5 * x / peak)), &f)?;
        files.push(f);
        let _ = write!(
            html,
            "<h2>Local reflectance function (paper Fig. 6, bottom)</h2>\
             <p>First {n} of {} (light, view) samples; mid-grey = 0, white = +{peak:.3e} /sr, black = -{peak:.3e} /sr (negative values are kept).</p>\
             <img src=\"lrf.png\">\n",
            model.lrf.maps.len()
        );
    }
    if let Some(d) = &model.diagnostics {
        if !d.notes.is_empty() {
            html.push_str("<h2>Notes</h2><ul>\n");
            for n in &d.notes {
                let _ = writeln!(html, "<li>{}</li>", html_escape(n));
            }
            html.push_str("</ul>\n");
        }
    }
    html.push_str("</body></html>\n");
    let f = out.join("index.html");
    write(&f, &html)?;
    Ok(ReportFiles { html: f, files })
}

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::{FitOptions, fit_capture};
    use crate::synth::{SynthSpec, write_synthetic};

    #[test]
    fn report_of_a_fitted_model() {
        let truth = crate::DipoleParams {
            alpha_prime: [0.99, 0.97, 0.9],
            sigma_t_prime: [1.0, 1.5, 2.0],
            eta: 1.3,
            model: crate::profile::ProfileModel::Dipole,
        };
        let cap = tempfile::tempdir().unwrap();
        let mut spec = SynthSpec::small(truth);
        spec.width = 24;
        spec.height = 24;
        spec.scan_offsets_mm = vec![-3.0, -1.1, 0.7, 2.3];
        write_synthetic(cap.path(), &spec).unwrap();
        let (model, _) = fit_capture(cap.path(), &FitOptions::default()).unwrap();
        let out = tempfile::tempdir().unwrap();
        let rep = write_report(&model, cap.path(), out.path()).unwrap();
        let html = std::fs::read_to_string(&rep.html).unwrap();
        assert!(
            html.contains("profile.svg") && html.contains("lrf.png") && html.contains("fv.png")
        );
        let svg = std::fs::read_to_string(out.path().join("profile.svg")).unwrap();
        assert!(svg.matches("<polyline").count() == 3 && svg.contains("<circle"));
        assert!(!svg.contains("NaN"));
        let png = image::open(out.path().join("lrf.png")).unwrap();
        assert!(png.width() > 100);
        // A homogeneous model without diagnostics still reports.
        let m = MaterialModel::homogeneous(truth);
        let out2 = tempfile::tempdir().unwrap();
        let rep = write_report(&m, Path::new("x"), out2.path()).unwrap();
        assert!(!out2.path().join("profile.svg").exists());
        assert!(rep.files.iter().any(|f| f.ends_with("entrance.svg")));
    }
}
