//! The top surface as a height field z = h(x, y) over the sample's
//! footprint: ray intersection from the air, segment crossing from inside,
//! visibility towards a camera, and normals. A flat field takes fast paths.

use glam::Vec3;

use crate::medium::Sphere;
use crate::rng::Rng;

#[derive(Debug, Clone)]
pub struct HeightField {
    /// Half extents of the footprint, mm.
    pub half: [f32; 2],
    pub cell: f32,
    pub n: [usize; 2],
    /// Heights at grid nodes, row-major in y; empty if flat.
    pub h: Vec<f32>,
    pub h_min: f32,
    pub h_max: f32,
    /// Height of a flat field (targets: the two-height plane uses `steps`).
    pub flat_height: f32,
    /// Two-height target: y < 0 at steps.0, y >= 0 at steps.1.
    pub steps: Option<(f32, f32)>,
    /// Minimum height over tiles of TILE x TILE cells (row-major), so
    /// segments well below the local surface skip the ray march.
    pub tile_min: Vec<f32>,
    pub tiles: [usize; 2],
}

/// Cells per side of a `tile_min` tile.
const TILE: usize = 8;

impl HeightField {
    pub fn flat(half: [f32; 2], height: f32) -> Self {
        HeightField {
            half,
            cell: 1.0,
            n: [0, 0],
            h: vec![],
            h_min: height,
            h_max: height,
            flat_height: height,
            steps: None,
            tile_min: vec![],
            tiles: [0, 0],
        }
    }

    pub fn two_steps(half: [f32; 2], low: f32, high: f32) -> Self {
        HeightField {
            steps: Some((low, high)),
            h_min: low.min(high),
            h_max: low.max(high),
            ..HeightField::flat(half, low)
        }
    }

    /// Random smooth bumps (sum of 16 sinusoids, rms `amplitude`, wavelengths
    /// around `scale`) and pores carved where open void spheres cut the top.
    pub fn relief(
        half: [f32; 2],
        cell: f32,
        amplitude: f32,
        scale: f32,
        pores: &[Sphere],
        seed: u64,
    ) -> Self {
        let n = [
            (2.0 * half[0] / cell).ceil() as usize + 1,
            (2.0 * half[1] / cell).ceil() as usize + 1,
        ];
        let mut rng = Rng::new(seed, 0x6865_6967_6874);
        let waves: Vec<(f32, f32, f32)> = (0..16)
            .map(|_| {
                let k = std::f32::consts::TAU / (scale * (0.6 + 0.8 * rng.uniform()));
                let th = std::f32::consts::TAU * rng.uniform();
                (
                    k * th.cos(),
                    k * th.sin(),
                    std::f32::consts::TAU * rng.uniform(),
                )
            })
            .collect();
        // rms of a sum of 16 unit sinusoids is sqrt(8)
        let a = amplitude / 8f32.sqrt();
        let mut h = vec![0f32; n[0] * n[1]];
        for j in 0..n[1] {
            let y = j as f32 * cell - half[1];
            for i in 0..n[0] {
                let x = i as f32 * cell - half[0];
                h[j * n[0] + i] = a * waves
                    .iter()
                    .map(|(kx, ky, p)| (kx * x + ky * y + p).sin())
                    .sum::<f32>();
            }
        }
        for s in pores {
            let r = s.radius;
            let (i0, i1) = (
                ((s.centre[0] - r + half[0]) / cell).floor().max(0.0) as usize,
                (((s.centre[0] + r + half[0]) / cell).ceil() as usize).min(n[0]),
            );
            let (j0, j1) = (
                ((s.centre[1] - r + half[1]) / cell).floor().max(0.0) as usize,
                (((s.centre[1] + r + half[1]) / cell).ceil() as usize).min(n[1]),
            );
            for j in j0..j1 {
                let y = j as f32 * cell - half[1];
                for i in i0..i1 {
                    let x = i as f32 * cell - half[0];
                    let d2 = (x - s.centre[0]).powi(2) + (y - s.centre[1]).powi(2);
                    if d2 < r * r {
                        // the sphere's floor, where it lies below the bumpy top
                        let floor = s.centre[2] - (r * r - d2).sqrt();
                        let top = s.centre[2] + (r * r - d2).sqrt();
                        let v = &mut h[j * n[0] + i];
                        if top > *v && floor < *v {
                            *v = floor;
                        }
                    }
                }
            }
        }
        let h_min = h.iter().copied().fold(f32::INFINITY, f32::min);
        let h_max = h.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        // tile minima over the nodes a bilinear lookup in the tile can touch
        let tiles = [(n[0] - 1).div_ceil(TILE), (n[1] - 1).div_ceil(TILE)];
        let mut tile_min = vec![f32::INFINITY; tiles[0] * tiles[1]];
        for j in 0..n[1] {
            for i in 0..n[0] {
                let v = h[j * n[0] + i];
                // node (i, j) borders tiles (i-1)/T..=i/T in each direction
                for tj in (j.saturating_sub(1) / TILE)..=(j / TILE).min(tiles[1] - 1) {
                    for ti in (i.saturating_sub(1) / TILE)..=(i / TILE).min(tiles[0] - 1) {
                        let m = &mut tile_min[tj * tiles[0] + ti];
                        *m = m.min(v);
                    }
                }
            }
        }
        HeightField {
            half,
            cell,
            n,
            h,
            h_min,
            h_max,
            flat_height: 0.0,
            steps: None,
            tile_min,
            tiles,
        }
    }

