//! A bounding-volume hierarchy over the object's triangles: binned SAH
//! build (12 bins per axis), flattened depth-first, closest-hit and any-hit
//! traversal with Moller-Trumbore triangle tests.

use glam::Vec3;

/// Triangles per leaf at most.
const LEAF: usize = 4;
/// SAH bins per axis.
const BINS: usize = 12;

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle in `order`; inner: index of the right child
    /// (the left child follows the node).
    start: u32,
    /// Triangles in the leaf; 0 for an inner node.
    count: u32,
}

/// The closest hit of a ray.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub t: f32,
    pub tri: u32,
    /// Barycentric coordinates of corners 1 and 2.
    pub b1: f32,
    pub b2: f32,
}

#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    /// Triangle corners, in leaf order.
    tris: Vec<[Vec3; 3]>,
    /// Original triangle index, in leaf order.
    ids: Vec<u32>,
}

fn bounds_of(t: &[Vec3; 3]) -> (Vec3, Vec3) {
    (t[0].min(t[1]).min(t[2]), t[0].max(t[1]).max(t[2]))
}

fn area(lo: Vec3, hi: Vec3) -> f32 {
    let e = (hi - lo).max(Vec3::ZERO);
    2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
}

impl Bvh {
    pub fn new(tris: &[[Vec3; 3]]) -> Bvh {
        let mut items: Vec<(u32, Vec3, Vec3, Vec3)> = tris
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let (lo, hi) = bounds_of(t);
                (i as u32, lo, hi, (lo + hi) * 0.5)
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF + 1);
        if !items.is_empty() {
            let n = items.len();
            build(&mut items, 0, n, &mut nodes);
        }
        let ids: Vec<u32> = items.iter().map(|i| i.0).collect();
        Bvh {
            nodes,
            tris: ids.iter().map(|&i| tris[i as usize]).collect(),
            ids,
        }
    }

    /// Closest hit with t in (0, t_max).
    pub fn intersect(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        self.traverse(o, d, &mut t_best, |k, t, b1, b2| {
            best = Some(Hit {
                t,
                tri: self.ids[k],
                b1,
                b2,
            });
            false
        });
        best
    }

    /// Whether anything is hit with t in (0, t_max).
    pub fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool {
        let mut t = t_max;
        let mut hit = false;
        self.traverse(o, d, &mut t, |_, _, _, _| {
            hit = true;
            true
        });
        hit
    }

    /// Visits triangles the ray may hit; `on_hit` gets (leaf-order index, t,
    /// b1, b2) of each hit closer than `t_max` (which shrinks to it) and
    /// returns true to stop.
    #[inline]
    fn traverse(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: &mut f32,
        mut on_hit: impl FnMut(usize, f32, f32, f32) -> bool,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let inv = Vec3::ONE / d;
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let ni = stack[sp] as usize;
            let node = &self.nodes[ni];
            if !slab_hit(node.lo, node.hi, o, inv, *t_max) {
                continue;
            }
            if node.count > 0 {
                let s = node.start as usize;
                for k in s..s + node.count as usize {
                    if let Some((t, b1, b2)) = triangle_hit(&self.tris[k], o, d)
                        && t < *t_max
                    {
                        *t_max = t;
                        if on_hit(k, t, b1, b2) {
                            return;
                        }
                    }
                }
            } else if sp + 2 <= stack.len() {
                // near child last, so it is popped first
                let (l, r) = (ni as u32 + 1, node.start);
                let axis = {
                    let e = node.hi - node.lo;
                    if e.x >= e.y && e.x >= e.z {
                        0
                    } else if e.y >= e.z {
                        1
                    } else {
                        2
                    }
                };
                if d[axis] < 0.0 {
                    stack[sp] = l;
                    stack[sp + 1] = r;
                } else {
                    stack[sp] = r;
                    stack[sp + 1] = l;
                }
                sp += 2;
            }
        }
    }
}

#[inline(always)]
fn slab_hit(lo: Vec3, hi: Vec3, o: Vec3, inv: Vec3, t_max: f32) -> bool {
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    let tn = t0.min(t1).max_element().max(0.0);
    let tf = t0.max(t1).min_element().min(t_max);
    // NaN (0 * inf on a slab plane) is treated as a hit
    tn <= tf * 1.000_000_2 || tn.is_nan() || tf.is_nan()
}

