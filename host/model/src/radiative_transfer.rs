//! Radiative transfer, solved without diffusion, for the case the fit
//! models: a homogeneous half-space of reduced albedo a' with isotropic
//! scattering under a smooth boundary of relative index eta, lit by a normal
//! line beam. Lengths are in mean free paths (s'_t = 1); everything scales
//! as the dipole does, I(d; s'_t) = s'_t g(s'_t d).
//!
//! Method: Fourier transform across the stripe (frequency k), which leaves
//! a one-dimensional integral equation in depth for the scattering source
//! C(z) = a' φ(z):
//!
//!   C(z) = a' e^{-z} + a' ∫ [K(k, |z - z'|) + K_F(k, z + z')] C(z') dz',
//!   K(k, t)   = ½ ∫_0^1 e^{-t/μ} J0(k t s/μ) dμ/μ,       s = sqrt(1 - μ²),
//!   K_F(k, t) = ½ ∫_0^1 F(μ) e^{-t/μ} J0(k t s/μ) dμ/μ    (internal Fresnel
//!                                                        reflection: an image),
//!   M̂(k) = ∫ C(z) T(k, z) dz,  T(k, z) = ½ ∫_0^1 (1 - F(μ)) e^{-z/μ} J0(k z s/μ) dμ.
//!
//! C is piecewise constant on depth cells, collocated at their midpoints,
//! with the kernels integrated exactly over each cell through tabulated
//! primitives; below NEAR_DEPTH it is the slowest exact transport mode.
//! Single scattering is taken out and integrated in real space (its
//! transform decays slowly); the rest is transformed back by a Filon rule.
//! At k = 0 the same system gives the exact total reflectance, and a Hankel
//! transform of the same data the radial profile R_d(r) the renderer uses.
//! Checked against Chandrasekhar's exact index-matched reflectance and
//! against sim-light's Monte Carlo (tests/tests/model_mc_profile.rs).
//! J0 and the transforms over it are in [`crate::special`].

use std::f64::consts::PI;
use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;

use crate::error::ModelError;
use crate::fresnel::fresnel_dielectric;
use crate::quad::{self, GL4};
use crate::special::{bessel_j0, filon_cos, hankel_j0};

/// Direction cosines μ in (0, 1) with weights and the internal Fresnel
/// reflectance F(μ): composite Gauss-Legendre, panels refined towards
/// grazing (where e^{-t/μ} is steep) and split at the critical angle.
struct Angles {
    mu: Vec<f64>,
    weight: Vec<f64>,
    fresnel: Vec<f64>,
}

impl Angles {
    fn new(eta: f64) -> Self {
        let mut cuts = vec![
            0.0, 1e-5, 1e-4, 1e-3, 3e-3, 0.01, 0.03, 0.06, 0.1, 0.15, 0.2,
        ];
        cuts.extend((3..=10).map(|k| k as f64 / 10.0));
        let mu_c = (1.0 - 1.0 / (eta * eta)).max(0.0).sqrt();
        cuts.push(mu_c);
        cuts.sort_by(f64::total_cmp);
        cuts.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        let (mut mu, mut weight, mut fresnel) = (vec![], vec![], vec![]);
        for w in cuts.windows(2) {
            // Two 4-point panels per interval.
            let h = 0.25 * (w[1] - w[0]);
            for c in [w[0] + h, w[1] - h] {
                for &(x, wt) in &GL4 {
                    let m = c + h * x;
                    mu.push(m);
                    weight.push(h * wt);
                    fresnel.push(fresnel_dielectric(m, 1.0 / eta));
                }
            }
        }
        Angles {
            mu,
            weight,
            fresnel,
        }
    }
}

/// Distances (in mfp) at which the kernel primitives are tabulated: 0, then
/// geometric from 1e-6 to 4000 with ratio 1.02.
fn primitive_grid() -> Vec<f64> {
    let mut d = vec![0.0];
    let mut x = 1e-6;
    while x < 4000.0 {
        d.push(x);
        x *= 1.02;
    }
    d.push(x);
    d
}

/// Primitives of the three kernels at one k, on `primitive_grid()`:
/// P(t) = ∫_0^t K, P_F(t) = ∫_0^t K_F, P_T(t) = ∫_0^t T.
struct Primitives {
    /// `primitive_grid()`, one copy shared by every k.
    grid: Arc<[f64]>,
    p: Vec<f64>,
    p_f: Vec<f64>,
    p_t: Vec<f64>,
}

/// Beyond this u, e^{-u} < 2.4e-16: G has reached its limit
/// 1 / sqrt(1 + c²) to double precision, so the quadrature stops there.
const DAMPED_REACH: f64 = 36.0;

/// G(c, X) = ∫_0^X e^{-u} J0(c u) du at the sorted `xs`, cumulatively.
fn damped_j0_primitive(c: f64, xs: impl Iterator<Item = f64>, out: &mut Vec<f64>) {
    let saturated = 1.0 / (1.0 + c * c).sqrt();
    let (mut x_prev, mut acc) = (0.0f64, 0.0f64);
    for x in xs {
        if x_prev >= DAMPED_REACH {
            out.push(saturated);
            continue;
        }
        let x_to = x.min(DAMPED_REACH);
        let len = x_to - x_prev;
        if len > 0.0 {
            let n = ((len * (1.0 + c)).ceil() as usize).clamp(1, 100_000);
            let h = len / n as f64;
            for j in 0..n {
                let mid = x_prev + (j as f64 + 0.5) * h;
                for &(t, w) in &GL4 {
                    let u = mid + 0.5 * h * t;
                    acc += 0.5 * h * w * (-u).exp() * bessel_j0(c * u);
                }
            }
        }
        x_prev = x_to;
        out.push(if x >= DAMPED_REACH { saturated } else { acc });
    }
}