    /// Lowest surface height over the tiles covering an xy box.
    #[inline]
    fn min_over(&self, x0: f32, x1: f32, y0: f32, y1: f32) -> f32 {
        if self.tile_min.is_empty() {
            return self.h_min;
        }
        let ts = self.cell * TILE as f32;
        let ix = |x: f32, m: usize| (((x + self.half[0]) / ts).max(0.0) as usize).min(m - 1);
        let iy = |y: f32, m: usize| (((y + self.half[1]) / ts).max(0.0) as usize).min(m - 1);
        let (i0, i1) = (ix(x0, self.tiles[0]), ix(x1, self.tiles[0]));
        let (j0, j1) = (iy(y0, self.tiles[1]), iy(y1, self.tiles[1]));
        let mut m = f32::INFINITY;
        for j in j0..=j1 {
            for i in i0..=i1 {
                m = m.min(self.tile_min[j * self.tiles[0] + i]);
            }
        }
        m
    }

    #[inline]
    pub fn is_flat(&self) -> bool {
        self.h.is_empty() && self.steps.is_none()
    }

    #[inline]
    pub fn inside_footprint(&self, x: f32, y: f32) -> bool {
        x.abs() <= self.half[0] && y.abs() <= self.half[1]
    }

    /// h(x, y), bilinear between nodes.
    #[inline]
    pub fn height(&self, x: f32, y: f32) -> f32 {
        if let Some((lo, hi)) = self.steps {
            return if y < 0.0 { lo } else { hi };
        }
        if self.h.is_empty() {
            return self.flat_height;
        }
        let fx = ((x + self.half[0]) / self.cell).clamp(0.0, (self.n[0] - 1) as f32 - 1e-3);
        let fy = ((y + self.half[1]) / self.cell).clamp(0.0, (self.n[1] - 1) as f32 - 1e-3);
        let (i, j) = (fx as usize, fy as usize);
        let (tx, ty) = (fx - i as f32, fy - j as f32);
        let k = j * self.n[0] + i;
        let (h00, h10, h01, h11) = (
            self.h[k],
            self.h[k + 1],
            self.h[k + self.n[0]],
            self.h[k + self.n[0] + 1],
        );
        (h00 * (1.0 - tx) + h10 * tx) * (1.0 - ty) + (h01 * (1.0 - tx) + h11 * tx) * ty
    }

    /// Outward unit normal at (x, y).
    pub fn normal(&self, x: f32, y: f32) -> Vec3 {
        if self.h.is_empty() {
            return Vec3::Z;
        }
        let e = self.cell * 0.5;
        let dx = (self.height(x + e, y) - self.height(x - e, y)) / (2.0 * e);
        let dy = (self.height(x, y + e) - self.height(x, y - e)) / (2.0 * e);
        Vec3::new(-dx, -dy, 1.0).normalize()
    }

