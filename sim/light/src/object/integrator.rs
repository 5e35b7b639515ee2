//! The object's estimator: camera path tracing (pbrt's `VolPathIntegrator`
//! without MIS) through the mesh, its dielectric boundary and the volume,
//! with next-event estimation of the delta lights from every scattering
//! vertex through the boundary.
//!
//! Why camera paths with NEE through the interface (and not light
//! tracing): environment maps need camera paths anyway (exit rays look the
//! map up), so one estimator serves every light and gives per-pixel
//! independent samples, hence an honest per-pixel variance; and the one
//! hard connection, a delta light seen from a volume vertex through a
//! smooth interface, is solved where it is cheapest, on the entry side:
//!
//! - **Smooth boundary** (the homogeneous presets, alpha 0): the entry
//!   point x whose refraction of the light's ray passes through the vertex p
//!   is found by a fixed-point walk on the surface (trace from p against the
//!   refracted direction at the last x, re-refract; the one-interface
//!   manifold walk of Jakob and Marschner 2012 with a step of
//!   the mesh's own ray cast), started from the straight line to the light.
//!   The irradiance of the refracted beam at p, per unit area normal to
//!   it, is E_p = T(x) Phi' / |(dy/du1 x dy/du2) . t|, with u the beam's
//!   parameters (position across a directional light, direction out of a
//!   point light; Phi' its irradiance or intensity), y(u) = x(u) + s t(u)
//!   the refracted ray at p's distance s, derivatives by central finite
//!   differences in f64 on the hit triangle's plane with its interpolated
//!   shading normal. On a plane this is T E cos_i / cos_t exactly. The walk
//!   finds the solution next to the straight line; others exist only
//!   beyond the refraction's first caustic (for eta 1.3 on a sphere of
//!   radius R, at least R cos(theta_t) from the entry, many mean free paths
//!   for the presets) and light that reaches p after two or more specular
//!   events without scattering (a Fresnel reflection at a far wall) is not
//!   connected: both carry at most F exp(-tau) of the beam, tau the optical
//!   depth crossed.
//! - **Rough boundary**: a direction from p, uniform on the sphere, to the
//!   boundary point x, the microfacet BTDF towards the light there.
//!
//! A vertex whose straight line to the light crosses the optical depth tau
//! makes its estimate with probability min(1, 10 exp(-tau)), at least
//! 0.05, and is weighted by the inverse (Russian roulette; deep vertices
//! cost a ray cast, not a walk).
//!
//! Radiance in radiance mode: crossing into the medium divides by eta^2,
//! leaving multiplies (pbrt's `TransportMode::Radiance`). Free flights are
//! sampled against s_t (delta tracking against the majorant when the
//! volume is a voxel grid, the grid tiled in 3D over the object), isotropic
//! scattering with the reduced coefficients (as everywhere in sim-light),
//! throughput Russian roulette after 8 events. Each channel is its own path.
//!
//! Determinism: pixel (x, y) draws from its own stream (seed, y * width +
//! x), so the image is identical for any thread count and schedule.

use std::f32::consts::PI;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::bvh::{Bvh, Hit};
use super::cellular::check_lights;
use super::{DeltaLight, ObjectError, ObjectScene};
use crate::medium::Volume;
use crate::microfacet::{
    Dielectric, SingleScatteringAlbedo, TransportMode, fr_dielectric, refract,
};
use crate::rng::{WalkRng, exp1_from_bits, mix64};
use crate::walk::sample_uniform_sphere_bits;

/// Isotropic phase function.
const PHASE: f32 = 1.0 / (4.0 * PI);
/// Iterations of the entry-point walk.
const WALK_STEPS: usize = 48;
/// Surface events per path at most (glass-like bounces between walls).
const MAX_SURFACE_EVENTS: u32 = 256;

/// Image size, samples and seed.
#[derive(Debug, Clone)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Camera paths per pixel and channel (at least 2, for the variance).
    pub spp: u32,
    pub seed: u64,
    /// Scattering events per path at most (the rest is counted truncated).
    pub max_events: u32,
    /// Count environment light that crossed the object without scattering
    /// (the environment seen through the object as through a lens). On
    /// for ground truth; off to compare the scattered light alone (the
    /// delta lights' lens image, a point on the film, is never rendered).
    pub unscattered_env: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 256,
            height: 256,
            spp: 64,
            seed: 1,
            max_events: 1_000_000,
            unscattered_env: true,
        }
    }
}

