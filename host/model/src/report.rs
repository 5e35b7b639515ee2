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

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::ModelError;
use crate::fresnel::{fresnel_transmittance_ratio, normal_transmittance};
use crate::model::{FitDiagnostics, MaterialModel, Texture};
use crate::profile::SIGMA_T_PRIME_MAX;
use crate::rectified::Rectified;

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

// ---------------------------------------------------------------- plots

/// A plot frame mapping data to an SVG viewport.
struct Frame {
    w: f64,
    h: f64,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    log_y: bool,
    /// Spacing of the x ticks (0: round numbers chosen for the range).
    x_step: f64,
}

impl Frame {
    const L: f64 = 62.0;
    const R: f64 = 14.0;
    const T: f64 = 28.0;
    const B: f64 = 44.0;
    fn px(&self, x: f64) -> f64 {
        Self::L + (x - self.x0) / (self.x1 - self.x0) * (self.w - Self::L - Self::R)
    }
    fn py(&self, y: f64) -> f64 {
        let (a, b, v) = if self.log_y {
            (self.y0.log10(), self.y1.log10(), y.max(self.y0).log10())
        } else {
            (self.y0, self.y1, y)
        };
        self.h - Self::B - (v - a) / (b - a) * (self.h - Self::T - Self::B)
    }
    fn bottom(&self) -> f64 {
        self.h - Self::B
    }
    fn open(&self, title: &str, xlabel: &str, ylabel: &str) -> String {
        let (w, h) = (self.w, self.h);
        let mut s = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"11\">\n\
             <rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n\
             <text x=\"{cx}\" y=\"16\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{title}</text>\n\
             <text x=\"{cx}\" y=\"{xl}\" text-anchor=\"middle\">{xlabel}</text>\n\
             <text x=\"13\" y=\"{cy}\" text-anchor=\"middle\" transform=\"rotate(-90 13 {cy})\">{ylabel}</text>\n",
            cx = Self::L + (w - Self::L - Self::R) / 2.0,
            xl = h - 8.0,
            cy = Self::T + (h - Self::T - Self::B) / 2.0,
            title = esc(title),
            xlabel = esc(xlabel),
            ylabel = esc(ylabel),
        );
        let (l, t, pw, ph) = (
            Self::L,
            Self::T,
            w - Self::L - Self::R,
            h - Self::T - Self::B,
        );
        let xs = if self.x_step > 0.0 {
            let n = ((self.x1 - self.x0) / self.x_step + 1e-9).floor() as usize;
            (0..=n).map(|k| self.x0 + k as f64 * self.x_step).collect()
        } else {
            nice_ticks(self.x0, self.x1)
        };
        for x in xs {
            let _ = writeln!(
                s,
                "<line x1=\"{X:.1}\" x2=\"{X:.1}\" y1=\"{t}\" y2=\"{b}\" stroke=\"#e4e4e4\"/>\
                 <text x=\"{X:.1}\" y=\"{ty:.1}\" text-anchor=\"middle\">{}</text>",
                tick(x),
                X = self.px(x),
                b = self.bottom(),
                ty = self.bottom() + 14.0
            );
        }
        let ticks: Vec<f64> = if self.log_y {
            let (a, b) = (
                self.y0.log10().floor() as i32,
                self.y1.log10().ceil() as i32,
            );
            (a..=b)
                .map(|e| 10f64.powi(e))
                .filter(|v| *v >= self.y0 * 0.999 && *v <= self.y1 * 1.001)
                .collect()
        } else {
            nice_ticks(self.y0, self.y1)
        };
        for y in ticks {
            let label = if self.log_y {
                format!("1e{}", y.log10().round())
            } else {
                tick(y)
            };
            let _ = writeln!(
                s,
                "<line x1=\"{l}\" x2=\"{r}\" y1=\"{Y:.1}\" y2=\"{Y:.1}\" stroke=\"#e4e4e4\"/>\
                 <text x=\"{tx:.1}\" y=\"{ty:.1}\" text-anchor=\"end\">{label}</text>",
                r = l + pw,
                Y = self.py(y),
                tx = l - 4.0,
                ty = self.py(y) + 4.0
            );
        }
        let _ = writeln!(
            s,
            "<rect x=\"{l}\" y=\"{t}\" width=\"{pw}\" height=\"{ph}\" fill=\"none\" stroke=\"#333\"/>"
        );
        s
    }
    /// A clip path for the plot area, so curves stop at the axes.
    fn clip(&self, id: &str) -> String {
        format!(
            "<clipPath id=\"{id}\"><rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\"/></clipPath>\n",
            Self::L,
            Self::T,
            self.w - Self::L - Self::R,
            self.h - Self::T - Self::B
        )
    }
}

