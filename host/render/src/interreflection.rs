//! Light the object sends itself: bounces of the global term between
//! parts that see each other (a teapot's handle and its body). Without it
//! the inside of a handle gets only what the lights send it; an apple
//! teapot under one light is then 4.5 % dark over all and 10 % on its
//! handle and spout against sim-light.
//!
//! Each surface sample casts a few cosine-distributed rays out of its
//! side of the surface. Where one hits the object, the radiance coming
//! back is the global exitance there as a diffuse emitter, M / π, taken
//! from the nearest probe (a subset of the samples, M from the octree)
//! that faces the ray; it enters like any other light, through the
//! entrance. Each bounce takes the exitance from the octree the previous
//! one left. A convex object's rays all escape: its samples keep their
//! irradiance bit for bit and no probe is evaluated.

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::bvh::Ray;
use crate::light::luminance;
use crate::material::Material;
use crate::octree::{DipoleTree, QueryStats, RdTable};
use crate::points::{Entrance, PointGrid, SurfaceSamples, frame, refract_in, to_local};
use crate::scene::Scene;

/// Samples whose exitance stands for the surface's, at most.
const PROBES: usize = 2048;

/// Where one sample's ray met the object: the direction it left along and
/// the probe whose exitance comes back.
struct Return {
    dir: Vec3,
    probe: u32,
}

/// The octree's sum at one point: what [`Interreflection::bounce`] needs
/// of the global term (the exitance M along the normal).
pub struct Exitance<'a> {
    pub tree: &'a DipoleTree,
    pub rd: &'a RdTable,
    pub epsilon: f32,
    pub r_min: f32,
}

/// The rays of every sample that came back to the object, and the probes
/// they reached.
pub struct Interreflection {
    returns: Vec<Vec<Return>>,
    probes: Probes,
    /// The probes that any ray reached: only their exitance is needed.
    reached: Vec<bool>,
    rays: usize,
}

impl Interreflection {
    /// Casts `rays` rays per sample; None when none comes back (a convex
    /// object, or `rays` = 0).
    pub fn trace(
        scene: &Scene,
        samples: &SurfaceSamples,
        rays: usize,
        seed: u64,
    ) -> Option<Interreflection> {
        let n = samples.pos.len();
        if rays == 0 || n == 0 {
            return None;
        }
        let probes = Probes::new(samples);
        let returns: Vec<Vec<Return>> = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut rng = Pcg64Mcg::seed_from_u64(
                    seed ^ 0x1b7e ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
                );
                let f = frame(samples.normal[i], Vec3::X);
                let origin = samples.pos[i] + samples.normal[i] * scene.eps;
                (0..rays)
                    .filter_map(|k| {
                        // Stratified in sin² θ, so cosine-distributed.
                        let u0 = (k as f32 + rng.random::<f32>()) / rays as f32;
                        let phi = std::f32::consts::TAU * rng.random::<f32>();
                        let (s, c) = (u0.sqrt(), (1.0 - u0).max(0.0).sqrt());
                        let dir = f.0 * (s * phi.cos()) + f.1 * (s * phi.sin()) + f.2 * c;
                        let ray = Ray { o: origin, d: dir };
                        let hit = scene.bvh.intersect(&ray, f32::INFINITY)?;
                        let at = origin + dir * hit.t;
                        let facing = scene.mesh.face_normal(hit.tri as usize);
                        // The side the ray sees; the other side's probes
                        // are another surface (a thin part's far face).
                        let facing = if facing.dot(dir) < 0.0 {
                            facing
                        } else {
                            -facing
                        };
                        let probe = probes.nearest_facing(at, facing)?;
                        Some(Return { dir, probe })
                    })
                    .collect()
            })
            .collect();
        let mut reached = vec![false; probes.index.len()];
        for r in returns.iter().flatten() {
            reached[r.probe as usize] = true;
        }
        reached.contains(&true).then_some(Interreflection {
            returns,
            probes,
            reached,
            rays,
        })
    }

    /// How many rays came back.
    pub fn count(&self) -> usize {
        self.returns.iter().map(Vec::len).sum()
    }

    /// Sets each sample's irradiance and entry direction to `direct` (the
    /// lights' and env map's) plus what comes back from the object as
    /// `exitance` has it: one more bounce each call.
    pub fn bounce<M: Material>(
        &self,
        samples: &mut SurfaceSamples,
        direct: &(Vec<Vec3>, Vec<Vec3>),
        exitance: &Exitance,
        entrance: &Entrance<'_, M>,
    ) {
        let m: Vec<Vec3> = (0..self.probes.index.len())
            .into_par_iter()
            .map(|p| {
                if !self.reached[p] {
                    return Vec3::ZERO;
                }
                let i = self.probes.index[p];
                exitance
                    .tree
                    .query_flux(
                        samples.pos[i],
                        samples.normal[i],
                        Vec3::ZERO,
                        exitance.rd,
                        exitance.epsilon,
                        exitance.r_min,
                        &mut QueryStats::default(),
                    )
                    .0
                    .max(Vec3::ZERO)
            })
            .collect();
        let eta = entrance.eta() as f32;
        samples.irradiance.clone_from(&direct.0);
        samples.entry.clone_from(&direct.1);
        for (i, back) in self.returns.iter().enumerate() {
            let n_i = samples.normal[i];
            let t = samples.tangent.get(i).copied().unwrap_or(Vec3::ZERO);
            let f = frame(n_i, t);
            for r in back {
                // Radiance M / π over cosine-distributed rays: each brings
                // E = π L / rays = M / rays, through the entrance.
                let de =
                    entrance.eval(to_local(&f, r.dir)) * m[r.probe as usize] / self.rays as f32;
                samples.irradiance[i] += de;
                if let Some(e) = samples.entry.get_mut(i) {
                    *e += refract_in(r.dir, n_i, eta) * luminance(de).max(0.0);
                }
            }
        }
    }
}

