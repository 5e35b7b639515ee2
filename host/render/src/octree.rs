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
    /// Φ_plane(r) per channel (lane 3 unused) on the grid of `values` (with
    /// the geometry).
    planar: Vec<Vec4>,
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
        // Midpoint rule on the disk: equal-area rings x half the angles
        // (the integrand is symmetric about the line to the centre).
        // Finer where the hole's edge cuts through the disk.
        let (n_ring, n_ang) = if hole > 0.0 { (32, 32) } else { (12, 12) };
        let disk: Vec<(f64, f64)> = (0..n_ring)
            .flat_map(|i| {
                let s = rho * ((i as f64 + 0.5) / n_ring as f64).sqrt();
                (0..n_ang).map(move |j| {
                    let phi = std::f64::consts::PI * (j as f64 + 0.5) / n_ang as f64;
                    (s * phi.cos(), s * phi.sin())
                })
            })
            .collect();
        let values = (0..n)
            .into_par_iter()
            .map(|k| {
                let r = k as f64 * dr;
                let v = if rho == 0.0 {
                    g(r)
                } else {
                    let mut acc = [0.0f64; 3];
                    for &(dx, dy) in &disk {
                        let v = g(((r - dx).powi(2) + dy * dy).sqrt());
                        for c in 0..3 {
                            acc[c] += v[c];
                        }
                    }
                    acc.map(|a| a / disk.len() as f64)
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
            planar: Vec::new(),
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
    /// consistently.
    pub fn with_geometry(mut self, params: &DipoleParams) -> RdTable {
        let g: [qhm_model::dipole::Dipole; 3] = std::array::from_fn(|c| params.channel(c));
        let dr = 1.0 / self.inv_dr as f64;
        self.planar = (0..self.values.len())
            .map(|k| {
                let r2 = (k as f64 * dr).powi(2);
                let v: [f32; 3] = std::array::from_fn(|c| {
                    let d = &g[c];
                    let phi = |z: f64| {
                        let dd = (r2 + z * z).sqrt();
                        z * (d.sigma_tr * dd + 1.0) * (-d.sigma_tr * dd).exp() / (dd * dd * dd)
                    };
                    (phi(d.z_r) + phi(d.z_v)) as f32
                });
                Vec3::from(v).extend(0.0)
            })
            .collect();
        let lanes = |f: fn(&qhm_model::dipole::Dipole) -> f64| {
            Vec4::new(f(&g[0]) as f32, f(&g[1]) as f32, f(&g[2]) as f32, 0.0)
        };
        self.geometry = Some(DipoleLanes {
            z_r: lanes(|d| d.z_r),
            z_v: lanes(|d| d.z_v),
            sigma_tr: lanes(|d| d.sigma_tr),
        });
        self
    }

    /// G for a sample at offset `dx` = x_o - x_i with normal `ni`, seen
    /// from a query with normal `no` (see [`RdTable::with_geometry`]). The
    /// three channels go in the lanes of one vector: this is the inner loop
    /// of a render with the geometry factor.
    #[inline]
    fn geometry_factor(&self, dx: Vec3, r: f32, ni: Vec3, no: Vec3) -> Vec3 {
        let Some(g) = &self.geometry else {
            return Vec3::ONE;
        };
        let h = no.dot(dx);
        let c = no.dot(ni);
        if h.abs() < 1e-4 * r.max(1e-3) && c > 0.9999 {
            return Vec3::ONE;
        }
        let along = ni.dot(dx);
        let r2 = r * r;
        let planar = {
            let x = r * self.inv_dr;
            let i = (x as usize).min(self.planar.len().saturating_sub(2));
            let t = (x - i as f32).min(1.0);
            self.planar[i] * (1.0 - t) + self.planar[i + 1] * t
        };
        // z (s_tr d + 1) e^{-s_tr d} / d³ with a signed z.
        let phi = |z: Vec4, d2: Vec4| {
            let d2 = d2.max(Vec4::splat(1e-12));
            let dd = Vec4::from_array(d2.to_array().map(f32::sqrt));
            let sd = g.sigma_tr * dd;
            z * (sd + Vec4::ONE) * exp_neg(sd) / (d2 * dd)
        };
        // Real source s_r = x_i - z_r n_i, image s_v = x_i + z_v n_i.
        let dr2 = g.z_r * (g.z_r + Vec4::splat(2.0 * along)) + Vec4::splat(r2);
        let dv2 = g.z_v * (g.z_v - Vec4::splat(2.0 * along)) + Vec4::splat(r2);
        let geo = phi(Vec4::splat(h) + g.z_r * c, dr2) - phi(Vec4::splat(h) - g.z_v * c, dv2);
        let usable = planar.cmpgt(Vec4::ZERO) & geo.is_finite_mask();
        Vec4::select(usable, geo.max(Vec4::ZERO) / planar, Vec4::ONE).truncate()
    }

    /// Irradiance interpolation in the near field. The kernel is split as
    /// R = w R + (1 - w) R with a smooth window w (1 out to r_c / 2, a cos²
    /// taper to 0 at r_c = `radius`). The far part is summed over the
    /// samples as before; the near part becomes ∫ w R dA times the w R
    /// A-weighted mean of the samples' irradiance:
    ///
    ///   M(x) = Σ_i (1 - w) R E_i A_i + ∫ w R dA · Σ_i w R E_i A_i / Σ_i w R A_i.
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
        self.near_integral = Vec3::ZERO;
        if self.near_radius > 0.0 {
            let n = 2048;
            let dr = self.near_radius / n as f32;
            for k in 0..n {
                let r = (k as f32 + 0.5) * dr;
                self.near_integral +=
                    self.eval(r) * (self.near_weight(r) * 2.0 * std::f32::consts::PI * r * dr);
            }
        }
        self
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
}

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
        let (mut n_w, mut n_area) = (Vec3::ZERO, Vec3::ZERO);
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
        let mut node = Node {
            lo,
            hi,
            centroid,
            normal,
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
        if self.nodes.is_empty() {
            return Vec3::ZERO;
        }
        let r_min2 = r_min * r_min;
        let r_max2 = rd.r_max * rd.r_max;
        let mut sum = Vec3::ZERO;
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
                let g = || rd.geometry_factor(x - node.centroid, r, node.normal, n);
                nf.add(rd, r, g, node.e * node.area, node.area, &mut sum);
                stats.nodes_used += 1;
                continue;
            }
            if node.leaf {
                for &i in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    let d2 = self.pos[i as usize].distance_squared(x);
                    if d2 >= r_min2 {
                        let i = i as usize;
                        let r = d2.sqrt();
                        let g = || rd.geometry_factor(x - self.pos[i], r, self.normal[i], n);
                        nf.add(rd, r, g, self.ea[i], self.area[i], &mut sum);
                        stats.points_used += 1;
                    }
                }
            } else {
                for c in node.start..node.start + node.count {
                    stack.push(c);
                }
            }
        }
        sum + nf.finish(rd)
    }

    /// The O(n) sum over every sample (the same estimator, near field
    /// included), for comparison.
    pub fn brute_force(&self, x: Vec3, n: Vec3, rd: &RdTable, r_min: f32) -> Vec3 {
        let r_min2 = r_min * r_min;
        let mut sum = Vec3::ZERO;
        let mut nf = NearSums::default();
        for i in 0..self.pos.len() {
            let d2 = self.pos[i].distance_squared(x);
            if d2 >= r_min2 {
                let r = d2.sqrt();
                let g = || rd.geometry_factor(x - self.pos[i], r, self.normal[i], n);
                nf.add(rd, r, g, self.ea[i], self.area[i], &mut sum);
            }
        }
        sum + nf.finish(rd)
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
    let bits: glam::IVec4 = (i.as_ivec4() + 127) << 23i32;
    Vec4::from_array(bits.to_array().map(|b| f32::from_bits(b as u32))) * p
}

