//! The renderer: paper eq. 4 evaluated at the first surface hit of every
//! camera ray,
//!
//!   L(x_o, w_o) = max(0, L_local + L_global), per channel, where
//!   L_local  = ∫ R(x_o, w_i, w_o) L(w_i) dw_i
//!            = Σ_lights R(x_o, w_l, w_o) V E_l + (1/N) Σ_k R L_env(w_k) V / pdf(w_k)
//!   L_global = f_v(x_o, w_o) / pi · Σ_i R_d(|x_o - x_i|) E_i A_i     (mode full)
//!
//! with E_i the irradiance of the surface samples that enters, T(0) f(w_i)
//! E (see [`crate::points`]), and the sum evaluated by the octree
//! ([`crate::octree`]). Normalisation, as qhm-model defines its fit
//! (docs/model-format.md): R_d integrates to R_total(a'), the outgoing per
//! entered flux (Jensen et al. 2001; sim-light's Monte Carlo slab agrees
//! with it per entered photon), so Σ R_d E A is a diffuse exitance, 1/pi
//! turns it into radiance, and f_v (1 for a homogeneous material) carries
//! the view dependence. f is 1 at normal incidence; T(0) = 1 - F_r(eta, 0)
//! is the normal beam's entry (qhm-model fits a' from R / T(0)). The
//! plain-dipole modes use the smooth-surface Fresnel shapes of Jensen et
//! al. 2001 instead of f and f_v: E_i attenuated by 1 - F_r(eta, w_i), and
//! L_global = (1 - F_r(eta, w_o)) / ((1 - F̄) pi) · Σ R_d E_i A_i, the exit
//! normalised because R_total(a') already counts only light that left
//! (Jensen's unnormalised 1 - F_r on exit would apply it a second time, as
//! would any Fresnel factor on top of f_v in eq. 4, which already contains
//! the outgoing Fresnel term; paper section 3).
//!
//! When the material has an LRF, the dipole sum leaves out the disc A_o of
//! radius `Material::local_disc_mm` around x_o: eq. 4 sums over B_o = A - A_o,
//! and the LRF already holds what enters and leaves inside A_o (qhm-model's
//! fit subtracts R_total - R_texel, the texel's own equal-area disc kept in
//! the LRF). Summing the whole plane would count that part twice.
//!
//! Modes (paper Fig. 9): `full` (LRF + f, f_v, dipole), `lrf-only` (the BTF
//! part alone), `lrf-dipole` (LRF + plain dipole without f and f_v) and
//! `dipole-only` (plain dipole). Pixels are rendered in 16 x 16 tiles in
//! parallel (rayon), with a progress bar; each pixel takes `spp` stratified
//! jittered samples. The dipole sum is smooth at the scale of the surface
//! samples' spacing, so where pixels are finer than that it is summed on a
//! grid every other pixel and interpolated ([`GlobalGrid`]).

use std::f32::consts::PI;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::bvh::Ray;
use crate::error::RenderError;
use crate::film::Image;
use crate::material::Material;
use crate::octree::QueryStats;
use crate::points::{frame, to_local};
use crate::prepare::{Prepared, prepare};
use crate::scene::Scene;
use crate::settings::{RenderSettings, RenderStats};

/// Renders `scene` with `material`: the API the CLI and tests use.
pub fn render_scene<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
) -> Result<Image, RenderError> {
    render_scene_stats(scene, material, settings).map(|(img, _)| img)
}

/// [`render_scene`] with timings.
pub fn render_scene_stats<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
) -> Result<(Image, RenderStats), RenderError> {
    render_scene_camera(scene, material, settings, |x, y| {
        scene.camera.ray(x, y, settings.width, settings.height)
    })
}

/// [`render_scene_stats`] through the caller's camera model instead of
/// `scene.camera`: `ray(x, y)` is the ray through film position (x, y) in
/// pixels of the `settings.width` x `settings.height` image (origin top
/// left, pixel i spanning [i, i + 1)).
/// For cameras the pinhole [`crate::Camera`] cannot express, e.g. a
/// calibrated camera with lens distortion (the Fig. 7 comparison renders
/// through the simulated rig's camera).
pub fn render_scene_camera<M: Material, F>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    ray: F,
) -> Result<(Image, RenderStats), RenderError>
where
    F: Fn(f32, f32) -> Ray + Sync,
{
    let t0 = Instant::now();
    let mut stats = RenderStats::default();
    let prep = prepare(scene, material, settings, &mut stats)?;
    let t = Instant::now();
    let (img, queries, terms) = render_pixels(scene, material, settings, &prep, &ray, None);
    stats.secs_pixels = t.elapsed().as_secs_f64();
    stats.queries = queries;
    stats.terms = terms;
    stats.secs_total = t0.elapsed().as_secs_f64();
    Ok((img, stats))
}