impl Primitives {
    fn new(k: f64, angles: &Angles, grid: &Arc<[f64]>) -> Self {
        let n = grid.len();
        let (mut p, mut p_f, mut p_t) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut g = Vec::with_capacity(n);
        for q in 0..angles.mu.len() {
            let (mu, w, f) = (angles.mu[q], angles.weight[q], angles.fresnel[q]);
            let c = k * (1.0 - mu * mu).sqrt();
            g.clear();
            damped_j0_primitive(c, grid.iter().map(|&t| t / mu), &mut g);
            for m in 0..n {
                p[m] += 0.5 * w * g[m];
                p_f[m] += 0.5 * w * f * g[m];
                p_t[m] += 0.5 * w * (1.0 - f) * mu * g[m];
            }
        }
        Primitives {
            grid: grid.clone(),
            p,
            p_f,
            p_t,
        }
    }

    /// Linear interpolation of a table at t >= 0.
    fn at(&self, table: &[f64], t: f64) -> f64 {
        Lerp::locate(&self.grid, t).of(table)
    }
}

/// Where a distance t falls on [`primitive_grid`]: a table's value there is
/// `w0 table[i] + w1 table[i + 1]` (0 at t <= 0, the last entry beyond).
#[derive(Clone, Copy)]
struct Lerp {
    i: usize,
    w0: f64,
    w1: f64,
}

impl Lerp {
    fn locate(g: &[f64], t: f64) -> Lerp {
        let last = g.len() - 2;
        if t <= 0.0 {
            return Lerp {
                i: 0,
                w0: 0.0,
                w1: 0.0,
            };
        }
        if t >= g[g.len() - 1] {
            return Lerp {
                i: last,
                w0: 0.0,
                w1: 1.0,
            };
        }
        // Geometric grid: index from the logarithm, then fix up.
        let mut i = if t < 1e-6 {
            0
        } else {
            (((t / 1e-6).ln() / 1.02f64.ln()) as usize + 1).min(last)
        };
        while i > 0 && g[i] > t {
            i -= 1;
        }
        while i + 2 < g.len() && g[i + 1] < t {
            i += 1;
        }
        let f = (t - g[i]) / (g[i + 1] - g[i]);
        Lerp {
            i,
            w0: 1.0 - f,
            w1: f,
        }
    }

    #[inline]
    fn of(self, table: &[f64]) -> f64 {
        table[self.i] * self.w0 + table[self.i + 1] * self.w1
    }
}

/// Where [`solve_source_for`]'s matrix reads the kernel primitives. The
/// distances are the same at every frequency and albedo (the depth cells
/// and the grid are fixed), so they are located on the grid once per
/// process instead of once per matrix entry.
struct Stencil {
    /// [`depth_cells`] and their midpoints.
    edges: Vec<f64>,
    mid: Vec<f64>,
    /// Per cell pair (i, j), row-major: the direct kernel's integral over
    /// cell j seen from the midpoint of cell i is P(a) + sign P(b), the
    /// image's P_F(c) - P_F(d).
    pairs: Vec<([Lerp; 4], f64)>,
    /// Per cell i: P at t0 = NEAR_DEPTH - z_i, and at t0 + s for the tail's
    /// nodes s.
    tail_start: Vec<Lerp>,
    tail: Vec<Lerp>,
    tail_nodes: Vec<(f64, f64)>,
}

fn stencil() -> &'static Stencil {
    static STENCIL: OnceLock<Stencil> = OnceLock::new();
    STENCIL.get_or_init(|| {
        let grid = primitive_grid();
        let at = |t: f64| Lerp::locate(&grid, t);
        let edges = depth_cells();
        let mid: Vec<f64> = edges.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
        let tail_nodes = tail_nodes();
        let mut pairs = Vec::with_capacity(mid.len() * mid.len());
        let (mut tail_start, mut tail) = (Vec::new(), Vec::new());
        for &zi in &mid {
            for w in edges.windows(2) {
                let (lo, hi) = (w[0], w[1]);
                let ((a, b), sign) = if zi < lo {
                    ((hi - zi, lo - zi), -1.0)
                } else if zi > hi {
                    ((zi - lo, zi - hi), -1.0)
                } else {
                    ((zi - lo, hi - zi), 1.0)
                };
                pairs.push(([at(a), at(b), at(zi + hi), at(zi + lo)], sign));
            }
            let t0 = NEAR_DEPTH - zi;
            tail_start.push(at(t0));
            tail.extend(tail_nodes.iter().map(|&(s, _)| at(t0 + s)));
        }
        Stencil {
            edges,
            mid,
            pairs,
            tail_start,
            tail,
            tail_nodes,
        }
    })
}

/// Depth below which the source is the asymptotic transport mode: the
/// boundary's transients decay as e^{-z} and are below 1e-8 there.
const NEAR_DEPTH: f64 = 20.0;

/// Cell edges of the near region [0, NEAR_DEPTH]: 1e-3 mfp at the surface,
/// growing by 10 % per cell to 0.1 mfp (the cell width sets the error of
/// the effective diffusion coefficient, h²/4 relative: 0.25 %).
fn depth_cells() -> Vec<f64> {
    let mut edges = vec![0.0];
    let mut h = 1e-3;
    while *edges.last().unwrap() < NEAR_DEPTH {
        let z = edges.last().unwrap() + h;
        edges.push(z.min(NEAR_DEPTH));
        h = (h * 1.1).min(0.1);
    }
    edges
}

