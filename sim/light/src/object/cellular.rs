//! Camera paths through an object filled with a cellular sample
//! ([`crate::cells`]): the mesh's inside is the wall material minus the air
//! cells, the cell lattice tiled in object space. Where a cell cuts the
//! mesh the pore is open: a ray crosses the surface there without an
//! interface, so light passes through chains of open pores (a thin sheet
//! against a back light).
//!
//! The physics is [`crate::cellwalk`]'s, traced the other way:
//! - the mesh boundary is the sample's rough dielectric, single-scattering
//!   microfacet model (the masked share lost, or kept as at a wall with
//!   `conserve_energy`), as the slab's top;
//! - a cell wall is the wall dielectric with its masked share returned to
//!   the lobe: the photon walk resamples until a sample survives, so a
//!   photon arriving from u leaves towards v with density
//!   f(u, v) |cos v| / A(u), A(u) the single-scattering albedo from u. A
//!   camera path needs the adjoint, f_rad(v, u) / A(u): the sampled
//!   weight divided by the albedo of the direction sampled
//!   ([`SingleScatteringAlbedo`], tabulated once per render).
//!
//! Delta lights reach a path only through the air, so each is connected at
//! the last interface before it. Every light path starts light -> x1 with
//! x1 on a boundary's air side; the camera path counts it at x1 when its
//! vertex before x1 is the camera or another boundary (estimate at the
//! boundary event through the BSDF), and at that vertex when it is a
//! volume vertex (a uniform direction from the vertex to the first
//! boundary, the BSDF towards the light there), never both. Visibility is
//! traced through the air: pores, open pores and the outside. Both
//! estimates need rough boundaries (`check_lights`).

use glam::Vec3;

use super::bvh::Hit;
use super::integrator::{Ctx, Frame};
use crate::cells::Cells;
use crate::microfacet::{Dielectric, TransportMode};
use crate::rng::{WalkRng, exp1_from_bits};
use crate::walk::sample_uniform_sphere_bits;

use super::{DeltaLight, ObjectError, ObjectStats};

/// Boundary events per path at most (a path crosses hundreds of walls).
const MAX_BOUNDARY_EVENTS: u32 = 1_000_000;
/// Where a camera path is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum At {
    /// Outside the object.
    Out,
    /// In the air of a cell inside the object.
    Pore,
    /// In the wall material.
    Wall,
}

/// A point on a boundary, seen from one side.
#[derive(Clone, Copy)]
struct Boundary {
    x: Vec3,
    /// Geometric normal into the air side.
    ng: Vec3,
    /// The mesh's hit (its shading normal), None on a cell wall.
    mesh: Option<Hit>,
}

/// How a ray through the air ends.
enum AirEnd {
    Hit(Boundary),
    /// Reached the light's distance, or left everything; `crossed`: through
    /// the object (in and out of its open pores).
    Free {
        crossed: bool,
    },
    /// Numerically stuck (a point within rounding of a wall) or out of an open mesh.
    Lost,
}

/// Delta lights need rough boundaries: they reach the inside only through
/// a boundary's BTDF.
pub(super) fn check_lights(
    lights: &[DeltaLight],
    surface: &Dielectric,
    cells: &Cells,
) -> Result<(), ObjectError> {
    if lights.is_empty() {
        return Ok(());
    }
    if surface.mf.effectively_smooth() || cells.wall.mf.effectively_smooth() {
        return Err(ObjectError::Sample(
            "a cellular object under directional or point lights needs rough boundaries (surface roughness and wall_roughness > 0); light it with an environment map instead".into(),
        ));
    }
    Ok(())
}

