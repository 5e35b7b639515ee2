//! Pass 2 of Jensen & Buhler 2002: the dipole sum
//!
//!   M(x) = sum_i R_d(|x - x_i|) E_i A_i
//!
//! over all surface samples, evaluated hierarchically. An octree over the
//! samples stores at each node the aggregate of its subtree: summed area A,
//! area-weighted mean irradiance E, and the irradiance-weighted centroid.
//! A node is used as one sample when the query point lies outside its box
//! and its solid-angle estimate A / |x - centroid|^2 is below `epsilon`;
//! otherwise the query descends. [`DipoleTree::brute_force`] is the O(n)
//! sum for comparison. R_d comes from `qhm_model` via a tabulated kernel
//! ([`RdTable`]); nodes entirely beyond the kernel's range are skipped.

use glam::{Vec3, Vec4};
use qhm_model::DipoleParams;
use rayon::prelude::*;

use crate::light::luminance;
use crate::points::SurfaceSamples;

/// R_d(r) of the model's dipole, tabulated in r for speed (linear
/// interpolation, 4096 cells up to `r_max` where R_d has fallen below 1e-6
/// of its value at one mean free path in every channel; zero beyond).
///
/// Each surface sample stands for a patch of area A, so the table holds the
/// mean of R_d over a disk of radius rho = sqrt(A / pi) centred at distance
/// r, not the point value: far away the two agree, but near a sample the
/// point value would overweight it (R_d peaks within 1/s'_t, often less
/// than the sample spacing) and print the sample pattern into the image.
/// rho = 0 gives the plain R_d(r).
#[derive(Clone, Debug)]
pub struct RdTable {
    values: Vec<Vec3>,
    inv_dr: f32,
    pub r_max: f32,
    /// Radius of the near field (0 = none): see [`RdTable::with_near_field`].
    pub near_radius: f32,
    /// ∫ w(r) R(r) dA over the plane, the near field's exact weight.
    near_integral: Vec3,
    /// The classic dipole's constants for the geometry factor
    /// ([`RdTable::with_geometry`]); None = planar R_d(r) only.
    geometry: Option<DipoleLanes>,
}

impl RdTable {
    pub fn new(params: &DipoleParams, rho: f32) -> RdTable {
        RdTable::with_hole(params, rho, 0.0)
    }