/// Decay rate p0 of the infinite medium's slowest mode at k = 0:
/// a' artanh(p0)/p0 = 1 (exact transport; diffusion's sqrt(3(1-a')) to first order).
pub fn asymptotic_decay(alpha: f64) -> f64 {
    if alpha >= 1.0 {
        return 0.0;
    }
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..200 {
        let p = 0.5 * (lo + hi);
        let v = if p < 1e-4 {
            1.0 + p * p / 3.0
        } else {
            p.atanh() / p
        };
        if alpha * v < 1.0 {
            lo = p;
        } else {
            hi = p;
        }
    }
    0.5 * (lo + hi)
}

/// Gauss-Legendre panels for ∫_0^60 ds, finer near 0.
fn tail_nodes() -> Vec<(f64, f64)> {
    let cuts = [
        0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 2.0, 4.0, 8.0, 15.0, 25.0, 40.0, 60.0,
    ];
    let mut nodes = vec![];
    for w in cuts.windows(2) {
        let (c, h) = (0.5 * (w[0] + w[1]), 0.5 * (w[1] - w[0]));
        nodes.extend(GL4.iter().map(|&(x, wt)| (c + h * x, h * wt)));
    }
    nodes
}

/// The source C(z) at frequency k: its value in each cell of
/// [`depth_cells`], then the amplitude B of the deep field below
/// NEAR_DEPTH, B e^{-κ (z - NEAR_DEPTH)}, κ = sqrt(p0² + k²) with p0 =
/// [`asymptotic_decay`] of `alpha`, B continuous with the last cell.
fn solve_source(alpha: f64, p0: f64, k: f64, prim: &Primitives) -> Vec<f64> {
    let source = stencil()
        .edges
        .windows(2)
        .map(|w| first_collisions(alpha, w[0], w[1]))
        .collect();
    solve_source_for(alpha, p0, k, prim, source)
}

/// [`solve_source`] for any first-collision source (one value per cell).
fn solve_source_for(
    alpha: f64,
    p0: f64,
    k: f64,
    prim: &Primitives,
    mut source: Vec<f64>,
) -> Vec<f64> {
    let st = stencil();
    let n = st.mid.len();
    let m = n + 1; // cells + the tail's amplitude
    let kappa = (p0 * p0 + k * k).sqrt();
    let p_inf = prim.p[prim.p.len() - 1];
    let nodes = st.tail_nodes.len();
    let decay: Vec<f64> = st
        .tail_nodes
        .iter()
        .map(|&(s, _)| (-kappa * s).exp())
        .collect();
    let beyond = p_inf * (-kappa * 60.0).exp();
    let mut a = vec![0.0; m * m];
    for i in 0..n {
        let row = &mut a[i * m..(i + 1) * m];
        for (entry, ([da, db, ic, id], sign)) in row.iter_mut().zip(&st.pairs[i * n..(i + 1) * n]) {
            let direct = da.of(&prim.p) + sign * db.of(&prim.p);
            let image = ic.of(&prim.p_f) - id.of(&prim.p_f);
            *entry = -alpha * (direct + image);
        }
        // ∫_0^∞ K(t0 + s) e^{-κ s} ds by parts: -P(t0) + κ ∫ P(t0 + s) e^{-κ s} ds
        // (P = P(∞) beyond s = 60). The image of the tail is below e^{-60}.
        let body: f64 = st
            .tail_nodes
            .iter()
            .zip(&st.tail[i * nodes..(i + 1) * nodes])
            .zip(&decay)
            .map(|((&(_, w), l), e)| w * l.of(&prim.p) * e)
            .sum();
        row[n] = -alpha * (-st.tail_start[i].of(&prim.p) + kappa * body + beyond);
        row[i] += 1.0;
    }
    // B = C(z) continued from the last cell's midpoint.
    a[n * m + n] = 1.0;
    a[n * m + n - 1] = -(-kappa * (NEAR_DEPTH - st.mid[n - 1])).exp();
    source.push(0.0);
    solve_dense(&mut a, source, m)
}

/// Total diffuse reflectance of the half-space per entered flux for a
/// collimated beam that travels at direction cosine `mu0` inside (after
/// refraction), at each of `mu0s`, for reduced albedo `alpha` under a
/// smooth boundary of index `eta`. The first collisions are a' e^{-z/μ0}/μ0
/// instead of a' e^{-z}: an oblique beam scatters first nearer the surface,
/// so more of it comes back out than at normal incidence (at a' 0.7, eta
/// 1.3, about a third more at grazing incidence). Only the k = 0 kernel is
/// built (about 10 ms for the lot), not the full [`HalfSpace`].
pub fn oblique_reflectance(eta: f64, alpha: f64, mu0s: &[f64]) -> Vec<f64> {
    let angles = Angles::new(eta);
    let grid: Arc<[f64]> = primitive_grid().into();
    let prim = Primitives::new(0.0, &angles, &grid);
    let edges = depth_cells();
    let p0 = asymptotic_decay(alpha);
    mu0s.par_iter()
        .map(|&mu0| {
            let mu0 = mu0.clamp(1e-3, 1.0);
            // Cell means of the first-collision density (exact on each cell).
            let first: Vec<f64> = edges
                .windows(2)
                .map(|w| alpha * ((-w[0] / mu0).exp() - (-w[1] / mu0).exp()) / (w[1] - w[0]))
                .collect();
            let c = solve_source_for(alpha, p0, 0.0, &prim, first.clone());
            let multiple: f64 = edges
                .windows(2)
                .zip(c.iter().zip(&first))
                .map(|(w, (cj, fj))| {
                    (cj - fj) * (prim.at(&prim.p_t, w[1]) - prim.at(&prim.p_t, w[0]))
                })
                .sum();
            // Single scattering: a'/2 ∫ (1 - F(μ)) μ / (μ + μ0) dμ.
            let single: f64 = (0..angles.mu.len())
                .map(|q| {
                    let mu = angles.mu[q];
                    0.5 * alpha * angles.weight[q] * (1.0 - angles.fresnel[q]) * mu / (mu + mu0)
                })
                .sum();
            multiple + single
        })
        .collect()
}

