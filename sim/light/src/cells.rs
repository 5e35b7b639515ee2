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

use crate::microfacet::{Dielectric, SingleScatteringAlbedo};
use crate::rng::Rng;

mod scan;

#[cfg(target_arch = "x86_64")]
use scan::Avx2;
use scan::{Portable, Scan};

/// Where a line meets a cell wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallHit {
    /// Distance along the (unit) direction, mm.
    pub t: f32,
    /// Unit normal of the wall at the hit, pointing into the cell's air.
    pub normal: Vec3,
}

/// Spheres per [`Block`]: one AVX register per coordinate.
const LANES: usize = 8;

/// Up to eight spheres of one grid cell in lanes (two cache lines), so the
/// tests run without branches; unused lanes hold [`EMPTY`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
struct Block {
    x: [f32; LANES],
    y: [f32; LANES],
    z: [f32; LANES],
    /// Squared radius.
    r2: [f32; LANES],
}

/// A sphere no line reaches and no point lies in (radius 0, far away).
const EMPTY: [f32; 4] = [1e9, 1e9, 1e9, 0.0];

/// The queries' lane arrays on the stack, aligned so that no vector load
/// or store of one splits a cache line.
#[repr(align(64))]
struct Aligned<T>(T);

/// Blocks of a grid cell's list whose pore-crossing intervals `Cells::cross`
/// keeps on the stack (longer lists, rare, keep them on the heap).
const MAX_SWEEP: usize = 8;

/// Side of a grid cell in mean sphere radii, where the lists fit in
/// LIST_BYTES: fewer cells per flight against more spheres per cell. The
/// bench (k paths per CPU s, 1 thread) measured 2.5 best: rice-cake 25.0 at
/// 1.5, 26.5 at 2.5, 25.9 at 3; bread 118, 123, 116 (the sponge is held by
/// LIST_BYTES).
const GRID_RADII: f32 = 2.5;

/// Memory the grid's lists may take (see `Cells::build`): twice a core's
/// 2 MB L2 measured best overall (`qhm sim bench`: sponge 4.1 M collisions
/// per CPU s against 3.1 M at 2 MB, bread equal, rice-cake 1.4 against 1.5).
const LIST_BYTES: f64 = 4.0e6;

/// floor(x) for |x| < 2^31 without a libm call (no SSE4.1 round by default).
#[inline(always)]
fn floor_i(x: f32) -> i32 {
    let i = x as i32;
    i - (x < i as f32) as i32
}

/// floor(x) as a float, the value of `floor_i(x) as f32`, without a
/// conversion to an integer and back where |x| < 2^22: adding and
/// subtracting 1.5 * 2^23 rounds x to the nearest integer.
#[inline(always)]
fn floor_f(x: f32) -> f32 {
    const M: f32 = 12_582_912.0;
    if x.abs() < 4_194_304.0 {
        let r = (x + M) - M;
        r - (r > x) as i32 as f32
    } else {
        floor_i(x) as f32
    }
}

/// A line's walk through the grid cells (Amanatides-Woo) in unbounded cell
/// coordinates of the tile frame, kept as the cell in the tile and the
/// tile it is in; without branches on the signs of the direction, a coin
/// toss per flight.
struct GridWalk {
    /// The grid cell in the tile, per axis.
    cell: [i32; 3],
    /// The tile, per axis (in periods from the starting point's tile).
    tile: [i32; 3],
    step: [i32; 3],
    /// Distance along the line to the next grid plane, per axis.
    t_next: [f32; 3],
    t_delta: [f32; 3],
}

impl GridWalk {
    /// From `q` (in the tile's frame) in grid cell `c` along the unit `d`.
    #[inline(always)]
    fn new(q: Vec3, c: [usize; 3], d: Vec3, g: f32) -> GridWalk {
        let cell = c.map(|c| c as i32);
        let (dv, qv) = ([d.x, d.y, d.z], [q.x, q.y, q.z]);
        // one (vector) division for the three axes
        let inv = (Vec3::ONE / d).to_array();
        GridWalk {
            cell,
            tile: [0; 3],
            step: std::array::from_fn(|a| (dv[a] > 0.0) as i32 - (dv[a] < 0.0) as i32),
            t_next: std::array::from_fn(|a| {
                let wall = (cell[a] + (dv[a] > 0.0) as i32) as f32 * g;
                if dv[a] != 0.0 {
                    (wall - qv[a]) * inv[a]
                } else {
                    f32::INFINITY
                }
            }),
            // (inf along a grid plane: 1 / 0 is inf)
            t_delta: std::array::from_fn(|a| g * inv[a].abs()),
        }
    }