    /// The table of R_d(r) 1[r > hole], disk-averaged like [`RdTable::new`]:
    /// summed over the samples it integrates R_d over the surface outside
    /// the disc of radius `hole` around the query (eq. 4's B_o = A - A_o).
    pub fn with_hole(params: &DipoleParams, rho: f32, hole: f32) -> RdTable {
        let rho = rho.max(0.0) as f64;
        let hole = hole.max(0.0) as f64;
        let subsurface = params.subsurface();
        let g = |r: f64| {
            if hole == 0.0 || r > hole {
                subsurface.rd(r)
            } else {
                [0.0; 3]
            }
        };
        // R_d at one mean free path of the densest channel (at 0,
        // radiative transfer's single scattering is singular).
        let mfp = 1.0 / params.sigma_t_prime.iter().fold(0.0f64, |a, &b| a.max(b));
        let peak = subsurface.rd(mfp);
        let below = |r: f64| {
            let v = subsurface.rd(r);
            (0..3).all(|c| !(v[c] > 1e-6 * peak[c]))
        };
        let mut r_max = 1.0f64;
        while !below(r_max) && r_max < 1e4 {
            r_max *= 1.25;
        }
        r_max += rho;
        let n = 4096;
        let dr = r_max / (n - 1) as f64;
        // The mean of g over a disk of radius rho centred at distance r, as
        // an integral over the distance s from the origin: the circle of
        // radius s lies inside the disk over an angle theta(s), so the mean
        // is ∫ g(s) theta(s) s ds / (pi rho²). g(s) s stays finite where
        // radiative transfer's single scattering makes g singular at 0, so a
        // midpoint rule in s keeps ∫ R_d dA (a midpoint rule over the disk's
        // area lost 5 % of skin1's blue at rho 0.4 mm, more at 1 mm).
        // Finer where the hole's edge cuts through the disk.
        let n_s = if hole > 0.0 { 1024 } else { 128 };
        let values = (0..n)
            .into_par_iter()
            .map(|k| {
                let r = k as f64 * dr;
                let v = if rho == 0.0 {
                    g(r)
                } else {
                    let (s0, s1) = ((r - rho).max(0.0), r + rho);
                    let ds = (s1 - s0) / n_s as f64;
                    let mut acc = [0.0f64; 3];
                    for i in 0..n_s {
                        let s = s0 + (i as f64 + 0.5) * ds;
                        let theta = if s + r <= rho {
                            2.0 * std::f64::consts::PI
                        } else {
                            2.0 * ((s * s + r * r - rho * rho) / (2.0 * s * r))
                                .clamp(-1.0, 1.0)
                                .acos()
                        };
                        let v = g(s);
                        for c in 0..3 {
                            acc[c] += v[c] * theta * s * ds;
                        }
                    }
                    acc.map(|a| a / (std::f64::consts::PI * rho * rho))
                };
                Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32)
            })
            .collect();
        RdTable {
            values,
            inv_dr: (1.0 / dr) as f32,
            r_max: r_max as f32,
            near_radius: 0.0,
            near_integral: Vec3::ZERO,
            geometry: None,
        }
    }

    /// The geometry factor. R_d(r) is the exitance of a flat half-space:
    /// light entering at x_i leaves at x_o on the same plane. The classic
    /// dipole is the flux -D n · grad(phi) through the surface of the field
    /// of a real source one reduced mean free path z_r below x_i (along its
    /// normal n_i) and a negative image z_v above it. On a curved or thin
    /// object the flux is taken through the surface at x_o, along x_o's own
    /// normal n_o, for the same two sources:
    ///
    ///   G = Φ / Φ_plane,  Φ = z_r' (s_tr d_r + 1) e^{-s_tr d_r} / d_r³ - z_v' (s_tr d_v + 1) e^{-s_tr d_v} / d_v³,
    ///
    /// with z_r' = n_o · (x_o - s_r), z_v' = n_o · (x_o - s_v), d the
    /// distances from x_o to s_r = x_i - z_r n_i and s_v = x_i + z_v n_i, and
    /// Φ_plane the same on a plane (z_r' = z_r, z_v' = -z_v): G = 1 there.
    /// Across a convex terminator the real source lies deeper below x_o's
    /// tangent plane and the flux leaving there is larger; through a thin
    /// part lit from behind the flux points straight out of x_o. Negative
    /// flux (into the surface, as in a concavity) counts as 0. The normals
    /// are the mesh's own (its winding), so a mesh must be wound
    /// consistently. This is the pair at normal incidence; under oblique
    /// light the sources follow the refracted beam
    /// ([`RdTable::flux_factors`]).
    pub fn with_geometry(self, params: &DipoleParams) -> RdTable {
        self.geometry_tables(params, true)
    }

    /// [`RdTable::with_geometry`] without the curvature gain: the dipole's
    /// images at every pair as it lies (`[render] curvature = false`).
    pub fn with_geometry_without_curvature(self, params: &DipoleParams) -> RdTable {
        self.geometry_tables(params, false)
    }

    fn geometry_tables(mut self, params: &DipoleParams, curvature: bool) -> RdTable {
        let g: [qhm_model::dipole::Dipole; 3] = std::array::from_fn(|c| params.channel(c));
        let dr = 1.0 / self.inv_dr as f64;
        let lanes = |f: &dyn Fn(&qhm_model::dipole::Dipole) -> f64| {
            Vec4::new(f(&g[0]) as f32, f(&g[1]) as f32, f(&g[2]) as f32, 0.0)
        };
        let sources = |depths: &'static [(f32, f32)]| Sources {
            depths,
            planar: (0..self.values.len())
                .map(|k| {
                    let r2 = (k as f64 * dr).powi(2);
                    lanes(&|d| {
                        let phi = |z: f64| {
                            let dd = (r2 + z * z).sqrt();
                            z * (d.sigma_tr * dd + 1.0) * (-d.sigma_tr * dd).exp() / (dd * dd * dd)
                        };
                        depths
                            .iter()
                            .map(|&(t, w)| {
                                let z = t as f64 * d.z_r;
                                w as f64 * (phi(z) + phi(z + d.z_v - d.z_r))
                            })
                            .sum::<f64>()
                    })
                })
                .collect(),
        };
        let z_r = lanes(&|d| d.z_r);
        let share = if curvature {
            lanes(&|d| ((d.alpha_prime - DIFFUSION_ALBEDO) / 0.04 + 1.0).clamp(0.0, 1.0))
        } else {
            Vec4::ZERO
        };
        self.geometry = Some(DipoleLanes {
            z_r,
            z_v: lanes(&|d| d.z_v),
            sigma_tr: lanes(&|d| d.sigma_tr),
            beam_reach: BEAM_REACH * z_r.max_element(),
            image_reach: (0..3)
                .map(|c| {
                    let d = &g[c];
                    ((SLAB_IMAGE_DEPTH / d.sigma_tr + d.z_r) / 2.0 - (d.z_v - d.z_r)) as f32
                })
                .fold(0.0, f32::max),
            beam: sources(&BEAM),
            point: sources(&[(1.0, 1.0)]),
            // The series only for a material some channel of which takes it.
            curvature: if share != Vec4::ZERO {
                self.curvature_table(&g)
            } else {
                Vec::new()
            },
            curvature_share: share,
            oblique_norm: vec![Vec4::ONE; OBLIQUE_STEPS],
            near_oblique: Vec::new(),
            oblique_flow: Vec::new(),
        });
        // Normalise the kernel as it is summed (this table, these sources)
        // to normal incidence's total, then weigh the near field.
        let whole = self.plane_totals(self.r_max, |_| 1.0, false);
        let at_normal = whole[OBLIQUE_STEPS - 1];
        let norm = whole
            .iter()
            .map(|&t| {
                let q = at_normal / t;
                Vec3::select(t.cmpgt(Vec3::splat(1e-6) * at_normal), q, Vec3::ONE).extend(1.0)
            })
            .collect();
        if let Some(g) = &mut self.geometry {
            g.oblique_norm = norm;
        }
        // Over the far part only: the near field takes the window's mean
        // irradiance out of its tangential sum, which leaves a uniformly
        // lit window nothing already.
        let far = |r: f32| 1.0 - self.near_weight(r);
        let far_total = self.radial_integral(self.r_max, far);
        // Kept over sin θ_t (the flow goes as the beam's tangent), so a
        // term takes it off with no square root.
        let mut flow: Vec<Vec3> = self
            .plane_totals(self.r_max, far, true)
            .iter()
            .enumerate()
            .map(|(k, &f)| {
                let cos_t = k as f32 / (OBLIQUE_STEPS - 1) as f32;
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                let per = f / (far_total * sin_t);
                Vec3::select(per.is_finite_mask(), per, Vec3::ZERO)
            })
            .collect();
        flow[OBLIQUE_STEPS - 1] = flow[OBLIQUE_STEPS - 2];
        if let Some(g) = &mut self.geometry {
            g.oblique_flow = flow;
        }
        if self.near_radius > 0.0 && self.near_integral.min_element() > 0.0 {
            let near: Vec<Vec3> = self
                .plane_totals(self.near_radius, |r| self.near_weight(r), false)
                .iter()
                .map(|&t| t / self.near_integral)
                .collect();
            if let Some(g) = &mut self.geometry {
                g.near_oblique = near;
            }
        }
        self
    }

    /// F(r) of each channel on the table's grid: exact on COARSE points out
    /// to where R_d has fallen to e^-8 of its near values (held beyond),
    /// linear between them.
    fn curvature_table(&self, d: &[qhm_model::dipole::Dipole; 3]) -> Vec<Vec4> {
        const COARSE: usize = 65;
        let dr = 1.0 / self.inv_dr as f64;
        let r_end = self.values.len() as f64 * dr;
        let per_channel: Vec<(f64, Vec<f64>)> = d
            .par_iter()
            .map(|d| {
                let reach = (8.0 / d.sigma_tr.max(1e-9) + 10.0 * d.z_v).min(r_end);
                let rs: Vec<f64> = (0..COARSE)
                    .map(|i| reach * i as f64 / (COARSE - 1) as f64)
                    .collect();
                (reach, crate::curvature::first_order(d, &rs))
            })
            .collect();
        (0..self.values.len())
            .map(|k| {
                let lane = |c: usize| {
                    let (reach, f) = &per_channel[c];
                    let x =
                        ((k as f64 * dr) / reach * (COARSE - 1) as f64).min((COARSE - 1) as f64);
                    let i = (x as usize).min(COARSE - 2);
                    let t = x - i as f64;
                    (f[i] * (1.0 - t) + f[i + 1] * t) as f32
                };
                Vec4::new(lane(0), lane(1), lane(2), 0.0)
            })
            .collect()
    }

    /// ∫ weight(r) R(r) G dA over a plane out to `radius`, lit along a beam
    /// refracted to cos θ_t = k / (OBLIQUE_STEPS - 1), for each k: polar
    /// midpoint rule with the radii packed towards the entry, where an
    /// oblique beam's shallow sources put their flux.
    /// With `flow`, the same integral of G_u along the beam's tangent.
    fn plane_totals(&self, radius: f32, weight: impl Fn(f32) -> f32, flow: bool) -> Vec<Vec3> {
        let (nr, nphi) = (256, 16);
        let dphi = std::f32::consts::PI / nphi as f32;
        let rings: Vec<(f32, Vec3)> = (0..nr)
            .map(|i| {
                let x = (i as f32 + 0.5) / nr as f32;
                let (r, dr) = (radius * x * x, radius * 2.0 * x / nr as f32);
                // Symmetric about the plane of incidence: half the azimuths, twice.
                (r, self.eval(r) * weight(r) * (r * dr * dphi * 2.0))
            })
            .collect();
        let u = if flow { Vec3::X } else { Vec3::ZERO };
        (0..OBLIQUE_STEPS)
            .into_par_iter()
            .map(|k| {
                let cos_t = k as f32 / (OBLIQUE_STEPS - 1) as f32;
                let wi = Vec3::new((1.0 - cos_t * cos_t).max(0.0).sqrt(), 0.0, -cos_t);
                let mut sum = Vec3::ZERO;
                for &(r, kw) in &rings {
                    for j in 0..nphi {
                        let phi = (j as f32 + 0.5) * dphi;
                        let dx = Vec3::new(r * phi.cos(), r * phi.sin(), 0.0);
                        let half_space = f32::INFINITY;
                        let (g, g_u) =
                            self.flux_factors(dx, r, Vec3::Z, wi, half_space, Vec3::Z, u);
                        sum += kw * if flow { g_u } else { g };
                    }
                }
                sum
            })
            .collect()
    }

    /// The near field's weight for a sample whose light enters at
    /// cos θ_t = `cos_t` relative to normal incidence's
    /// ([`DipoleLanes::near_oblique`]); 1 without the geometry.
    #[inline]
    fn near_entry(&self, cos_t: f32) -> Vec3 {
        match &self.geometry {
            Some(g) if !g.near_oblique.is_empty() && cos_t < 0.9999 => {
                at_entry_angle(&g.near_oblique, cos_t)
            }
            _ => Vec3::ONE,
        }
    }

    /// G for a sample at offset `dx` = x_o - x_i with normal `ni`, lit at
    /// normal incidence, seen from a query with normal `no` (see
    /// [`RdTable::with_geometry`]).
    #[cfg(test)]
    fn geometry_factor(&self, dx: Vec3, r: f32, ni: Vec3, no: Vec3) -> Vec3 {
        self.flux_factors(dx, r, ni, -ni, f32::INFINITY, no, Vec3::ZERO)
            .0
    }

    /// The geometry factor G and the tangential flux factor G_u of a
    /// sample at offset `dx` = x_o - x_i with normal `ni` whose light
    /// enters along the unit direction `wi` (refracted, into the medium),
    /// seen from a query with normal `no`. The three channels go in the
    /// lanes of one vector: this is the inner loop of a render.
    ///
    /// The real source lies one reduced mean free path along the entering
    /// light, s_r = x_i + z_r w_i, at depth z' = z_r cos θ_t; the image lies
    /// z' + 2 z_b above the plane over it, s_v = s_r + (2 z' + z_v - z_r) n_i
    /// (normal incidence gives the classic pair). Along the beam the pairs
    /// sit at the depths of [`BEAM`] out to BEAM_REACH mean free paths from
    /// x_i, one pair at t = 1 beyond (the planar tables follow the same
    /// split, so G is 1 on a plane lit at normal incidence either way). An
    /// oblique beam so moves the exitance forward. Its total over a plane
    /// is scaled back to normal incidence's (`oblique_norm`, integrated
    /// numerically in [`RdTable::with_geometry`]), since the entrance (f,
    /// or the smooth boundary's entry shape) already holds how much more
    /// an oblique beam returns.
    ///
    /// Where x_o's plane faces away from x_i's (n_o · n_i < 0, a thin
    /// part's far side) the exit boundary's own images join, weighted by
    /// -n_o · n_i: s_r and s_v mirrored across the plane z_b outside x_o,
    /// with opposite signs, the first terms of the slab's multipole.
    ///
    /// On the entry side of a part `thick` thick (the distance from x_i
    /// along -n_i to the far face, [`crate::points::compute_thickness`]),
    /// light that a half-space would send back leaves through the far face
    /// instead: the slab's multipole (Donner & Jensen 2005). The planes z_b
    /// outside both faces lie L = thick + 2 z_b apart, and mirroring the
    /// pair in both repeats it every 2 L along n_i, with the same signs;
    /// the orders of [`SLAB_IMAGES`] are summed, for the pair at the beam's
    /// mean depth, weighted by n_o · n_i and only for x_o within half the
    /// thickness of x_i's plane (elsewhere, on a curved part, an image can
    /// lie next to x_o). Parts thicker than the images' reach
    /// ([`DipoleLanes::image_reach`]) are half-spaces.
    ///
    /// Where x_o's plane faces x_i's (n_o · n_i above 0.25) the pair is
    /// laid flat on x_i's tangent plane and the curvature between the two
    /// takes the gain of diffusion theory in a sphere instead
    /// ([`crate::curvature`]), for the channels whose albedo it holds at.
    ///
    /// G_u is the flux through x_o along the unit tangent `u` over the
    /// planar normal flux, u · (f_r (x_o - s_r) - f_v (x_o - s_v)) / Φ_plane
    /// with f = (s_tr d + 1) e^{-s_tr d} / d³ (see
    /// [`DipoleTree::query_flux`]) less what a uniformly lit plane gives
    /// ([`RdTable::uniform_flow`]); `u` = 0 gives G_u = 0.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn flux_factors(
        &self,
        dx: Vec3,
        r: f32,
        ni: Vec3,
        wi: Vec3,
        thick: f32,
        no: Vec3,
        u: Vec3,
    ) -> (Vec3, Vec3) {
        let Some(g) = &self.geometry else {
            return (Vec3::ONE, Vec3::ZERO);
        };
        let slab_near = ni.dot(dx).abs() < 0.5 * thick;
        let c = no.dot(ni);
        if c <= CURVED_COS.0 || g.curvature_share == Vec4::ZERO {
            return self.pair_flux(g, dx, r, ni, wi, thick, slab_near, no, u);
        }
        // The sphere's first-order gain for the curvature the two normals
        // give (on a sphere (n_o - n_i) · dx / r² is exactly 1 / R), and
        // the pair laid flat: x_o on x_i's tangent plane at the same chord,
        // but for an offset along n_i that the curvature does not explain
        // (the sphere's sag is -k r² / 2). x_o above that plane keeps its
        // height; below it, only beyond the part's far face (a gap under
        // an overhang). A surface that falls away faster than its normals
        // turn, as over the teapot's shoulder, is convex all the same:
        // keeping that drop made the teapot 4-9 % darker than sim-light.
        let r2 = (r * r).max(1e-12);
        let k = (no - ni).dot(dx) / r2;
        let nd = ni.dot(dx);
        let off = nd + 0.5 * k * r2;
        let off = if -nd < thick { off.max(0.0) } else { off };
        // dx's part along the plane, |.|² = r² - nd², stretched to the
        // flat pair's sqrt(r² - off²).
        let along2 = r2 - nd * nd;
        let stretch = if along2 > 1e-12 * r2 {
            ((r2 - off * off).max(0.0) / along2).sqrt()
        } else {
            0.0
        };
        let flat = (dx - ni * nd) * stretch + ni * off;
        let u_flat = (u - ni * ni.dot(u)).normalize_or_zero();
        let (gf, guf) = self.pair_flux(g, flat, r, ni, wi, thick, slab_near, ni, u_flat);
        let gain = self.curvature_gain(g, r, k);
        let curved = (gf * gain, guf * gain);
        // Towards a thin part's far side the images of the pair as it lies
        // take over, and where diffusion theory does not hold they stay.
        let t = g.curvature_share.truncate()
            * ((c - CURVED_COS.0) / (CURVED_COS.1 - CURVED_COS.0)).min(1.0);
        if t == Vec3::ONE {
            return curved;
        }
        let (go, guo) = self.pair_flux(g, dx, r, ni, wi, thick, slab_near, no, u);
        (go + (curved.0 - go) * t, guo + (curved.1 - guo) * t)
    }

    /// The tangential flux factor that a plane lit uniformly along `wi`
    /// would sum to per unit of R_d, along `u`: each term takes it off,
    /// so such a plane flows nothing along its surface, as its depth-only
    /// field says ([`DipoleLanes::oblique_flow`]).
    #[inline]
    fn uniform_flow(&self, ni: Vec3, wi: Vec3, u: Vec3) -> Vec3 {
        match &self.geometry {
            Some(g) if !g.oblique_flow.is_empty() => {
                // u · (the beam's part along the plane), sin θ_t long.
                let cos_t = -wi.dot(ni);
                at_entry_angle(&g.oblique_flow, cos_t) * (u.dot(wi) + u.dot(ni) * cos_t)
            }
            _ => Vec3::ZERO,
        }
    }

    /// 1 + F(r) k per channel ([`crate::curvature`]), for the curvature k
    /// (1/mm, negative where concave), kept within [0, MAX_CURVATURE_GAIN].
    #[inline]
    fn curvature_gain(&self, g: &DipoleLanes, r: f32, k: f32) -> Vec3 {
        (Vec4::ONE + self.lanes_at(&g.curvature, r) * k)
            .clamp(Vec4::ZERO, Vec4::splat(MAX_CURVATURE_GAIN))
            .truncate()
    }

    /// A per-channel table on [`RdTable::eval`]'s grid at `r`, linear
    /// between its points and held at the last.
    #[inline]
    fn lanes_at(&self, table: &[Vec4], r: f32) -> Vec4 {
        let x = r * self.inv_dr;
        let i = (x as usize).min(table.len().saturating_sub(2));
        let t = (x - i as f32).min(1.0);
        table[i] * (1.0 - t) + table[i + 1] * t
    }

    /// [`RdTable::flux_factors`] of one pair as the dipole's images give
    /// it: `slab_near` tells whether x_o lies within half the thickness of
    /// x_i's plane.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn pair_flux(
        &self,
        g: &DipoleLanes,
        dx: Vec3,
        r: f32,
        ni: Vec3,
        wi: Vec3,
        thick: f32,
        slab_near: bool,
        no: Vec3,
        u: Vec3,
    ) -> (Vec3, Vec3) {
        let h = no.dot(dx);
        let c = no.dot(ni);
        let cos_t = -wi.dot(ni);
        let tangential = u != Vec3::ZERO;
        let normal_entry = cos_t > 0.9999;
        let slabby = thick < g.image_reach;
        if !tangential && normal_entry && !slabby && h.abs() < 1e-4 * r.max(1e-3) && c > 0.9999 {
            return (Vec3::ONE, Vec3::ZERO);
        }
        // The beam near its entry, one pair (at its mean depth) beyond.
        let set = if r < g.beam_reach { &g.beam } else { &g.point };
        let planar = self.lanes_at(&set.planar, r);
        // (s_tr d + 1) e^{-s_tr d} / d³.
        let f = |d2: Vec4| {
            let d2 = d2.max(Vec4::splat(1e-12));
            let dd = sqrt4(d2);
            let sd = g.sigma_tr * dd;
            (sd + Vec4::ONE) * exp_neg(sd) / (d2 * dd)
        };
        let s = Vec4::splat;
        let (wdx, ndx, nw, udx, uw, un) = (
            wi.dot(dx),
            ni.dot(dx),
            no.dot(wi),
            u.dot(dx),
            u.dot(wi),
            u.dot(ni),
        );
        let (mut geo, mut flow) = (Vec4::ZERO, Vec4::ZERO);
        // The far boundary's images count as much as x_o's plane faces the
        // entry plane: fully on a slab's far face, not at all on the entry
        // side (where the entry image already is the mirror).
        let exit_w = if r < g.beam_reach { (-c).max(0.0) } else { 0.0 };
        // The slab's images on the entry side of a thin part.
        let slab_w = if slabby && slab_near { c.max(0.0) } else { 0.0 };
        for &(t, w) in set.depths {
            // Source k: s_r = x_i + t z_r w_i; its image s_v = s_r + q n_i.
            let zr = g.z_r * t;
            let q = zr * (2.0 * cos_t) + g.z_v - g.z_r;
            let dr2 = s(r * r) - zr * s(2.0 * wdx) + zr * zr;
            let along_r = s(ndx) + zr * cos_t;
            let dv2 = dr2 - q * along_r * 2.0 + q * q;
            let h_r = s(h) - zr * nw;
            let fr = f(dr2);
            // A source beyond x_o's tangent plane lies outside the object
            // there (a thin part the beam has crossed): it adds nothing.
            let w = Vec4::select(h_r.cmpgt(Vec4::ZERO), s(w), Vec4::ZERO);
            let fv = f(dv2);
            geo += (fr * h_r - fv * (h_r - q * c)) * w;
            if exit_w > 0.0 {
                // Both mirrored across x_o's extrapolated plane (z_b out):
                // a negative image of s_r, a positive one of s_v.
                let zb = (g.z_v - g.z_r) * 0.5;
                let h_v = h_r - q * c;
                let fe = f(dr2 + zb * (h_r + zb) * 4.0);
                let fve = f(dv2 + zb * (h_v + zb) * 4.0);
                geo += (fe * (h_r + zb * 2.0) - fve * (h_v + zb * 2.0)) * (w * exit_w);
            }
            if tangential {
                let u_r = s(udx) - zr * uw;
                flow += (fr * u_r - fv * (u_r - q * un)) * w;
            }
        }
        if slab_w > 0.0 {
            // The images lie far from x_i next to the beam's own depths:
            // one set for the pair at the beam's mean depth (t = 1).
            let zr = g.z_r;
            let q = zr * (2.0 * cos_t) + g.z_v - g.z_r;
            let dr2 = s(r * r) - zr * s(2.0 * wdx) + zr * zr;
            let along_r = s(ndx) + zr * cos_t;
            let h_r = s(h) - zr * nw;
            let u_r = s(udx) - zr * uw;
            let two_l = (s(thick) + g.z_v - g.z_r) * 2.0;
            let w = Vec4::select(h_r.cmpgt(Vec4::ZERO), s(slab_w), Vec4::ZERO);
            for k in SLAB_IMAGES {
                // the pair shifted by m_r = 2 k L along n_i
                let (mr, mv) = (two_l * k, q + two_l * k);
                let fr = f(dr2 - mr * along_r * 2.0 + mr * mr);
                let fv = f(dr2 - mv * along_r * 2.0 + mv * mv);
                geo += (fr * (h_r - mr * c) - fv * (h_r - mv * c)) * w;
                if tangential {
                    flow += (fr * (u_r - mr * un) - fv * (u_r - mv * un)) * w;
                }
            }
        }
        // Back to normal incidence's total over a plane.
        let norm = if normal_entry {
            Vec4::ONE
        } else {
            at_entry_angle(&g.oblique_norm, cos_t)
        };
        let usable = planar.cmpgt(Vec4::ZERO) & geo.is_finite_mask() & norm.is_finite_mask();
        let normal =
            Vec4::select(usable, geo.max(Vec4::ZERO) * norm / planar, Vec4::ONE).truncate();
        if !tangential {
            return (normal, Vec3::ZERO);
        }
        let usable = usable & flow.is_finite_mask();
        let flow = Vec4::select(usable, flow * norm / planar, Vec4::ZERO).truncate();
        (normal, flow - self.uniform_flow(ni, wi, u))
    }

    /// Irradiance interpolation in the near field. The kernel is split as
    /// R = w R + (1 - w) R with a smooth window w (1 out to r_c / 2, a cos²
    /// taper to 0 at r_c = `radius`). The far part is summed over the
    /// samples as before; the near part becomes ∫ w R dA times the mean of
    /// the samples' irradiance, weighted by w R A and the geometry factor:
    ///
    ///   M(x) = Σ_i (1 - w) R G_i E_i A_i + ∫ w R dA · Σ_i w R G_i E_i A_i / Σ_i w R G_i A_i
    ///
    /// (times the oblique kernel's share of the window; the tangential
    /// flux likewise, see `NearSums::finish`).
    ///
    /// The plain sum Σ w R A_i over an irregular (Poisson-disk) set of
    /// points scatters around ∫ w R dA by a few percent from point to point,
    /// and that scatter, at the scale of a few sample spacings, is the
    /// low-frequency mottling of a render; the normalised mean keeps only
    /// the irradiance's variation. The plane's integral stands for the
    /// surface's: r_c is a few sample spacings, well below the curvature
    /// radius of the meshes this is used on.
    pub fn with_near_field(mut self, radius: f32) -> RdTable {
        self.near_radius = radius.max(0.0);
        self.near_integral = if self.near_radius > 0.0 {
            self.radial_integral(self.near_radius, |r| self.near_weight(r))
        } else {
            Vec3::ZERO
        };
        self
    }

    /// ∫ weight(r) R(r) dA over a plane out to `radius` (midpoint rule).
    fn radial_integral(&self, radius: f32, weight: impl Fn(f32) -> f32) -> Vec3 {
        let n = 2048;
        let dr = radius / n as f32;
        (0..n)
            .map(|k| {
                let r = (k as f32 + 0.5) * dr;
                self.eval(r) * (weight(r) * 2.0 * std::f32::consts::PI * r * dr)
            })
            .sum()
    }

    /// The near-field window w(r).
    #[inline]
    pub fn near_weight(&self, r: f32) -> f32 {
        let rc = self.near_radius;
        if rc <= 0.0 || r >= rc {
            0.0
        } else if r <= 0.5 * rc {
            1.0
        } else {
            let c = (std::f32::consts::PI * (r / rc - 0.5)).cos();
            c * c
        }
    }

    #[inline]
    pub fn eval(&self, r: f32) -> Vec3 {
        let x = r * self.inv_dr;
        let i = x as usize;
        if i + 1 >= self.values.len() {
            return Vec3::ZERO;
        }
        let t = x - i as f32;
        self.values[i] * (1.0 - t) + self.values[i + 1] * t
    }
}

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    centroid: Vec3,
    /// Irradiance-weighted mean normal (unit; area-weighted without light).
    normal: Vec3,
    /// Irradiance-weighted mean direction of the entering light (unit).
    entry: Vec3,
    /// Irradiance-weighted mean thickness behind the samples (capped).
    thick: f32,
    /// Summed area.
    area: f32,
    /// Area-weighted mean irradiance.
    e: Vec3,
    /// Leaf: first index in `order`; inner: first child index.
    start: u32,
    /// Leaf: number of points; inner: number of children; `leaf` tells which.
    count: u32,
    leaf: bool,
}

