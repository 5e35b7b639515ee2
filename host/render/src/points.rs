//! Pass 1 of Jensen & Buhler 2002: an even set of sample points on the
//! surface (Poisson-disk by dart throwing, each standing for an equal share
//! of the area), and the irradiance at each from every light, with shadow
//! rays, attenuated by the mesostructure entrance function f(w_i):
//!
//!   E_i = T(0) [sum over delta lights of f(w_l) cos(theta_l) V E_l
//!       + (1/N) sum_k L_env(w_k) f(w_k) cos(theta_k) V / pdf(w_k)].
//!
//! The cosine is the dx_i = (n . w_i) dA of paper eq. 1; f carries the
//! angular attenuation (Fresnel and mesostructure) relative to normal
//! incidence and T(0) = 1 - F_r(eta, 0) the share of a normal beam that
//! enters (R_d counts entered light). Surfaces are
//! treated as two-sided: light counts on whichever side it arrives, so
//! meshes with inconsistent winding still work.

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::boundary::EntryShape;
use crate::bvh::Ray;
use crate::light::luminance;
use crate::material::Material;
use crate::mesh::Mesh;
use crate::scene::Scene;

/// Surface sample points with their area and irradiance.
#[derive(Clone, Debug, Default)]
pub struct SurfaceSamples {
    pub pos: Vec<Vec3>,
    /// Geometric normal of the triangle each point lies on.
    pub normal: Vec<Vec3>,
    pub tri: Vec<u32>,
    /// The texture's +u direction at each point ([`crate::tangent_field`]);
    /// empty = any direction.
    pub tangent: Vec<Vec3>,
    /// Area each point stands for, mm^2: about total area / count, less
    /// where the points are denser ([`poisson_disk`]).
    pub area: Vec<f32>,
    /// Irradiance (linear RGB), already attenuated by f.
    pub irradiance: Vec<Vec3>,
    /// The entering light's mean direction in the medium (refracted at a
    /// smooth surface, into the mesh), weighted by luminance; unnormalised,
    /// zero without light. Empty = straight in along the normal.
    pub entry: Vec<Vec3>,
    /// The object's thickness behind each point: the distance along the
    /// inward normal to the next surface, INFINITY where there is none
    /// (see [`compute_thickness`]). Empty = unknown (infinite).
    pub thickness: Vec<f32>,
    /// Poisson-disk radius used, mm.
    pub radius: f32,
}

impl SurfaceSamples {
    /// The mean area a point stands for, mm^2.
    pub fn mean_area(&self) -> f32 {
        self.area.iter().sum::<f32>() / self.area.len().max(1) as f32
    }
}

/// How incoming light is attenuated on entering the material.
#[derive(Clone, Copy, Debug)]
pub enum Entrance<'a, M: Material> {
    /// The model's mesostructure entrance function f(w_i), relative to
    /// normal incidence, times the share T(0) = 1 - F_r(eta, 0) of a normal
    /// beam that enters: R_d counts entered light (Jensen et al. 2001's
    /// F_t(w_i) R_d; qhm-model fits a' from R / T(0)).
    /// With the smooth boundary's entry shape when the material has one
    /// (`Material::smooth_boundary`).
    Model(&'a M, Option<&'a EntryShape>),
    /// Plain dipole: the smooth-surface Fresnel transmittance 1 - F_r(eta, w_i),
    /// times the entry shape.
    Fresnel(f64, Option<&'a EntryShape>),
}

impl<M: Material> Entrance<'_, M> {
    /// The index of refraction light enters through.
    pub(crate) fn eta(&self) -> f64 {
        match self {
            Entrance::Model(m, _) => m.dipole().eta,
            Entrance::Fresnel(eta, _) => *eta,
        }
    }

    pub(crate) fn eval(&self, wi_local: Vec3) -> Vec3 {
        use qhm_model::fresnel::{fresnel_dielectric, normal_transmittance};
        let (base, eta, shape) = match self {
            Entrance::Model(m, shape) => {
                let eta = m.dipole().eta;
                let f =
                    Vec3::from(m.entrance(wi_local.to_array())) * normal_transmittance(eta) as f32;
                (f, eta, shape)
            }
            Entrance::Fresnel(eta, shape) => (
                Vec3::splat((1.0 - fresnel_dielectric(wi_local.z as f64, *eta)) as f32),
                *eta,
                shape,
            ),
        };
        match shape {
            Some(g) => base * g.eval(wi_local.z, eta as f32),
            None => base,
        }
    }
}

