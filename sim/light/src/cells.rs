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

/// Where a line meets a cell wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallHit {
    /// Distance along the (unit) direction, mm.
    pub t: f32,
    /// Unit normal of the wall at the hit, pointing into the cell's air.
    pub normal: Vec3,
}

/// Spheres per [`Block`]: one SSE register per coordinate.
const LANES: usize = 4;

/// Up to four spheres of one grid cell in lanes (one cache line), so the
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

/// A lane-wise value; written so that the compiler vectorises it.
#[inline(always)]
fn lanes(f: impl FnMut(usize) -> f32) -> [f32; LANES] {
    std::array::from_fn(f)
}

/// Lane-wise `if m { a } else { b }`.
#[inline(always)]
fn select<T: Copy>(m: [bool; LANES], a: [T; LANES], b: [T; LANES]) -> [T; LANES] {
    std::array::from_fn(|j| if m[j] { a[j] } else { b[j] })
}

/// max(x, 0) for numbers (no NaN handling, unlike `f32::max`).
#[inline(always)]
fn max0(x: f32) -> f32 {
    if x > 0.0 { x } else { 0.0 }
}

/// The smallest lane, for numbers (no NaN handling, unlike `f32::min`).
#[inline(always)]
fn min4(v: [f32; LANES]) -> f32 {
    let m = [
        if v[0] < v[2] { v[0] } else { v[2] },
        if v[1] < v[3] { v[1] } else { v[3] },
    ];
    if m[0] < m[1] { m[0] } else { m[1] }
}

/// Index of the largest lane (the first of equals), without branches.
#[inline(always)]
fn argmax(v: [f32; LANES]) -> usize {
    let mut j = 0;
    for i in 1..LANES {
        j = if v[i] > v[j] { i } else { j };
    }
    j
}

/// Blocks of a grid cell's list whose pore-crossing intervals `Cells::cross`
/// keeps (longer lists take one grid lookup per overlapping cell).
const MAX_SWEEP: usize = 16;