/// The octree of irradiance aggregates.
#[derive(Clone, Debug)]
pub struct DipoleTree {
    nodes: Vec<Node>,
    order: Vec<u32>,
    pos: Vec<Vec3>,
    ea: Vec<Vec3>,
    area: Vec<f32>,
    normal: Vec<Vec3>,
    entry: Vec<Vec3>,
    /// The object's thickness behind each sample (capped at THICK_CAP).
    thick: Vec<f32>,
}

/// A finite stand-in for "no far face" in the nodes' means.
const THICK_CAP: f32 = 1e6;

const LEAF_SIZE: usize = 8;

/// Counters of one query (for the benchmark).
#[derive(Clone, Copy, Debug, Default)]
pub struct QueryStats {
    pub nodes_used: u64,
    pub points_used: u64,
}

impl DipoleTree {
    pub fn new(samples: &SurfaceSamples) -> DipoleTree {
        let n = samples.pos.len();
        let mut tree = DipoleTree {
            nodes: Vec::with_capacity(n / 2 + 1),
            order: (0..n as u32).collect(),
            pos: samples.pos.clone(),
            ea: (0..n)
                .map(|i| samples.irradiance[i] * samples.area[i])
                .collect(),
            area: samples.area.clone(),
            normal: samples.normal.clone(),
            entry: (0..n)
                .map(|i| entry_or_normal(samples.entry.get(i).copied(), samples.normal[i]))
                .collect(),
            thick: (0..n)
                .map(|i| {
                    samples
                        .thickness
                        .get(i)
                        .map_or(THICK_CAP, |t| t.min(THICK_CAP))
                })
                .collect(),
        };
        let area = &samples.area;
        if n > 0 {
            tree.nodes.push(empty_node());
            let mut order = std::mem::take(&mut tree.order);
            tree.build(0, &mut order, 0, n, area, 0);
            tree.order = order;
        }
        tree
    }