impl RenderOptions {
    pub fn validate(&self) -> Result<(), ObjectError> {
        let bad = |m: String| Err(ObjectError::Settings(m));
        if !(1..=16384).contains(&self.width) || !(1..=16384).contains(&self.height) {
            return bad(format!(
                "image {} x {} must be 1..=16384 on each side",
                self.width, self.height
            ));
        }
        if !(2..=1_000_000).contains(&self.spp) {
            return bad(format!(
                "spp {} must be in 2..=1000000 (two or more give the variance)",
                self.spp
            ));
        }
        if self.max_events == 0 {
            return bad("max_events must be at least 1".into());
        }
        Ok(())
    }
}

/// What the render did (integer counts, identical for any thread count).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ObjectStats {
    /// Camera paths traced (pixels x spp x 3 channels).
    pub paths: u64,
    /// Real scattering events.
    pub events: u64,
    /// Null collisions of delta tracking.
    pub null_events: u64,
    /// Delta-light estimates made at volume vertices (after roulette).
    pub nee: u64,
    /// Entry-point walks that did not converge (their estimate is dropped).
    pub nee_unconverged: u64,
    /// Paths ended at MAX events.
    pub truncated: u64,
    /// Paths ended because a sampled direction and the geometric normal
    /// disagreed (shading normals) or the mesh was left open.
    pub lost: u64,
}

impl std::ops::Add for ObjectStats {
    type Output = ObjectStats;
    fn add(self, o: ObjectStats) -> ObjectStats {
        ObjectStats {
            paths: self.paths + o.paths,
            events: self.events + o.events,
            null_events: self.null_events + o.null_events,
            nee: self.nee + o.nee,
            nee_unconverged: self.nee_unconverged + o.nee_unconverged,
            truncated: self.truncated + o.truncated,
            lost: self.lost + o.lost,
        }
    }
}

/// The rendered image: per-pixel mean radiance and the variance of that
/// mean (sample variance / spp), linear RGB, row-major, top row first.
#[derive(Debug, Clone)]
pub struct ObjectImage {
    pub width: u32,
    pub height: u32,
    pub radiance: Vec<[f32; 3]>,
    pub variance: Vec<[f32; 3]>,
    pub stats: ObjectStats,
    pub secs: f64,
}

impl ObjectImage {
    /// Mean radiance per channel over the image.
    pub fn mean(&self) -> [f64; 3] {
        let n = self.radiance.len().max(1) as f64;
        [0, 1, 2].map(|c| self.radiance.iter().map(|p| p[c] as f64).sum::<f64>() / n)
    }

    /// Relative standard error of the image mean per channel.
    pub fn mean_rel_error(&self) -> [f64; 3] {
        let n = self.radiance.len().max(1) as f64;
        let m = self.mean();
        [0, 1, 2].map(|c| {
            let v: f64 = self.variance.iter().map(|p| p[c] as f64).sum::<f64>() / (n * n);
            v.sqrt() / m[c].abs().max(1e-30)
        })
    }
}

/// An orthonormal frame around n.
pub(super) struct Frame {
    s: Vec3,
    t: Vec3,
    n: Vec3,
}

impl Frame {
    pub(super) fn new(n: Vec3) -> Frame {
        let s = n.any_orthonormal_vector();
        Frame {
            s,
            t: n.cross(s),
            n,
        }
    }
    pub(super) fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }
    pub(super) fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

/// The prepared scene.
pub(super) struct Ctx<'a> {
    pub(super) scene: &'a ObjectScene,
    pub(super) bvh: Bvh,
    vol: Volume,
    pub(super) tables: [Vec<(f32, f32)>; 3],
    pub(super) bsdf: Dielectric,
    /// A(u) of `bsdf` when the sample's top keeps the share its lobe masks
    /// (`SurfaceDesc::conserve_energy`): the adjoint of the photon walk's
    /// resampling divides by the albedo of the light-side direction.
    top_albedo: Option<SingleScatteringAlbedo>,
    smooth: bool,
    pub(super) eps: f32,
    /// Finite-difference step: mm across a directional beam, radians out
    /// of a point light.
    fd_step: f64,
    pub(super) max_events: u32,
    pub(super) unscattered_env: bool,
}