/// Ticks at 1, 2 or 5 times a power of ten, about five over [a, b].
fn nice_ticks(a: f64, b: f64) -> Vec<f64> {
    let span = b - a;
    if !(span > 0.0 && span.is_finite()) {
        return vec![a];
    }
    let raw = span / 5.0;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s >= raw * 0.7)
        .unwrap_or(10.0 * p);
    let first = (a / step).ceil() as i64;
    let last = (b / step + 1e-9).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// A tick label with as many digits as it needs, trailing zeros dropped.
fn tick(v: f64) -> String {
    let s = tick_digits(v);
    if s.contains('.') && !s.contains('e') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn tick_digits(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// The profile fit of one channel (paper Fig. 5): measured I(d) as dots,
/// the fitted T(0) I_D(d) as a line, the fitted range shaded.
fn channel_profile_svg(model: &MaterialModel, ch: &crate::profile::ChannelFit) -> Option<String> {
    let c = ch.channel.min(2);
    let x1 = (ch.fit.range_mm[1] * 1.25).max(1.0);
    let pos = ch
        .profile
        .distance_mm
        .iter()
        .zip(&ch.profile.intensity)
        .filter(|(d, i)| **d <= x1 && **i > 0.0 && i.is_finite())
        .map(|(_, i)| *i);
    let y1 = pos.clone().fold(0.0, f64::max) * 2.0;
    let y0 = (pos.fold(f64::INFINITY, f64::min) * 0.5).max(y1 * 1e-7);
    if !(y1 > 0.0 && y0 < y1) {
        return None;
    }
    let f = Frame {
        w: 400.0,
        h: 300.0,
        x0: 0.0,
        x1,
        y0,
        y1,
        log_y: true,
        x_step: 0.0,
    };
    let (a, st) = (ch.fit.alpha_prime, ch.fit.sigma_t_prime);
    let mut s = f.open(
        &format!("{} (a' {a:.4}, s'_t {st:.3}/mm)", NAMES[c]),
        "distance from the stripe d (mm)",
        "I(d) per incident flux (1/mm)",
    );
    let id = format!("clip-profile-{c}");
    let _ = write!(
        s,
        "<defs>{}</defs>\n<g clip-path=\"url(#{id})\">\n",
        f.clip(&id)
    );
    let [lo, hi] = ch.fit.range_mm;
    let _ = writeln!(
        s,
        "<rect x=\"{:.1}\" y=\"{}\" width=\"{:.1}\" height=\"{}\" fill=\"{}\" opacity=\"0.10\"/>",
        f.px(lo),
        Frame::T,
        f.px(hi.min(x1)) - f.px(lo),
        f.bottom() - Frame::T,
        COLOURS[c]
    );
    for x in [lo, hi.min(x1)] {
        let _ = writeln!(
            s,
            "<line x1=\"{X:.1}\" x2=\"{X:.1}\" y1=\"{}\" y2=\"{}\" stroke=\"{}\" stroke-dasharray=\"4 3\"/>",
            Frame::T,
            f.bottom(),
            COLOURS[c],
            X = f.px(x)
        );
    }
    for (d, i) in ch.profile.distance_mm.iter().zip(&ch.profile.intensity) {
        if *d <= x1 && *i > 0.0 && i.is_finite() {
            let inside = *d >= lo && *d <= hi;
            let _ = writeln!(
                s,
                "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"1.7\" fill=\"{}\" opacity=\"{}\"/>",
                f.px(*d),
                f.py(*i),
                COLOURS[c],
                if inside { "0.75" } else { "0.3" }
            );
        }
    }
    // The fit's own model; measured points are per incident flux: T(0) I_D(d).
    let table = ch
        .fit
        .model
        .stripe_table(a, model.dipole.eta, st * x1 * 1.01);
    let t_in = normal_transmittance(model.dipole.eta);
    let pts: Vec<String> = (0..=300)
        .map(|k| {
            let d = x1 * k as f64 / 300.0;
            format!("{:.1},{:.1}", f.px(d), f.py(t_in * table.eval(d, st)))
        })
        .collect();
    let _ = writeln!(
        s,
        "<polyline points=\"{}\" fill=\"none\" stroke=\"#111\" stroke-width=\"1.4\"/>\n</g>",
        pts.join(" ")
    );
    // Legend.
    let lx = f.w - Frame::R - 150.0;
    let _ = writeln!(
        s,
        "<g font-size=\"10\"><circle cx=\"{}\" cy=\"{}\" r=\"2.5\" fill=\"{c0}\"/><text x=\"{}\" y=\"{}\">measured I(d)</text>\
         <line x1=\"{}\" x2=\"{}\" y1=\"{}\" y2=\"{}\" stroke=\"#111\" stroke-width=\"1.4\"/><text x=\"{}\" y=\"{}\">fitted T(0) I_D(d)</text>\
         <rect x=\"{}\" y=\"{}\" width=\"10\" height=\"8\" fill=\"{c0}\" opacity=\"0.25\"/><text x=\"{}\" y=\"{}\">fit range {lo:.2}-{hi:.2} mm</text></g>",
        lx + 5.0,
        Frame::T + 12.0,
        lx + 14.0,
        Frame::T + 15.0,
        lx,
        lx + 10.0,
        Frame::T + 26.0,
        Frame::T + 26.0,
        lx + 14.0,
        Frame::T + 29.0,
        lx,
        Frame::T + 36.0,
        lx + 14.0,
        Frame::T + 43.0,
        c0 = COLOURS[c]
    );
    s.push_str("</svg>\n");
    Some(s)
}

/// The profile fits of every channel side by side; None without diagnostics.
pub fn profile_svg(model: &MaterialModel) -> Option<String> {
    let diag = model.diagnostics.as_ref()?;
    let panels: Vec<String> = diag
        .channels
        .iter()
        .filter_map(|ch| channel_profile_svg(model, ch))
        .collect();
    if panels.is_empty() {
        return None;
    }
    // One SVG of the panels in a row, for the file beside the page.
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"300\">\n",
        400 * panels.len()
    );
    for (k, p) in panels.iter().enumerate() {
        let _ = writeln!(s, "<g transform=\"translate({} 0)\">{p}</g>", 400 * k);
    }
    s.push_str("</svg>\n");
    Some(s)
}

/// f(θ_i) per channel: measured samples (dots), the fitted table at φ = 0,
/// 90, 180, 270 degrees (thin lines), and the smooth dielectric's Fresnel
/// ratio T(θ_i)/T(0) at the model's eta (dashed): a flat, smooth surface's f.
pub fn entrance_svg(model: &MaterialModel) -> String {
    let e = &model.entrance;
    let samples: &[([f32; 3], [f32; 3])] = model
        .diagnostics
        .as_ref()
        .map_or(&[], |d| &d.entrance_samples);
    let y1 = e
        .values
        .iter()
        .flat_map(|v| v.iter())
        .chain(samples.iter().flat_map(|s| s.1.iter()))
        .filter(|v| v.is_finite())
        .fold(1.0f32, |a, b| a.max(*b)) as f64
        * 1.1;
    let f = Frame {
        w: 640.0,
        h: 380.0,
        x0: 0.0,
        x1: 90.0,
        y0: 0.0,
        y1,
        log_y: false,
        x_step: 15.0,
    };
    let mut s = f.open(
        &format!(
            "Entrance function f(w_i) against the Fresnel ratio (eta {})",
            model.dipole.eta
        ),
        "incidence angle theta_i (degrees)",
        "f(w_i)",
    );
    let _ = write!(
        s,
        "<defs>{}</defs>\n<g clip-path=\"url(#clip-entrance)\">\n",
        f.clip("clip-entrance")
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
                "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"0.8\" opacity=\"0.45\"/>",
                pts.join(" "),
                COLOURS[c]
            );
        }
    }
    let pts: Vec<String> = (0..=180)
        .map(|k| {
            let t = k as f64 * 0.5;
            let r = fresnel_transmittance_ratio(t.to_radians().cos(), model.dipole.eta);
            format!("{:.1},{:.1}", f.px(t), f.py(r))
        })
        .collect();
    let _ = writeln!(
        s,
        "<polyline points=\"{}\" fill=\"none\" stroke=\"#111\" stroke-width=\"1.6\" stroke-dasharray=\"6 4\"/>",
        pts.join(" ")
    );
    for (dir, v) in samples {
        let th = dir[2].clamp(-1.0, 1.0).acos().to_degrees() as f64;
        for c in 0..3 {
            if v[c].is_finite() {
                let _ = writeln!(
                    s,
                    "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"3.2\" fill=\"{}\" stroke=\"white\" stroke-width=\"0.6\"/>",
                    f.px(th + (c as f64 - 1.0) * 0.6),
                    f.py(v[c] as f64),
                    COLOURS[c]
                );
            }
        }
    }
    s.push_str("</g>\n");
    let (lx, ly) = (Frame::L + 12.0, f.bottom() - 60.0);
    let _ = write!(
        s,
        "<g font-size=\"10\"><rect x=\"{}\" y=\"{}\" width=\"215\" height=\"54\" fill=\"white\" opacity=\"0.85\" stroke=\"#ccc\"/>",
        lx - 6.0,
        ly - 12.0
    );
    for c in 0..3 {
        let _ = write!(
            s,
            "<circle cx=\"{}\" cy=\"{}\" r=\"3\" fill=\"{}\"/><text x=\"{}\" y=\"{}\">measured, {}</text>",
            lx,
            ly + c as f64 * 12.0 - 3.0,
            COLOURS[c],
            lx + 8.0,
            ly + c as f64 * 12.0,
            NAMES[c]
        );
    }
    let _ = writeln!(
        s,
        "<line x1=\"{}\" x2=\"{}\" y1=\"{y:.1}\" y2=\"{y:.1}\" stroke=\"#111\" stroke-dasharray=\"6 4\" stroke-width=\"1.6\"/><text x=\"{}\" y=\"{}\">Fresnel T(theta)/T(0); thin: fitted table</text></g>",
        lx - 4.0,
        lx + 10.0,
        lx + 14.0,
        ly + 39.0,
        y = ly + 36.0
    );
    s.push_str("</svg>\n");
    s
}