/// A local frame: z = n, x = tangent projected onto the plane.
pub fn frame(n: Vec3, t: Vec3) -> (Vec3, Vec3, Vec3) {
    let x = (t - n * n.dot(t))
        .try_normalize()
        .unwrap_or_else(|| n.any_orthonormal_vector());
    (x, n.cross(x), n)
}

/// World direction -> local frame (x, y, n).
pub fn to_local(f: &(Vec3, Vec3, Vec3), d: Vec3) -> Vec3 {
    Vec3::new(d.dot(f.0), d.dot(f.1), d.dot(f.2))
}

/// Dart throwing: uniform candidates by area, accepted when no accepted point
/// lies within `radius`. The radius is set from `target` so that a maximal
/// set holds about `target` points (random close packing covers ~70% of the
/// area with disks of radius r/2, hence r = sqrt(0.7 A / N)).
pub fn poisson_disk(mesh: &Mesh, target: usize, seed: u64) -> SurfaceSamples {
    let target = target.max(1);
    let areas: Vec<f32> = (0..mesh.triangles.len()).map(|t| mesh.area(t)).collect();
    let total: f32 = areas.iter().sum();
    let mut cdf = Vec::with_capacity(areas.len());
    let mut acc = 0.0f64;
    for a in &areas {
        acc += *a as f64;
        cdf.push(acc / total as f64);
    }
    let radius = (0.7 * total / target as f32).sqrt();
    // A dense grid of cells at least `radius` wide (linked lists of points),
    // coarser if the box would need more than ~8M cells.
    let (lo, hi) = mesh.bounds();
    let ext = (hi - lo).max(Vec3::splat(radius));
    let cell = radius.max((ext.x * ext.y * ext.z / 8.0e6).cbrt());
    let dims = (ext / cell).floor().as_uvec3() + 1;
    let (nx, ny, nz) = (dims.x as usize, dims.y as usize, dims.z as usize);
    let mut heads = vec![u32::MAX; nx * ny * nz];
    let mut next: Vec<u32> = Vec::new();
    let cell_of = |p: Vec3| {
        let c = ((p - lo) / cell).floor().max(Vec3::ZERO).as_uvec3();
        [
            (c.x as usize).min(nx - 1),
            (c.y as usize).min(ny - 1),
            (c.z as usize).min(nz - 1),
        ]
    };
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut out = SurfaceSamples {
        radius,
        ..Default::default()
    };
    let r2 = radius * radius;
    let candidates = 12 * target;
    for _ in 0..candidates {
        let u: f64 = rng.random();
        let t = cdf.partition_point(|&c| c < u).min(areas.len() - 1);
        let (mut b1, mut b2): (f32, f32) = (rng.random(), rng.random());
        if b1 + b2 > 1.0 {
            (b1, b2) = (1.0 - b1, 1.0 - b2);
        }
        let [a, b, c] = mesh.corners(t);
        let p = a + (b - a) * b1 + (c - a) * b2;
        let k = cell_of(p);
        let mut free = true;
        'scan: for x in k[0].saturating_sub(1)..=(k[0] + 1).min(nx - 1) {
            for y in k[1].saturating_sub(1)..=(k[1] + 1).min(ny - 1) {
                for z in k[2].saturating_sub(1)..=(k[2] + 1).min(nz - 1) {
                    let mut j = heads[(z * ny + y) * nx + x];
                    while j != u32::MAX {
                        if out.pos[j as usize].distance_squared(p) < r2 {
                            free = false;
                            break 'scan;
                        }
                        j = next[j as usize];
                    }
                }
            }
        }
        if free {
            let h = &mut heads[(k[2] * ny + k[1]) * nx + k[0]];
            next.push(*h);
            *h = out.pos.len() as u32;
            out.pos.push(p);
            out.normal.push(mesh.face_normal(t));
            out.tri.push(t as u32);
        }
    }
    out.area = local_areas(&out.pos, &out.normal, total, radius);
    out.irradiance = vec![Vec3::ZERO; out.pos.len()];
    out
}