    fn step(&self) -> f32 {
        if self.steps.is_some() {
            0.05
        } else {
            0.4 * self.cell
        }
    }

    /// First hit of a ray from the air (origin above h_max) with the surface
    /// inside the footprint.
    pub fn intersect_from_above(&self, o: Vec3, d: Vec3) -> Option<(f32, Vec3)> {
        if d.z >= 0.0 {
            return None;
        }
        if self.is_flat() {
            let t = (self.flat_height - o.z) / d.z;
            let p = o + d * t;
            return (t > 0.0 && self.inside_footprint(p.x, p.y)).then_some((t, p));
        }
        let t0 = ((self.h_max + 1e-3 - o.z) / d.z).max(0.0);
        let t_end = (self.h_min - 1e-3 - o.z) / d.z;
        let dt = self.step();
        let mut t = t0;
        let mut prev = t0;
        while t <= t_end + dt {
            let p = o + d * t;
            if self.inside_footprint(p.x, p.y) && p.z < self.height(p.x, p.y) {
                if t == t0 {
                    return Some((t, p));
                }
                let th = self.bisect(o, d, prev, t, true);
                return Some((th, o + d * th));
            }
            prev = t;
            t += dt;
        }
        None
    }

    /// First hit of a ray from a point in the air above the surface (not
    /// necessarily above h_max; it may be inside a dip) with the surface
    /// inside the footprint; None when it leaves upwards or past the footprint.
    pub fn hit_from_air(&self, o: Vec3, d: Vec3) -> Option<(f32, Vec3)> {
        if self.is_flat() {
            if d.z >= 0.0 {
                return None;
            }
            let t = ((self.flat_height - o.z) / d.z).max(0.0);
            let p = o + d * t;
            return self.inside_footprint(p.x, p.y).then_some((t, p));
        }
        if o.z > self.h_max + 1e-3 {
            return self.intersect_from_above(o, d);
        }
        let dt = self.step();
        let mut prev = 0.0f32;
        let mut t = 0.5 * dt;
        for _ in 0..1_000_000 {
            let p = o + d * t;
            if (p.z > self.h_max && d.z >= 0.0) || !self.inside_footprint(p.x, p.y) {
                return None;
            }
            if p.z < self.height(p.x, p.y) {
                let th = self.bisect(o, d, prev, t, true);
                return Some((th, o + d * th));
            }
            prev = t;
            t += dt;
        }
        None
    }

    /// Refine a crossing between t_a (on the start side) and t_b.
    fn bisect(&self, o: Vec3, d: Vec3, mut ta: f32, mut tb: f32, from_above: bool) -> f32 {
        for _ in 0..20 {
            let tm = 0.5 * (ta + tb);
            let p = o + d * tm;
            let below = p.z < self.height(p.x, p.y);
            if below == from_above {
                tb = tm;
            } else {
                ta = tm;
            }
        }
        tb
    }

    /// First point where the segment o + t d, 0 < t <= t_max, starting inside
    /// the medium (below the surface), crosses the surface going up.
    #[inline(always)]
    pub fn crossing_from_below(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Vec3)> {
        if self.is_flat() {
            // the walk's hot path: inlined, the relief's ray march is not
            if o.z + d.z * t_max > self.flat_height && d.z > 0.0 {
                let t = (self.flat_height - o.z) / d.z;
                return Some((t, o + d * t));
            }
            return None;
        }
        // (most flights stay below the relief: no call)
        if o.z.max(o.z + d.z * t_max) < self.h_min {
            return None;
        }
        self.crossing_from_below_relief(o, d, t_max)
    }