/// The pixel pass alone, through `scene.camera`, on an existing pass 1:
/// a camera move with the object, lights and mode unchanged reuses `prep`
/// whole (`qhm view`). Returns None, unfinished, once `cancel` is set (it is
/// read before each tile). The image equals [`render_scene_stats`]'s when
/// `prep` was made with the same settings.
pub fn render_prepared<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    prep: &Prepared,
    cancel: &AtomicBool,
) -> Option<(Image, RenderStats)> {
    let t = Instant::now();
    let ray = |x, y| scene.camera.ray(x, y, settings.width, settings.height);
    let (img, queries, terms) = render_pixels(scene, material, settings, prep, &ray, Some(cancel));
    if cancel.load(Ordering::Relaxed) {
        return None;
    }
    let secs = t.elapsed().as_secs_f64();
    let stats = RenderStats {
        surface_samples: prep.samples.pos.len(),
        octree_nodes: prep.tree.node_count(),
        secs_pixels: secs,
        secs_total: secs,
        queries,
        terms,
        ..RenderStats::default()
    };
    Some((img, stats))
}

const TILE: u32 = 16;

fn render_pixels<M: Material, F>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    prep: &Prepared,
    camera: &F,
    cancel: Option<&AtomicBool>,
) -> (Image, u64, u64)
where
    F: Fn(f32, f32) -> Ray + Sync,
{
    let (w, h) = (settings.width, settings.height);
    let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE))
        .flat_map(|ty| (0..w.div_ceil(TILE)).map(move |tx| (tx * TILE, ty * TILE)))
        .collect();
    // A bar on a terminal, a line every few seconds in a log.
    let bar = qhm_progress::Bar::new("render tiles", tiles.len() as u64, !settings.progress);
    let m = (settings.spp as f32).sqrt().ceil() as u32;
    let n_cam = m * m;
    let results: Vec<(u32, u32, Vec<Vec3>, QueryStats, u64)> = tiles
        .par_iter()
        .map(|&(x0, y0)| {
            let mut out = Vec::with_capacity((TILE * TILE) as usize);
            let mut qs = QueryStats::default();
            let mut queries = 0u64;
            if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                return (x0, y0, out, qs, queries);
            }
            let mut grid = (settings.mode.has_global() && !prep.tree.is_empty()).then(|| {
                let size = ((x0 + TILE).min(w) - x0, (y0 + TILE).min(h) - y0);
                GlobalGrid::new(scene, size, |gx, gy| camera(x0 as f32 + gx, y0 as f32 + gy))
            });
            for y in y0..(y0 + TILE).min(h) {
                for x in x0..(x0 + TILE).min(w) {
                    let mut rng = Pcg64Mcg::seed_from_u64(
                        settings.seed
                            ^ ((y as u64) << 32 | x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                    );
                    let mut sum = Vec3::ZERO;
                    let mut cache = None;
                    for a in 0..m {
                        for b in 0..m {
                            let px = x as f32 + (a as f32 + rng.random::<f32>()) / m as f32;
                            let py = y as f32 + (b as f32 + rng.random::<f32>()) / m as f32;
                            let ray = camera(px, py);
                            sum += radiance(
                                scene,
                                material,
                                settings,
                                prep,
                                &ray,
                                (px - x0 as f32, py - y0 as f32),
                                grid.as_mut(),
                                &mut rng,
                                &mut cache,
                                &mut qs,
                                &mut queries,
                            );
                        }
                    }
                    out.push(sum / n_cam as f32);
                }
            }
            bar.inc(1);
            (x0, y0, out, qs, queries)
        })
        .collect();
    bar.finish();
    let mut img = Image::new(w, h);
    let (mut queries, mut terms) = (0, 0);
    for (x0, y0, px, qs, q) in results {
        queries += q;
        terms += qs.nodes_used + qs.points_used;
        let tw = (x0 + TILE).min(w) - x0;
        for (k, c) in px.into_iter().enumerate() {
            let (x, y) = (x0 + k as u32 % tw, y0 + k as u32 / tw);
            img.pixels[(y * w + x) as usize] = c.to_array();
        }
    }
    (img, queries, terms)
}