    /// Index of the current grid cell in the tile's lists.
    #[inline(always)]
    fn index(&self, ng: i32) -> usize {
        let n = ng as usize;
        (self.cell[2] as usize * n + self.cell[1] as usize) * n + self.cell[0] as usize
    }

    /// Offset of the current tile from the starting one.
    #[inline(always)]
    fn shift(&self, period: f32) -> Vec3 {
        Vec3::new(
            self.tile[0] as f32,
            self.tile[1] as f32,
            self.tile[2] as f32,
        ) * period
    }

    /// The axis whose grid plane the line meets next, and the distance to it
    /// (where the line leaves the current grid cell).
    #[inline(always)]
    fn exit(&self) -> (usize, f32) {
        let t = &self.t_next;
        let a = if t[0] <= t[1] && t[0] <= t[2] {
            0
        } else if t[1] <= t[2] {
            1
        } else {
            2
        };
        (a, t[a])
    }

    /// Into the next grid cell across axis `a`'s plane.
    #[inline(always)]
    fn advance(&mut self, a: usize, ng: i32) {
        self.cell[a] += self.step[a];
        if self.cell[a] == ng {
            self.cell[a] = 0;
            self.tile[a] += 1;
        } else if self.cell[a] < 0 {
            self.cell[a] = ng - 1;
            self.tile[a] -= 1;
        }
        self.t_next[a] += self.t_delta[a];
    }
}