    #[inline(never)]
    fn crossing_from_below_relief(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Vec3)> {
        // (the caller has tested the segment's top against h_min)
        let z1 = o.z + d.z * t_max;
        let z_top = o.z.max(z1);
        let (x1, y1) = (o.x + d.x * t_max, o.y + d.y * t_max);
        if z_top < self.min_over(o.x.min(x1), o.x.max(x1), o.y.min(y1), o.y.max(y1)) {
            return None;
        }
        let dt = self.step();
        let mut prev = 0.0;
        let mut t = dt.min(t_max);
        loop {
            let p = o + d * t;
            if p.z > self.height(p.x, p.y) {
                let th = self.bisect(o, d, prev, t, false);
                return Some((th, o + d * th));
            }
            if t >= t_max {
                return None;
            }
            prev = t;
            t = (t + dt).min(t_max);
        }
    }

    /// Whether a point on the surface sees along `w` (upwards) without the
    /// height field in the way.
    #[inline]
    pub fn visible(&self, p: Vec3, w: Vec3) -> bool {
        if self.is_flat() {
            return w.z > 0.0;
        }
        if w.z <= 0.0 {
            return false;
        }
        let dt = self.step();
        let mut t = 2e-3 + dt * 0.5;
        loop {
            let q = p + w * t;
            if q.z >= self.h_max || !self.inside_footprint(q.x, q.y) {
                return true;
            }
            if q.z < self.height(q.x, q.y) - 1e-4 {
                return false;
            }
            t += dt;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_and_relief_intersections_agree_on_height() {
        let hf = HeightField::relief([10.0, 10.0], 0.1, 0.2, 2.0, &[], 3);
        let mut rng = Rng::new(2, 2);
        for _ in 0..200 {
            let o = Vec3::new(rng.uniform() * 8.0 - 4.0, rng.uniform() * 8.0 - 4.0, 50.0);
            let d = Vec3::new(
                0.2 * (rng.uniform() - 0.5),
                0.2 * (rng.uniform() - 0.5),
                -1.0,
            )
            .normalize();
            let (_, p) = hf.intersect_from_above(o, d).unwrap();
            assert!((p.z - hf.height(p.x, p.y)).abs() < 1e-3);
            // and from just below, going up along -d, the crossing is the same point
            let q = p + d * 0.5;
            let (_, p2) = hf.crossing_from_below(q, -d, 2.0).unwrap();
            assert!((p2 - p).length() < 2e-3, "{p} {p2}");
        }
        assert!(hf.h_max > 0.1 && hf.h_min < -0.1);
    }

    #[test]
    fn tile_minima_bound_the_surface() {
        let s = Sphere {
            centre: [1.0, -2.0, 0.2],
            radius: 0.8,
            material: 1,
        };
        let hf = HeightField::relief([6.0, 6.0], 0.1, 0.3, 1.5, &[s], 5);
        let mut rng = Rng::new(8, 8);
        for _ in 0..20_000 {
            let (x, y) = (rng.uniform() * 12.0 - 6.0, rng.uniform() * 12.0 - 6.0);
            assert!(hf.min_over(x, x, y, y) <= hf.height(x, y) + 1e-6, "{x} {y}");
        }
    }

    #[test]
    fn a_step_shadows_the_low_side() {
        let hf = HeightField::two_steps([30.0, 30.0], 0.0, 10.0);
        // on the low side next to the wall, looking over the wall at 45 degrees: blocked
        let w = Vec3::new(0.0, 1.0, 1.0).normalize();
        assert!(!hf.visible(Vec3::new(0.0, -2.0, 0.0), w));
        assert!(hf.visible(
            Vec3::new(0.0, -2.0, 0.0),
            Vec3::new(0.0, -1.0, 1.0).normalize()
        ));
        let (_, p) = hf
            .intersect_from_above(Vec3::new(0.0, 5.0, 100.0), -Vec3::Z)
            .unwrap();
        assert!((p.z - 10.0).abs() < 1e-5, "{p}");
    }

    #[test]
    fn pores_dip_below_the_relief() {
        let s = Sphere {
            centre: [0.0, 0.0, 0.0],
            radius: 1.0,
            material: 1,
        };
        let hf = HeightField::relief([5.0, 5.0], 0.05, 0.0, 2.0, &[s], 1);
        assert!((hf.height(0.0, 0.0) + 1.0).abs() < 0.01);
        assert!(hf.height(3.0, 3.0).abs() < 1e-6);
    }
}
