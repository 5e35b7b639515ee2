//! Cellular media: air cells in a solid wall material of their own
//! refractive index (a bread crumb, a foam, a puffed rice cake).
//!
//! The cells are overlapping spheres (a Boolean "Swiss cheese" model: the
//! air is the union of the spheres, the walls are what is left), placed
//! uniformly at random in a cube of side `period` that tiles space
//! periodically in x, y and z, so a slab or any object of any size is filled
//! from the same few tens of thousands of spheres. A uniform grid over the
//! tile lists the spheres (with their periodic images) that touch each grid
//! cell.
//!
//! The geometric steps of light through such a medium, all in the frame of
//! the tiling (any point of space, mm):
//! - [`Cells::inside`]: whether a point is in the air of a cell;
//! - [`Cells::first_entry`]: along a segment in the wall, the first point
//!   where it enters a cell, with the wall's normal there;
//! - [`Cells::cross`]: from a point in a cell's air, where the line leaves
//!   the union of the cells (the pore crossing), with the wall's normal there.
//!
//! Normals returned by these functions point into the air (the cell), the
//! convention of [`crate::microfacet::Dielectric`] (outside = air, +z of
//! the local frame). What happens at the wall (reflection or refraction) is
//! the caller's: sample the [`Cells::wall`] dielectric there.

use glam::Vec3;

use crate::microfacet::Dielectric;
use crate::rng::Rng;

/// Where a line meets a cell wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallHit {
    /// Distance along the (unit) direction, mm.
    pub t: f32,
    /// Unit normal of the wall at the hit, pointing into the cell's air.
    pub normal: Vec3,
}

/// A periodic tiling of air cells (see the module documentation).
#[derive(Debug, Clone)]
pub struct Cells {
    /// Side of the periodic tile, mm.
    pub period: f32,
    /// The wall's boundary: index of the wall material relative to the air
    /// in the cells, and the GGX roughness of the wall surfaces.
    pub wall: Dielectric,
    /// Porosity (air volume fraction) of the tile, measured on a lattice.
    pub porosity: f64,
    /// Number of spheres in the tile.
    pub count: usize,
    /// Mean sphere radius, mm.
    pub mean_radius: f32,
    /// Grid cells per tile side and their size.
    ng: i32,
    g: f32,
    inv_g: f32,
    /// Start of each grid cell's list in `spheres` (ng^3 + 1 entries).
    start: Vec<u32>,
    /// Centre (in the tile's frame; periodic images may lie outside it) and
    /// squared radius, per list entry.
    spheres: Vec<[f32; 4]>,
}