/// The first-collision source a' e^{-z} at a cell's midpoint: what
/// [`solve_source`] less this leaves is the multiply scattered part.
fn first_collisions(alpha: f64, lo: f64, hi: f64) -> f64 {
    alpha * (-0.5 * (lo + hi)).exp()
}

/// The multiply scattered part of [`solve_source`] on each cell.
fn multiple_source(alpha: f64, p0: f64, k: f64, prim: &Primitives) -> Vec<f64> {
    let c = solve_source(alpha, p0, k, prim);
    stencil()
        .edges
        .windows(2)
        .zip(&c)
        .map(|(w, &cj)| cj - first_collisions(alpha, w[0], w[1]))
        .collect()
}

/// The multiply scattered exitance M̂_ms(k) at frequency k (single
/// scattering is integrated exactly elsewhere).
fn solve_k(alpha: f64, p0: f64, k: f64, prim: &Primitives) -> f64 {
    stencil()
        .edges
        .windows(2)
        .zip(multiple_source(alpha, p0, k, prim))
        .map(|(w, c)| c * (prim.at(&prim.p_t, w[1]) - prim.at(&prim.p_t, w[0])))
        .sum()
}

/// Gaussian elimination with partial pivoting (row-major `a`, n x n). The
/// elimination is most of a fit's time; compiled for AVX2 too where the CPU
/// has it (the same operations in the same order: the same bits, no FMA).
fn solve_dense(a: &mut [f64], b: Vec<f64>, n: usize) -> Vec<f64> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { solve_dense_avx2(a, b, n) };
    }
    solve_dense_any(a, b, n)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn solve_dense_avx2(a: &mut [f64], b: Vec<f64>, n: usize) -> Vec<f64> {
    solve_dense_any(a, b, n)
}

#[inline(always)]
fn solve_dense_any(a: &mut [f64], mut b: Vec<f64>, n: usize) -> Vec<f64> {
    for col in 0..n {
        let piv = (col..n)
            .max_by(|&r, &s| a[r * n + col].abs().total_cmp(&a[s * n + col].abs()))
            .unwrap();
        if piv != col {
            for k in 0..n {
                a.swap(col * n + k, piv * n + k);
            }
            b.swap(col, piv);
        }
        let (top, below) = a.split_at_mut((col + 1) * n);
        let pivot_row = &top[col * n + col..];
        let d = pivot_row[0];
        for (r, row) in (col + 1..n).zip(below.chunks_exact_mut(n)) {
            let f = row[col] / d;
            if f != 0.0 {
                for (x, &p) in row[col..].iter_mut().zip(pivot_row) {
                    *x -= f * p;
                }
                b[r] -= f * b[col];
            }
        }
    }
    for col in (0..n).rev() {
        let s: f64 = (col + 1..n).map(|k| a[col * n + k] * b[k]).sum();
        b[col] = (b[col] - s) / a[col * n + col];
    }
    b
}

/// Kernel tables for one eta, shared by every albedo: the primitives at
/// each spatial frequency and the single-scattering line profile of unit
/// albedo. Building each takes about a second; [`HalfSpace::shared`] keeps
/// one per eta for the process. The line profile's table is built when a
/// line profile is first asked for: a renderer needs only radial profiles.
pub struct HalfSpace {
    pub eta: f64,
    angles: Angles,
    k: Vec<f64>,
    prims: Vec<Primitives>,
    /// M̂_ms(k) of the last few albedos (the fit asks for the same one
    /// from its profile search and its reflectance bookkeeping).
    recent: Mutex<Vec<(f64, Arc<Vec<f64>>)>>,
    /// Radial profiles of the last few albedos (a renderer asks per channel).
    radial: Mutex<Vec<(f64, Arc<RadialProfile>)>>,
    /// ln of single scattering of unit albedo at x = SS_NEAR e^{i·SS_STEP}
    /// (logarithmic at the line and exponential away from it, so
    /// tabulated in ln x and interpolated in ln g).
    single: OnceLock<Vec<f64>>,
}

/// Highest spatial frequency of the multiple-scattering transform, 1/mfp.
const K_MAX: f64 = 60.0;

/// Grid of the single-scattering table: from SS_NEAR mfp, steps in ln x.
const SS_NEAR: f64 = 1e-4;
const SS_STEP: f64 = 0.02;

/// Single scattering beyond this many mfp from the line is below e^{-40}.
const SS_REACH: f64 = 40.0;

impl HalfSpace {
    pub fn new(eta: f64) -> Self {
        let angles = Angles::new(eta);
        let grid: Arc<[f64]> = primitive_grid().into();
        let mut k = vec![0.0];
        let mut x = 1e-4;
        while x < K_MAX {
            k.push(x);
            x *= 1.08;
        }
        k.push(K_MAX);
        let prims: Vec<Primitives> = k
            .par_iter()
            .map(|&k| Primitives::new(k, &angles, &grid))
            .collect();
        HalfSpace {
            eta,
            angles,
            k,
            prims,
            recent: Mutex::new(Vec::new()),
            radial: Mutex::new(Vec::new()),
            single: OnceLock::new(),
        }
    }

    /// The tables [`HalfSpace::shared`] gives, with the line profile's
    /// single-scattering table built too (for a fit, ahead of time).
    pub fn shared_for_line_profiles(eta: f64) -> Arc<HalfSpace> {
        let hs = HalfSpace::shared(eta);
        hs.single_table();
        hs
    }

