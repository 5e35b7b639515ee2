//! The sample's volume: one homogeneous material, or a voxel grid of
//! material ids holding spherical inclusions (or void cells) of several
//! materials, placed uniformly at random from a seed.
//!
//! The slab spans |x| <= half[0], |y| <= half[1], -half[2] <= z <= 0 (half[2]
//! is the full depth). Void ("air") inclusions on the voxel grid are
//! index-matched: light crosses them without refraction. Air cells with an
//! interface index (`crate::cells`) refract and reflect at their walls.

use crate::cells::Cells;
use crate::rng::Rng;
use crate::sample::{Coefficients, SampleDesc, resolve};

/// Spheres of one inclusion kind (kept for carving pores into the top).
#[derive(Debug, Clone, Copy)]
pub struct Sphere {
    pub centre: [f32; 3],
    pub radius: f32,
    pub material: u8,
}

#[derive(Debug, Clone)]
pub struct VoxelGrid {
    pub n: [usize; 3],
    pub voxel: f32,
    pub ids: Vec<u8>,
}

#[derive(Debug, Clone)]
pub struct Volume {
    /// Half extents in x, y and the depth, mm.
    pub half: [f32; 3],
    /// Material 0 is the matrix, 1.. the inclusions, in description order.
    pub materials: Vec<Coefficients>,
    pub grid: Option<VoxelGrid>,
    /// Majorant of s_t per channel (the largest material s_t).
    pub majorant: [f32; 3],
    /// Spheres of void materials (s_t = 0) that reach the top surface.
    pub open_voids: Vec<Sphere>,
    /// Measured volume fraction of each material in the grid.
    pub fractions: Vec<f64>,
    /// Air cells with refracting walls (material 0 is the wall); no grid then.
    pub cells: Option<Cells>,
}

impl Volume {
    pub fn build(desc: &SampleDesc) -> Volume {
        let half = [
            desc.size_mm[0] as f32 / 2.0,
            desc.size_mm[1] as f32 / 2.0,
            desc.size_mm[2] as f32,
        ];
        let mut materials = vec![resolve(&desc.volume.material)];
        materials.extend(desc.volume.inclusions.iter().map(|i| resolve(&i.material)));
        let mut majorant = [0.0f32; 3];
        for m in &materials {
            for (c, t) in m.sigma_t().iter().enumerate() {
                majorant[c] = majorant[c].max(*t as f32);
            }
        }
        let active: Vec<_> = desc
            .volume
            .inclusions
            .iter()
            .filter(|i| i.volume_fraction > 0.0)
            .collect();
        if active.is_empty() {
            return Volume {
                half,
                materials,
                grid: None,
                majorant,
                open_voids: vec![],
                fractions: vec![1.0],
                cells: None,
            };
        }
        if let Some(inc) = active.iter().find(|i| i.is_cells()) {
            let cells = Cells::build(
                inc.volume_fraction,
                inc.radius_mm,
                inc.period_mm,
                inc.interface_eta.unwrap_or(1.0) as f32,
                inc.wall_roughness as f32,
                desc.seed,
            );
            let p = cells.porosity;
            return Volume {
                half,
                majorant: [0, 1, 2].map(|c| materials[0].sigma_t()[c] as f32),
                materials,
                grid: None,
                open_voids: vec![],
                fractions: vec![1.0 - p, p],
                cells: Some(cells),
            };
        }
        // Resolve the smallest inclusions with ~3 voxels per radius.
        let r_min = active
            .iter()
            .map(|i| i.radius_mm[0])
            .fold(f64::INFINITY, f64::min) as f32;
        let mut voxel = (r_min / 3.0).clamp(0.05, 0.25);
        // Keep the grid under ~64 M voxels for big slabs.
        let cells =
            |v: f32| (2.0 * half[0] / v).ceil() * (2.0 * half[1] / v).ceil() * (half[2] / v).ceil();
        while cells(voxel) > 64.0e6 {
            voxel *= 1.25;
        }
        let n = [
            (2.0 * half[0] / voxel).ceil() as usize,
            (2.0 * half[1] / voxel).ceil() as usize,
            (half[2] / voxel).ceil() as usize,
        ];
        let total = n[0] * n[1] * n[2];
        let mut ids = vec![0u8; total];
        let mut rng = Rng::new(desc.seed, 0x766f_6c75_6d65);
        let mut open_voids = Vec::new();
        let mut counts = vec![0usize; materials.len()];
        counts[0] = total;
        for (k, inc) in desc.volume.inclusions.iter().enumerate() {
            let id = (k + 1) as u8;
            let target = (inc.volume_fraction * total as f64) as usize;
            let void = materials[k + 1].sigma_t().iter().all(|&t| t == 0.0);
            let [r0, r1] = inc.radius_mm;
            let mut guard = 0usize;
            while counts[k + 1] < target && guard < 50_000_000 {
                let r = (r0 + (r1 - r0) * rng.uniform_f64()) as f32;
                let c = [
                    (rng.uniform_f64() as f32 * 2.0 - 1.0) * half[0],
                    (rng.uniform_f64() as f32 * 2.0 - 1.0) * half[1],
                    -(rng.uniform_f64() as f32) * half[2],
                ];
                // rasterise the sphere
                let lo = |x: f32, o: f32| (((x - r + o) / voxel).floor().max(0.0)) as usize;
                let hi =
                    |x: f32, o: f32, m: usize| ((((x + r + o) / voxel).ceil()) as usize).min(m);
                let (x0, x1) = (lo(c[0], half[0]), hi(c[0], half[0], n[0]));
                let (y0, y1) = (lo(c[1], half[1]), hi(c[1], half[1], n[1]));
                let (z0, z1) = (lo(c[2], half[2]), hi(c[2], half[2], n[2]));
                for iz in z0..z1 {
                    let z = (iz as f32 + 0.5) * voxel - half[2];
                    for iy in y0..y1 {
                        let y = (iy as f32 + 0.5) * voxel - half[1];
                        for ix in x0..x1 {
                            let x = (ix as f32 + 0.5) * voxel - half[0];
                            let d2 = (x - c[0]).powi(2) + (y - c[1]).powi(2) + (z - c[2]).powi(2);
                            if d2 <= r * r {
                                let cell = &mut ids[(iz * n[1] + iy) * n[0] + ix];
                                counts[*cell as usize] -= 1;
                                counts[id as usize] += 1;
                                *cell = id;
                            }
                        }
                    }
                }
                if void && c[2] + r > 0.0 {
                    open_voids.push(Sphere {
                        centre: c,
                        radius: r,
                        material: id,
                    });
                }
                guard += 1;
            }
        }
        let fractions = counts.iter().map(|&c| c as f64 / total as f64).collect();
        Volume {
            half,
            materials,
            grid: Some(VoxelGrid { n, voxel, ids }),
            majorant,
            open_voids,
            fractions,
            cells: None,
        }
    }