/// The area each point stands for. Darts leave patches a few spacings
/// across 5-8 % denser or sparser than the mean; with equal shares a
/// dipole sum over a sparse patch comes out low there, which shows as
/// mottling. Where the surface is smooth around a point (every point within
/// `DENSITY_RADII` Poisson radii has a normal within 25° of its own) its
/// area is the inverse of the local density (a biweight kernel over that
/// radius), scaled so that such points keep their share of the total (the
/// estimate counts the point itself and none within its Poisson radius, a
/// bias the same everywhere). Near an edge or a crease, where a ball holds
/// more surface than a disc, a point keeps total / n.
fn local_areas(pos: &[Vec3], normal: &[Vec3], total: f32, radius: f32) -> Vec<f32> {
    let n = pos.len();
    let share = total / n.max(1) as f32;
    let rho = DENSITY_RADII * radius;
    let grid = PointGrid::new(pos, rho);
    let smooth_cos = 25f32.to_radians().cos();
    // None where the neighbourhood is not smooth.
    let density: Vec<Option<f32>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut sum = 0.0;
            for j in grid.near(pos[i], 1) {
                let j = j as usize;
                let s = pos[j].distance_squared(pos[i]) / (rho * rho);
                if s >= 1.0 {
                    continue;
                }
                if normal[j].dot(normal[i]) < smooth_cos {
                    return None;
                }
                sum += (1.0 - s) * (1.0 - s);
            }
            Some(sum)
        })
        .collect();
    let inverse: Vec<f32> = density
        .iter()
        .flatten()
        .map(|d| 1.0 / d.max(f32::MIN_POSITIVE))
        .collect();
    if inverse.is_empty() {
        return vec![share; n];
    }
    let scale = share * inverse.len() as f32 / inverse.iter().sum::<f32>();
    density
        .iter()
        .map(|d| d.map_or(share, |d| scale / d.max(f32::MIN_POSITIVE)))
        .collect()
}

/// Points hashed into cubes of a given side, for the points near a place.
pub(crate) struct PointGrid {
    cell: f32,
    cells: std::collections::HashMap<[i32; 3], Vec<u32>>,
}

impl PointGrid {
    pub(crate) fn new(pos: &[Vec3], cell: f32) -> PointGrid {
        let mut grid = PointGrid {
            cell,
            cells: Default::default(),
        };
        for (i, p) in pos.iter().enumerate() {
            grid.cells.entry(grid.key(*p)).or_default().push(i as u32);
        }
        grid
    }

    fn key(&self, p: Vec3) -> [i32; 3] {
        (p / self.cell).floor().as_ivec3().to_array()
    }

    /// The points in the cubes within `reach` cubes of `p`'s along each
    /// axis (a superset of those within `reach` sides), cube by cube.
    pub(crate) fn near(&self, p: Vec3, reach: i32) -> impl Iterator<Item = u32> + '_ {
        let c = self.key(p);
        (-reach..=reach)
            .flat_map(move |dz| (-reach..=reach).map(move |dy| (dz, dy)))
            .flat_map(move |(dz, dy)| (-reach..=reach).map(move |dx| [dx, dy, dz]))
            .filter_map(move |[dx, dy, dz]| self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]))
            .flat_map(|list| list.iter().copied())
    }
}

/// The radius of [`local_areas`]'s density estimate, in Poisson radii.
const DENSITY_RADII: f32 = 4.0;

/// Fills `samples.thickness`: a ray from each point along its inward
/// normal (the mesh's winding) to the surface it meets first.
pub fn compute_thickness(scene: &Scene, samples: &mut SurfaceSamples) {
    samples.thickness = samples
        .pos
        .par_iter()
        .zip(&samples.normal)
        .map(|(&p, &n)| {
            let ray = Ray {
                o: p - n * scene.eps,
                d: -n,
            };
            scene
                .bvh
                .intersect(&ray, f32::INFINITY)
                .map_or(f32::INFINITY, |h| h.t + scene.eps)
        })
        .collect();
}

/// Fills `samples.irradiance` from the scene's lights (parallel).
///
/// The environment is turned into one shared set of `env_samples`
/// importance-sampled directions (stratified), used for every point: the
/// estimate is then smooth over the surface instead of mottled by
/// independent per-point noise, which the dipole would smear into blotches.
pub fn compute_irradiance<M: Material>(
    scene: &Scene,
    samples: &mut SurfaceSamples,
    entrance: &Entrance<'_, M>,
    env_samples: usize,
    seed: u64,
) {
    let env_set = env_directions(scene, env_samples, seed);
    let SurfaceSamples {
        pos,
        normal,
        tangent,
        irradiance,
        entry,
        ..
    } = samples;
    let eta = entrance.eta() as f32;
    let lit: Vec<(Vec3, Vec3)> = (0..pos.len())
        .into_par_iter()
        .map(|i| {
            let t = tangent.get(i).copied().unwrap_or(Vec3::ZERO);
            irradiance_at(scene, pos[i], normal[i], t, entrance, &env_set, eta)
        })
        .collect();
    (*irradiance, *entry) = lit.into_iter().unzip();
}