    fn single_table(&self) -> &[f64] {
        if let Some(table) = self.single.get() {
            return table;
        }
        // Built outside any lock: a rayon worker waiting in this par_iter may
        // run another line profile's job, which must not block on the table.
        // Callers that race compute the same table; the first one is kept.
        let n = ((SS_REACH / SS_NEAR).ln() / SS_STEP).ceil() as usize + 2;
        let table = (0..n)
            .into_par_iter()
            .map(|i| single_line(self.eta, SS_NEAR * (i as f64 * SS_STEP).exp()).ln())
            .collect();
        let _ = self.single.set(table);
        self.single.get().expect("set above")
    }

    /// The tables for `eta`, built once per process (built outside the
    /// lock, as [`remembered`] does: a rayon worker waiting in the build's
    /// par_iter may run a job that asks for them too; callers that race
    /// build the same tables and the first kept is shared).
    pub fn shared(eta: f64) -> Arc<HalfSpace> {
        static CACHE: OnceLock<Mutex<Vec<Arc<HalfSpace>>>> = OnceLock::new();
        let cache = CACHE.get_or_init(|| Mutex::new(Vec::new()));
        let lock = || cache.lock().unwrap_or_else(|e| e.into_inner());
        let find = |c: &[Arc<HalfSpace>]| c.iter().find(|h| h.eta == eta).cloned();
        if let Some(hs) = find(&lock()) {
            return hs;
        }
        let built = Arc::new(HalfSpace::new(eta));
        let mut cache = lock();
        if let Some(hs) = find(&cache) {
            return hs;
        }
        cache.push(built.clone());
        built
    }

    /// Single scattering's total exitance (exact): ½ a' ∫ (1 - F) μ/(1 + μ) dμ.
    fn single_total(&self, alpha: f64) -> f64 {
        let an = &self.angles;
        (0..an.mu.len())
            .map(|q| {
                0.5 * alpha * an.weight[q] * (1.0 - an.fresnel[q]) * an.mu[q] / (1.0 + an.mu[q])
            })
            .sum()
    }

    /// Total diffuse reflectance per entered flux of reduced albedo `alpha`.
    pub fn total_reflectance(&self, alpha: f64) -> f64 {
        solve_k(alpha, asymptotic_decay(alpha), 0.0, &self.prims[0]) + self.single_total(alpha)
    }

    /// Inverts [`Self::total_reflectance`] (monotone in a') in s = sqrt(1 - a'),
    /// where R is nearly linear near a' = 1, by regula falsi (Illinois),
    /// to 1e-10 in a'. R must be in (0, 1].
    pub fn albedo_from_reflectance(&self, r: f64) -> Result<f64, ModelError> {
        if !(r.is_finite() && r > 0.0 && r <= 1.0) {
            return Err(ModelError::Domain(format!(
                "total diffuse reflectance R = {r} is outside (0, 1]"
            )));
        }
        // g(s) = R(1 - s²) - r falls from g(0) >= 0 to g(1) = -r.
        let g = |s: f64| self.total_reflectance(1.0 - s * s) - r;
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        let (mut g_lo, mut g_hi) = (g(lo), -r);
        if g_lo <= 0.0 {
            return Ok(1.0);
        }
        let mut side = 0;
        for _ in 0..100 {
            let s = (lo * g_hi - hi * g_lo) / (g_hi - g_lo);
            let gs = g(s);
            if gs > 0.0 {
                (lo, g_lo) = (s, gs);
                if side == 1 {
                    g_hi *= 0.5;
                }
                side = 1;
            } else {
                (hi, g_hi) = (s, gs);
                if side == -1 {
                    g_lo *= 0.5;
                }
                side = -1;
            }
            if hi - lo < 1e-11 || gs == 0.0 {
                break;
            }
        }
        let s = if g_lo.abs() < g_hi.abs() { lo } else { hi };
        Ok(1.0 - s * s)
    }

    /// The radiance under the boundary of all the light a normal beam
    /// sends back (k = 0), by the direction it meets the boundary in.
    pub fn emergent(&self, alpha: f64) -> Emergent {
        let mut emergent = Emergent {
            eta: self.eta,
            alpha,
            edges: depth_cells(),
            multiple: multiple_source(alpha, asymptotic_decay(alpha), 0.0, &self.prims[0]),
            exitance: 0.0,
        };
        let an = &self.angles;
        emergent.exitance = (0..an.mu.len())
            .map(|q| {
                let mu = an.mu[q];
                2.0 * PI
                    * an.weight[q]
                    * (1.0 - an.fresnel[q])
                    * emergent.internal_radiance(mu)
                    * mu
            })
            .sum();
        emergent
    }

    /// The line profile g(x) of reduced albedo `alpha` (exitance per entered
    /// flux per mfp of line, s'_t = 1) at the distances `xs` (mfp).
    pub fn line_profile(&self, alpha: f64, xs: &[f64]) -> Vec<f64> {
        let ms = self.multiple_transform(alpha);
        xs.par_iter()
            .map(|&x| filon_cos(&self.k, &ms, x) / PI + alpha * self.single_at(x))
            .collect()
    }

    /// M̂_ms(k) on the frequency grid, remembered for the last 8 albedos.
    fn multiple_transform(&self, alpha: f64) -> Arc<Vec<f64>> {
        remembered(&self.recent, alpha, || {
            let p0 = asymptotic_decay(alpha);
            self.k
                .par_iter()
                .zip(&self.prims)
                .map(|(&k, p)| solve_k(alpha, p0, k, p))
                .collect()
        })
    }