/// A periodic tiling of air cells (see the module documentation).
#[derive(Debug, Clone)]
pub struct Cells {
    /// Side of the periodic tile, mm.
    pub period: f32,
    /// The wall's boundary: index of the wall material relative to the air
    /// in the cells, and the GGX roughness of the wall surfaces.
    pub wall: Dielectric,
    /// A(u) of `wall`.
    pub albedo: SingleScatteringAlbedo,
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
    inv_l: f32,
    /// First block of each grid cell's list in `blocks` (ng^3 + 1 entries).
    start: Vec<u32>,
    /// Centres (in the tile's frame; periodic images may lie outside it) and
    /// squared radii of the spheres touching each grid cell.
    blocks: Vec<Block>,
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
        // grid: cells GRID_RADII mean radii wide, at most 128
        // per side, and coarser where the lists would outgrow LIST_BYTES:
        // the lookups of a walk land all over the tile, and a cache miss
        // costs more than the tests of a longer list
        let mean_radius = 0.5 * (r0 + r1);
        let list_bytes = |ng: i32| {
            let g = (l / ng as f32) as f64;
            let per_sphere: f64 = centres
                .iter()
                .map(|s| {
                    let r = s[3] as f64;
                    // grid cells within r of a random centre (Steiner formula)
                    let pi = std::f64::consts::PI;
                    (g.powi(3)
                        + 6.0 * g * g * r
                        + 3.0 * pi * g * r * r
                        + 4.0 / 3.0 * pi * r.powi(3))
                        / g.powi(3)
                })
                .sum();
            let cells = (ng as f64).powi(3);
            16.0 * (per_sphere + cells * (LANES - 1) as f64 / 2.0) + 4.0 * cells
        };
        let mut ng = ((l / (GRID_RADII * mean_radius)).floor() as i32).clamp(1, 128);
        while ng > 1 && list_bytes(ng) > LIST_BYTES {
            ng -= 1;
        }
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
        let mut blocks = Vec::new();
        for list in &lists {
            start.push(blocks.len() as u32);
            for chunk in list.chunks(LANES) {
                let mut b = Block {
                    x: [EMPTY[0]; LANES],
                    y: [EMPTY[1]; LANES],
                    z: [EMPTY[2]; LANES],
                    r2: [EMPTY[3]; LANES],
                };
                for (k, s) in chunk.iter().enumerate() {
                    (b.x[k], b.y[k], b.z[k], b.r2[k]) = (s[0], s[1], s[2], s[3]);
                }
                blocks.push(b);
            }
        }
        start.push(blocks.len() as u32);
        let wall = Dielectric::new(eta, roughness);
        Cells {
            period: l,
            albedo: SingleScatteringAlbedo::new(&wall),
            wall,
            porosity: measured,
            count: centres.len(),
            mean_radius,
            ng,
            g,
            inv_g: 1.0 / g,
            inv_l: 1.0 / l,
            start,
            blocks,
        }
    }

    /// The point in the tile's frame and the grid cell it lies in.
    #[inline(always)]
    fn locate_cell(&self, p: Vec3) -> (Vec3, [usize; 3]) {
        let l = self.period;
        let f = |x: f32| floor_f(x * self.inv_l) * l;
        let q = p - Vec3::new(f(p.x), f(p.y), f(p.z));
        let i = |x: f32| ((x * self.inv_g) as i32).clamp(0, self.ng - 1) as usize;
        (q, [i(q.x), i(q.y), i(q.z)])
    }

    /// The point in the tile's frame and the index of its grid cell.
    #[inline(always)]
    fn locate(&self, p: Vec3) -> (Vec3, usize) {
        let (q, [x, y, z]) = self.locate_cell(p);
        let n = self.ng as usize;
        (q, (z * n + y) * n + x)
    }

    /// The first and one-past-last index in `blocks` of a grid cell's list.
    #[inline(always)]
    fn span(&self, cell: usize) -> (usize, usize) {
        (self.start[cell] as usize, self.start[cell + 1] as usize)
    }

    #[inline(always)]
    fn list(&self, cell: usize) -> &[Block] {
        let (b0, b1) = self.span(cell);
        &self.blocks[b0..b1]
    }

    /// Whether `p` lies in the air of a cell.
    #[inline]
    pub fn inside(&self, p: Vec3) -> bool {
        let (q, cell) = self.locate(p);
        self.list(cell).iter().any(|s| {
            // all lanes, then one test (no early exit: they vectorise)
            let i: [bool; LANES] = std::array::from_fn(|j| {
                let (ox, oy, oz) = (q.x - s.x[j], q.y - s.y[j], q.z - s.z[j]);
                ox * ox + oy * oy + oz * oz < s.r2[j]
            });
            i.iter().fold(false, |a, &b| a | b)
        })
    }

    /// From `p` in the wall along the unit direction `d`: the first point
    /// within `t_max` where the line enters a cell, or None. Spheres that
    /// already contain `p` (a point within rounding of a wall) are ignored.
    pub fn first_entry(&self, p: Vec3, d: Vec3, t_max: f32) -> Option<WallHit> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe { self.first_entry_avx2(p, d, t_max) };
        }
        self.first_entry_with::<Portable>(p, d, t_max)
    }

    /// `first_entry` with the AVX2 inner loop (the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn first_entry_avx2(&self, p: Vec3, d: Vec3, t_max: f32) -> Option<WallHit> {
        self.first_entry_with::<Avx2>(p, d, t_max)
    }

    #[inline(always)]
    fn first_entry_with<S: Scan>(&self, p: Vec3, d: Vec3, t_max: f32) -> Option<WallHit> {
        let l = self.period;
        let (q0, c0) = self.locate_cell(p);
        let ng = self.ng;
        let mut walk = GridWalk::new(q0, c0, d, self.g);
        // per lane: nearest entry so far and the index of its block (as a
        // float, exact below 2^24 blocks); the block, lane and tile shift
        // of the nearest
        let mut lanes = Aligned([[t_max; LANES], [0.0f32; LANES]]);
        let [best, which] = &mut lanes.0;
        let mut nearest = t_max;
        let mut hit = (0usize, 0usize, Vec3::ZERO);
        loop {
            let cell = walk.index(ng);
            let shift = walk.shift(l);
            S::entries(
                self.list(cell),
                self.span(cell).0,
                q0 - shift,
                d,
                best,
                which,
            );
            // the first lane of equals (a sphere met again in another grid
            // cell, in another lane, gives the same t): a lane before the
            // kept one, or a new minimum, is from this cell
            let (m, j) = S::first_min(best);
            if m <= nearest {
                if m < nearest || j != hit.1 {
                    hit = (which[j] as i32 as usize, j, shift);
                }
                nearest = m;
            }
            let (a, t_exit) = walk.exit();
            // (a NaN direction ends the walk too)
            if nearest <= t_exit || t_exit >= t_max || t_exit.is_nan() {
                break;
            }
            walk.advance(a, ng);
        }
        if nearest >= t_max {
            return None;
        }
        let x = q0 + d * nearest;
        Some(WallHit {
            t: nearest,
            normal: (self.centre(hit.0, hit.1, hit.2) - x).normalize(),
        })
    }

    /// Centre of the sphere in lane `j` of block `b`, shifted by `shift`.
    #[inline(always)]
    fn centre(&self, b: usize, j: usize, shift: Vec3) -> Vec3 {
        let s = &self.blocks[b];
        Vec3::new(s.x[j], s.y[j], s.z[j]) + shift
    }

    /// The pore crossing: from `p` in the air of a cell along the unit
    /// direction `d`, where the line leaves the union of the cells (it may
    /// pass from cell to overlapping cell), and the normal of the wall it
    /// meets there (into the air it comes from). None when `p` is in no
    /// cell (a point within rounding of a wall).
    pub fn cross(&self, p: Vec3, d: Vec3) -> Option<WallHit> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe { self.cross_avx2(p, d) };
        }
        self.cross_with::<Portable>(p, d)
    }

    /// `cross` with the AVX2 inner loops (the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn cross_avx2(&self, p: Vec3, d: Vec3) -> Option<WallHit> {
        self.cross_with::<Avx2>(p, d)
    }

    #[inline(always)]
    fn cross_with<S: Scan>(&self, p: Vec3, d: Vec3) -> Option<WallHit> {
        let l = self.period;
        let (q0, c0) = self.locate_cell(p);
        let ng = self.ng;
        let mut walk = GridWalk::new(q0, c0, d, self.g);
        // The air along the line is the union of the spheres' intervals
        // [t_in, t_out]. From s = 0 (p is in the air), s moves to the far end
        // of the interval that covers it and reaches furthest, a hair
        // beyond, until no interval covers s. Every sphere that covers a
        // point of the line is in the list of the grid cell the point is in,
        // so the grid cells are taken in the line's order: a cell's spheres
        // wait only for the (predictable) branch that says s has reached it.
        let mut s = 0.0f32;
        // the block, lane and tile shift of the sphere whose interval s last
        // left (its wall is where the line leaves the air)
        let mut last: Option<(usize, usize, Vec3)> = None;
        let mut jumps = 0;
        let mut stack = Aligned([[[0.0f32; LANES]; MAX_SWEEP]; 2]);
        let mut heap: [Vec<[f32; LANES]>; 2] = Default::default();
        'cells: loop {
            let (axis, t_cell) = walk.exit();
            if t_cell.is_nan() {
                // a NaN direction: no grid cell is ever left
                return None;
            }
            if s < t_cell {
                let cell = walk.index(ng);
                let shift = walk.shift(l);
                let (b0, list) = (self.span(cell).0, self.list(cell));
                let n = list.len();
                let [t_in, t_out] = if n <= MAX_SWEEP {
                    let [a, b] = &mut stack.0;
                    [&mut a[..n], &mut b[..n]]
                } else {
                    heap.iter_mut().for_each(|v| v.resize(n, [0.0; LANES]));
                    let [a, b] = &mut heap;
                    [&mut a[..], &mut b[..]]
                };
                S::intervals(list, q0 - shift, d, t_in, t_out);
                loop {
                    let Some((far, k, j)) = S::covering(t_in, t_out, s) else {
                        // no interval covers s: the line leaves the air
                        // here (None: p is in no cell)
                        break 'cells;
                    };
                    s = far + 2e-5;
                    last = Some((b0 + k, j, shift));
                    jumps += 1;
                    if jumps >= 256 {
                        // 256 overlapping cells along one line: give the
                        // last wall met
                        break 'cells;
                    }
                    if s >= t_cell {
                        break;
                    }
                }
            }
            walk.advance(axis, ng);
        }
        let (b, j, shift) = last?;
        Some(WallHit {
            t: s,
            normal: (self.centre(b, j, shift) - (q0 + d * s)).normalize(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells() -> Cells {
        Cells::build(0.75, [0.2, 0.8], 8.0, 1.45, 0.3, 3)
    }

    /// A foam whose grid cells' lists outgrow the crossing's stack.
    fn dense() -> Cells {
        Cells::build(0.95, [0.1, 0.3], 6.0, 1.5, 0.3, 5)
    }

    /// A point in a 30 mm cube around the origin and a unit direction.
    fn random_ray(rng: &mut Rng) -> (Vec3, Vec3) {
        let p = Vec3::new(
            rng.uniform() * 30.0 - 15.0,
            rng.uniform() * 30.0 - 15.0,
            rng.uniform() * 30.0 - 15.0,
        );
        (
            p,
            crate::walk::sample_uniform_sphere([rng.uniform(), rng.uniform()]),
        )
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
        assert_eq!(c.blocks, cells().blocks);
    }

    /// The AVX2 inner loops give the portable ones' bits (the same
    /// arithmetic in the same order), so a capture does not depend on the CPU.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_queries_give_the_portable_bits() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("skipped: this CPU has no AVX2");
            return;
        }
        let mut rng = Rng::new(11, 3);
        let (mut entries, mut crossings) = (0, 0);
        for c in [&cells(), &dense()] {
            for _ in 0..10_000 {
                let (p, d) = random_ray(&mut rng);
                let t_max = rng.uniform() * 4.0;
                let bits = |h: Option<WallHit>| {
                    h.map(|h| (h.t.to_bits(), h.normal.to_array().map(f32::to_bits)))
                };
                // SAFETY: AVX2 is present (checked above)
                let (e, x) = unsafe { (c.first_entry_avx2(p, d, t_max), c.cross_avx2(p, d)) };
                assert_eq!(bits(e), bits(c.first_entry_with::<Portable>(p, d, t_max)));
                assert_eq!(bits(x), bits(c.cross_with::<Portable>(p, d)));
                entries += e.is_some() as usize;
                crossings += x.is_some() as usize;
            }
        }
        assert!(entries > 5000 && crossings > 5000, "{entries} {crossings}");
    }

    /// first_entry and cross against a brute-force march along the line.
    #[test]
    fn wall_hits_match_a_fine_march() {
        march_check(&cells(), 300);
    }

    /// A NaN direction ends both queries (no endless grid walk).
    #[test]
    fn a_nan_direction_ends_the_queries() {
        let c = cells();
        let mut rng = Rng::new(2, 9);
        for d in [Vec3::new(f32::NAN, 0.0, 1.0), Vec3::NAN] {
            for _ in 0..200 {
                let p = Vec3::new(
                    rng.uniform() * 8.0,
                    rng.uniform() * 8.0,
                    rng.uniform() * 8.0,
                );
                assert!(c.cross(p, d).is_none());
                assert!(c.first_entry(p, d, 1.0).is_none());
            }
        }
    }

    /// The same on the dense foam (the crossing's heap path).
    #[test]
    fn wall_hits_match_a_fine_march_in_a_dense_foam() {
        let c = dense();
        let longest = (0..c.start.len() - 1)
            .map(|i| c.list(i).len())
            .max()
            .unwrap();
        assert!(longest > MAX_SWEEP, "{longest} blocks");
        march_check(&c, 100);
    }

    /// Checks of `cross` and `first_entry` (at least `entries` of the latter) at random points.
    fn march_check(c: &Cells, entries: usize) {
        let mut rng = Rng::new(7, 1);
        let mut checked = (0, 0);
        let mut junction = 0usize;
        for _ in 0..3000 {
            let (p, d) = random_ray(&mut rng);
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
        assert!(checked.0 > 1000 && checked.1 > entries, "{checked:?}");
        assert!(junction * 100 < checked.0, "{junction} of {}", checked.0);
    }
}