/// Radiance along one camera ray.
#[allow(clippy::too_many_arguments)]
fn radiance<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    prep: &Prepared,
    ray: &Ray,
    film: (f32, f32),
    grid: Option<&mut GlobalGrid>,
    rng: &mut Pcg64Mcg,
    cache: &mut Option<(Vec3, Vec3)>,
    qs: &mut QueryStats,
    queries: &mut u64,
) -> Vec3 {
    let Some(at) = SurfaceHit::first(scene, ray) else {
        return match (&scene.env, scene.env_visible) {
            (Some(env), true) => env.radiance(ray.d),
            _ => Vec3::ZERO,
        };
    };
    let mesh = &scene.mesh;
    let SurfaceHit { p, wo, ng, ns, .. } = at;
    let (t, hit) = (at.tri, at.hit);
    let fr = frame(ns, prep.field.at(mesh, t, hit.b1, hit.b2));
    let mut wo_l = to_local(&fr, wo);
    wo_l.z = wo_l.z.max(1e-3);
    let wo_l = wo_l.normalize();
    let tex = prep.texture.lookup(mesh, t, hit.b1, hit.b2, p, ns);
    let origin = p + ng * scene.eps;
    let mut l = Vec3::ZERO;

    // Local term: the LRF over the light arriving at x_o.
    if settings.mode.has_lrf() && material.has_lrf() {
        let lrf_light = |wi: Vec3, dist: f32, e: Vec3| {
            if ng.dot(wi) <= 0.0 {
                return Vec3::ZERO;
            }
            let wi_l = to_local(&fr, wi);
            if wi_l.z <= 0.0
                || scene
                    .bvh
                    .occluded(&Ray { o: origin, d: wi }, dist - 2.0 * scene.eps)
            {
                return Vec3::ZERO;
            }
            material.lrf_blend(&tex, wi_l.to_array(), wo_l.to_array()) * e
        };
        for light in &scene.lights {
            let s = light.sample(p);
            l += lrf_light(s.wi, s.dist, s.e_perp);
        }
        if let Some(env) = &scene.env {
            let n = settings.light_samples;
            for _ in 0..n {
                let (wi, le, pdf) = env.sample(rng.random(), rng.random());
                if pdf > 0.0 {
                    l += lrf_light(wi, f32::INFINITY, le / (pdf * n as f32));
                }
            }
        }
    }

    // Global term: the hierarchical dipole sum, modulated on exit.
    if settings.mode.has_global() && !prep.tree.is_empty() {
        let interpolated = grid.and_then(|g| g.interpolate(film, &at, settings, prep, qs, queries));
        let m = match interpolated {
            Some(m) => m,
            None => {
                // Within a pixel the dipole sum is smooth: samples that land
                // within a surface-sample radius of the previous query reuse
                // its value.
                let r2 = prep.samples.radius * prep.samples.radius;
                match *cache {
                    Some((q, m)) if q.distance_squared(p) < r2 => m,
                    _ => {
                        let m = global_exitance(settings, prep, &at, qs);
                        *queries += 1;
                        *cache = Some((p, m));
                        m
                    }
                }
            }
        };
        let exit = if settings.mode.plain_dipole() {
            // Normalised: (1 - F_r(w_o)) / ((1 - F̄) pi) integrates to 1
            // against cos dw_o, so the exitance stays Σ R_d E A (see the
            // module comment).
            let per_radiance = qhm_model::fresnel::exitance_per_radiance(
                wo_l.z as f64,
                prep.eta,
                prep.fresnel_average,
            );
            Vec3::splat((1.0 / per_radiance) as f32)
        } else {
            let fv = material.exiting_blend(&tex, wo_l.to_array());
            match &prep.exit_shape {
                Some(shape) => fv * shape.eval(wo_l.z) / PI,
                None => fv / PI,
            }
        };
        l += exit * m;
    }
    // Negative sums (the LRF is a difference of images) are clamped here.
    l.max(Vec3::ZERO)
}