    pub fn len(&self) -> usize {
        self.pos.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    fn build(
        &mut self,
        idx: usize,
        order: &mut [u32],
        start: usize,
        end: usize,
        area: &[f32],
        depth: u32,
    ) {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let (mut a_sum, mut ea_sum, mut c_w, mut c_sum, mut c_area) =
            (0.0f32, Vec3::ZERO, 0.0f32, Vec3::ZERO, Vec3::ZERO);
        let (mut n_w, mut n_area, mut entry) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
        let (mut thick_w, mut thick_area) = (0.0f32, 0.0f32);
        for &i in &order[start..end] {
            let (p, a) = (self.pos[i as usize], area[i as usize]);
            lo = lo.min(p);
            hi = hi.max(p);
            a_sum += a;
            ea_sum += self.ea[i as usize];
            let w = luminance(self.ea[i as usize]).max(0.0);
            c_w += w;
            c_sum += p * w;
            c_area += p * a;
            let n = self.normal.get(i as usize).copied().unwrap_or(Vec3::Z);
            n_w += n * w;
            n_area += n * a;
            entry += self.entry[i as usize] * w;
            thick_w += self.thick[i as usize] * w;
            thick_area += self.thick[i as usize] * a;
        }
        let normal = if c_w > 0.0 { n_w } else { n_area }
            .try_normalize()
            .unwrap_or(Vec3::Z);
        // Irradiance-weighted centroid; area-weighted when there is no light.
        let centroid = if c_w > 0.0 {
            c_sum / c_w
        } else {
            c_area / a_sum.max(f32::MIN_POSITIVE)
        };
        let entry = entry_or_normal(Some(entry), normal);
        let thick = if c_w > 0.0 {
            thick_w / c_w
        } else {
            thick_area / a_sum.max(f32::MIN_POSITIVE)
        };
        let mut node = Node {
            lo,
            hi,
            centroid,
            normal,
            entry,
            thick,
            area: a_sum,
            e: ea_sum / a_sum.max(f32::MIN_POSITIVE),
            start: start as u32,
            count: (end - start) as u32,
            leaf: true,
        };
        if end - start <= LEAF_SIZE || depth >= 24 || (hi - lo).max_element() <= 0.0 {
            self.nodes[idx] = node;
            return;
        }
        // Split into octants around the box centre (in-place partition).
        let mid = (lo + hi) * 0.5;
        let octant = |p: Vec3| {
            (p.x > mid.x) as usize | ((p.y > mid.y) as usize) << 1 | ((p.z > mid.z) as usize) << 2
        };
        let slice = &mut order[start..end];
        slice.sort_unstable_by_key(|&i| octant(self.pos[i as usize]));
        let mut bounds = Vec::with_capacity(8);
        let mut s = 0;
        for o in 0..8 {
            let e = s + slice[s..].partition_point(|&i| octant(self.pos[i as usize]) == o);
            if e > s {
                bounds.push((start + s, start + e));
            }
            s = e;
        }
        let first_child = self.nodes.len();
        for _ in 0..bounds.len() {
            self.nodes.push(empty_node());
        }
        node.leaf = false;
        node.start = first_child as u32;
        node.count = bounds.len() as u32;
        self.nodes[idx] = node;
        for (k, (s, e)) in bounds.into_iter().enumerate() {
            self.build(first_child + k, order, s, e, area, depth + 1);
        }
    }

    /// Hierarchical sum M(x) = sum R_d(|x - x_i|) E_i A_i, skipping points
    /// closer than `r_min` (the local disk of the LRF; 0 keeps all). `n` is
    /// the surface normal at x in the mesh's winding, for the geometry
    /// factor ([`RdTable::with_geometry`]).
    pub fn query(&self, x: Vec3, n: Vec3, rd: &RdTable, epsilon: f32, r_min: f32) -> Vec3 {
        self.query_stats(x, n, rd, epsilon, r_min, &mut QueryStats::default())
    }

    pub fn query_stats(
        &self,
        x: Vec3,
        n: Vec3,
        rd: &RdTable,
        epsilon: f32,
        r_min: f32,
        stats: &mut QueryStats,
    ) -> Vec3 {
        self.query_flux(x, n, Vec3::ZERO, rd, epsilon, r_min, stats)
            .0
    }

    /// The hierarchical sum of [`DipoleTree::query`] and beside it the
    /// same sum of the tangential flux along the unit tangent `u` at x:
    /// Σ R_d G_u E_i A_i ([`RdTable::flux_factors`]; 0 when `u` = 0 or
    /// without the geometry), the near field's part included.
    #[allow(clippy::too_many_arguments)]
    pub fn query_flux(
        &self,
        x: Vec3,
        n: Vec3,
        u: Vec3,
        rd: &RdTable,
        epsilon: f32,
        r_min: f32,
        stats: &mut QueryStats,
    ) -> (Vec3, Vec3) {
        if self.nodes.is_empty() {
            return (Vec3::ZERO, Vec3::ZERO);
        }
        let r_min2 = r_min * r_min;
        let r_max2 = rd.r_max * rd.r_max;
        let mut sum = (Vec3::ZERO, Vec3::ZERO);
        let mut nf = NearSums::default();
        let mut stack = Vec::with_capacity(64);
        stack.push(0u32);
        while let Some(k) = stack.pop() {
            let node = &self.nodes[k as usize];
            // Nearest point of the box: skip nodes entirely out of R_d's range.
            let near = x.clamp(node.lo, node.hi);
            let d_near2 = near.distance_squared(x);
            if d_near2 > r_max2 {
                continue;
            }
            let inside = d_near2 == 0.0;
            let dc2 = node.centroid.distance_squared(x);
            // Far: the node's box is clear of the excluded disk and small in solid angle.
            let far_from_disk = r_min == 0.0 || d_near2 > r_min2;
            if !inside && far_from_disk && node.area < epsilon * dc2 {
                let r = dc2.sqrt();
                let g = || {
                    rd.flux_factors(
                        x - node.centroid,
                        r,
                        node.normal,
                        node.entry,
                        node.thick,
                        n,
                        u,
                    )
                };
                let cos_t = -node.entry.dot(node.normal);
                nf.add(rd, r, g, cos_t, node.e * node.area, node.area, &mut sum);
                stats.nodes_used += 1;
                continue;
            }
            if node.leaf {
                for &i in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    let d2 = self.pos[i as usize].distance_squared(x);
                    if d2 >= r_min2 {
                        let i = i as usize;
                        let r = d2.sqrt();
                        let g = || {
                            let (ni, wi) = (self.normal[i], self.entry[i]);
                            rd.flux_factors(x - self.pos[i], r, ni, wi, self.thick[i], n, u)
                        };
                        let cos_t = -self.entry[i].dot(self.normal[i]);
                        nf.add(rd, r, g, cos_t, self.ea[i], self.area[i], &mut sum);
                        stats.points_used += 1;
                    }
                }
            } else {
                for c in node.start..node.start + node.count {
                    stack.push(c);
                }
            }
        }
        let (near, near_u) = nf.finish(rd);
        (sum.0 + near, sum.1 + near_u)
    }

