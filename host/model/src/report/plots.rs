//! The report's SVG plots: a plot frame with round-number ticks, the
//! laser-stripe profile fit per channel (paper Fig. 5) and f(w_i) against
//! the smooth surface's Fresnel ratio.

use std::fmt::Write as _;

use super::{COLOURS, NAMES, esc};
use crate::fresnel::{fresnel_transmittance_ratio, normal_transmittance};
use crate::model::MaterialModel;
use crate::profile::ChannelFit;

/// A plot frame mapping data to an SVG viewport.
pub(super) struct Frame {
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
pub(super) fn nice_ticks(a: f64, b: f64) -> Vec<f64> {
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
pub(super) fn tick(v: f64) -> String {
    let s = tick_digits(v);
    if s.contains('.') && !s.contains('e') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

pub(super) fn tick_digits(v: f64) -> String {
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
pub(super) fn channel_profile_svg(model: &MaterialModel, ch: &ChannelFit) -> Option<String> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_numbers() {
        assert_eq!(nice_ticks(0.0, 10.9), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(nice_ticks(0.0, 90.0), vec![0.0, 20.0, 40.0, 60.0, 80.0]);
        let t = nice_ticks(0.0, 1.1);
        assert_eq!(t.len(), 6);
        assert!((t[5] - 1.0).abs() < 1e-12);
    }
}
