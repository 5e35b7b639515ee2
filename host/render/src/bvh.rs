//! A bounding volume hierarchy over the mesh triangles, built top-down with
//! the surface area heuristic over 12 centroid bins per axis, flattened
//! into an array; closest-hit and any-hit (shadow) traversal.

use glam::Vec3;

use crate::mesh::Mesh;

/// A ray `o + t d` (d need not be unit length; t is in units of |d|).
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub o: Vec3,
    pub d: Vec3,
}

/// The closest intersection: triangle index and barycentrics (b1, b2).
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub tri: u32,
    pub b1: f32,
    pub b2: f32,
}

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first index into `order`; inner: index of the left child
    /// (the right child follows the left subtree).
    start: u32,
    /// Leaf: triangle count (> 0); inner: 0, with `right` set.
    count: u32,
    right: u32,
}

/// The BVH; it copies the triangle corners for cache-friendly tests.
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
    corners: Vec<[Vec3; 3]>,
}

const BINS: usize = 12;
const LEAF_MAX: usize = 4;

fn area(lo: Vec3, hi: Vec3) -> f32 {
    let d = (hi - lo).max(Vec3::ZERO);
    2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
}

impl Bvh {
    pub fn new(mesh: &Mesh) -> Bvh {
        let corners: Vec<[Vec3; 3]> = (0..mesh.triangles.len()).map(|t| mesh.corners(t)).collect();
        let centroids: Vec<Vec3> = corners.iter().map(|c| (c[0] + c[1] + c[2]) / 3.0).collect();
        let mut order: Vec<u32> = (0..corners.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * corners.len());
        build(
            &corners,
            &centroids,
            &mut order,
            0,
            corners.len(),
            &mut nodes,
        );
        let corners = order.iter().map(|&i| corners[i as usize]).collect();
        Bvh {
            nodes,
            order,
            corners,
        }
    }

    /// Closest hit with t in (0, t_max).
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut limit = t_max;
        // `traverse` only reports hits closer than every earlier one.
        self.traverse(
            ray,
            |tri, t, b1, b2| {
                best = Some(Hit { t, tri, b1, b2 });
                false
            },
            &mut limit,
        );
        best
    }

    /// True if anything blocks the ray before `t_max`.
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        let mut hit = false;
        let mut limit = t_max;
        self.traverse(
            ray,
            |_, _, _, _| {
                hit = true;
                true
            },
            &mut limit,
        );
        hit
    }

    /// Walks the tree; `on_hit(tri, t, b1, b2)` returns true to stop.
    /// Boxes farther than the closest hit so far are skipped.
    fn traverse(
        &self,
        ray: &Ray,
        mut on_hit: impl FnMut(u32, f32, f32, f32) -> bool,
        t_limit: &mut f32,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let inv = ray.d.recip();
        let mut stack = [0u32; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if !slab_test(node.lo, node.hi, ray.o, inv, *t_limit) {
                continue;
            }
            if node.count > 0 {
                for k in node.start..node.start + node.count {
                    if let Some((t, b1, b2)) = intersect_tri(ray, &self.corners[k as usize])
                        && t < *t_limit
                    {
                        *t_limit = t;
                        if on_hit(self.order[k as usize], t, b1, b2) {
                            return;
                        }
                    }
                }
            } else if sp + 2 <= stack.len() {
                stack[sp] = node.right;
                stack[sp + 1] = node.start;
                sp += 2;
            }
        }
    }
}

fn slab_test(lo: Vec3, hi: Vec3, o: Vec3, inv: Vec3, t_max: f32) -> bool {
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    let tmin = t0.min(t1).max_element().max(0.0);
    let tmax = t0.max(t1).min_element().min(t_max);
    tmin <= tmax
}