// ---------------------------------------------------------------- images

/// A colour map: value in 0..1 to sRGB.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Map {
    /// Perceptually uniform, dark to light (viridis).
    Viridis,
    /// Diverging about the middle, blue - grey - red (coolwarm).
    CoolWarm,
    /// Grey with display gamma 2.2 (for RGB images).
    Grey,
}

impl Map {
    fn stops(self) -> &'static [[u8; 3]] {
        match self {
            Map::Viridis => &[
                [68, 1, 84],
                [71, 44, 122],
                [59, 81, 139],
                [44, 113, 142],
                [33, 144, 141],
                [39, 173, 129],
                [92, 200, 99],
                [170, 220, 50],
                [253, 231, 37],
            ],
            Map::CoolWarm => &[
                [59, 76, 192],
                [124, 159, 249],
                [192, 212, 245],
                [221, 221, 221],
                [242, 203, 183],
                [238, 132, 104],
                [180, 4, 38],
            ],
            Map::Grey => &[[0, 0, 0], [255, 255, 255]],
        }
    }
    fn at(self, t: f64) -> [u8; 3] {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        if self == Map::Grey {
            let v = (t.powf(1.0 / 2.2) * 255.0).round() as u8;
            return [v; 3];
        }
        let s = self.stops();
        let x = t * (s.len() - 1) as f64;
        let k = (x.floor() as usize).min(s.len() - 2);
        let f = x - k as f64;
        std::array::from_fn(|c| (s[k][c] as f64 * (1.0 - f) + s[k + 1][c] as f64 * f).round() as u8)
    }
}