impl Ctx<'_> {
    /// From `o` in the air (`in_object`: in a cell inside the object) along
    /// the unit `d`, over at most `t_max`, to the first solid boundary.
    fn air_ray(
        &self,
        cells: &Cells,
        mut o: Vec3,
        d: Vec3,
        mut in_object: bool,
        t_max: f32,
    ) -> AirEnd {
        let mut left = t_max;
        let mut crossed = in_object;
        for _ in 0..4096 {
            let hm = self.bvh.intersect(o, d, left);
            if !in_object {
                let Some(h) = hm else {
                    return AirEnd::Free { crossed };
                };
                let x = o + d * h.t;
                let q = x + d * self.eps;
                if cells.inside(q) {
                    // an open pore: on into the cell without an interface
                    left -= h.t + self.eps;
                    o = q;
                    in_object = true;
                    crossed = true;
                    continue;
                }
                return AirEnd::Hit(Boundary {
                    x,
                    ng: Vec3::ZERO,
                    mesh: Some(h),
                });
            }
            let Some(c) = cells.cross(o, d) else {
                return AirEnd::Lost;
            };
            match hm {
                Some(h) if h.t <= c.t => {
                    // out of the object through an open pore
                    left -= h.t + self.eps;
                    o += d * (h.t + self.eps);
                    in_object = false;
                    continue;
                }
                None if c.t >= left => return AirEnd::Free { crossed },
                None => return AirEnd::Lost,
                _ => {}
            }
            return AirEnd::Hit(Boundary {
                x: o + d * c.t,
                ng: c.normal,
                mesh: None,
            });
        }
        AirEnd::Lost
    }

    /// Radiance of channel `c` along the camera ray (o, d) through a
    /// cellular object.
    pub(super) fn radiance_cells(
        &self,
        cells: &Cells,
        o: Vec3,
        d: Vec3,
        c: usize,
        rng: &mut WalkRng,
        st: &mut ObjectStats,
    ) -> f32 {
        st.paths += 1;
        let (s_t, alb) = self.tables[c][0];
        let (mut o, mut d) = (o, d);
        let mut at = At::Out;
        let (mut l, mut beta) = (0.0f32, 1.0f32);
        let (mut primary, mut entered, mut after_vertex) = (true, false, false);
        let (mut events, mut boundary_events) = (0u32, 0u32);
        loop {
            // to the next boundary (from_inside: from the solid side) or volume vertex
            let (b, from_solid) = match at {
                At::Out | At::Pore => {
                    match self.air_ray(cells, o, d, at == At::Pore, f32::INFINITY) {
                        AirEnd::Hit(b) => (b, false),
                        AirEnd::Free { crossed } => {
                            // left the object (from a pore: through open pores); a
                            // primary ray through open pores sees what is behind it
                            if let Some(env) = &self.scene.env
                                && (!primary || crossed || self.scene.env_visible)
                                && (self.unscattered_env || events > 0 || !entered)
                            {
                                l += beta * env.radiance(d)[c];
                            }
                            break;
                        }
                        AirEnd::Lost => {
                            st.lost += 1;
                            break;
                        }
                    }
                }
                At::Wall => {
                    let Some(hm) = self.bvh.intersect(o, d, f32::INFINITY) else {
                        st.lost += 1;
                        break;
                    };
                    let dist = if s_t > 0.0 {
                        exp1_from_bits(rng.next_u32()) / s_t
                    } else {
                        f32::INFINITY
                    };
                    let lim = dist.min(hm.t);
                    if let Some(w) = cells.first_entry(o, d, lim) {
                        let b = Boundary {
                            x: o + d * w.t,
                            ng: w.normal,
                            mesh: None,
                        };
                        (b, true)
                    } else if hm.t <= dist {
                        let b = Boundary {
                            x: o + d * hm.t,
                            ng: Vec3::ZERO,
                            mesh: Some(hm),
                        };
                        (b, true)
                    } else {
                        // a volume vertex
                        let p = o + d * dist;
                        events += 1;
                        st.events += 1;
                        if !self.scene.lights.is_empty() {
                            l += beta * alb * self.cell_vertex_lights(cells, p, c, rng, st);
                        }
                        beta *= alb;
                        if events >= self.max_events {
                            st.truncated += 1;
                            break;
                        }
                        if events > 8 {
                            let q = (1.0 - beta).max(0.0);
                            if rng.uniform() < q {
                                break;
                            }
                            beta /= 1.0 - q;
                        }
                        if !(beta > 0.0 && beta.is_finite()) {
                            break;
                        }
                        o = p;
                        d = sample_uniform_sphere_bits(rng.next_u64());
                        after_vertex = true;
                        continue;
                    }
                }
            };
            // the boundary event at b
            let (frame, ng, wall) = self.frame_at(&b, d, from_solid);
            let bsdf = if wall { &cells.wall } else { &self.bsdf };
            let wo = frame.to_local(-d);
            if !after_vertex {
                l += beta * self.boundary_lights(cells, &b, &frame, ng, wall, wo, c);
            }
            let Some(s) = bsdf.sample_f(
                wo,
                rng.uniform(),
                [rng.uniform(), rng.uniform()],
                TransportMode::Radiance,
            ) else {
                break;
            };
            let wi = frame.to_world(s.wi).normalize();
            let to_air = s.wi.z > 0.0;
            if (wi.dot(ng) > 0.0) != to_air {
                st.lost += 1;
                break;
            }
            beta *= if wall {
                s.weight / cells.albedo.at(s.wi)
            } else {
                s.weight * self.top_inv_albedo(s.wi)
            };
            if !(beta > 0.0 && beta.is_finite()) {
                break;
            }
            boundary_events += 1;
            if boundary_events > MAX_BOUNDARY_EVENTS {
                st.truncated += 1;
                break;
            }
            if to_air {
                at = if wall { At::Pore } else { At::Out };
                o = b.x + ng * self.eps;
            } else {
                at = At::Wall;
                entered = true;
                o = b.x - ng * self.eps;
            }
            d = wi;
            primary = false;
            after_vertex = false;
        }
        l
    }

    /// Frame, geometric normal into the air, and whether it is a cell wall.
    fn frame_at(&self, b: &Boundary, d: Vec3, from_solid: bool) -> (Frame, Vec3, bool) {
        match &b.mesh {
            None => (Frame::new(b.ng), b.ng, true),
            Some(h) => {
                let (ng, mut ns, _) = self.normals(h, d, if from_solid { 1.0 } else { -1.0 });
                if (ns.dot(-d) > 0.0) != (ng.dot(-d) > 0.0) {
                    ns = ng;
                }
                (Frame::new(ns), ng, false)
            }
        }
    }

    /// The delta lights at a boundary point through its BSDF (camera side
    /// `wo`, local), visibility through the air.
    #[allow(clippy::too_many_arguments)]
    fn boundary_lights(
        &self,
        cells: &Cells,
        b: &Boundary,
        frame: &Frame,
        ng: Vec3,
        wall: bool,
        wo: Vec3,
        c: usize,
    ) -> f32 {
        let bsdf = if wall { &cells.wall } else { &self.bsdf };
        let mut l = 0.0;
        for light in &self.scene.lights {
            let (wl, dist, e) = light.at(b.x);
            if ng.dot(wl) <= 0.0 {
                continue;
            }
            let wi = frame.to_local(wl);
            if wi.z <= 0.0 {
                continue;
            }
            let mut f = bsdf.f(wo, wi, TransportMode::Radiance);
            if !(f > 0.0 && f.is_finite()) {
                continue;
            }
            if wall {
                f /= cells.albedo.at(wi);
            } else {
                f *= self.top_inv_albedo(wi);
            }
            let o = b.x + ng * self.eps;
            if !matches!(
                self.air_ray(cells, o, wl, wall, dist - 2.0 * self.eps),
                AirEnd::Free { .. }
            ) {
                continue;
            }
            l += f * wi.z * e[c];
        }
        l
    }

    /// In-scattered radiance from the delta lights at a volume vertex `p`
    /// in the wall, divided by the albedo: a uniform direction to the first
    /// boundary, the BTDF towards each light there.
    fn cell_vertex_lights(
        &self,
        cells: &Cells,
        p: Vec3,
        c: usize,
        rng: &mut WalkRng,
        st: &mut ObjectStats,
    ) -> f32 {
        let s_t = self.tables[c][0].0;
        let mut l = 0.0;
        for light in &self.scene.lights {
            let w = sample_uniform_sphere_bits(rng.next_u64());
            let Some(hm) = self.bvh.intersect(p, w, f32::INFINITY) else {
                continue;
            };
            let (b, s) = match cells.first_entry(p, w, hm.t) {
                Some(e) => (
                    Boundary {
                        x: p + w * e.t,
                        ng: e.normal,
                        mesh: None,
                    },
                    e.t,
                ),
                None => (
                    Boundary {
                        x: p + w * hm.t,
                        ng: Vec3::ZERO,
                        mesh: Some(hm),
                    },
                    hm.t,
                ),
            };
            let q = self.nee_probability(c, s);
            if rng.uniform() >= q {
                continue;
            }
            st.nee += 1;
            let (frame, ng, wall) = self.frame_at(&b, w, true);
            let bsdf = if wall { &cells.wall } else { &self.bsdf };
            let (wl, dist, e) = light.at(b.x);
            if ng.dot(wl) <= 0.0 {
                continue;
            }
            let wi = frame.to_local(wl);
            if wi.z <= 0.0 {
                continue;
            }
            let mut f = bsdf.f(frame.to_local(-w), wi, TransportMode::Radiance);
            if !(f > 0.0 && f.is_finite()) {
                continue;
            }
            if wall {
                f /= cells.albedo.at(wi);
            } else {
                f *= self.top_inv_albedo(wi);
            }
            if !matches!(
                self.air_ray(cells, b.x + ng * self.eps, wl, wall, dist - 2.0 * self.eps),
                AirEnd::Free { .. }
            ) {
                continue;
            }
            // phase / pdf(w) = (1 / 4 pi) / (1 / 4 pi)
            l += f * wi.z * e[c] * (-s_t * s).exp() / q;
        }
        l
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// The camera path's wall weight is the adjoint of the photon walk's
    /// resampled wall: for two cones of directions U and V, the photon
    /// walk's transfer from U into V, integral over U x V of
    /// f(u, v) / A(u) |cos u| |cos v|, equals the camera estimate of the
    /// same integral from V (weight / A of the direction sampled, in U).
    #[test]
    fn wall_weight_is_the_adjoint_of_the_photon_walks_resampling() {
        let wall = Dielectric::new(1.45, 0.3);
        let albedo = crate::microfacet::SingleScatteringAlbedo::new(&wall);
        let mut rng = Rng::new(11, 2);
        let cos_cone = 15f32.to_radians().cos();
        let omega = 2.0 * std::f32::consts::PI * (1.0 - cos_cone);
        let dir = |theta: f32, phi: f32| {
            Vec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            )
        };
        let in_cone = |axis: Vec3, rng: &mut Rng| {
            let z = 1.0 - rng.uniform() * (1.0 - cos_cone);
            let phi = std::f32::consts::TAU * rng.uniform();
            let r = (1.0 - z * z).max(0.0).sqrt();
            Frame::new(axis).to_world(Vec3::new(r * phi.cos(), r * phi.sin(), z))
        };
        let pairs = [
            (dir(0.3, 0.0), dir(2.8, 3.0)), // air -> wall (transmission)
            (dir(2.8, 0.0), dir(0.5, 2.5)), // wall -> air
            (dir(1.0, 0.0), dir(0.9, 3.1)), // reflection on the air side
        ];
        let n = 400_000;
        for (cu, cv) in pairs {
            // photons from U, resampled importance lobe, landing in V
            let mut photon = 0.0f64;
            for _ in 0..n {
                let u = in_cone(cu, &mut rng);
                let s = loop {
                    if let Some(s) = wall.sample_f(
                        u,
                        rng.uniform(),
                        [rng.uniform(), rng.uniform()],
                        TransportMode::Importance,
                    ) && (s.weight >= 1.0 || rng.uniform() < s.weight)
                    {
                        break s;
                    }
                };
                if s.wi.dot(cv) > cos_cone {
                    photon += (u.z.abs() * omega) as f64;
                }
            }
            // camera paths from V, radiance lobe, weight / A, landing in U
            let mut camera = 0.0f64;
            for _ in 0..n {
                let v = in_cone(cv, &mut rng);
                if let Some(s) = wall.sample_f(
                    v,
                    rng.uniform(),
                    [rng.uniform(), rng.uniform()],
                    TransportMode::Radiance,
                ) && s.wi.dot(cu) > cos_cone
                {
                    camera += (v.z.abs() * omega * s.weight / albedo.at(s.wi)) as f64;
                }
            }
            let ratio = camera / photon;
            assert!(
                (ratio - 1.0).abs() < 0.03,
                "U {cu} V {cv}: camera {camera} photon {photon}"
            );
            // (without the division by A the wall-to-air pair is 11 % low)
        }
    }
}
