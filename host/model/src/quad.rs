//! Adaptive Gauss-Kronrod (G7/K15) quadrature in f64: the tool behind the
//! virtual laser stripe I_D(d), which has no closed form in the paper.

/// K15 nodes on [-1, 1] (non-negative half; node 0 is the centre).
const XK: [f64; 8] = [
    0.991_455_371_120_812_6,
    0.949_107_912_342_758_5,
    0.864_864_423_359_769_1,
    0.741_531_185_599_394_4,
    0.586_087_235_467_691_1,
    0.405_845_151_377_397_2,
    0.207_784_955_007_898_5,
    0.0,
];
/// K15 weights matching `XK`.
const WK: [f64; 8] = [
    0.022_935_322_010_529_22,
    0.063_092_092_629_978_55,
    0.104_790_010_322_250_2,
    0.140_653_259_715_525_9,
    0.169_004_726_639_267_9,
    0.190_350_578_064_785_4,
    0.204_432_940_075_298_9,
    0.209_482_141_084_728_8,
];
/// G7 weights for the odd K15 nodes (XK[1], XK[3], XK[5], XK[7]).
const WG: [f64; 4] = [
    0.129_484_966_168_869_7,
    0.279_705_391_489_276_7,
    0.381_830_050_505_118_9,
    0.417_959_183_673_469_4,
];

/// One K15 panel: (Kronrod estimate, |Kronrod - Gauss| error estimate).
fn gk15(f: &impl Fn(f64) -> f64, a: f64, b: f64) -> (f64, f64) {
    let c = 0.5 * (a + b);
    let h = 0.5 * (b - a);
    let fc = f(c);
    let mut k = WK[7] * fc;
    let mut g = WG[3] * fc;
    for j in 0..7 {
        let dx = h * XK[j];
        let s = f(c - dx) + f(c + dx);
        k += WK[j] * s;
        if j % 2 == 1 {
            g += WG[j / 2] * s;
        }
    }
    (k * h, ((k - g) * h).abs())
}

/// Integral of `f` over [a, b] to relative tolerance `rel_tol` (absolute floor
/// `abs_tol`), bisecting the panel with the largest error first. Stops after
/// `max_panels` panels and returns the best estimate.
pub fn integrate(
    f: impl Fn(f64) -> f64,
    a: f64,
    b: f64,
    rel_tol: f64,
    abs_tol: f64,
    max_panels: usize,
) -> f64 {
    let (v, e) = gk15(&f, a, b);
    let mut panels = vec![(a, b, v, e)];
    let mut total = v;
    let mut err = e;
    while err > abs_tol.max(rel_tol * total.abs()) && panels.len() < max_panels {
        // Split the worst panel.
        let (worst, _) = panels
            .iter()
            .enumerate()
            .max_by(|x, y| x.1.3.total_cmp(&y.1.3))
            .expect("at least one panel");
        let (pa, pb, pv, pe) = panels.swap_remove(worst);
        let m = 0.5 * (pa + pb);
        let (v1, e1) = gk15(&f, pa, m);
        let (v2, e2) = gk15(&f, m, pb);
        total += v1 + v2 - pv;
        err += e1 + e2 - pe;
        panels.push((pa, m, v1, e1));
        panels.push((m, pb, v2, e2));
    }
    // Re-sum to avoid drift from the running updates.
    panels.iter().map(|p| p.2).sum()
}

/// 4-point Gauss-Legendre on [-1, 1].
pub const GL4: [(f64, f64); 4] = [
    (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
];

/// Gauss-Legendre 5-point nodes and weights on [-1, 1], for bin averages.
pub const GL5: [(f64, f64); 5] = [
    (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
    (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.0, 0.568_888_888_888_888_9),
    (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.906_179_845_938_664, 0.236_926_885_056_189_1),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polynomials_and_exponentials_are_exact() {
        let v = integrate(|x| x * x * x - 2.0 * x, 0.0, 2.0, 1e-13, 0.0, 100);
        assert!((v - 0.0).abs() < 1e-12, "{v}");
        let v = integrate(|x| (-x).exp(), 0.0, 40.0, 1e-12, 0.0, 200);
        assert!((v - (1.0 - (-40.0f64).exp())).abs() < 1e-11, "{v}");
    }

    #[test]
    fn peaked_integrand_needs_adaptivity() {
        // Lorentzian of width 1e-3: integral atan(1/w)*2*w/w = 2 atan(1000).
        let w = 1e-3;
        let v = integrate(|x| w / (x * x + w * w), -1.0, 1.0, 1e-10, 0.0, 500);
        let exact = 2.0 * (1.0f64 / w).atan();
        assert!((v - exact).abs() < 1e-8, "{v} vs {exact}");
    }
}