/// The colour of a texel with a channel that is not a number (not measured).
const INVALID: [u8; 3] = [255, 0, 255];

/// A caption's note when some texels of `maps` are not valid.
fn invalid_note(maps: &[&Texture]) -> String {
    let n: usize = maps
        .iter()
        .map(|t| {
            t.data
                .iter()
                .filter(|p| p.iter().any(|x| !x.is_finite()))
                .count()
        })
        .sum();
    if n == 0 {
        String::new()
    } else {
        format!("; magenta: {n} texels not valid (NaN in a channel)")
    }
}

/// How one row of images turns values into colours.
#[derive(Clone, Copy, Debug)]
struct Scale {
    map: Map,
    lo: f64,
    hi: f64,
    /// RGB kept per channel (Grey map) instead of the mean of the channels.
    rgb: bool,
}

impl Scale {
    fn t(&self, v: f64) -> f64 {
        (v - self.lo) / (self.hi - self.lo)
    }
    fn pixel(&self, v: [f32; 3]) -> [u8; 3] {
        if v.iter().any(|x| !x.is_finite()) {
            return INVALID;
        }
        if self.rgb {
            return std::array::from_fn(|c| self.map.at(self.t(v[c] as f64))[0]);
        }
        let m = (v[0] as f64 + v[1] as f64 + v[2] as f64) / 3.0;
        self.map.at(self.t(m))
    }
}