/// Where a camera ray first meets the object, its normals two-sided.
struct SurfaceHit {
    tri: usize,
    hit: crate::bvh::Hit,
    p: Vec3,
    wo: Vec3,
    /// Face and shading normals, turned towards the viewer.
    ng: Vec3,
    ns: Vec3,
    /// The shading normal in the mesh's winding (the dipole's geometry
    /// factor takes that one).
    n_winding: Vec3,
}

impl SurfaceHit {
    fn first(scene: &Scene, ray: &Ray) -> Option<SurfaceHit> {
        let hit = scene.bvh.intersect(ray, f32::INFINITY)?;
        let tri = hit.tri as usize;
        let wo = -ray.d;
        let mut ng = scene.mesh.face_normal(tri);
        let mut ns = scene.mesh.shading_normal(tri, hit.b1, hit.b2);
        let n_winding = ns;
        if ng.dot(wo) < 0.0 {
            ng = -ng;
            ns = -ns;
        }
        Some(SurfaceHit {
            tri,
            p: ray.o + ray.d * hit.t,
            hit,
            wo,
            ng,
            ns,
            n_winding,
        })
    }
}

/// The global term's exitance M at `at` (before f_v and 1/pi): the
/// hierarchical dipole sum, with the diffusion (P1) radiance inside
/// refracted out towards w_o. The flux along the view's tangent u adds
/// 3 s' M_u / (2A + 3 c') to the normal flux M_n, s' = sin θ_o / η.
fn global_exitance(
    settings: &RenderSettings,
    prep: &Prepared,
    at: &SurfaceHit,
    qs: &mut QueryStats,
) -> Vec3 {
    let (u, k) = if prep.geometry {
        let t = at.wo - at.ns * at.wo.dot(at.ns);
        let s = (t.length() / prep.eta as f32).min(1.0);
        let c = (1.0 - s * s).sqrt();
        let a = qhm_model::dipole::boundary_a(prep.eta) as f32;
        (t.normalize_or_zero(), 3.0 * s / (2.0 * a + 3.0 * c))
    } else {
        (Vec3::ZERO, 0.0)
    };
    let (mn, mu) = prep.tree.query_flux(
        at.p,
        at.n_winding,
        u,
        &prep.rd,
        settings.epsilon,
        settings.local_radius_mm,
        qs,
    );
    (mn + mu * k).max(Vec3::ZERO)
}

/// Pixels between corners of the global term's grid.
const GRID_STEP: u32 = 2;

/// How far a corner may lie from the point it serves, in surface sample
/// radii.
const GRID_REACH: f32 = 3.0;

/// The global term on a grid over one tile, every [`GRID_STEP`] pixels:
/// M is a sum of kernels at least a surface sample's radius wide, so
/// within that radius it is smooth, and a camera sample whose four
/// corners lie on the same surface close by takes M bilinearly from
/// them. The corners' rays are traced up front; their M is summed when a
/// camera sample first needs it, so a grid whose corners are too far
/// apart (a small image) costs only those rays.
struct GlobalGrid {
    cols: usize,
    nodes: Vec<Option<GridNode>>,
}

struct GridNode {
    at: SurfaceHit,
    m: Option<Vec3>,
}

impl GlobalGrid {
    /// The grid over a tile `size` pixels wide and high; `camera(x, y)` is
    /// the ray through the tile's film position (x, y).
    fn new(scene: &Scene, size: (u32, u32), camera: impl Fn(f32, f32) -> Ray) -> GlobalGrid {
        let cols = size.0.div_ceil(GRID_STEP) as usize + 1;
        let rows = size.1.div_ceil(GRID_STEP) as usize + 1;
        let nodes = (0..rows * cols)
            .map(|k| {
                let (i, j) = ((k % cols) as u32, (k / cols) as u32);
                let ray = camera((i * GRID_STEP) as f32, (j * GRID_STEP) as f32);
                SurfaceHit::first(scene, &ray).map(|at| GridNode { at, m: None })
            })
            .collect();
        GlobalGrid { cols, nodes }
    }