/// A subset of the samples on a hash grid, for the nearest one facing a
/// direction.
struct Probes {
    /// Sample index of each probe.
    index: Vec<usize>,
    pos: Vec<Vec3>,
    normal: Vec<Vec3>,
    grid: PointGrid,
}

impl Probes {
    fn new(samples: &SurfaceSamples) -> Probes {
        let n = samples.pos.len();
        // The samples are in dart-throwing order, spatially random: every
        // stride-th is a uniform subset.
        let stride = n.div_ceil(PROBES).max(1);
        let index: Vec<usize> = (0..n).step_by(stride).collect();
        let area: f32 = samples.area.iter().sum();
        let cell = (area / index.len() as f32).sqrt().max(f32::MIN_POSITIVE);
        let pos: Vec<Vec3> = index.iter().map(|&i| samples.pos[i]).collect();
        let normal: Vec<Vec3> = index.iter().map(|&i| samples.normal[i]).collect();
        Probes {
            grid: PointGrid::new(&pos, cell),
            index,
            pos,
            normal,
        }
    }

    /// The nearest probe within two cells whose normal is within 60° of
    /// `facing`, distance off the plane through `p` weighing more.
    fn nearest_facing(&self, p: Vec3, facing: Vec3) -> Option<u32> {
        let mut best: Option<(f32, u32)> = None;
        for k in self.grid.near(p, 2) {
            if self.normal[k as usize].dot(facing) < 0.5 {
                continue;
            }
            // Off the hit's plane counts four times over: a parallel
            // surface nearby (a lid over its shoulder) is another surface.
            let off = self.pos[k as usize] - p;
            let d = off.length_squared() + 4.0 * off.dot(facing).powi(2);
            if best.is_none_or(|(b, kb)| d < b || (d == b && k < kb)) {
                best = Some((d, k));
            }
        }
        best.map(|(_, k)| k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtin::sphere;
    use crate::mesh::Mesh;
    use crate::mesh_input::MeshInput;
    use crate::points::poisson_disk;

    #[test]
    fn a_convex_object_sends_itself_nothing() {
        let scene = Scene::lit(sphere(20.0, 64, 32).unwrap());
        let samples = poisson_disk(&scene.mesh, 3000, 1);
        assert!(Interreflection::trace(&scene, &samples, 16, 1).is_none());
    }

    /// Two 100 x 100 x 5 mm plates 2 mm apart, face to face.
    fn facing_plates() -> Scene {
        let mut m = MeshInput::default();
        for z0 in [0.0f32, 7.0] {
            let b = crate::builtin::box_mesh(
                Vec3::new(-50.0, -50.0, z0),
                Vec3::new(50.0, 50.0, z0 + 5.0),
            )
            .unwrap();
            let base = m.positions.len() as u32;
            m.positions.extend(b.positions.iter().map(|p| p.to_array()));
            m.triangles
                .extend(b.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        Scene::lit(Mesh::build(m, None).unwrap())
    }

    #[test]
    fn facing_plates_see_each_other_and_nothing_else() {
        let scene = facing_plates();
        let samples = poisson_disk(&scene.mesh, 20_000, 2);
        let ir = Interreflection::trace(&scene, &samples, 8, 2).unwrap();
        let (mut cast, mut came_back) = (0, 0);
        for (i, back) in ir.returns.iter().enumerate() {
            let (p, n) = (samples.pos[i], samples.normal[i]);
            let inner =
                (p.z - 5.0).abs() < 1e-3 && n.z > 0.9 || (p.z - 7.0).abs() < 1e-3 && n.z < -0.9;
            let central = p.x.abs() < 30.0 && p.y.abs() < 30.0;
            if inner && central {
                // Only rays within a few degrees of grazing get out sideways.
                cast += 8;
                came_back += back.len();
                // Each ray comes back from the other plate's inner face.
                for r in back {
                    let q = ir.probes.pos[r.probe as usize];
                    assert!((q.z - (12.0 - p.z)).abs() < 1e-3, "{p} -> {q}");
                }
            } else if !inner {
                assert!(back.is_empty(), "{p} {n}");
            }
        }
        assert!(
            came_back as f64 > 0.99 * cast as f64,
            "{came_back} of {cast}"
        );
    }

    #[test]
    fn a_bounce_brings_back_the_other_plates_exitance() {
        use crate::materials::{Homogeneous, preset};
        let scene = facing_plates();
        let mut samples = poisson_disk(&scene.mesh, 20_000, 3);
        let inner: Vec<bool> = (0..samples.pos.len())
            .map(|i| {
                let (p, n) = (samples.pos[i], samples.normal[i]);
                (p.z - 5.0).abs() < 1e-3 && n.z > 0.9 || (p.z - 7.0).abs() < 1e-3 && n.z < -0.9
            })
            .collect();
        let e0 = Vec3::splat(1.0);
        samples.irradiance = inner
            .iter()
            .map(|&k| if k { e0 } else { Vec3::ZERO })
            .collect();
        samples.entry = vec![Vec3::ZERO; samples.pos.len()];
        let material = Homogeneous {
            dipole: preset("skin1").unwrap(),
        };
        let entrance = Entrance::Model(&material, None);
        let tree = DipoleTree::new(&samples);
        let radius = (samples.mean_area() / std::f32::consts::PI).sqrt();
        let rd = RdTable::new(&material.dipole(), radius);
        let exitance = Exitance {
            tree: &tree,
            rd: &rd,
            epsilon: 0.1,
            r_min: 0.0,
        };
        let ir = Interreflection::trace(&scene, &samples, 64, 3).unwrap();
        let direct = (samples.irradiance.clone(), samples.entry.clone());
        ir.bounce(&mut samples, &direct, &exitance, &entrance);
        // The cosine-weighted mean of the entrance over the hemisphere.
        let steps = 2000;
        let mean_entrance: Vec3 = (0..steps)
            .map(|k| {
                let s2 = (k as f32 + 0.5) / steps as f32; // sin² θ, uniform
                let w = Vec3::new(s2.sqrt(), 0.0, (1.0 - s2).sqrt());
                entrance.eval(w) / steps as f32
            })
            .sum();
        let (mut got, mut expected) = (Vec3::ZERO, Vec3::ZERO);
        for (i, &on_inner_face) in inner.iter().enumerate() {
            let p = samples.pos[i];
            if on_inner_face && p.x.abs() < 20.0 && p.y.abs() < 20.0 {
                let m = tree.query(p, samples.normal[i], &rd, 0.1, 0.0);
                got += samples.irradiance[i] - e0;
                expected += mean_entrance * m;
            }
        }
        // A lost factor of 2 or π in the rays' share would be far out.
        let ratio = got / expected;
        eprintln!("bounce over the plates' exitance: {ratio}");
        assert!(expected.min_element() > 0.0);
        assert!((ratio - Vec3::ONE).abs().max_element() < 0.03, "{ratio}");
    }
}