    /// The O(n) sum over every sample (the same estimator, near field
    /// included), for comparison.
    pub fn brute_force(&self, x: Vec3, n: Vec3, rd: &RdTable, r_min: f32) -> Vec3 {
        let r_min2 = r_min * r_min;
        let mut sum = (Vec3::ZERO, Vec3::ZERO);
        let mut nf = NearSums::default();
        for i in 0..self.pos.len() {
            let d2 = self.pos[i].distance_squared(x);
            if d2 >= r_min2 {
                let r = d2.sqrt();
                let (ni, wi) = (self.normal[i], self.entry[i]);
                let g =
                    || rd.flux_factors(x - self.pos[i], r, ni, wi, self.thick[i], n, Vec3::ZERO);
                nf.add(rd, r, g, -wi.dot(ni), self.ea[i], self.area[i], &mut sum);
            }
        }
        sum.0 + nf.finish(rd).0
    }
}

/// √x per lane: one SSE instruction where there is SSE (glam's Vec4 is
/// an __m128 there), four scalar roots elsewhere.
#[inline]
fn sqrt4(x: Vec4) -> Vec4 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        use std::arch::x86_64::{__m128, _mm_sqrt_ps};
        // SAFETY: SSE2 is enabled for this target (the cfg above).
        Vec4::from(unsafe { _mm_sqrt_ps(__m128::from(x)) })
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        Vec4::from_array(x.to_array().map(f32::sqrt))
    }
}

/// e^{-x} per lane for x >= 0 to ~3e-6 relative (2^(-x log2 e) split into
/// an exponent and a Taylor polynomial on [-1/2, 1/2]).
#[inline]
fn exp_neg(x: Vec4) -> Vec4 {
    let t = -x.clamp(Vec4::ZERO, Vec4::splat(87.0)) * std::f32::consts::LOG2_E;
    // Round to nearest by the 1.5 * 2^23 trick: `round` is a libm call per
    // lane where the target has no SSE4.1.
    const SHIFT: f32 = 12_582_912.0;
    let i = (t + Vec4::splat(SHIFT)) - Vec4::splat(SHIFT);
    let f = t - i;
    let p = Vec4::ONE
        + f * (Vec4::splat(std::f32::consts::LN_2)
            + f * (Vec4::splat(0.240_226_5)
                + f * (Vec4::splat(0.055_504_1)
                    + f * (Vec4::splat(0.009_618_1) + f * 0.001_333_4))));
    two_to(i) * p
}

/// 2^i per lane for integral i in [-126, 127], built as the float's bits
/// (the lanes stay in one register: a cast per lane took an eighth of the
/// flux factors' time).
#[inline]
fn two_to(i: Vec4) -> Vec4 {
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        use std::arch::x86_64::{
            __m128, _mm_add_epi32, _mm_castsi128_ps, _mm_cvttps_epi32, _mm_set1_epi32,
            _mm_slli_epi32,
        };
        // SAFETY: SSE2 is enabled for this target (the cfg above).
        unsafe {
            let e = _mm_add_epi32(_mm_cvttps_epi32(__m128::from(i)), _mm_set1_epi32(127));
            Vec4::from(_mm_castsi128_ps(_mm_slli_epi32::<23>(e)))
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        let bits: glam::IVec4 = (i.as_ivec4() + 127) << 23i32;
        Vec4::from_array(bits.to_array().map(|b| f32::from_bits(b as u32)))
    }
}

/// The classic dipole's z_r, z_v and sigma_tr per channel, in the lanes of
/// a vector (lane 3 unused).
#[derive(Clone, Debug)]
struct DipoleLanes {
    z_r: Vec4,
    z_v: Vec4,
    sigma_tr: Vec4,
    /// Sources along the entering beam: (depth in units of z_r, weight).
    /// Beyond this distance (BEAM_REACH z_r of the deepest channel) one
    /// pair stands for the beam.
    beam_reach: f32,
    /// Thickness below which the slab's images join
    /// ([`RdTable::flux_factors`]): beyond it the first image lies more
    /// than `SLAB_IMAGE_DEPTH` diffusion lengths deeper than the source in
    /// every channel.
    image_reach: f32,
    beam: Sources,
    point: Sources,
    /// F(r) of [`crate::curvature::first_order`] per channel (lane 3
    /// unused) on the grid of [`RdTable::eval`].
    curvature: Vec<Vec4>,
    /// How much of each channel's geometry factor the curvature gain of
    /// diffusion theory gives, by the channel's albedo (lane 3 unused):
    /// 1 at a' >= DIFFUSION_ALBEDO, 0 below DIFFUSION_ALBEDO - 0.04; the
    /// rest comes from the dipole's images at the pair as it lies.
    curvature_share: Vec4,
    /// Σ R G dA over a plane lit at normal incidence over that at
    /// cos θ_t = k / (OBLIQUE_STEPS - 1), per channel (lane 3 unused): the
    /// kernel as summed keeps normal incidence's total.
    oblique_norm: Vec<Vec4>,
    /// ∫ w R G dA over a plane lit at cos θ_t = k / (OBLIQUE_STEPS - 1),
    /// over ∫ w R dA (the near field's weight, which takes no G): an
    /// oblique beam's exitance is closer to its entry, so more of it falls
    /// in the near field. Empty without a near field.
    near_oblique: Vec<Vec3>,
    /// ∫ (1 - w) R G_u dA along the beam's tangent over ∫ (1 - w) R dA
    /// and over sin θ_t (w the near field's window), over a plane lit
    /// at cos θ_t = k / (OBLIQUE_STEPS - 1), per channel: what a
    /// uniformly lit plane would flow along its surface, which is
    /// nothing (its field depends on depth only), and each term gives
    /// back ([`RdTable::uniform_flow`]). It is not 0 as summed because
    /// R_d's radial profile (radiative transfer's, or the dipole's on the
    /// table's grid) is not the pairs' own.
    oblique_flow: Vec<Vec3>,
}

/// A set of real sources along the entering light with their images, and
/// its tables.
#[derive(Clone, Debug)]
struct Sources {
    /// (depth in units of z_r, weight).
    depths: &'static [(f32, f32)],
    /// Φ_plane(r) per channel (lane 3 unused) at normal incidence, on the
    /// grid of [`RdTable::eval`].
    planar: Vec<Vec4>,
}

/// Distance, in reduced mean free paths, out to which the beam's sources
/// are summed one by one.
const BEAM_REACH: f32 = 16.0;

/// The sources along an entering beam: depth in units of z_r and weight,
/// the 2-point Gauss-Laguerre rule for ∫ e^{-t} s(t) dt (the beam's
/// exponential attenuation over one reduced mean free path).
const BEAM: [(f32, f32); 2] = [(0.585786, 0.853553), (3.414214, 0.146447)];

/// The orders k of the slab's multipole images summed beside the entry
/// pair (k = 0): the pairs shifted by 2 k L along the entry normal. On a
/// 4 mm sponge sheet (Table 2) orders up to 1, 2, 3, 4 give 1.047, 1.025,
/// 1.021, 1.020 of sim-light's front-lit radiance.
const SLAB_IMAGES: [f32; 6] = [-3.0, -2.0, -1.0, 1.0, 2.0, 3.0];

/// See [`DipoleLanes::image_reach`]: 5 leaves out images that still move a
/// 4 mm skin1 slab's front by 4 %, 8 costs a third more render time on the
/// teapot for no change there.
const SLAB_IMAGE_DEPTH: f64 = 6.5;

/// The albedo a' from which diffusion theory's curvature gain
/// ([`crate::curvature`]) is used in full. The presets below it (skin1's
/// green and blue, ketchup) are low-order scattering, and on the 20 mm
/// sphere against Mitsuba 3 the images at the pair hold better there:
/// skin1's green and blue 0.98 / 0.97 front-lit with them, 0.96 / 0.95
/// with the gain; ketchup's red 1.01 against 0.88.
const DIFFUSION_ALBEDO: f64 = 0.97;

/// Between these n_o · n_i the curvature gain hands over to the pair's
/// own images, linearly: a thin part's far side, or across a strongly
/// curved one.
const CURVED_COS: (f32, f32) = (0.25, 0.5);

/// The largest curvature gain a pair takes (a 20 mm sphere's exact
/// diffusion gives 3.2 at a chord of 30 mm for apple's red).
const MAX_CURVATURE_GAIN: f32 = 4.0;

/// Steps of [`DipoleLanes::oblique_norm`] in cos θ_t.
const OBLIQUE_STEPS: usize = 65;