impl Cells {
    /// Spheres with radii uniform in `radius_mm`, added until the union
    /// fills `porosity` of the tile (measured on a 96^3 lattice); seeded.
    pub fn build(
        porosity: f64,
        radius_mm: [f64; 2],
        period_mm: f64,
        eta: f32,
        roughness: f32,
        seed: u64,
    ) -> Cells {
        let l = period_mm as f32;
        let [r0, r1] = [radius_mm[0] as f32, radius_mm[1] as f32];
        let mut rng = Rng::new(seed, 0x0063_656c_6c73);
        // porosity lattice
        let m = 96usize;
        let h = l / m as f32;
        let mut air = vec![false; m * m * m];
        let mut filled = 0usize;
        let target = (porosity * (m * m * m) as f64) as usize;
        let mut centres: Vec<[f32; 4]> = Vec::new();
        while filled < target && centres.len() < 4_000_000 {
            let r = r0 + (r1 - r0) * rng.uniform();
            let c = [rng.uniform() * l, rng.uniform() * l, rng.uniform() * l];
            // lattice points within r, with periodic wrap
            let lo = |x: f32| ((x - r) / h - 0.5).floor() as i64;
            let hi = |x: f32| ((x + r) / h - 0.5).ceil() as i64;
            for iz in lo(c[2])..=hi(c[2]) {
                let z = (iz as f32 + 0.5) * h - c[2];
                for iy in lo(c[1])..=hi(c[1]) {
                    let y = (iy as f32 + 0.5) * h - c[1];
                    for ix in lo(c[0])..=hi(c[0]) {
                        let x = (ix as f32 + 0.5) * h - c[0];
                        if x * x + y * y + z * z <= r * r {
                            let w = |i: i64| i.rem_euclid(m as i64) as usize;
                            let k = (w(iz) * m + w(iy)) * m + w(ix);
                            if !air[k] {
                                air[k] = true;
                                filled += 1;
                            }
                        }
                    }
                }
            }
            centres.push([c[0], c[1], c[2], r]);
        }
        let measured = filled as f64 / (m * m * m) as f64;
        // grid: cells about the mean radius wide (as fast as half of it, with
        // a quarter of the memory), at most 128 per side
        let mean_radius = 0.5 * (r0 + r1);
        let ng = ((l / mean_radius).floor() as i32).clamp(1, 128);
        let g = l / ng as f32;
        let n3 = (ng * ng * ng) as usize;
        let mut lists: Vec<Vec<[f32; 4]>> = vec![Vec::new(); n3];
        for s in &centres {
            let r = s[3];
            let lo = |x: f32| ((x - r) / g).floor() as i32;
            let hi = |x: f32| ((x + r) / g).floor() as i32;
            for iz in lo(s[2])..=hi(s[2]) {
                for iy in lo(s[1])..=hi(s[1]) {
                    for ix in lo(s[0])..=hi(s[0]) {
                        // distance from the centre to the grid cell (unbounded coordinates)
                        let d = |i: i32, c: f32| {
                            let (a, b) = (i as f32 * g, (i + 1) as f32 * g);
                            if c < a {
                                a - c
                            } else if c > b {
                                c - b
                            } else {
                                0.0
                            }
                        };
                        let (dx, dy, dz) = (d(ix, s[0]), d(iy, s[1]), d(iz, s[2]));
                        if dx * dx + dy * dy + dz * dz > r * r {
                            continue;
                        }
                        // the tile cell and the image of the sphere in its frame
                        let (kx, ky, kz) =
                            (ix.div_euclid(ng), iy.div_euclid(ng), iz.div_euclid(ng));
                        let w = |i: i32| i.rem_euclid(ng) as usize;
                        let cell = (w(iz) * ng as usize + w(iy)) * ng as usize + w(ix);
                        lists[cell].push([
                            s[0] - kx as f32 * l,
                            s[1] - ky as f32 * l,
                            s[2] - kz as f32 * l,
                            r * r,
                        ]);
                    }
                }
            }
        }
        let mut start = Vec::with_capacity(n3 + 1);
        let mut spheres = Vec::new();
        for list in &lists {
            start.push(spheres.len() as u32);
            spheres.extend_from_slice(list);
        }
        start.push(spheres.len() as u32);
        Cells {
            period: l,
            wall: Dielectric::new(eta, roughness),
            porosity: measured,
            count: centres.len(),
            mean_radius,
            ng,
            g,
            inv_g: 1.0 / g,
            start,
            spheres,
        }
    }

    /// The point in the tile's frame and the tile cell it lies in.
    #[inline(always)]
    fn locate(&self, p: Vec3) -> (Vec3, usize) {
        let l = self.period;
        let q = p - (p / l).floor() * l;
        let i = |x: f32| ((x * self.inv_g) as i32).clamp(0, self.ng - 1) as usize;
        let n = self.ng as usize;
        (q, (i(q.z) * n + i(q.y)) * n + i(q.x))
    }

    #[inline(always)]
    fn list(&self, cell: usize) -> &[[f32; 4]] {
        &self.spheres[self.start[cell] as usize..self.start[cell + 1] as usize]
    }

    /// Whether `p` lies in the air of a cell.
    #[inline]
    pub fn inside(&self, p: Vec3) -> bool {
        let (q, cell) = self.locate(p);
        self.list(cell).iter().any(|s| {
            let o = q - Vec3::new(s[0], s[1], s[2]);
            o.length_squared() < s[3]
        })
    }