/// The classic dipole's z_r, z_v and sigma_tr per channel, in the lanes of
/// a vector (lane 3 unused).
#[derive(Clone, Copy, Debug)]
struct DipoleLanes {
    z_r: Vec4,
    z_v: Vec4,
    sigma_tr: Vec4,
}

/// The near field's sums Σ w R E A and Σ w R A ([`RdTable::with_near_field`]).
#[derive(Default)]
struct NearSums {
    ea: Vec3,
    a: Vec3,
}

impl NearSums {
    /// One sample (or node) at distance `r` with E A = `ea` and area `a`:
    /// the far part goes into `sum`, the near part into the sums.
    #[inline]
    /// `g` is the geometry factor, applied to the far part (the near
    /// field is a few sample spacings across, where the surface is flat).
    fn add(
        &mut self,
        rd: &RdTable,
        r: f32,
        g: impl FnOnce() -> Vec3,
        ea: Vec3,
        a: f32,
        sum: &mut Vec3,
    ) {
        let k = rd.eval(r);
        let w = rd.near_weight(r);
        if w >= 1.0 {
            self.ea += k * ea;
            self.a += k * a;
        } else if w > 0.0 {
            let wk = k * w;
            self.ea += wk * ea;
            self.a += wk * a;
            *sum += (k - wk) * g() * ea;
        } else {
            *sum += k * g() * ea;
        }
    }