/// Moller-Trumbore: (t, b1, b2) for t > 0.
#[inline(always)]
fn triangle_hit(tri: &[Vec3; 3], o: Vec3, d: Vec3) -> Option<(f32, f32, f32)> {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-20 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tri[0];
    let b1 = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let q = s.cross(e1);
    let b2 = d.dot(q) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some((t, b1, b2))
}

fn build(items: &mut [(u32, Vec3, Vec3, Vec3)], first: usize, n: usize, nodes: &mut Vec<Node>) {
    let slice = &mut items[first..first + n];
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let (mut clo, mut chi) = (lo, hi);
    for it in slice.iter() {
        lo = lo.min(it.1);
        hi = hi.max(it.2);
        clo = clo.min(it.3);
        chi = chi.max(it.3);
    }
    let me = nodes.len();
    nodes.push(Node {
        lo,
        hi,
        start: first as u32,
        count: n as u32,
    });
    if n <= LEAF {
        return;
    }
    // binned SAH over the centroid bounds
    let mut best = (f32::INFINITY, 0usize, 0usize);
    let ext = chi - clo;
    for axis in 0..3 {
        if ext[axis] <= 0.0 {
            continue;
        }
        let mut bins = [(
            0usize,
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
        ); BINS];
        let bin_of =
            |c: Vec3| (((c[axis] - clo[axis]) / ext[axis] * BINS as f32) as usize).min(BINS - 1);
        for it in slice.iter() {
            let b = &mut bins[bin_of(it.3)];
            b.0 += 1;
            b.1 = b.1.min(it.1);
            b.2 = b.2.max(it.2);
        }
        let mut right = [(0usize, 0.0f32); BINS];
        let (mut c, mut l, mut h) = (
            0,
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
        );
        for k in (1..BINS).rev() {
            c += bins[k].0;
            l = l.min(bins[k].1);
            h = h.max(bins[k].2);
            right[k] = (c, area(l, h));
        }
        let (mut c, mut l, mut h) = (
            0,
            Vec3::splat(f32::INFINITY),
            Vec3::splat(f32::NEG_INFINITY),
        );
        for k in 0..BINS - 1 {
            c += bins[k].0;
            l = l.min(bins[k].1);
            h = h.max(bins[k].2);
            let (rc, ra) = right[k + 1];
            if c == 0 || rc == 0 {
                continue;
            }
            let cost = c as f32 * area(l, h) + rc as f32 * ra;
            if cost < best.0 {
                best = (cost, axis, k);
            }
        }
    }
    let mid = if best.0.is_finite() {
        let (axis, k) = (best.1, best.2);
        let mut i = 0;
        for j in 0..n {
            let c = slice[j].3[axis];
            let b = (((c - clo[axis]) / ext[axis] * BINS as f32) as usize).min(BINS - 1);
            if b <= k {
                slice.swap(i, j);
                i += 1;
            }
        }
        i
    } else {
        n / 2 // all centroids coincide
    };
    let mid = if mid == 0 || mid == n { n / 2 } else { mid };
    build(items, first, mid, nodes);
    let right = nodes.len() as u32;
    build(items, first + mid, n - mid, nodes);
    nodes[me].start = right;
    nodes[me].count = 0;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::WalkRng;

    fn brute(tris: &[[Vec3; 3]], o: Vec3, d: Vec3) -> Option<(f32, u32)> {
        let mut best: Option<(f32, u32)> = None;
        for (i, t) in tris.iter().enumerate() {
            if let Some((t, _, _)) = triangle_hit(t, o, d)
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, i as u32));
            }
        }
        best
    }

    #[test]
    fn closest_hits_match_brute_force() {
        let mut r = WalkRng::new(5, 5);
        let mut v = || Vec3::new(r.uniform(), r.uniform(), r.uniform()) * 10.0 - 5.0;
        let tris: Vec<[Vec3; 3]> = (0..500)
            .map(|_| {
                let c = v();
                [c, c + v() * 0.2, c + v() * 0.2]
            })
            .collect();
        let bvh = Bvh::new(&tris);
        for _ in 0..2000 {
            let o = v() * 2.0;
            let d = (v() - o * 0.3).normalize();
            let a = bvh.intersect(o, d, f32::INFINITY).map(|h| (h.t, h.tri));
            let b = brute(&tris, o, d);
            assert_eq!(a.map(|x| x.1), b.map(|x| x.1));
            assert_eq!(bvh.occluded(o, d, f32::INFINITY), b.is_some());
        }
    }
}