/// A stratified, importance-sampled set of environment directions, each
/// with its weight L(w) / (pdf(w) N): the env map as N directional lights.
pub fn env_directions(scene: &Scene, n: usize, seed: u64) -> Vec<(Vec3, Vec3)> {
    let Some(env) = &scene.env else {
        return Vec::new();
    };
    if n == 0 {
        return Vec::new();
    }
    let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 0xe4f);
    let m = (n as f32).sqrt().ceil() as usize;
    let n_tot = (m * m) as f32;
    let mut out = Vec::with_capacity(m * m);
    for a in 0..m {
        for b in 0..m {
            let u0 = (a as f32 + rng.random::<f32>()) / m as f32;
            let u1 = (b as f32 + rng.random::<f32>()) / m as f32;
            let (wi, l, pdf) = env.sample(u0, u1);
            if pdf > 0.0 {
                out.push((wi, l / (pdf * n_tot)));
            }
        }
    }
    out
}

/// Irradiance at one surface point, attenuated by the entrance, and the
/// luminance-weighted sum of the directions the light enters along
/// (refracted at index `eta`); `env_set` from [`env_directions`]. Two-sided,
/// unless the scene's mesh is closed ([`Scene::outside`]): then light comes
/// from its outside only.
pub fn irradiance_at<M: Material>(
    scene: &Scene,
    p: Vec3,
    n: Vec3,
    tangent: Vec3,
    entrance: &Entrance<'_, M>,
    env_set: &[(Vec3, Vec3)],
    eta: f32,
) -> (Vec3, Vec3) {
    let mut e = Vec3::ZERO;
    let mut entry = Vec3::ZERO;
    let mut add = |wi: Vec3, dist: f32, radiance_term: Vec3| {
        let cos = n.dot(wi);
        if cos.abs() < 1e-6 || scene.outside.is_some_and(|s| cos * s < 0.0) {
            return;
        }
        let ns = if cos > 0.0 { n } else { -n };
        let ray = Ray {
            o: p + ns * scene.eps,
            d: wi,
        };
        if scene.bvh.occluded(&ray, dist - 2.0 * scene.eps) {
            return;
        }
        let f = frame(ns, tangent);
        let de = entrance.eval(to_local(&f, wi)) * cos.abs() * radiance_term;
        e += de;
        entry += refract_in(wi, ns, eta) * luminance(de).max(0.0);
    };
    for light in &scene.lights {
        let s = light.sample(p);
        add(s.wi, s.dist, s.e_perp);
    }
    for &(wi, w) in env_set {
        add(wi, f32::INFINITY, w);
    }
    (e, entry)
}

/// The direction light from `wi` (towards the light) travels after
/// refraction into a smooth surface of normal `n` (on the light's side).
pub(crate) fn refract_in(wi: Vec3, n: Vec3, eta: f32) -> Vec3 {
    let cos_i = wi.dot(n).clamp(0.0, 1.0);
    let cos_t = (1.0 - (1.0 - cos_i * cos_i) / (eta * eta)).max(0.0).sqrt();
    -wi / eta + n * (cos_i / eta - cos_t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtin::slab;

    #[test]
    fn poisson_points_are_spread_and_cover_the_area() {
        let m = slab(40.0, 5.0).unwrap();
        let s = poisson_disk(&m, 3000, 7);
        assert!(s.pos.len() > 2000 && s.pos.len() < 4500, "{}", s.pos.len());
        let r2 = s.radius * s.radius;
        // Minimum distance holds (checked on a subset).
        for i in (0..s.pos.len()).step_by(37) {
            for j in 0..s.pos.len() {
                if i != j {
                    assert!(s.pos[i].distance_squared(s.pos[j]) >= r2 * 0.999);
                }
            }
        }
        let total: f32 = s.area.iter().sum();
        assert!((total - m.total_area()).abs() / total < 1e-4);
        // Counts follow the face areas (top face: 1600 of 4000 mm^2).
        let top = s.pos.iter().filter(|p| p.z > -1e-4).count() as f32 / s.pos.len() as f32;
        assert!((top - 0.4).abs() < 0.03, "{top}");
    }
}