/// Moller-Trumbore; returns (t, b1, b2) for t > 0.
fn intersect_tri(ray: &Ray, c: &[Vec3; 3]) -> Option<(f32, f32, f32)> {
    let e1 = c[1] - c[0];
    let e2 = c[2] - c[0];
    let p = ray.d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-20 {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = ray.o - c[0];
    let b1 = s.dot(p) * inv_det;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let q = s.cross(e1);
    let b2 = ray.d.dot(q) * inv_det;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv_det;
    (t > 0.0).then_some((t, b1, b2))
}

fn build(
    corners: &[[Vec3; 3]],
    centroids: &[Vec3],
    order: &mut [u32],
    start: usize,
    end: usize,
    nodes: &mut Vec<Node>,
) -> u32 {
    let idx = nodes.len() as u32;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let (mut clo, mut chi) = (lo, hi);
    for &i in &order[start..end] {
        for p in corners[i as usize] {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        clo = clo.min(centroids[i as usize]);
        chi = chi.max(centroids[i as usize]);
    }
    nodes.push(Node {
        lo,
        hi,
        start: start as u32,
        count: (end - start) as u32,
        right: 0,
    });
    let n = end - start;
    if n <= LEAF_MAX {
        return idx;
    }
    // Binned SAH over the centroid bounds.
    let mut best = (f32::INFINITY, 0usize, 0usize);
    let extent = chi - clo;
    for axis in 0..3 {
        if extent[axis] <= 0.0 {
            continue;
        }
        let mut bins = [(
            0usize,
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
        ); BINS];
        let scale = BINS as f32 / extent[axis];
        for &i in &order[start..end] {
            let b = (((centroids[i as usize][axis] - clo[axis]) * scale) as usize).min(BINS - 1);
            bins[b].0 += 1;
            for p in corners[i as usize] {
                bins[b].1 = bins[b].1.min(p);
                bins[b].2 = bins[b].2.max(p);
            }
        }
        let mut right_cost = [0f32; BINS];
        let (mut rn, mut rlo, mut rhi) = (
            0,
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
        );
        for b in (1..BINS).rev() {
            rn += bins[b].0;
            rlo = rlo.min(bins[b].1);
            rhi = rhi.max(bins[b].2);
            right_cost[b] = rn as f32 * area(rlo, rhi);
        }
        let (mut ln, mut llo, mut lhi) = (
            0,
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
        );
        for b in 0..BINS - 1 {
            ln += bins[b].0;
            llo = llo.min(bins[b].1);
            lhi = lhi.max(bins[b].2);
            if ln == 0 || ln == n {
                continue;
            }
            let cost = ln as f32 * area(llo, lhi) + right_cost[b + 1];
            if cost < best.0 {
                best = (cost, axis, b);
            }
        }
    }
    let leaf_cost = n as f32 * area(lo, hi);
    let mid = if best.0.is_finite() && (best.0 < leaf_cost || n > 16) {
        let (axis, split) = (best.1, best.2);
        let scale = BINS as f32 / extent[axis];
        let slice = &mut order[start..end];
        let mut m = 0;
        for k in 0..slice.len() {
            let c = centroids[slice[k] as usize][axis];
            if (((c - clo[axis]) * scale) as usize).min(BINS - 1) <= split {
                slice.swap(k, m);
                m += 1;
            }
        }
        start + m
    } else if n > 16 {
        // All centroids coincide: split in the middle of the list.
        start + n / 2
    } else {
        return idx;
    };
    nodes[idx as usize].count = 0;
    let left = build(corners, centroids, order, start, mid, nodes);
    let right = build(corners, centroids, order, mid, end, nodes);
    nodes[idx as usize].start = left;
    nodes[idx as usize].right = right;
    idx
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtin::sphere;

    #[test]
    fn rays_hit_a_sphere_where_expected() {
        let m = sphere(10.0, 64, 32).unwrap();
        let bvh = Bvh::new(&m);
        // Sphere centred at (0, 0, 10), radius 10.
        for k in 0..50 {
            let y = -9.0 + 18.0 * k as f32 / 49.0;
            let ray = Ray {
                o: Vec3::new(-50.0, y, 10.0),
                d: Vec3::X,
            };
            let hit = bvh.intersect(&ray, f32::INFINITY).expect("hit");
            let exact = 50.0 - (100.0 - y * y).sqrt();
            assert!((hit.t - exact).abs() < 0.1, "y {y}: {} vs {exact}", hit.t);
            assert!(bvh.occluded(&ray, f32::INFINITY));
            assert!(!bvh.occluded(&ray, exact - 0.2));
        }
        let miss = Ray {
            o: Vec3::new(-50.0, 11.0, 10.0),
            d: Vec3::X,
        };
        assert!(bvh.intersect(&miss, f32::INFINITY).is_none());
    }

    #[test]
    fn bvh_agrees_with_brute_force() {
        let m = crate::builtin::teapot(10.0, 0.1).unwrap();
        let bvh = Bvh::new(&m);
        let mut s = 1u32;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as f32 / u32::MAX as f32
        };
        for _ in 0..300 {
            let o = Vec3::new(
                rnd() * 80.0 - 40.0,
                rnd() * 80.0 - 40.0,
                rnd() * 50.0 - 10.0,
            );
            let d = Vec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize();
            let ray = Ray { o, d };
            let brute = (0..m.triangles.len())
                .filter_map(|t| intersect_tri(&ray, &m.corners(t)).map(|h| h.0))
                .fold(f32::INFINITY, f32::min);
            let got = bvh
                .intersect(&ray, f32::INFINITY)
                .map_or(f32::INFINITY, |h| h.t);
            assert_eq!(got, brute);
        }
    }
}