/// The `p`-quantile (0..1) of the finite values, by selection; None if none.
fn quantile(values: &mut [f64], p: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let k = ((values.len() - 1) as f64 * p).round() as usize;
    let (_, v, _) = values.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    Some(*v)
}

/// At most ~1M values of `maps`, as `f` of each texel (strided for big models).
fn values(maps: &[&Texture], f: impl Fn([f32; 3]) -> Vec<f64>) -> Vec<f64> {
    let n: usize = maps.iter().map(|t| t.data.len()).sum();
    let stride = (n / 1_000_000).max(1);
    maps.iter()
        .flat_map(|t| t.data.iter().step_by(stride))
        .flat_map(|v| f(*v))
        .filter(|v| v.is_finite())
        .collect()
}

/// Sequential scale over the 1st..99th percentile of the channels' mean.
fn seq_scale(maps: &[&Texture]) -> Scale {
    let mut v = values(maps, |p| {
        vec![(p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0]
    });
    let lo = quantile(&mut v, 0.01).unwrap_or(0.0);
    let mut hi = quantile(&mut v, 0.99).unwrap_or(1.0);
    if !(hi > lo) {
        hi = lo + lo.abs().max(1e-6) * 0.1;
        return Scale {
            map: Map::Viridis,
            lo: lo - (hi - lo),
            hi,
            rgb: false,
        };
    }
    Scale {
        map: Map::Viridis,
        lo,
        hi,
        rgb: false,
    }
}

/// Diverging scale symmetric about 0 at the 99th percentile of |mean|.
fn div_scale(maps: &[&Texture]) -> Scale {
    let mut v = values(maps, |p| {
        vec![((p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0).abs()]
    });
    let peak = quantile(&mut v, 0.99).filter(|p| *p > 0.0).unwrap_or(1e-6);
    Scale {
        map: Map::CoolWarm,
        lo: -peak,
        hi: peak,
        rgb: false,
    }
}

/// RGB scale from 0 to the 99th percentile of all channels.
fn rgb_scale(maps: &[&Texture]) -> Scale {
    let mut v = values(maps, |p| p.iter().map(|x| *x as f64).collect());
    let hi = quantile(&mut v, 0.99).filter(|p| *p > 0.0).unwrap_or(1.0);
    Scale {
        map: Map::Grey,
        lo: 0.0,
        hi,
        rgb: true,
    }
}

/// A texture as a PNG, scaled up (nearest) to about `size` pixels.
fn texture_png(t: &Texture, scale: &Scale, size: usize) -> Vec<u8> {
    let k = (size / t.width.max(t.height).max(1)).max(1);
    let (w, h) = (t.width * k, t.height * k);
    let mut img = image::RgbImage::new(w as u32, h as u32);
    for y in 0..h {
        for x in 0..w {
            img.put_pixel(
                x as u32,
                y as u32,
                image::Rgb(scale.pixel(t.get(x / k, y / k))),
            );
        }
    }
    png_bytes(&img)
}

fn png_bytes(img: &image::RgbImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding into memory");
    out.into_inner()
}

/// Tiles textures into one PNG (for the files beside the page).
fn mosaic_png(maps: &[&Texture], scale: &Scale) -> Vec<u8> {
    let cols = (maps.len() as f64).sqrt().ceil().max(1.0) as usize;
    let rows = maps.len().div_ceil(cols).max(1);
    let (w, h) = (maps[0].width, maps[0].height);
    let k = (128 / w.max(h)).max(1);
    let gap = 2;
    let mut img = image::RgbImage::from_pixel(
        (cols * (w * k + gap) + gap) as u32,
        (rows * (h * k + gap) + gap) as u32,
        image::Rgb([255, 255, 255]),
    );
    for (n, t) in maps.iter().enumerate() {
        let (ox, oy) = (
            (n % cols) * (w * k + gap) + gap,
            (n / cols) * (h * k + gap) + gap,
        );
        for y in 0..h * k {
            for x in 0..w * k {
                img.put_pixel(
                    (ox + x) as u32,
                    (oy + y) as u32,
                    image::Rgb(scale.pixel(t.get(x / k, y / k))),
                );
            }
        }
    }
    png_bytes(&img)
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn data_uri(png: &[u8]) -> String {
    format!("data:image/png;base64,{}", base64(png))
}

/// A colour bar: the map's gradient with tick labels of the values.
fn colour_bar(id: &str, scale: &Scale, label: &str) -> String {
    let (w, bw, x0) = (380.0, 300.0, 28.0);
    let mut s = format!(
        "<svg class=\"cbar\" xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"46\" font-family=\"Helvetica, Arial, sans-serif\" font-size=\"10\">\
         <defs><linearGradient id=\"{id}\" x1=\"0\" x2=\"1\" y1=\"0\" y2=\"0\">"
    );
    for k in 0..=16 {
        let t = k as f64 / 16.0;
        let [r, g, b] = scale.map.at(t);
        let _ = write!(
            s,
            "<stop offset=\"{t:.4}\" stop-color=\"rgb({r},{g},{b})\"/>"
        );
    }
    let _ = write!(
        s,
        "</linearGradient></defs><rect x=\"{x0}\" y=\"4\" width=\"{bw}\" height=\"12\" fill=\"url(#{id})\" stroke=\"#555\" stroke-width=\"0.5\"/>"
    );
    for k in 0..=4 {
        let v = scale.lo + (scale.hi - scale.lo) * k as f64 / 4.0;
        let x = x0 + bw * k as f64 / 4.0;
        let _ = write!(
            s,
            "<line x1=\"{x}\" x2=\"{x}\" y1=\"16\" y2=\"20\" stroke=\"#333\"/><text x=\"{x}\" y=\"30\" text-anchor=\"middle\">{}</text>",
            tick(v)
        );
    }
    let _ = write!(s, "<text x=\"{x0}\" y=\"43\">{}</text></svg>", esc(label));
    s
}

/// θ and φ of a direction in degrees; φ is left out where θ is 0.
fn dir_label(v: [f32; 3]) -> String {
    let th = v[2].clamp(-1.0, 1.0).acos().to_degrees();
    let ph = (v[1].atan2(v[0]).to_degrees().round() as i32).rem_euclid(360);
    if th < 0.05 {
        "θ 0°".into()
    } else if th < 9.95 {
        format!("θ {th:.1}°, φ {ph}°")
    } else {
        format!("θ {th:.0}°, φ {ph}°")
    }
}

/// One labelled image tile.
fn tile(png: &[u8], alt: &str, caption: &str) -> String {
    format!(
        "<figure class=\"tile\"><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        data_uri(png),
        esc(alt),
        caption
    )
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
            if let Some([i0, j0, w, h]) = model.diagnostics.as_ref().and_then(|d| d.window) {
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
        let _ = writeln!(
            html,
            "<h2>Local reflectance function, first {n} of {} samples</h2>\n<p class=\"meta\">Mean of R, G and B, symmetric about 0 at the 99th percentile of |LRF| over all samples (values beyond it saturate).</p>\n<div class=\"row small\">",
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
/// `entrance.svg`, `fv.png` and `lrf.png` into `out`.
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
    fn ticks_are_round_numbers() {
        assert_eq!(nice_ticks(0.0, 10.9), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(nice_ticks(0.0, 90.0), vec![0.0, 20.0, 40.0, 60.0, 80.0]);
        let t = nice_ticks(0.0, 1.1);
        assert_eq!(t.len(), 6);
        assert!((t[5] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn base64_matches_the_rfc_examples() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }

    #[test]
    fn one_outlier_does_not_set_the_scale() {
        let mut t = Texture::filled(10, 10, [0.01; 3]);
        for (k, p) in t.data.iter_mut().enumerate() {
            *p = [if k % 2 == 0 { 0.01 } else { -0.01 }; 3];
        }
        t.data[0] = [1e3; 3];
        let s = div_scale(&[&t]);
        assert!((s.hi - 0.01).abs() < 1e-9, "{s:?}");
        // The outlier saturates, the rest spans the map.
        assert_eq!(s.pixel([1e3; 3]), Map::CoolWarm.at(1.0));
        assert_eq!(s.pixel([-0.01; 3]), Map::CoolWarm.at(0.0));
    }

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
        for f in ["profile.svg", "entrance.svg", "fv.png", "lrf.png"] {
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