    /// The radial profile R_d(x) of a normal pencil beam (per entered flux,
    /// unit s'_t) of reduced albedo `alpha`, remembered for the last 8.
    pub fn radial_profile(&self, alpha: f64) -> Arc<RadialProfile> {
        remembered(&self.radial, alpha, || RadialProfile::new(self, alpha))
    }

    /// Unit-albedo single scattering at x, from the table (its first entry
    /// below SS_NEAR).
    fn single_at(&self, x: f64) -> f64 {
        let single = self.single_table();
        let u = (x.abs().max(SS_NEAR) / SS_NEAR).ln() / SS_STEP;
        let i = u.floor() as usize;
        if i + 1 >= single.len() {
            return 0.0;
        }
        let f = u - i as f64;
        (single[i] * (1.0 - f) + single[i + 1] * f).exp()
    }
}

/// The angular distribution of the reflected light under the boundary, from
/// the k = 0 source: L(μ) = (1/4π μ) ∫ C(z) e^{-z/μ} dz, with single
/// scattering exact and the multiply scattered source constant on each
/// cell (the deep field's share is below e^{-NEAR_DEPTH}).
pub struct Emergent {
    eta: f64,
    alpha: f64,
    edges: Vec<f64>,
    multiple: Vec<f64>,
    /// 2π ∫ (1 - F(μ)) L(μ) μ dμ on the solver's angles: the total reflectance.
    exitance: f64,
}

impl Emergent {
    /// Radiance per entered flux, moving up at direction cosine `mu` inside.
    pub fn internal_radiance(&self, mu: f64) -> f64 {
        let mu = mu.clamp(1e-9, 1.0);
        let cells: f64 = self
            .edges
            .windows(2)
            .zip(&self.multiple)
            .map(|(w, &c)| c * ((-w[0] / mu).exp() - (-w[1] / mu).exp()))
            .sum();
        (cells + self.alpha / (1.0 + mu)) / (4.0 * PI)
    }

    /// The exitance, 2π ∫ (1 - F(μ)) L(μ) μ dμ: the total reflectance.
    pub fn exitance(&self) -> f64 {
        self.exitance
    }

    /// Exitance per unit radiance seen outside at `cos_view`: what turns a
    /// camera's radiance into exitance. Refraction maps the view to μ inside,
    /// and radiance across the boundary is (1 - F) L / eta².
    pub fn exitance_per_radiance(&self, cos_view: f64) -> f64 {
        let cos_view = cos_view.clamp(0.0, 1.0);
        let mu = (1.0 - (1.0 - cos_view * cos_view) / (self.eta * self.eta)).sqrt();
        let seen = (1.0 - fresnel_dielectric(mu, 1.0 / self.eta)) * self.internal_radiance(mu)
            / (self.eta * self.eta);
        self.exitance / seen
    }
}

/// The value for `alpha` from `cache` (the last 8 albedos asked), or `make`'s.
fn remembered<T>(
    cache: &Mutex<Vec<(f64, Arc<T>)>>,
    alpha: f64,
    make: impl FnOnce() -> T,
) -> Arc<T> {
    let lock = || cache.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, v)) = lock().iter().find(|(a, _)| *a == alpha) {
        return v.clone();
    }
    let v = Arc::new(make());
    let mut cache = lock();
    if cache.len() >= 8 {
        cache.remove(0);
    }
    cache.push((alpha, v.clone()));
    v
}

/// R_d(x) of a normal pencil beam at unit s'_t, tabulated in ln x from
/// RADIAL_NEAR to where it has fallen below 1e-9 of its value at 1 mfp:
/// multiple scattering by the Hankel transform (1/2π) ∫ M̂_ms(k) J0(kx) k dk
/// of the line's transform (a radially symmetric profile has the same 2D
/// transform), single scattering by quadrature along the beam; the far
/// field as the slowest transport mode.
#[derive(Debug)]
pub struct RadialProfile {
    ln_rd: Vec<f64>,
    /// 2π ∫_0^{x_i} x R_d dx at the grid points.
    cumulative: Vec<f64>,
    /// Total reflectance per entered flux.
    pub total: f64,
}

const RADIAL_NEAR: f64 = 1e-3;
const RADIAL_STEP: f64 = 0.02;

impl RadialProfile {
    fn new(hs: &HalfSpace, alpha: f64) -> Self {
        let ms = hs.multiple_transform(alpha);
        let eta = hs.eta;
        let value = |x: f64| hankel_j0(&hs.k, &ms, x) / (2.0 * PI) + alpha * single_point(eta, x);
        let reference = value(1.0);
        let x_at = |j: usize| RADIAL_NEAR * (j as f64 * RADIAL_STEP).exp();
        // The transform gives R_d to about 1 % while it is above 1e-4 of its
        // value at 1 mfp; beyond, the interpolation of M̂ between frequency
        // nodes shows, and the far field is the slowest transport mode,
        // B e^{-p0 x} (1 + p0 x) / x³, continued from there.
        let mut values = vec![];
        let mut j = 0;
        loop {
            let chunk: Vec<f64> = (j..j + 32)
                .into_par_iter()
                .map(|j| value(x_at(j)))
                .collect();
            j += 32;
            let end = chunk.iter().position(|&v| !(v > 1e-4 * reference));
            match end {
                Some(e) => {
                    values.extend_from_slice(&chunk[..e.max(1)]);
                    break;
                }
                None => values.extend(chunk),
            }
            if j > 2000 {
                break;
            }
        }
        let p0 = asymptotic_decay(alpha);
        let mode = |x: f64| (-p0 * x).exp() * (1.0 + p0 * x) / (x * x * x);
        let x_end = x_at(values.len() - 1);
        let b = values[values.len() - 1] / mode(x_end);
        while values.len() < 4000 {
            let v = b * mode(x_at(values.len()));
            values.push(v);
            if !(v > 1e-9 * reference) {
                break;
            }
        }
        let ln_rd: Vec<f64> = values.iter().map(|v| v.max(1e-300).ln()).collect();
        // Trapezoid in ln x: 2π x² R_d d(ln x); the disc below RADIAL_NEAR
        // holds (singular) single scattering, 2π ∫ x R_d ≈ 2π x R_d x.
        let f = |j: usize| 2.0 * PI * x_at(j).powi(2) * ln_rd[j].exp();
        let mut cumulative = vec![f(0)];
        for j in 1..ln_rd.len() {
            let c = cumulative[j - 1] + 0.5 * RADIAL_STEP * (f(j - 1) + f(j));
            cumulative.push(c);
        }
        RadialProfile {
            ln_rd,
            cumulative,
            total: hs.total_reflectance(alpha),
        }
    }