    /// From `p` in the wall along the unit direction `d`: the first point
    /// within `t_max` where the line enters a cell, or None. Spheres that
    /// already contain `p` (a point within rounding of a wall) are ignored.
    pub fn first_entry(&self, p: Vec3, d: Vec3, t_max: f32) -> Option<WallHit> {
        let l = self.period;
        let q0 = p - (p / l).floor() * l;
        let ng = self.ng;
        let g = self.g;
        // grid walk (Amanatides-Woo) in unbounded cell coordinates of the tile frame
        let cell0 = |x: f32| ((x * self.inv_g) as i32).clamp(0, ng - 1);
        let mut ci = [cell0(q0.x), cell0(q0.y), cell0(q0.z)];
        let dv = [d.x, d.y, d.z];
        let qv = [q0.x, q0.y, q0.z];
        let mut step = [0i32; 3];
        let mut t_next = [f32::INFINITY; 3];
        let mut t_delta = [f32::INFINITY; 3];
        for a in 0..3 {
            if dv[a] > 0.0 {
                step[a] = 1;
                t_next[a] = ((ci[a] + 1) as f32 * g - qv[a]) / dv[a];
                t_delta[a] = g / dv[a];
            } else if dv[a] < 0.0 {
                step[a] = -1;
                t_next[a] = (ci[a] as f32 * g - qv[a]) / dv[a];
                t_delta[a] = -g / dv[a];
            }
        }
        let mut best = t_max;
        let mut hit: Option<Vec3> = None;
        let n = ng as usize;
        loop {
            let w = |i: i32| i.rem_euclid(ng) as usize;
            let cell = (w(ci[2]) * n + w(ci[1])) * n + w(ci[0]);
            let shift = Vec3::new(
                ci[0].div_euclid(ng) as f32,
                ci[1].div_euclid(ng) as f32,
                ci[2].div_euclid(ng) as f32,
            ) * l;
            let o = q0 - shift;
            for s in self.list(cell) {
                let c = Vec3::new(s[0], s[1], s[2]);
                let oc = o - c;
                let b = oc.dot(d);
                if b >= 0.0 {
                    continue; // moving away from the centre
                }
                let cc = oc.length_squared() - s[3];
                if cc <= 0.0 {
                    continue;
                }
                // r^2 - |perpendicular|^2: no cancellation near tangency
                let disc = s[3] - (oc - d * b).length_squared();
                if disc <= 0.0 {
                    continue;
                }
                let t = -b - disc.sqrt();
                if t < best {
                    best = t;
                    hit = Some(c + shift);
                }
            }
            let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
                0
            } else if t_next[1] <= t_next[2] {
                1
            } else {
                2
            };
            let t_exit = t_next[a];
            if best <= t_exit || t_exit >= t_max {
                break;
            }
            ci[a] += step[a];
            t_next[a] += t_delta[a];
        }
        hit.map(|c| {
            let x = q0 + d * best;
            WallHit {
                t: best,
                normal: (c - x).normalize(),
            }
        })
    }

    /// The pore crossing: from `p` in the air of a cell along the unit
    /// direction `d`, where the line leaves the union of the cells (it may
    /// pass from cell to overlapping cell), and the normal of the wall it
    /// meets there (into the air it comes from). None when `p` is in no
    /// cell (a point within rounding of a wall).
    pub fn cross(&self, p: Vec3, d: Vec3) -> Option<WallHit> {
        let mut t = 0.0f32;
        let mut last: Option<Vec3> = None;
        let l = self.period;
        for _ in 0..256 {
            let x = p + d * t;
            let (q, cell) = self.locate(x);
            let base = x - q; // tile origin of x
            let mut far = -1.0f32;
            let mut centre = Vec3::ZERO;
            for s in self.list(cell) {
                let c = Vec3::new(s[0], s[1], s[2]);
                let oc = q - c;
                let cc = oc.length_squared() - s[3];
                if cc >= 0.0 {
                    continue;
                }
                let b = oc.dot(d);
                let te = -b + (s[3] - (oc - d * b).length_squared()).max(0.0).sqrt();
                if te > far {
                    far = te;
                    centre = c + base;
                }
            }
            if far < 0.0 {
                let _ = l;
                return last.map(|c| {
                    let y = p + d * t;
                    WallHit {
                        t,
                        normal: (c - y).normalize(),
                    }
                });
            }
            // to the far side of the cell reaching furthest, a hair beyond
            t += far + 2e-5;
            last = Some(centre);
        }
        // 256 overlapping cells along one line: give the last wall met
        last.map(|c| WallHit {
            t,
            normal: (c - (p + d * t)).normalize(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells() -> Cells {
        Cells::build(0.75, [0.2, 0.8], 8.0, 1.45, 0.3, 3)
    }

    #[test]
    fn porosity_hits_its_target_and_sampled_points_agree() {
        let c = cells();
        assert!((c.porosity - 0.75).abs() < 0.01, "{}", c.porosity);
        // the grid's inside test against the lattice measure, over several tiles
        let mut rng = Rng::new(5, 5);
        let n = 40_000;
        let hits = (0..n)
            .filter(|_| {
                let p = Vec3::new(
                    rng.uniform() * 40.0 - 20.0,
                    rng.uniform() * 40.0 - 20.0,
                    -rng.uniform() * 20.0,
                );
                c.inside(p)
            })
            .count();
        let f = hits as f64 / n as f64;
        assert!((f - c.porosity).abs() < 0.012, "{f} vs {}", c.porosity);
        // periodic: the same answer one period away
        for _ in 0..2000 {
            let p = Vec3::new(
                rng.uniform() * 8.0,
                rng.uniform() * 8.0,
                rng.uniform() * 8.0,
            );
            assert_eq!(c.inside(p), c.inside(p + Vec3::new(8.0, -16.0, 24.0)));
        }
        // same seed, same tile
        assert_eq!(c.spheres, cells().spheres);
    }

    /// first_entry and cross against a brute-force march along the line.
    #[test]
    fn wall_hits_match_a_fine_march() {
        let c = cells();
        let mut rng = Rng::new(7, 1);
        let mut checked = (0, 0);
        let mut junction = 0usize;
        for _ in 0..3000 {
            let p = Vec3::new(
                rng.uniform() * 30.0 - 15.0,
                rng.uniform() * 30.0 - 15.0,
                rng.uniform() * 30.0 - 15.0,
            );
            let d = crate::walk::sample_uniform_sphere([rng.uniform(), rng.uniform()]);
            let march = |from_inside: bool| {
                let mut t = 0.0f32;
                while t < 6.0 {
                    if c.inside(p + d * t) != from_inside {
                        return Some(t);
                    }
                    t += 1e-3;
                }
                None
            };
            // A march of 1 um steps can step over slivers thinner than that,
            // so it may find a later wall than the exact one, never an earlier.
            if c.inside(p) {
                let h = c.cross(p, d).unwrap();
                if let Some(tm) = march(true) {
                    assert!(tm >= h.t - 2e-3, "cross {} beyond the march's {tm}", h.t);
                    assert!(!c.inside(p + d * h.t) && c.inside(p + d * (h.t - 1e-4)));
                    assert!((h.t - tm).abs() < 2e-3 || c.inside(p + d * (h.t + 1e-3)));
                    // the normal points back into the air
                    // (near a junction of cells, the wall side may be another cell)
                    assert!(c.inside(p + d * h.t + h.normal * 1e-4));
                    junction += c.inside(p + d * h.t - h.normal * 1e-4) as usize;
                    checked.0 += 1;
                }
            } else {
                let h = c.first_entry(p, d, 6.0);
                match (h, march(false)) {
                    (Some(h), Some(tm)) => {
                        assert!(tm >= h.t - 2e-3, "entry {} beyond the march's {tm}", h.t);
                        // (a grazing entry's point is uncertain along the line)
                        let graze = h.normal.dot(d) < 0.05;
                        assert!(c.inside(p + d * (h.t + 1e-4)) || graze, "{h:?} {tm}");
                        assert!(!c.inside(p + d * (h.t - 1e-4)) || graze, "{h:?} {tm}");
                        assert!(h.normal.dot(d) > 0.0, "the normal points into the cell");
                        checked.1 += 1;
                    }
                    (None, None) => {}
                    (None, Some(tm)) => panic!("no entry, the march enters at {tm}"),
                    (Some(h), None) => {
                        // a grazing sliver the march steps over
                        assert!(h.normal.dot(d) < 0.05, "{h:?}");
                    }
                }
            }
        }
        assert!(checked.0 > 1000 && checked.1 > 300, "{checked:?}");
        assert!(junction * 100 < checked.0, "{junction} of {}", checked.0);
    }
}