    /// M at the tile's film position `film` for the surface point `at`,
    /// bilinear in the cell's corners, or None where a corner misses the
    /// object, lies [`GRID_REACH`] surface sample radii or more from `at`,
    /// or turns its normal by more than ~25° (a silhouette, another part, a
    /// crease).
    fn interpolate(
        &mut self,
        film: (f32, f32),
        at: &SurfaceHit,
        settings: &RenderSettings,
        prep: &Prepared,
        qs: &mut QueryStats,
        queries: &mut u64,
    ) -> Option<Vec3> {
        let (fx, fy) = (film.0 / GRID_STEP as f32, film.1 / GRID_STEP as f32);
        let (i, j) = (fx as usize, fy as usize);
        if i + 1 >= self.cols {
            return None;
        }
        let corners = [
            j * self.cols + i,
            j * self.cols + i + 1,
            (j + 1) * self.cols + i,
            (j + 1) * self.cols + i + 1,
        ];
        let r2 = (GRID_REACH * prep.samples.radius).powi(2);
        for &k in &corners {
            let node = self.nodes.get(k)?.as_ref()?;
            if node.at.p.distance_squared(at.p) >= r2 || node.at.n_winding.dot(at.n_winding) < 0.9 {
                return None;
            }
        }
        let (s, t) = (fx - i as f32, fy - j as f32);
        let weights = [(1.0 - s) * (1.0 - t), s * (1.0 - t), (1.0 - s) * t, s * t];
        let mut m = Vec3::ZERO;
        for (k, w) in corners.into_iter().zip(weights) {
            let node = self.nodes[k].as_mut()?;
            let mk = *node.m.get_or_insert_with(|| {
                *queries += 1;
                global_exitance(settings, prep, &node.at, qs)
            });
            m += mk * w;
        }
        Some(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::materials::{Homogeneous, preset};

    /// Over every tile of a lit teapot at 384 x 384, M from the grid against
    /// M summed at each camera sample's own point: the bilinear weights are
    /// within 0.6 % (RMS; measured 0.47 %) of it, where the nearest corner's
    /// value alone is more than 2.5 times further off (1.85 %).
    #[test]
    fn the_global_grid_gives_the_sum_at_each_point() {
        let scene = Scene::lit(crate::builtin::teapot(12.0, crate::builtin::TEAPOT_CELL).unwrap());
        let material = Homogeneous {
            dipole: preset("marble").unwrap(),
        };
        let settings = RenderSettings {
            width: 384,
            height: 384,
            surface_samples: 12_000,
            ..RenderSettings::default()
        };
        let prep = prepare(&scene, &material, &settings, &mut RenderStats::default()).unwrap();
        let (mut qs, mut queries) = (QueryStats::default(), 0);
        let (mut rng, tile) = (Pcg64Mcg::seed_from_u64(3), TILE as f32);
        let (mut err, mut nearest_err, mut norm, mut served) = (0.0f64, 0.0f64, 0.0f64, 0);
        for (x0, y0) in
            (0..384 / TILE).flat_map(|y| (0..384 / TILE).map(move |x| (x * TILE, y * TILE)))
        {
            let camera = |x: f32, y: f32| scene.camera.ray(x0 as f32 + x, y0 as f32 + y, 384, 384);
            let mut grid = GlobalGrid::new(&scene, (TILE, TILE), camera);
            for _ in 0..16 {
                let film = (rng.random::<f32>() * tile, rng.random::<f32>() * tile);
                let Some(at) = SurfaceHit::first(&scene, &camera(film.0, film.1)) else {
                    continue;
                };
                let Some(m) = grid.interpolate(film, &at, &settings, &prep, &mut qs, &mut queries)
                else {
                    continue;
                };
                let exact = global_exitance(&settings, &prep, &at, &mut qs);
                let (i, j) = (
                    (film.0 / GRID_STEP as f32).round() as usize,
                    (film.1 / GRID_STEP as f32).round() as usize,
                );
                let nearest = grid.nodes[j * grid.cols + i].as_ref().unwrap().m.unwrap();
                let l = |v: Vec3| crate::light::luminance(v) as f64;
                err += (l(m) - l(exact)).powi(2);
                nearest_err += (l(nearest) - l(exact)).powi(2);
                norm += l(exact).powi(2);
                served += 1;
            }
        }
        let (rms, nearest_rms) = ((err / norm).sqrt(), (nearest_err / norm).sqrt());
        assert!(served > 400, "{served} samples taken from the grid");
        assert!(rms < 0.006, "bilinear: relative RMS {rms}");
        assert!(
            nearest_rms > 2.5 * rms,
            "nearest corner: {nearest_rms} against {rms}"
        );
    }
}