    fn index(&self, x: f64) -> (usize, f64) {
        let u = (x.max(RADIAL_NEAR) / RADIAL_NEAR).ln() / RADIAL_STEP;
        let i = u.floor() as usize;
        (i, u - i as f64)
    }

    /// R_d(x), unit s'_t (its value at RADIAL_NEAR closer in; 0 beyond the table).
    pub fn rd(&self, x: f64) -> f64 {
        let (i, f) = self.index(x);
        if i + 1 >= self.ln_rd.len() {
            return 0.0;
        }
        (self.ln_rd[i] * (1.0 - f) + self.ln_rd[i + 1] * f).exp()
    }

    /// 2π ∫_0^{x0} x R_d dx, unit s'_t.
    pub fn disc_integral(&self, x0: f64) -> f64 {
        let (i, f) = self.index(x0);
        if i + 1 >= self.cumulative.len() {
            return self.total;
        }
        self.cumulative[i] * (1.0 - f) + self.cumulative[i + 1] * f
    }
}

/// Single scattering of a unit-albedo normal pencil beam at distance x:
/// ∫ e^{-t} (1 - F(μ)) μ e^{-d} / (4π d²) dt, d² = x² + t², μ = t/d.
fn single_point(eta: f64, x: f64) -> f64 {
    let f = |s: f64| {
        if s >= 1.0 {
            return 0.0;
        }
        let u = 1.0 - s;
        let l = x.max(1e-9);
        let t = l * s / u;
        let d = (x * x + t * t).sqrt();
        let mu = t / d;
        (-t - d).exp() * (1.0 - fresnel_dielectric(mu, 1.0 / eta)) * mu / (4.0 * PI * d * d) * l
            / (u * u)
    };
    quad::integrate(f, 0.0, 1.0, 1e-7, 1e-300, 200)
}