/// Side of a grid cell in mean sphere radii, where the lists fit in
/// LIST_BYTES: fewer cells per flight against more spheres per cell. The
/// bench (M collisions per CPU s) measured 1.5 best: bread 4.58 at 1,
/// 4.76 at 1.5, 4.65 at 2; rice-cake 2.09, 2.14, 2.07 (sponge is held by
/// LIST_BYTES).
const GRID_RADII: f32 = 1.5;

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
        // grid: cells about 1.5 mean radii wide (GRID_RADII), at most 128
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
            let (ox, oy, oz) = (
                lanes(|j| q.x - s.x[j]),
                lanes(|j| q.y - s.y[j]),
                lanes(|j| q.z - s.z[j]),
            );
            let i: [bool; LANES] =
                std::array::from_fn(|j| ox[j] * ox[j] + oy[j] * oy[j] + oz[j] * oz[j] < s.r2[j]);
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
        self.first_entry_body(p, d, t_max)
    }

    /// `first_entry` compiled for AVX2 (the same arithmetic, so the same
    /// bits; about 10 % faster).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn first_entry_avx2(&self, p: Vec3, d: Vec3, t_max: f32) -> Option<WallHit> {
        self.first_entry_body(p, d, t_max)
    }

    #[inline(always)]
    fn first_entry_body(&self, p: Vec3, d: Vec3, t_max: f32) -> Option<WallHit> {
        let l = self.period;
        let (q0, c0) = self.locate_cell(p);
        let ng = self.ng;
        let g = self.g;
        // grid walk (Amanatides-Woo) in unbounded cell coordinates of the
        // tile frame, kept as the cell in the tile (wi) and the tile (k)
        let mut wi = c0.map(|c| c as i32);
        let mut k = [0i32; 3];
        // (without branches: the signs of d are a coin toss per flight)
        let dv = [d.x, d.y, d.z];
        let qv = [q0.x, q0.y, q0.z];
        let step: [i32; 3] = std::array::from_fn(|a| (dv[a] > 0.0) as i32 - (dv[a] < 0.0) as i32);
        let mut t_next: [f32; 3] = std::array::from_fn(|a| {
            let wall = (wi[a] + (dv[a] > 0.0) as i32) as f32 * g;
            if dv[a] != 0.0 {
                (wall - qv[a]) / dv[a]
            } else {
                f32::INFINITY
            }
        });
        let t_delta: [f32; 3] = std::array::from_fn(|a| {
            if dv[a] != 0.0 {
                g / dv[a].abs()
            } else {
                f32::INFINITY
            }
        });
        // per lane: nearest entry so far and the index of its block (as a
        // float, exact below 2^24 blocks); the block, lane and tile shift
        // of the nearest
        let mut best = [t_max; LANES];
        let mut which = [0.0f32; LANES];
        let mut nearest = t_max;
        let mut hit = (0usize, 0usize, Vec3::ZERO);
        let n = ng as usize;
        loop {
            let cell = (wi[2] as usize * n + wi[1] as usize) * n + wi[0] as usize;
            let shift = Vec3::new(k[0] as f32, k[1] as f32, k[2] as f32) * l;
            let o = q0 - shift;
            let b0 = self.span(cell).0;
            for (i, s) in self.list(cell).iter().enumerate() {
                let ox = lanes(|j| o.x - s.x[j]);
                let oy = lanes(|j| o.y - s.y[j]);
                let oz = lanes(|j| o.z - s.z[j]);
                let b = lanes(|j| ox[j] * d.x + oy[j] * d.y + oz[j] * d.z);
                let cc = lanes(|j| ox[j] * ox[j] + oy[j] * oy[j] + oz[j] * oz[j] - s.r2[j]);
                // r^2 - |perpendicular|^2: no cancellation near tangency
                let disc = lanes(|j| {
                    let (px, py, pz) = (ox[j] - d.x * b[j], oy[j] - d.y * b[j], oz[j] - d.z * b[j]);
                    s.r2[j] - (px * px + py * py + pz * pz)
                });
                let t = lanes(|j| -b[j] - max0(disc[j]).sqrt());
                // moving towards the centre, from outside, not missing
                let ok: [bool; LANES] = std::array::from_fn(|j| {
                    (b[j] < 0.0) & (cc[j] > 0.0) & (disc[j] > 0.0) & (t[j] < best[j])
                });
                best = select(ok, t, best);
                which = select(ok, [(b0 + i) as f32; LANES], which);
            }
            let m = min4(best);
            if m <= nearest {
                // the first lane of equals (a sphere met again in another
                // grid cell, in another lane, gives the same t): a lane
                // before the kept one, or a new minimum, is from this cell
                let j = (0..LANES).position(|j| best[j] == m).unwrap_or(0);
                if m < nearest || j != hit.1 {
                    hit = (which[j] as usize, j, shift);
                }
                nearest = m;
            }
            let a = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
                0
            } else if t_next[1] <= t_next[2] {
                1
            } else {
                2
            };
            let t_exit = t_next[a];
            if nearest <= t_exit || t_exit >= t_max {
                break;
            }
            wi[a] += step[a];
            if wi[a] == ng {
                wi[a] = 0;
                k[a] += 1;
            } else if wi[a] < 0 {
                wi[a] = ng - 1;
                k[a] -= 1;
            }
            t_next[a] += t_delta[a];
        }
        if nearest >= t_max {
            return None;
        }
        let s = &self.blocks[hit.0];
        let j = hit.1;
        let x = q0 + d * nearest;
        let c = Vec3::new(s.x[j], s.y[j], s.z[j]) + hit.2;
        Some(WallHit {
            t: nearest,
            normal: (c - x).normalize(),
        })
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
        self.cross_body(p, d)
    }

    /// `cross` compiled for AVX2 (the same arithmetic, so the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn cross_avx2(&self, p: Vec3, d: Vec3) -> Option<WallHit> {
        self.cross_body(p, d)
    }

    #[inline(always)]
    fn cross_body(&self, p: Vec3, d: Vec3) -> Option<WallHit> {
        let mut t = 0.0f32;
        let mut last = Vec3::ZERO;
        let inv_d = Vec3::ONE / d;
        let g = self.g;
        let n = self.ng as usize;
        // per axis: the side of a grid cell the line leaves it by (0 or 1),
        // and the distance to it per unit of coordinate (inf along a plane)
        let dv = [d.x, d.y, d.z];
        let iv = [inv_d.x, inv_d.y, inv_d.z];
        let side: [i32; 3] = std::array::from_fn(|a| (dv[a] > 0.0) as i32);
        let flat: [bool; 3] = std::array::from_fn(|a| dv[a] == 0.0);
        let mut jumps = 0;
        // the line's entry and exit of each sphere in the grid cell, kept to
        // follow the chain of overlapping cells inside the grid cell
        let mut t_in = [[0.0f32; LANES]; MAX_SWEEP];
        let mut t_out = [[0.0f32; LANES]; MAX_SWEEP];
        while jumps < 256 {
            let x = p + d * t;
            let (q, ci) = self.locate_cell(x);
            let cell = (ci[2] * n + ci[1]) * n + ci[0];
            let (b0, list) = (self.span(cell).0, self.list(cell));
            let base = x - q; // tile origin of x
            let sweep = list.len() <= MAX_SWEEP;
            // per lane: the furthest exit of a sphere containing x, and the
            // index of its block (as a float, exact below 2^24 blocks)
            let mut far = [-1.0f32; LANES];
            let mut which = [0.0f32; LANES];
            for (k, s) in list.iter().enumerate() {
                let ox = lanes(|j| q.x - s.x[j]);
                let oy = lanes(|j| q.y - s.y[j]);
                let oz = lanes(|j| q.z - s.z[j]);
                let cc = lanes(|j| ox[j] * ox[j] + oy[j] * oy[j] + oz[j] * oz[j] - s.r2[j]);
                let b = lanes(|j| ox[j] * d.x + oy[j] * d.y + oz[j] * d.z);
                let h = lanes(|j| {
                    let (px, py, pz) = (ox[j] - d.x * b[j], oy[j] - d.y * b[j], oz[j] - d.z * b[j]);
                    s.r2[j] - (px * px + py * py + pz * pz)
                });
                let sq = lanes(|j| max0(h[j]).sqrt());
                let te = lanes(|j| -b[j] + sq[j]);
                let ok: [bool; LANES] = std::array::from_fn(|j| (cc[j] < 0.0) & (te[j] > far[j]));
                far = select(ok, te, far);
                which = select(ok, [(b0 + k) as f32; LANES], which);
                if sweep {
                    let hit: [bool; LANES] = std::array::from_fn(|j| h[j] > 0.0);
                    t_in[k] = select(hit, lanes(|j| -b[j] - sq[j]), [f32::INFINITY; LANES]);
                    t_out[k] = te;
                }
            }
            let j = argmax(far);
            if far[j] < 0.0 {
                // (None: x is in no cell)
                return (jumps > 0).then(|| WallHit {
                    t,
                    normal: (last - (p + d * t)).normalize(),
                });
            }
            // to the far side of the cell reaching furthest, a hair beyond
            let mut s = far[j] + 2e-5;
            let c = &self.blocks[which[j] as usize];
            last = Vec3::new(c.x[j], c.y[j], c.z[j]) + base;
            jumps += 1;
            if sweep {
                // on while the point stays in this grid cell, whose list
                // holds every sphere that can contain it
                let qv = [q.x, q.y, q.z];
                let box_exit = |a: usize| {
                    let wall = (ci[a] as i32 + side[a]) as f32 * g;
                    if flat[a] {
                        f32::INFINITY
                    } else {
                        (wall - qv[a]) * iv[a]
                    }
                };
                let t_box = box_exit(0).min(box_exit(1)).min(box_exit(2)) - 1e-4;
                while s < t_box && jumps < 256 {
                    let mut far = [-1.0f32; LANES];
                    let mut which = [0.0f32; LANES];
                    for k in 0..list.len() {
                        let ok: [bool; LANES] = std::array::from_fn(|j| {
                            (t_in[k][j] < s) & (t_out[k][j] > s) & (t_out[k][j] > far[j])
                        });
                        far = select(ok, t_out[k], far);
                        which = select(ok, [k as f32; LANES], which);
                    }
                    let j = argmax(far);
                    if far[j] < 0.0 {
                        // out of the union by the intervals: the outer
                        // loop's point test (that of `inside`) decides
                        break;
                    }
                    s = far[j] + 2e-5;
                    let b = &list[which[j] as usize];
                    last = Vec3::new(b.x[j], b.y[j], b.z[j]) + base;
                    jumps += 1;
                }
            }
            t += s;
        }
        // 256 overlapping cells along one line: give the last wall met
        Some(WallHit {
            t,
            normal: (last - (p + d * t)).normalize(),
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
        assert_eq!(c.blocks, cells().blocks);
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