    /// Material id at a point inside the slab.
    #[inline]
    pub fn material_at(&self, p: [f32; 3]) -> usize {
        match &self.grid {
            None => 0,
            Some(g) => {
                let ix = (((p[0] + self.half[0]) / g.voxel) as usize).min(g.n[0] - 1);
                let iy = (((p[1] + self.half[1]) / g.voxel) as usize).min(g.n[1] - 1);
                let iz = (((p[2] + self.half[2]) / g.voxel).max(0.0) as usize).min(g.n[2] - 1);
                g.ids[(iz * g.n[1] + iy) * g.n[0] + ix] as usize
            }
        }
    }

    /// Per-material (s_t, single-scattering albedo) for one channel.
    pub fn channel_table(&self, ch: usize) -> Vec<(f32, f32)> {
        self.materials
            .iter()
            .map(|m| (m.sigma_t()[ch] as f32, m.albedo()[ch] as f32))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::SceneDesc;

    fn sample(name: &str) -> SampleDesc {
        match SceneDesc::preset(name).unwrap() {
            SceneDesc::Sample(s) => s,
            _ => unreachable!(),
        }
    }

    #[test]
    fn volume_fractions_hit_their_targets() {
        // index-matched air spheres on the voxel grid
        let mut d = sample("bread");
        d.volume.inclusions = vec![crate::sample::InclusionDesc::matched(
            crate::sample::MaterialDesc::Preset("air".into()),
            0.3,
            [0.2, 1.0],
        )];
        d.size_mm = [20.0, 20.0, 8.0];
        let v = Volume::build(&d);
        assert!((v.fractions[1] - 0.3).abs() < 0.01, "{:?}", v.fractions);
        assert!(!v.open_voids.is_empty());
        // same seed, same volume; other seed, other volume
        let v2 = Volume::build(&d);
        assert_eq!(v.grid.as_ref().unwrap().ids, v2.grid.as_ref().unwrap().ids);
        d.seed = 9;
        let v3 = Volume::build(&d);
        assert_ne!(v.grid.as_ref().unwrap().ids, v3.grid.as_ref().unwrap().ids);
    }

    #[test]
    fn inclusions_are_evenly_spread() {
        let mut d = sample("two-material");
        d.size_mm = [30.0, 30.0, 10.0];
        let v = Volume::build(&d);
        // the inclusion fraction in each quadrant stays near the global 0.4
        for (sx, sy) in [(-1.0f32, -1.0f32), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
            let mut hit = 0;
            let n = 4000;
            let mut r = Rng::new(4, 0);
            for _ in 0..n {
                let p = [
                    sx * 14.0 * r.uniform(),
                    sy * 14.0 * r.uniform(),
                    -9.5 * r.uniform(),
                ];
                hit += (v.material_at(p) == 1) as usize;
            }
            let f = hit as f64 / n as f64;
            assert!((f - 0.4).abs() < 0.07, "quadrant ({sx},{sy}): {f}");
        }
    }
}