/// Single scattering of a unit-albedo line beam at distance x, in real
/// space: ∫∫ e^{-z} (1 - F(μ)) μ e^{-R} / (4π R²) dy dz, μ = z/R.
fn single_line(eta: f64, x: f64) -> f64 {
    let inner = |z: f64| {
        let l = (x * x + z * z).sqrt().max(1e-9);
        let f = |t: f64| {
            if t >= 1.0 {
                return 0.0;
            }
            let u = 1.0 - t;
            let y = l * t / u;
            let r = (x * x + y * y + z * z).sqrt();
            let mu = z / r;
            (1.0 - fresnel_dielectric(mu, 1.0 / eta)) * mu * (-r).exp() / (4.0 * PI * r * r) * l
                / (u * u)
        };
        2.0 * quad::integrate(f, 0.0, 1.0, 1e-6, 1e-300, 200)
    };
    let outer = |t: f64| {
        if t >= 1.0 {
            return 0.0;
        }
        let u = 1.0 - t;
        let z = t / u;
        (-z).exp() * inner(z) / (u * u)
    };
    quad::integrate(outer, 0.0, 1.0, 1e-6, 1e-300, 200)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn oblique_reflectance_is_the_normal_one_at_mu_1_and_grows_obliquely() {
        for &(eta, a) in &[(1.3, 0.68), (1.3, 0.96), (1.5, 0.999)] {
            let hs = HalfSpace::shared(eta);
            let r = oblique_reflectance(eta, a, &[1.0, 0.8, 0.64]);
            let r0 = hs.total_reflectance(a);
            assert!(
                (r[0] - r0).abs() < 2e-3 * r0,
                "eta {eta} a' {a}: {} vs {r0}",
                r[0]
            );
            assert!(r[1] > r[0] && r[2] > r[1], "{r:?}");
        }
        // A deliberately wrong source (the normal one) would not grow.
        let r = oblique_reflectance(1.3, 0.68, &[0.64]);
        assert!(
            r[0] > 1.15 * HalfSpace::shared(1.3).total_reflectance(0.68),
            "{r:?}"
        );
    }

    /// Chandrasekhar's H-function of isotropic scattering, from
    /// 1/H(μ) = sqrt(1 - a) + (a/2) ∫ μ' H(μ') / (μ + μ') dμ', iterated.
    fn chandrasekhar_h(a: f64) -> impl Fn(f64) -> f64 {
        let n = 400;
        let mu: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64).collect();
        let mut h = vec![1.0; n];
        for _ in 0..2000 {
            let next: Vec<f64> = mu
                .iter()
                .map(|&m| {
                    let s: f64 = mu.iter().zip(&h).map(|(&q, &hq)| q * hq / (m + q)).sum();
                    1.0 / ((1.0 - a).sqrt() + 0.5 * a * s / n as f64)
                })
                .collect();
            h = next;
        }
        move |m: f64| {
            let s: f64 = mu.iter().zip(&h).map(|(&q, &hq)| q * hq / (m + q)).sum();
            1.0 / ((1.0 - a).sqrt() + 0.5 * a * s / n as f64)
        }
    }

    #[test]
    fn index_matched_reflectance_is_chandrasekhars() {
        // Normal incidence on an index-matched half-space: R = 1 - H(1) sqrt(1 - a).
        let hs = HalfSpace::new(1.0);
        for a in [0.3, 0.7, 0.9, 0.99, 0.999] {
            let exact = 1.0 - chandrasekhar_h(a)(1.0) * (1.0f64 - a).sqrt();
            let r = hs.total_reflectance(a);
            eprintln!("a {a}: R {r:.6} exact {exact:.6}");
            assert!((r - exact).abs() < 5e-4, "a {a}: R {r} vs {exact}");
        }
    }

    #[test]
    fn index_matched_emergent_radiance_is_chandrasekhars() {
        // Diffuse reflection of a normal beam, index-matched: the emergent
        // radiance goes as H(μ)/(1 + μ), and its exitance is R.
        let hs = HalfSpace::new(1.0);
        for a in [0.5, 0.9, 0.99] {
            let e = hs.emergent(a);
            let r = hs.total_reflectance(a);
            assert!(
                (e.exitance() / r - 1.0).abs() < 1e-3,
                "a {a}: {} vs {r}",
                e.exitance()
            );
            let h = chandrasekhar_h(a);
            for mu in [0.1, 0.3, 0.6] {
                let exact = h(mu) / (1.0 + mu) / (h(1.0) / 2.0);
                let got = e.internal_radiance(mu) / e.internal_radiance(1.0);
                assert!(
                    (got / exact - 1.0).abs() < 2e-3,
                    "a {a} μ {mu}: {got} vs {exact}"
                );
            }
        }
    }

    #[test]
    fn diffuse_light_leaves_as_fresnel_predicts() {
        // At a' = 1 the light under the boundary is nearly isotropic, so the
        // conversion is close to the diffuse-Fresnel one; at lower albedo
        // less leaves along the normal, more per radiance seen there.
        for eta in [1.3, 1.5] {
            let hs = HalfSpace::shared(eta);
            let fa = crate::fresnel::fresnel_hemispherical_average(eta);
            for cos in [1.0, 0.62] {
                let iso = crate::fresnel::exitance_per_radiance(cos, eta, fa);
                let white = hs.emergent(1.0).exitance_per_radiance(cos);
                assert!(
                    (white / iso - 1.0).abs() < 0.01,
                    "eta {eta}: {white} vs {iso}"
                );
                let grey = hs.emergent(0.8).exitance_per_radiance(1.0);
                assert!(grey > 1.02 * white, "eta {eta}: {grey} vs {white}");
            }
        }
    }

    #[test]
    fn conservative_half_space_reflects_everything() {
        for eta in [1.3, 1.5] {
            let r = HalfSpace::shared(eta).total_reflectance(1.0);
            assert!((r - 1.0).abs() < 2e-3, "eta {eta}: R {r}");
        }
    }

    #[test]
    fn albedo_inversion_round_trips() {
        let hs = HalfSpace::shared(1.3);
        for a in [0.2, 0.8, 0.97, 0.999, 0.99995] {
            let back = hs.albedo_from_reflectance(hs.total_reflectance(a)).unwrap();
            assert!((back - a).abs() < 1e-8, "{a} -> {back}");
        }
        assert!(hs.albedo_from_reflectance(0.0).is_err());
        assert!(hs.albedo_from_reflectance(1.5).is_err());
        assert!(hs.albedo_from_reflectance(f64::NAN).is_err());
    }

    #[test]
    fn line_profile_integrates_to_total_reflectance() {
        let hs = HalfSpace::shared(1.3);
        for a in [0.6, 0.99] {
            // 2 ∫_0^∞ g(x) dx in u = ln(1 + x), midpoint rule (g is
            // logarithmic at the line).
            let h = 0.002;
            let us: Vec<f64> = (0..(9.0 / h) as usize)
                .map(|i| (i as f64 + 0.5) * h)
                .collect();
            let xs: Vec<f64> = us.iter().map(|u| u.exp() - 1.0).collect();
            let g = hs.line_profile(a, &xs);
            let integral: f64 = g.iter().zip(&us).map(|(g, u)| h * g * u.exp()).sum();
            let r = hs.total_reflectance(a);
            assert!(
                (2.0 * integral / r - 1.0).abs() < 0.01,
                "a {a}: {} vs {r}",
                2.0 * integral
            );
        }
    }

    #[test]
    fn radial_profile_integrates_to_total_and_matches_the_line() {
        let hs = HalfSpace::shared(1.3);
        for a in [0.7, 0.99] {
            let p = hs.radial_profile(a);
            let total = p.disc_integral(1e9);
            let cum = p.cumulative.last().copied().unwrap();
            eprintln!("a {a}: radial integral {cum} vs total {}", p.total);
            assert!(
                (cum / p.total - 1.0).abs() < 0.01,
                "a {a}: {cum} vs {}",
                p.total
            );
            assert_eq!(total, p.total);
            // The line profile is the radial one integrated along the line.
            for x in [1.0, 3.0, 5.0] {
                let along = quad::integrate(
                    |s: f64| {
                        let u = 1.0 - s;
                        if u <= 0.0 {
                            return 0.0;
                        }
                        let y = x * s / u;
                        2.0 * p.rd((x * x + y * y).sqrt()) * x / (u * u)
                    },
                    0.0,
                    1.0,
                    1e-6,
                    1e-300,
                    200,
                );
                let line = hs.line_profile(a, &[x])[0];
                assert!(
                    (along / line - 1.0).abs() < 0.01,
                    "a {a} x {x}: {along} vs {line}"
                );
            }
        }
    }
}