/// Per-thread counters.
#[derive(Default)]
struct Counts(ObjectStats);

/// Render `scene` with `opts`; `progress` is called with the number of
/// image rows finished since the last call; `cancel` stops early (the
/// image is then incomplete).
pub fn render_object(
    scene: &ObjectScene,
    opts: &RenderOptions,
    progress: &(dyn Fn(u64) + Sync),
    cancel: Option<&AtomicBool>,
) -> Result<ObjectImage, ObjectError> {
    opts.validate()?;
    scene.mesh.validate()?;
    let start = Instant::now();
    let ctx = Ctx::new(scene, opts)?;
    let (w, h) = (opts.width, opts.height);
    type Row = (Vec<[f32; 3]>, Vec<[f32; 3]>, ObjectStats);
    let rows: Vec<Row> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut counts = Counts::default();
            let mut rad = Vec::with_capacity(w as usize);
            let mut var = Vec::with_capacity(w as usize);
            if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                return (
                    vec![[0.0; 3]; w as usize],
                    vec![[0.0; 3]; w as usize],
                    counts.0,
                );
            }
            for x in 0..w {
                let (m, v) = ctx.pixel(x, y, opts, &mut counts);
                rad.push(m);
                var.push(v);
            }
            progress(1);
            (rad, var, counts.0)
        })
        .collect();
    let mut img = ObjectImage {
        width: w,
        height: h,
        radiance: Vec::with_capacity((w * h) as usize),
        variance: Vec::with_capacity((w * h) as usize),
        stats: ObjectStats::default(),
        secs: 0.0,
    };
    for (r, v, s) in rows {
        img.radiance.extend(r);
        img.variance.extend(v);
        img.stats = img.stats + s;
    }
    img.secs = start.elapsed().as_secs_f64();
    Ok(img)
}

/// Wrap a point into the sample's slab (tiling the volume over space).
#[inline]
fn wrap(vol: &Volume, p: Vec3) -> [f32; 3] {
    let [hx, hy, d] = vol.half;
    [
        (p.x + hx).rem_euclid(2.0 * hx) - hx,
        (p.y + hy).rem_euclid(2.0 * hy) - hy,
        p.z.rem_euclid(d) - d,
    ]
}