    /// ∫ w R dA times the weighted mean irradiance (per channel; the plain
    /// sum where no sample is near).
    fn finish(&self, rd: &RdTable) -> Vec3 {
        let f = |ea: f32, a: f32, i: f32| if a > 0.0 { i * ea / a } else { ea };
        Vec3::new(
            f(self.ea.x, self.a.x, rd.near_integral.x),
            f(self.ea.y, self.a.y, rd.near_integral.y),
            f(self.ea.z, self.a.z, rd.near_integral.z),
        )
    }
}

fn empty_node() -> Node {
    Node {
        lo: Vec3::ZERO,
        hi: Vec3::ZERO,
        centroid: Vec3::ZERO,
        normal: Vec3::Z,
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
        assert_eq!(t.geometry_factor(d, 4.0, Vec3::Z, Vec3::Z), Vec3::ZERO);
        // Without with_geometry: 1.
        let plain = RdTable::new(&p, 0.0);
        assert_eq!(plain.geometry_factor(d, 4.0, Vec3::Z, -Vec3::Z), Vec3::ONE);
    }

    #[test]
    fn near_field_keeps_the_integral_and_removes_the_sample_pattern() {
        // Poisson-disk samples on a wide flat slab under constant
        // irradiance: M(x) should be R_total everywhere. The plain sum
        // scatters with the sample pattern; the near field's mean does not.
        let p = marble();
        let mesh = crate::builtin::slab(60.0, 20.0).unwrap();
        let mut s = crate::points::poisson_disk(&mesh, 20_000, 3);
        s.irradiance = vec![Vec3::ONE; s.pos.len()];
        let radius = (s.area[0] / std::f32::consts::PI).sqrt();
        let tree = DipoleTree::new(&s);
        let plain = RdTable::new(&p, 2.0 * radius);
        let near = RdTable::new(&p, 2.0 * radius).with_near_field(6.0 * radius);
        let probe = crate::points::poisson_disk(&mesh, 3000, 11);
        let stats = |t: &RdTable| {
            let v: Vec<f32> = probe
                .pos
                .iter()
                .filter(|q| q.z > -1e-3 && q.x.abs() < 8.0 && q.y.abs() < 8.0)
                .map(|&q| tree.brute_force(q, Vec3::Z, t, 0.0).y)
                .collect();
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
    }

    #[test]
    fn far_single_node_equals_point() {
        let s = SurfaceSamples {
            pos: vec![Vec3::ZERO],
            normal: vec![Vec3::Z],
            tri: vec![0],
            area: vec![2.0],
            irradiance: vec![Vec3::ONE],
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