/// The near field's sums ([`RdTable::with_near_field`]), per channel,
/// each term weighted by w R: A, A times the oblique kernel's share of
/// the window ([`RdTable::near_entry`]), E A, G E A, G A, G_u E A and
/// G_u A.
#[derive(Default)]
struct NearSums {
    a: Vec3,
    share: Vec3,
    e: Vec3,
    ge: Vec3,
    ga: Vec3,
    ue: Vec3,
    ua: Vec3,
}

impl NearSums {
    /// One sample (or node) at distance `r` whose light enters at
    /// cos θ_t = `cos_t`, with E A = `ea` and area `a`: the far part goes
    /// into `sum` (normal and tangential), the near part into the sums.
    /// `g` gives the geometry and tangential factors.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        rd: &RdTable,
        r: f32,
        g: impl FnOnce() -> (Vec3, Vec3),
        cos_t: f32,
        ea: Vec3,
        a: f32,
        sum: &mut (Vec3, Vec3),
    ) {
        let k = rd.eval(r);
        let (g, g_u) = g();
        let w = rd.near_weight(r);
        if w > 0.0 {
            let wk = k * w;
            self.a += wk * a;
            self.share += wk * a * rd.near_entry(cos_t);
            self.e += wk * ea;
            self.ge += wk * g * ea;
            self.ga += wk * g * a;
            self.ue += wk * g_u * ea;
            self.ua += wk * g_u * a;
        }
        let far = k * (1.0 - w);
        sum.0 += far * g * ea;
        sum.1 += far * g_u * ea;
    }

    /// The near field's normal and tangential flux. The total is the
    /// plane's: ∫ w R dA times the oblique kernel's mean share of it.
    /// From G it takes only how G weights the samples' irradiance (an
    /// oblique beam's shift across an irradiance gradient, towards a
    /// terminator): over a few samples a plain Σ w R G E A is as irregular
    /// as the samples, and an oblique beam's own sample, where G is low,
    /// would outweigh the rest. The tangential flux integrates to 0 over
    /// a uniformly lit plane, so only the irradiance's departure from its
    /// mean drives it. Where no sample is near, the plain sums.
    fn finish(&self, rd: &RdTable) -> (Vec3, Vec3) {
        let near = self.a.cmpgt(Vec3::ZERO);
        let a = Vec3::select(near, self.a, Vec3::ONE);
        let mean_e = self.e / a;
        let weighted_e = Vec3::select(self.ga.cmpgt(Vec3::ZERO), self.ge / self.ga, mean_e);
        let i = rd.near_integral;
        (
            Vec3::select(near, i * self.share / a * weighted_e, self.e),
            Vec3::select(near, i * (self.ue - mean_e * self.ua) / a, Vec3::ZERO),
        )
    }
}

/// A table over cos θ_t = k / (OBLIQUE_STEPS - 1), interpolated linearly.
#[inline]
fn at_entry_angle<T>(table: &[T], cos_t: f32) -> T
where
    T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    let x = cos_t.clamp(0.0, 1.0) * (OBLIQUE_STEPS - 1) as f32;
    let i = (x as usize).min(OBLIQUE_STEPS - 2);
    let t = x - i as f32;
    table[i] * (1.0 - t) + table[i + 1] * t
}

/// The unit entry direction from an (unnormalised) weighted sum, or
/// straight in along the normal `n` when there is none or it points out.
fn entry_or_normal(sum: Option<Vec3>, n: Vec3) -> Vec3 {
    match sum.and_then(Vec3::try_normalize) {
        Some(w) if w.dot(n) < -0.05 => w,
        _ => -n,
    }
}