impl<'a> Ctx<'a> {
    fn new(scene: &'a ObjectScene, opts: &RenderOptions) -> Result<Ctx<'a>, ObjectError> {
        let mesh = &scene.mesh;
        let tris: Vec<[Vec3; 3]> = (0..mesh.triangles.len()).map(|t| mesh.corners(t)).collect();
        let bvh = Bvh::new(&tris);
        let vol = Volume::build(&scene.sample);
        let tables = [0, 1, 2].map(|c| vol.channel_table(c));
        let sf = &scene.sample.surface;
        if !(sf.eta.is_finite() && sf.eta >= 1.0) {
            return Err(ObjectError::Sample(format!("eta {} must be >= 1", sf.eta)));
        }
        let bsdf = sf.dielectric();
        if let Some(cells) = &vol.cells {
            check_lights(&scene.lights, &bsdf, cells)?;
        }
        let (lo, hi) = mesh.bounds();
        let diag = (hi - lo).length();
        if !(diag.is_finite() && diag > 0.0) {
            return Err(ObjectError::Mesh("the mesh has no extent".into()));
        }
        Ok(Ctx {
            scene,
            bvh,
            vol,
            tables,
            smooth: bsdf.mf.effectively_smooth(),
            top_albedo: sf.kept_albedo(),
            bsdf,
            eps: diag * 2e-5,
            fd_step: 1e-4,
            max_events: opts.max_events,
            unscattered_env: opts.unscattered_env,
        })
    }

    /// Mean and variance of the mean of one pixel.
    fn pixel(
        &self,
        x: u32,
        y: u32,
        opts: &RenderOptions,
        counts: &mut Counts,
    ) -> ([f32; 3], [f32; 3]) {
        let mut rng = WalkRng::new(mix64(opts.seed), (y as u64) * opts.width as u64 + x as u64);
        let cam = &self.scene.camera;
        let (mut sum, mut sq) = ([0.0f64; 3], [0.0f64; 3]);
        for _ in 0..opts.spp {
            let px = x as f32 + rng.uniform();
            let py = y as f32 + rng.uniform();
            let d = cam.ray_dir(px, py, opts.width, opts.height);
            for c in 0..3 {
                let l = self.radiance(cam.eye, d, c, &mut rng, counts) as f64;
                sum[c] += l;
                sq[c] += l * l;
            }
        }
        let n = opts.spp as f64;
        let mean = sum.map(|s| s / n);
        let var = [0, 1, 2].map(|c| ((sq[c] / n - mean[c] * mean[c]).max(0.0) / (n - 1.0)) as f32);
        (mean.map(|m| m as f32), var)
    }

    /// Outward geometric and shading normals at a hit, oriented so the
    /// geometric one has the sign `sign` against `d` (+1: leaving along d).
    pub(super) fn normals(&self, h: &Hit, d: Vec3, sign: f32) -> (Vec3, Vec3, f32) {
        let mesh = &self.scene.mesh;
        let t = h.tri as usize;
        let ng = mesh.face_normal(t);
        let ns = mesh.shading_normal(t, h.b1, h.b2);
        let flip = if ng.dot(d) * sign < 0.0 { -1.0 } else { 1.0 };
        (ng * flip, ns * flip, flip)
    }

    /// Radiance of channel `c` along the camera ray (o, d).
    fn radiance(&self, o: Vec3, d: Vec3, c: usize, rng: &mut WalkRng, counts: &mut Counts) -> f32 {
        let st = &mut counts.0;
        if let Some(cells) = &self.vol.cells {
            return self.radiance_cells(cells, o, d, c, rng, st);
        }
        st.paths += 1;
        let table = &self.tables[c];
        let maj = self.vol.majorant[c];
        let homogeneous = self.vol.grid.is_none();
        let (mut o, mut d) = (o, d);
        let (mut l, mut beta) = (0.0f32, 1.0f32);
        let (mut inside, mut entered) = (false, false);
        let mut primary = true;
        let (mut events, mut surface_events) = (0u32, 0u32);
        loop {
            let hit = self.bvh.intersect(o, d, f32::INFINITY);
            if inside {
                let Some(h) = hit else {
                    st.lost += 1; // an open mesh let the path out
                    break;
                };
                // free flight to a real collision, or to the boundary
                let mut collision = None;
                if maj > 0.0 {
                    let mut t = 0.0f32;
                    loop {
                        t += exp1_from_bits(rng.next_u32()) / maj;
                        if t >= h.t {
                            break;
                        }
                        let p = o + d * t;
                        let (s_t, alb) = if homogeneous {
                            table[0]
                        } else {
                            table[self.vol.material_at(wrap(&self.vol, p))]
                        };
                        if !homogeneous && rng.uniform() * maj >= s_t {
                            st.null_events += 1;
                            continue;
                        }
                        collision = Some((p, alb));
                        break;
                    }
                }
                if let Some((p, alb)) = collision {
                    events += 1;
                    st.events += 1;
                    if !self.scene.lights.is_empty() {
                        l += beta * alb * self.lights_at_vertex(p, c, rng, st);
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
                    if beta <= 0.0 {
                        break;
                    }
                    o = p;
                    d = sample_uniform_sphere_bits(rng.next_u64());
                    continue;
                }
                // reached the boundary: fall through to the surface event
            }
            let Some(h) = hit else {
                if let Some(env) = &self.scene.env
                    && (!primary || self.scene.env_visible)
                    && (self.unscattered_env || events > 0 || !entered)
                {
                    l += beta * env.radiance(d)[c];
                }
                break;
            };
            // the surface event; normals point out of the object
            let x = o + d * h.t;
            let (ng, mut ns, _) = self.normals(&h, d, if inside { 1.0 } else { -1.0 });
            // a shading normal that puts the incoming ray on the wrong side
            // (grazing rays on a coarse mesh) yields to the geometric one
            if (ns.dot(-d) > 0.0) != (ng.dot(-d) > 0.0) {
                ns = ng;
            }
            let frame = Frame::new(ns);
            let wo = frame.to_local(-d);
            if !inside && !self.smooth {
                l += beta * self.surface_direct(x, ng, &frame, wo, c);
            }
            let Some(s) = self.bsdf.sample_f(
                wo,
                rng.uniform(),
                [rng.uniform(), rng.uniform()],
                TransportMode::Radiance,
            ) else {
                break;
            };
            let wi = frame.to_world(s.wi).normalize();
            let out = s.wi.z > 0.0;
            if (wi.dot(ng) > 0.0) != out {
                st.lost += 1;
                break;
            }
            if s.wi.z * wo.z < 0.0 {
                inside = !inside;
                entered = true;
            }
            beta *= s.weight * self.top_inv_albedo(s.wi);
            if !(beta > 0.0 && beta.is_finite()) {
                break;
            }
            surface_events += 1;
            if surface_events > MAX_SURFACE_EVENTS {
                st.truncated += 1;
                break;
            }
            o = x + ng * if out { self.eps } else { -self.eps };
            d = wi;
            primary = false;
        }
        l
    }

    /// 1 / A(u) of the sample's top, u the light-side direction (local);
    /// 1 where the top loses the share its lobe masks.
    pub(super) fn top_inv_albedo(&self, u: Vec3) -> f32 {
        self.top_albedo.as_ref().map_or(1.0, |a| 1.0 / a.at(u))
    }

    /// Reflection of the delta lights at an outside surface point (rough
    /// boundary only; a smooth one reflects them into a set of measure zero).
    fn surface_direct(&self, x: Vec3, ng: Vec3, frame: &Frame, wo: Vec3, c: usize) -> f32 {
        let mut l = 0.0;
        for light in &self.scene.lights {
            let (wl, dist, e) = light.at(x);
            if ng.dot(wl) <= 0.0 {
                continue;
            }
            let wi = frame.to_local(wl);
            let f = self.bsdf.f(wo, wi, TransportMode::Radiance);
            if f <= 0.0
                || self
                    .bvh
                    .occluded(x + ng * self.eps, wl, dist - 2.0 * self.eps)
            {
                continue;
            }
            l += f * wi.z.abs() * self.top_inv_albedo(wi) * e[c];
        }
        l
    }

    /// In-scattered radiance at volume vertex p from every delta light,
    /// divided by the vertex's albedo (phase times incident radiance).
    fn lights_at_vertex(&self, p: Vec3, c: usize, rng: &mut WalkRng, st: &mut ObjectStats) -> f32 {
        let mut l = 0.0;
        for light in &self.scene.lights {
            l += if self.smooth {
                self.smooth_nee(p, light, c, rng, st)
            } else {
                self.rough_nee(p, light, c, rng, st)
            };
        }
        l
    }

    /// The roulette probability of a vertex estimate over distance `s`.
    pub(super) fn nee_probability(&self, c: usize, s: f32) -> f32 {
        (10.0 * (-self.vol.majorant[c] * s).exp()).clamp(0.05, 1.0)
    }

    /// Smooth boundary: the entry-point walk, then T Phi' / beam area.
    fn smooth_nee(
        &self,
        p: Vec3,
        light: &DeltaLight,
        c: usize,
        rng: &mut WalkRng,
        st: &mut ObjectStats,
    ) -> f32 {
        let eta = self.bsdf.eta;
        let (mut w, _, _) = light.at(p);
        let Some(mut h) = self.bvh.intersect(p, w, f32::INFINITY) else {
            return 0.0;
        };
        let q = self.nee_probability(c, h.t);
        if rng.uniform() >= q {
            return 0.0;
        }
        st.nee += 1;
        let mut converged = None;
        let (mut lambda, mut r2_prev) = (1.0f32, f32::INFINITY);
        for _ in 0..WALK_STEPS {
            let x = p + w * h.t;
            let (ng, ns, flip) = self.normals(&h, w, 1.0);
            let (wl, dist, e) = light.at(x);
            let c = ns.dot(wl);
            // On the unlit side the walk goes on with the normal mirrored
            // across the light's wavefront (grazing entry at the
            // terminator), so points inside beyond the terminator, lit
            // by rays refracted at grazing entry, find their entry.
            let n_eff = if c > 0.0 {
                ns
            } else {
                (ns - 2.0 * c * wl).normalize()
            };
            let Some((t, _)) = refract(wl, n_eff, eta) else {
                return 0.0;
            };
            let r = (-t).normalize() - w;
            let r2 = r.length_squared();
            if c > 0.0 && ng.dot(wl) > 0.0 && r2 < 1e-10 {
                converged = Some((x, ng, ns, flip, wl, dist, e, t));
                break;
            }
            // relaxed: the step halves whenever the residual grows (far
            // from the entry the plain iteration overshoots)
            if r2 > r2_prev {
                lambda *= 0.5;
            }
            r2_prev = r2;
            w = (w + r * lambda).normalize();
            let Some(h2) = self.bvh.intersect(p, w, f32::INFINITY) else {
                return 0.0;
            };
            h = h2;
        }
        let Some((x, ng, ns, flip, wl, dist, e, t)) = converged else {
            st.nee_unconverged += 1;
            return 0.0;
        };
        if self
            .bvh
            .occluded(x + ng * self.eps, wl, dist - 2.0 * self.eps)
        {
            return 0.0;
        }
        let s = h.t;
        let tr = self.transmittance(p, w, s, c, rng);
        if tr <= 0.0 {
            return 0.0;
        }
        let area = self.beam_area(&h, flip, x, t, s, light);
        if !(area.is_finite() && area > 0.0) {
            return 0.0;
        }
        let tf = 1.0 - fr_dielectric(ns.dot(wl), eta);
        let e_p = (tf as f64 * e[c] as f64 * self.beam_flux_scale(light, dist) / area) as f32;
        PHASE * e_p * tr / q
    }

    /// Phi' over the light's value at the entry point: 1 for a directional
    /// light (E per area across the beam); r^2 for a point light (the
    /// value is I / r^2, the beam is parametrised per steradian).
    fn beam_flux_scale(&self, light: &DeltaLight, dist: f32) -> f64 {
        match light {
            DeltaLight::Directional { .. } => 1.0,
            DeltaLight::Point { .. } => (dist as f64) * (dist as f64),
        }
    }

    /// |(dy/du1 x dy/du2) . t| of the refracted beam at distance s from the
    /// entry x, per unit of the beam's parameter (see the module comment).
    fn beam_area(&self, h: &Hit, flip: f32, x: Vec3, t: Vec3, s: f32, light: &DeltaLight) -> f64 {
        let mesh = &self.scene.mesh;
        let tri = h.tri as usize;
        let [a, b, cc] = mesh.corners(tri).map(|v| v.as_dvec3());
        let ids = mesh.triangles[tri];
        let vn = ids.map(|i| mesh.normals[i as usize].as_dvec3());
        let ng = (b - a).cross(cc - a).normalize() * flip as f64;
        let face_only = vn.contains(&DVec3::ZERO);
        let eta = self.bsdf.eta as f64;
        let x = x.as_dvec3();
        let s = s as f64;
        // the shading normal at a point of the triangle's plane (barycentric
        // interpolation, extrapolated just outside), outward
        let normal_at = |q: DVec3| -> DVec3 {
            if face_only {
                return ng;
            }
            let (v0, v1, v2) = (b - a, cc - a, q - a);
            let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
            let (d20, d21) = (v2.dot(v0), v2.dot(v1));
            let den = d00 * d11 - d01 * d01;
            let b1 = (d11 * d20 - d01 * d21) / den;
            let b2 = (d00 * d21 - d01 * d20) / den;
            let n = (vn[0] * (1.0 - b1 - b2) + vn[1] * b1 + vn[2] * b2).normalize();
            if n.dot(ng) < 0.0 { -n } else { n }
        };
        // the refracted ray's point at distance s for beam parameter (u1, u2)
        let y_of = |u: [f64; 2], e1: DVec3, e2: DVec3| -> Option<DVec3> {
            let (xq, wl) = match *light {
                DeltaLight::Directional { to_light, .. } => {
                    let wl = to_light.as_dvec3();
                    let o = x + (e1 * u[0] + e2 * u[1]);
                    let tau = (x - o).dot(ng) / (-wl).dot(ng);
                    (o - wl * tau, wl)
                }
                DeltaLight::Point { position, .. } => {
                    let pos = position.as_dvec3();
                    let w0 = (x - pos).normalize();
                    let dq = (w0 + e1 * u[0] + e2 * u[1]).normalize();
                    let tau = (x - pos).dot(ng) / dq.dot(ng);
                    (pos + dq * tau, -dq)
                }
            };
            let n = normal_at(xq);
            let ci = wl.dot(n);
            if ci <= 0.0 {
                return None;
            }
            let sin2 = (1.0 - ci * ci).max(0.0) / (eta * eta);
            if sin2 >= 1.0 {
                return None;
            }
            let tq = -wl / eta + (ci / eta - (1.0 - sin2).sqrt()) * n;
            Some(xq + tq * s)
        };
        let axis = match *light {
            DeltaLight::Directional { to_light, .. } => to_light.as_dvec3(),
            DeltaLight::Point { position, .. } => (x - position.as_dvec3()).normalize(),
        };
        let e1 = axis.any_orthonormal_vector();
        let e2 = axis.cross(e1);
        // step: mm across a directional beam (relative to the distance
        // travelled), radians out of a point light
        let hstep = match light {
            DeltaLight::Directional { .. } => self.fd_step * (1.0 + s),
            DeltaLight::Point { .. } => self.fd_step,
        };
        let d = |e: DVec3| -> Option<DVec3> {
            let plus = y_of([hstep, 0.0], e, DVec3::ZERO)?;
            let minus = y_of([-hstep, 0.0], e, DVec3::ZERO)?;
            Some((plus - minus) / (2.0 * hstep))
        };
        let (Some(d1), Some(d2)) = (d(e1), d(e2)) else {
            return f64::NAN;
        };
        d1.cross(d2).dot(t.as_dvec3()).abs()
    }

    /// Rough boundary: a uniform direction to the boundary, the BTDF there.
    fn rough_nee(
        &self,
        p: Vec3,
        light: &DeltaLight,
        c: usize,
        rng: &mut WalkRng,
        st: &mut ObjectStats,
    ) -> f32 {
        let w = sample_uniform_sphere_bits(rng.next_u64());
        let Some(h) = self.bvh.intersect(p, w, f32::INFINITY) else {
            return 0.0;
        };
        let q = self.nee_probability(c, h.t);
        if rng.uniform() >= q {
            return 0.0;
        }
        st.nee += 1;
        let x = p + w * h.t;
        let (ng, mut ns, _) = self.normals(&h, w, 1.0);
        if (ns.dot(w) > 0.0) != (ng.dot(w) > 0.0) {
            ns = ng;
        }
        let (wl, dist, e) = light.at(x);
        if ng.dot(wl) <= 0.0 {
            return 0.0;
        }
        let frame = Frame::new(ns);
        let wi = frame.to_local(wl);
        let f = self.bsdf.f(frame.to_local(-w), wi, TransportMode::Radiance);
        if f.is_nan()
            || f <= 0.0
            || self
                .bvh
                .occluded(x + ng * self.eps, wl, dist - 2.0 * self.eps)
        {
            return 0.0;
        }
        let tr = self.transmittance(p, w, h.t, c, rng);
        // phase / pdf(w) = (1 / 4 pi) / (1 / 4 pi)
        f * wi.z.abs() * self.top_inv_albedo(wi) * e[c] * tr / q
    }

    /// Transmittance from p along w over s: exact when homogeneous, ratio
    /// tracking against the majorant in the tiled grid.
    fn transmittance(&self, p: Vec3, w: Vec3, s: f32, c: usize, rng: &mut WalkRng) -> f32 {
        let maj = self.vol.majorant[c];
        if self.vol.grid.is_none() {
            return (-self.tables[c][0].0 * s).exp();
        }
        if maj <= 0.0 {
            return 1.0;
        }
        let table = &self.tables[c];
        let (mut tr, mut t) = (1.0f32, 0.0f32);
        loop {
            t += exp1_from_bits(rng.next_u32()) / maj;
            if t >= s {
                return tr;
            }
            let m = self.vol.material_at(wrap(&self.vol, p + w * t));
            tr *= 1.0 - table[m].0 / maj;
            if tr < 1e-3 {
                if rng.uniform() < 0.5 {
                    return 0.0;
                }
                tr *= 2.0;
            }
        }
    }
}