fn empty_node() -> Node {
    Node {
        lo: Vec3::ZERO,
        hi: Vec3::ZERO,
        centroid: Vec3::ZERO,
        normal: Vec3::Z,
        entry: -Vec3::Z,
        thick: THICK_CAP,
        area: 0.0,
        e: Vec3::ZERO,
        start: 0,
        count: 0,
        leaf: true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    fn marble() -> DipoleParams {
        crate::materials::preset("marble").unwrap()
    }

    #[test]
    fn table_matches_the_model_dipole() {
        let p = marble();
        let t = RdTable::new(&p, 0.0);
        for r in [0.0, 0.05, 0.3, 1.0, 4.0, 17.0] {
            let exact = p.rd(r as f64);
            let got = t.eval(r);
            for c in 0..3 {
                let e = exact[c] as f32;
                assert!(
                    (got[c] - e).abs() <= 2e-3 * e + 1e-9,
                    "r {r} c {c}: {} vs {e}",
                    got[c]
                );
            }
        }
        assert_eq!(t.eval(t.r_max * 1.01), Vec3::ZERO);
    }

    #[test]
    fn disk_mean_kernel_keeps_the_integral() {
        // Σ over a grid of samples with the disk-mean kernel ≈ ∫ R_d dA.
        let p = marble();
        let spacing = 0.8f32;
        let rho = spacing / std::f32::consts::PI.sqrt();
        let t = RdTable::new(&p, rho);
        let n = (t.r_max / spacing) as i32 + 2;
        let mut sum = Vec3::ZERO;
        for i in -n..=n {
            for j in -n..=n {
                sum += t.eval(Vec2::new(i as f32, j as f32).length() * spacing) * spacing * spacing;
            }
        }
        for c in 0..3 {
            let total = p.channel(c).total() as f32;
            assert!(
                (sum[c] - total).abs() < 0.01 * total,
                "{c}: {} vs {total}",
                sum[c]
            );
        }
        // Near the centre it is below the sharp peak of the point value.
        assert!(t.eval(0.0).x < p.rd(0.0)[0] as f32);
    }

    /// Radiative transfer's R_d is singular at 0 (single scattering): the
    /// disk mean must still keep its integral, where most of a low albedo's
    /// reflectance lies within a sample's disk (skin1's blue, a' 0.68).
    #[test]
    fn disk_mean_of_the_transport_profile_keeps_the_integral() {
        let mut p = crate::materials::preset("skin1").unwrap();
        p.model = qhm_model::ProfileModel::Transport;
        let integral = |t: &RdTable| {
            let n = 100_000;
            let dr = t.r_max / n as f32;
            (0..n).fold(Vec3::ZERO, |acc, k| {
                let r = (k as f32 + 0.5) * dr;
                acc + t.eval(r) * (2.0 * std::f32::consts::PI * r * dr)
            })
        };
        for rho in [0.1, 0.4, 1.0] {
            let sum = integral(&RdTable::new(&p, rho));
            for c in 0..3 {
                let total = p.subsurface().total(c) as f32;
                assert!(
                    (sum[c] - total).abs() < 0.005 * total,
                    "rho {rho}, {c}: {} vs {total}",
                    sum[c]
                );
            }
        }
        // The point values, interpolated between the table's nodes, are not
        // the profile's integral near its singular core: the check sees it.
        let point = integral(&RdTable::new(&p, 0.0));
        assert!(
            point.z > 1.03 * p.subsurface().total(2) as f32,
            "{}",
            point.z
        );
    }

    #[test]
    fn kernel_with_hole_leaves_out_the_local_disc() {
        // Σ over sample grids (a few offsets of the query) with the holed
        // kernel ≈ ∫ R_d dA outside the disc: R_total - R_disc.
        let p = marble();
        let spacing = 0.3f32;
        let hole = 0.5 / std::f32::consts::PI.sqrt();
        let t = RdTable::with_hole(&p, 2.0 * spacing / std::f32::consts::PI.sqrt(), hole);
        let n = (t.r_max / spacing) as i32 + 2;
        let mut sum = Vec3::ZERO;
        let offsets = [(0.0, 0.0), (0.5, 0.0), (0.25, 0.75), (0.5, 0.5)];
        for (ox, oy) in offsets {
            for i in -n..=n {
                for j in -n..=n {
                    let d = Vec2::new(i as f32 + ox, j as f32 + oy) * spacing;
                    sum += t.eval(d.length()) * spacing * spacing / offsets.len() as f32;
                }
            }
        }
        for c in 0..3 {
            let d = p.channel(c);
            let outside = (d.total() - d.disc_integral(hole as f64)) as f32;
            let disc = (d.disc_integral(hole as f64)) as f32;
            // Within 3 % of the disc's share (which is ~9 % of the total).
            assert!(
                (sum[c] - outside).abs() < 0.03 * disc + 0.002 * outside,
                "{c}: {} vs {outside} (disc {disc})",
                sum[c]
            );
        }
    }

    #[test]
    fn geometry_factor_is_one_on_a_plane_and_follows_the_exit_normal() {
        let p = crate::materials::preset("skin1").unwrap();
        let t = RdTable::new(&p, 0.0).with_geometry(&p);
        // Coplanar: exactly the planar kernel.
        for r in [0.3f32, 2.0, 7.0] {
            let g = t.geometry_factor(Vec3::new(r, 0.0, 0.0), r, Vec3::Z, Vec3::Z);
            assert!((g - Vec3::ONE).abs().max_element() < 1e-5, "{r}: {g}");
        }
        // Across a convex terminator (a sphere of radius 20, 5 mm apart):
        // the real source lies deeper below the exit plane, more leaves.
        let (ra, a) = (20.0f32, 0.25f32);
        let (xi, xo) = (
            Vec3::new(0.0, 0.0, ra),
            Vec3::new(ra * a.sin(), 0.0, ra * a.cos()),
        );
        let g = t.geometry_factor(xo - xi, xo.distance(xi), xi / ra, xo / ra);
        assert!(g.min_element() > 1.0, "{g}");
        // The slab's far face, light entering on the near one: flux leaves
        // along the exit normal, far above the planar kernel at that
        // distance, and an exit normal turned the wrong way gets none.
        let d = Vec3::new(0.0, 0.0, -4.0);
        let through = t.geometry_factor(d, 4.0, Vec3::Z, -Vec3::Z);
        assert!(through.min_element() > 2.0, "{through}");
        // (8 mm down, under a 6 mm ceiling: below every source of the beam.)
        let deep = Vec3::new(0.0, 0.0, -8.0);
        let under = |thick| {
            t.flux_factors(deep, 8.0, Vec3::Z, -Vec3::Z, thick, Vec3::Z, Vec3::ZERO)
                .0
        };
        assert_eq!(under(6.0), Vec3::ZERO);
        // A beam that has crossed a thin part adds only what lies inside:
        // the deepest sources of red, beyond x_o, are left out.
        let thin = Vec3::new(0.0, 0.0, -2.0);
        assert!(
            t.geometry_factor(thin, 2.0, Vec3::Z, -Vec3::Z)
                .min_element()
                > 1.0
        );
        // Without with_geometry: 1.
        let plain = RdTable::new(&p, 0.0);
        assert_eq!(plain.geometry_factor(d, 4.0, Vec3::Z, -Vec3::Z), Vec3::ONE);
    }

    #[test]
    fn a_sphere_gains_what_diffusion_in_a_sphere_gives() {
        // apple on a 20 mm sphere, lit at normal incidence: the kernel as
        // summed (planar R_d times G) against the exact series in the
        // sphere over the half-space's (crate::curvature), at chords of
        // 1-7 mm; the dipole's images alone miss it by up to 8 %.
        let p = crate::materials::preset("apple").unwrap();
        let t = RdTable::new(&p, 0.0).with_geometry(&p);
        let images = RdTable::new(&p, 0.0).with_geometry_without_curvature(&p);
        let ra = 20.0f32;
        let d = p.channel(0);
        let z_b = 0.5 * (d.z_v - d.z_r);
        let rs = [1.0f64, 3.0, 5.0, 7.0];
        let sphere = crate::curvature::sphere_exitance(ra as f64, d.z_r, z_b, d.sigma_tr, &rs);
        let plane = crate::curvature::sphere_exitance(1e4, d.z_r, z_b, d.sigma_tr, &rs);
        let mut worst_images = 0.0f32;
        for (i, &r) in rs.iter().enumerate() {
            let a = 2.0 * (r as f32 / (2.0 * ra)).asin();
            let (xi, xo) = (
                Vec3::new(0.0, 0.0, ra),
                ra * Vec3::new(a.sin(), 0.0, a.cos()),
            );
            let g = |t: &RdTable| {
                t.flux_factors(
                    xo - xi,
                    r as f32,
                    Vec3::Z,
                    -Vec3::Z,
                    2.0 * ra,
                    xo / ra,
                    Vec3::ZERO,
                )
                .0
                .x
            };
            let exact = (sphere[i] / plane[i]) as f32;
            assert!(
                (g(&t) / exact - 1.0).abs() < 0.02,
                "r {r}: {} vs {exact}",
                g(&t)
            );
            worst_images = worst_images.max((g(&images) / exact - 1.0).abs());
        }
        assert!(worst_images > 0.05, "{worst_images}");
    }

    #[test]
    fn oblique_entry_moves_the_exitance_forward_and_keeps_its_total() {
        // A plane lit by a beam refracted to 45°, heading along +x: over
        // the plane, Σ R_d G dA keeps R_total, and its centroid lies ahead
        // of the entry point (the classic pair is symmetric about it).
        let p = crate::materials::preset("skin1").unwrap();
        let t = RdTable::new(&p, 0.0).with_geometry(&p);
        let wi = Vec3::new(1.0, 0.0, -1.0).normalize();
        let (h, n) = (0.02f32, 800);
        let (mut total, mut moment, mut straight) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
        for i in -n..=n {
            for j in -n..=n {
                let dx = Vec3::new(i as f32 + 0.5, j as f32 + 0.5, 0.0) * h;
                let r = dx.length();
                let k = t.eval(r) * h * h;
                let g = t
                    .flux_factors(dx, r, Vec3::Z, wi, f32::INFINITY, Vec3::Z, Vec3::ZERO)
                    .0;
                total += k * g;
                moment += k * g * dx.x;
                straight += k * t.geometry_factor(dx, r, Vec3::Z, Vec3::Z) * dx.x;
            }
        }
        for c in 0..3 {
            let r_total = p.subsurface().total(c) as f32;
            assert!(
                (total[c] - r_total).abs() < 0.03 * r_total,
                "{c}: {total} vs {r_total}"
            );
            let shift = moment[c] / total[c];
            assert!(shift > 0.05, "{c}: centroid {shift} mm");
            assert!(straight[c].abs() < 1e-3 * r_total, "{c}: {straight}");
        }
    }

    #[test]
    fn tangential_flux_points_away_from_the_entry() {
        let p = crate::materials::preset("skin1").unwrap();
        let t = RdTable::new(&p, 0.0).with_geometry(&p);
        let dx = Vec3::new(2.0, 0.0, 0.0);
        let (g, ahead) =
            t.flux_factors(dx, 2.0, Vec3::Z, -Vec3::Z, f32::INFINITY, Vec3::Z, Vec3::X);
        let (_, back) =
            t.flux_factors(dx, 2.0, Vec3::Z, -Vec3::Z, f32::INFINITY, Vec3::Z, -Vec3::X);
        let (_, across) =
            t.flux_factors(dx, 2.0, Vec3::Z, -Vec3::Z, f32::INFINITY, Vec3::Z, Vec3::Y);
        assert!((g - Vec3::ONE).abs().max_element() < 1e-4, "{g}");
        assert!(ahead.min_element() > 0.0, "{ahead}");
        assert!((ahead + back).abs().max_element() < 1e-5, "{ahead} {back}");
        assert!(across.abs().max_element() < 1e-5, "{across}");
        // Without the geometry there is no tangential part.
        let plain = RdTable::new(&p, 0.0);
        let (_, none) =
            plain.flux_factors(dx, 2.0, Vec3::Z, -Vec3::Z, f32::INFINITY, Vec3::Z, Vec3::X);
        assert_eq!(none, Vec3::ZERO);
    }

    #[test]
    fn a_thin_slab_returns_what_the_multipole_says() {
        // Σ R_d G dA over the lit face of a slab T thick, at normal
        // incidence, over the half-space's, against the slab multipole's
        // total reflectance over the half-space's: each source at depth z
        // sends 2π sgn(z) e^{-σ_tr |z|} through the plane.
        let p = crate::materials::preset("apple").unwrap();
        let t = RdTable::new(&p, 0.0).with_geometry(&p);
        let total = |thick: f32| {
            let (n, r_max) = (20_000, t.r_max);
            let dr = r_max / n as f32;
            (0..n).fold(Vec3::ZERO, |acc, i| {
                let r = (i as f32 + 0.5) * dr;
                let dx = Vec3::new(r, 0.0, 0.0);
                let g = t.flux_factors(dx, r, Vec3::Z, -Vec3::Z, thick, Vec3::Z, Vec3::ZERO);
                acc + t.eval(r) * g.0 * (2.0 * std::f32::consts::PI * r * dr)
            })
        };
        let half = total(f32::INFINITY);
        for thick in [2.0f32, 4.0, 8.0] {
            let got = total(thick) / half;
            for c in 0..3 {
                let d = p.channel(c);
                let l = thick as f64 + d.z_v - d.z_r;
                let flux = |z: f64| z.signum() * (-d.sigma_tr * z.abs()).exp();
                let pair = |k: f64| flux(d.z_r - 2.0 * k * l) - flux(-d.z_v - 2.0 * k * l);
                let want = (-3..=3).map(|k| pair(k as f64)).sum::<f64>() / pair(0.0);
                assert!(
                    (got[c] as f64 / want - 1.0).abs() < 0.02,
                    "{thick} mm, channel {c}: {} against the multipole's {want}",
                    got[c]
                );
            }
        }
    }

    /// Poisson-disk samples on a wide flat slab under unit irradiance,
    /// their equal-area radius, and a second set of points to probe at.
    fn lit_slab() -> (SurfaceSamples, f32, SurfaceSamples) {
        let mesh = crate::builtin::slab(60.0, 20.0).unwrap();
        let mut s = crate::points::poisson_disk(&mesh, 20_000, 3);
        s.irradiance = vec![Vec3::ONE; s.pos.len()];
        let radius = (s.mean_area() / std::f32::consts::PI).sqrt();
        (s, radius, crate::points::poisson_disk(&mesh, 3000, 11))
    }

    /// M(x) (green) at the probes on the middle of the slab's top face.
    fn top_exitance(tree: &DipoleTree, t: &RdTable, probe: &SurfaceSamples) -> Vec<f32> {
        probe
            .pos
            .iter()
            .filter(|q| q.z > -1e-3 && q.x.abs() < 8.0 && q.y.abs() < 8.0)
            .map(|&q| tree.brute_force(q, Vec3::Z, t, 0.0).y)
            .collect()
    }

    #[test]
    fn near_field_keeps_the_integral_and_removes_the_sample_pattern() {
        // Poisson-disk samples on a wide flat slab under constant
        // irradiance: M(x) should be R_total everywhere. The plain sum
        // scatters with the sample pattern; the near field's mean does not.
        let p = marble();
        let (s, radius, probe) = lit_slab();
        let tree = DipoleTree::new(&s);
        let plain = RdTable::new(&p, 2.0 * radius);
        let near = RdTable::new(&p, 2.0 * radius).with_near_field(6.0 * radius);
        let stats = |t: &RdTable| {
            let v = top_exitance(&tree, t, &probe);
            let m = v.iter().sum::<f32>() / v.len() as f32;
            let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f32>() / v.len() as f32).sqrt();
            (m, sd / m)
        };
        let total = p.channel(1).total() as f32;
        let (m0, sd0) = stats(&plain);
        let (m1, sd1) = stats(&near);
        assert!((m1 - total).abs() < 0.01 * total, "{m1} vs {total}");
        assert!((m0 - total).abs() < 0.02 * total, "{m0} vs {total}");
        assert!(sd1 < 0.5 * sd0, "scatter {sd1} vs plain {sd0}");
    }

    #[test]
    fn local_areas_take_out_the_darts_density_patches() {
        // The same slab with every sample standing for total / n: the
        // sum follows the darts' denser and sparser patches.
        let p = marble();
        let (s, radius, probe) = lit_slab();
        let mut equal = s.clone();
        equal.area = vec![s.mean_area(); s.pos.len()];
        let t = RdTable::new(&p, 2.0 * radius).with_near_field(6.0 * radius);
        let stats = |samples: &SurfaceSamples| {
            let v = top_exitance(&DipoleTree::new(samples), &t, &probe);
            let m = v.iter().sum::<f32>() / v.len() as f32;
            let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f32>() / v.len() as f32).sqrt();
            (m, sd / m)
        };
        let ((m_local, sd_local), (m_equal, sd_equal)) = (stats(&s), stats(&equal));
        eprintln!("scatter of M: {sd_local} with local areas, {sd_equal} with equal ones");
        assert!(
            (m_local - m_equal).abs() < 0.01 * m_equal,
            "{m_local} vs {m_equal}"
        );
        assert!(sd_local < 0.7 * sd_equal, "{sd_local} vs {sd_equal}");
    }

    #[test]
    fn oblique_light_keeps_the_near_fields_total() {
        // The slab above lit by a beam refracted to 60° from the normal:
        // with the geometry and the near field, M(x) should be what normal
        // incidence gives on the same samples, the oblique kernel's share
        // of the near window included; without that share it is not.
        let p = marble();
        let (mut s, radius, probe) = lit_slab();
        let straight = DipoleTree::new(&s);
        s.entry = vec![Vec3::new(0.75f32.sqrt(), 0.0, -0.5); s.pos.len()];
        let oblique = DipoleTree::new(&s);
        let t = RdTable::new(&p, 2.0 * radius)
            .with_near_field(6.0 * radius)
            .with_geometry(&p);
        let mut flat_near = t.clone();
        flat_near.geometry.as_mut().unwrap().near_oblique.clear();
        let mean = |tree: &DipoleTree, t: &RdTable| {
            let v = top_exitance(tree, t, &probe);
            v.iter().sum::<f32>() / v.len() as f32
        };
        let normal = mean(&straight, &t);
        let (with, without) = (mean(&oblique, &t), mean(&oblique, &flat_near));
        assert!((with - normal).abs() < 0.002 * normal, "{with} vs {normal}");
        assert!(
            (without - normal).abs() > 0.005 * normal,
            "{without} vs {normal}"
        );
    }

    /// The normal and tangential (along +x) flux of the slab's top
    /// summed over the probes that `keep` keeps.
    fn flux_along_x(
        tree: &DipoleTree,
        t: &RdTable,
        probe: &SurfaceSamples,
        keep: impl Fn(&Vec3) -> bool,
        r_min: f32,
    ) -> (Vec3, Vec3) {
        let mut st = QueryStats::default();
        probe
            .pos
            .iter()
            .filter(|q| keep(q))
            .map(|&q| tree.query_flux(q, Vec3::Z, Vec3::X, t, 0.02, r_min, &mut st))
            .fold((Vec3::ZERO, Vec3::ZERO), |a, b| (a.0 + b.0, a.1 + b.1))
    }

    #[test]
    fn the_near_field_carries_the_flow_across_a_shadow_edge() {
        // The slab's top lit for x < 0 only, by a beam refracted to 60°
        // towards +x, with a step (a cast shadow) or a ramp (a terminator);
        // probes just past the edge. With the near field the normal and
        // tangential flux should be what ten times as many samples, each
        // summed with its own G and G_u, give, in the channels whose
        // diffusion length is a few sample spacings or more (skin1's red
        // and green: within 1-6 % normal, 13 % tangential; its blue,
        // 0.7 mm against 0.44 mm spacings, overshoots by 13-49 %). The
        // near window's own flow is a large part of the tangential flux
        // there (without it, 15-54 % short), and the irradiance's plain
        // mean in place of its G-weighted one is 4-26 % short of the
        // normal flux.
        let p = crate::materials::preset("skin1").unwrap();
        let mesh = crate::builtin::slab(60.0, 20.0).unwrap();
        let probe = crate::points::poisson_disk(&mesh, 3000, 11);
        let plain = RdTable::new(&p, 0.0).with_geometry(&p);
        for light in [
            |x: f32| (x < 0.0) as u8 as f32,
            |x: f32| (-x / 20.0).max(0.0),
        ] {
            let edge = |n: usize| {
                let mut s = crate::points::poisson_disk(&mesh, n, 3);
                s.irradiance = s
                    .pos
                    .iter()
                    .map(|x| Vec3::splat(if x.z > -1e-3 { light(x.x) } else { 0.0 }))
                    .collect();
                s.entry = vec![Vec3::new(0.75f32.sqrt(), 0.0, -0.5); s.pos.len()];
                let radius = (s.mean_area() / std::f32::consts::PI).sqrt();
                (DipoleTree::new(&s), radius)
            };
            let ((tree, radius), (dense, _)) = (edge(20_000), edge(200_000));
            let near = RdTable::new(&p, 0.0)
                .with_near_field(6.0 * radius)
                .with_geometry(&p);
            let past_edge = |q: &Vec3| q.z > -1e-3 && q.x > 0.0 && q.x < 2.0 && q.y.abs() < 8.0;
            let sums = |tree: &DipoleTree, t: &RdTable, r_min: f32| {
                flux_along_x(tree, t, &probe, past_edge, r_min)
            };
            let ((mn, mu), (dn, du)) = (sums(&tree, &near, 0.0), sums(&dense, &plain, 0.0));
            let (_, far_u) = sums(&tree, &plain, 6.0 * radius);
            let rel = |a: Vec3, b: Vec3| ((a - b) / b).abs().truncate().max_element();
            eprintln!(
                "near / dense: normal {}, tangential {}; far part alone {}",
                mn / dn,
                mu / du,
                far_u / du
            );
            assert!(rel(mn, dn) < 0.07, "normal {mn} vs {dn}");
            assert!(rel(mu, du) < 0.2, "tangential {mu} vs {du}");
            assert!(rel(far_u, du) > 0.3, "far part alone {far_u} vs {du}");
        }
    }

    #[test]
    fn a_uniformly_lit_plane_flows_nothing_along_its_surface() {
        // The slab's top under a beam refracted to 60°: the field depends
        // on depth only, so the tangential flux along the beam is 0
        // (exact transport with isotropic scattering sees a flat surface
        // alike from every azimuth). Radiative transfer's R_d weighs the
        // pairs' flux by a profile not their own, which leaves a flow
        // unless the uniform plane's share is taken off.
        let p = crate::materials::preset("skin1").unwrap();
        let (mut s, radius, probe) = lit_slab();
        for (e, x) in s.irradiance.iter_mut().zip(&s.pos) {
            *e = if x.z > -1e-3 { Vec3::ONE } else { Vec3::ZERO };
        }
        s.entry = vec![Vec3::new(0.75f32.sqrt(), 0.0, -0.5); s.pos.len()];
        let tree = DipoleTree::new(&s);
        let t = RdTable::new(&p, 0.0)
            .with_near_field(6.0 * radius)
            .with_geometry(&p);
        let mut raw = t.clone();
        raw.geometry.as_mut().unwrap().oblique_flow.clear();
        let middle = |q: &Vec3| q.z > -1e-3 && q.x.abs() < 8.0 && q.y.abs() < 8.0;
        let flow = |t: &RdTable| {
            let (n, u) = flux_along_x(&tree, t, &probe, middle, 0.0);
            (u / n).abs().max_element()
        };
        let (with, without) = (flow(&t), flow(&raw));
        eprintln!(
            "M_u / M_n on a uniformly lit plane: {with} ({without} without the plane's share)"
        );
        assert!(with < 0.003, "M_u / M_n {with}");
        assert!(without > 0.01, "without the plane's share {without}");
    }

    #[test]
    fn fast_exp_is_exp() {
        for k in 0..2000 {
            // Each lane on its own: x, and x offset by a quarter step.
            let x = Vec4::new(0.0, 0.01, 0.02, 0.03) + k as f32 * 0.04;
            let a = exp_neg(x);
            for l in 0..4 {
                let b = (-x[l]).exp();
                assert!(
                    (a[l] - b).abs() <= 5e-6 * b + 1e-37,
                    "{}: {} vs {b}",
                    x[l],
                    a[l]
                );
            }
        }
        assert_eq!(exp_neg(Vec4::splat(200.0)), exp_neg(Vec4::splat(87.0)));
        assert_eq!(exp_neg(Vec4::splat(-3.0)), Vec4::ONE);
        // the exponent's bits, over exp_neg's whole range and beyond
        for i in -126..=127 {
            let v = Vec4::new(i as f32, i as f32, 0.0, -1.0);
            assert_eq!(
                two_to(v),
                Vec4::new(2f32.powi(i), 2f32.powi(i), 1.0, 0.5),
                "{i}"
            );
        }
    }

    #[test]
    fn far_single_node_equals_point() {
        let s = SurfaceSamples {
            pos: vec![Vec3::ZERO],
            normal: vec![Vec3::Z],
            tri: vec![0],
            tangent: Vec::new(),
            area: vec![2.0],
            irradiance: vec![Vec3::ONE],
            entry: Vec::new(),
            thickness: Vec::new(),
            radius: 1.0,
        };
        let tree = DipoleTree::new(&s);
        let rd = RdTable::new(&marble(), 0.0);
        let x = Vec3::new(3.0, 0.0, 0.0);
        assert_eq!(
            tree.query(x, Vec3::Z, &rd, 0.1, 0.0),
            tree.brute_force(x, Vec3::Z, &rd, 0.0)
        );
        assert_eq!(tree.query(x, Vec3::Z, &rd, 0.1, 4.0), Vec3::ZERO);
    }
}
