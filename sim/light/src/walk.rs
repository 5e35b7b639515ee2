//! The Monte Carlo photon walk: photons from a laser stripe, a lamp or a
//! pencil beam enter the sample through its rough dielectric top, random-walk
//! through the volume (free flights sampled against s_t, delta tracking with
//! the majorant in heterogeneous volumes, isotropic scattering with reduced
//! coefficients, analog absorption), and leave or die at the black sides and
//! bottom. Every surface event is splatted by next-event estimation into every
//! camera: the BSDF towards the camera, times visibility against the height
//! field, over the pixel's solid angle (light tracing, pbrt's
//! `LightPathIntegrator`). Nothing here uses a diffusion approximation.
//!
//! Determinism: photons go in fixed blocks, each with its own RNG stream;
//! splats add as 64-bit fixed point with atomics, so the sum (and tallies,
//! which are integers) is the same for any thread count and schedule.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use glam::{Mat3, Vec3};
use rayon::prelude::*;

use crate::medium::Volume;
use crate::microfacet::{
    Dielectric, ResampledLobe, SingleScatteringAlbedo, TransportMode, fr_dielectric, refract,
};
use crate::rng::{WalkRng, exp1_from_bits, mix64, unit_f32};
use crate::sample::{COLOUR_PATTERN, TargetDesc, colour_patch_at};
use crate::surface::HeightField;

/// Photons per RNG stream / work item.
pub const BLOCK: u64 = 2048;
/// A photon that scatters this often is counted as truncated.
pub const MAX_EVENTS: u32 = 1_000_000;
/// A photon in a cellular medium that meets this many walls is truncated.
pub const MAX_INTERFACES: u32 = 1_000_000;
/// Share of scattering vertices (within a mean free path of the surface)
/// that make a next-event estimate: consecutive vertices of one path see
/// nearly the same light, so a tenth of them loses little and saves most of
/// the cost.
pub(crate) const NEE_RATE: f32 = 0.1;
/// Share of uniformly sampled directions in the vertex estimate on a relief.
const DEFENSIVE: f32 = 0.1;
/// Fixed-point quanta per unit of normalised splat.
const QUANTUM: f64 = 4_294_967_296.0;

/// What the top surface is.
#[derive(Debug, Clone)]
pub enum SurfaceKind {
    /// A sample: rough dielectric over the volume.
    Dielectric(Dielectric),
    /// A calibration target: opaque Lambertian.
    Lambertian(TargetDesc),
}

/// The built scene the walks run in.
#[derive(Debug, Clone)]
pub struct Scene {
    pub surface: HeightField,
    pub kind: SurfaceKind,
    pub volume: Option<Volume>,
    /// A(u) of the dielectric top when it keeps the share its lobe masks
    /// (`SurfaceDesc::conserve_energy`, rough tops only): photons resample
    /// until a direction survives, and splats divide by A.
    pub top_albedo: Option<SingleScatteringAlbedo>,
}

impl Scene {
    /// 1 / A(u) of the top, u the light-side direction (local); 1 where the
    /// top loses the share its lobe masks.
    pub fn top_inv_albedo(&self, u: Vec3) -> f32 {
        self.top_albedo.as_ref().map_or(1.0, |a| 1.0 / a.at(u))
    }

    /// Lambertian reflectance of a target at (x, y).
    pub fn target_albedo(&self, x: f32, y: f32, ch: usize) -> f32 {
        let SurfaceKind::Lambertian(t) = &self.kind else {
            return 0.0;
        };
        let v = match t {
            TargetDesc::Checkerboard {
                square_mm, albedo, ..
            } => {
                let i =
                    (x as f64 / square_mm).floor() as i64 + (y as f64 / square_mm).floor() as i64;
                albedo[i.rem_euclid(2) as usize]
            }
            TargetDesc::ColourPattern { patch_mm } => {
                match colour_patch_at(x as f64, y as f64, *patch_mm) {
                    Some(k) => COLOUR_PATTERN[k][ch],
                    None => 0.02, // black mount around the chart
                }
            }
            TargetDesc::White { albedo, .. } => *albedo,
            TargetDesc::TwoHeight { albedo, .. } => *albedo,
        };
        v as f32
    }
}

/// A camera prepared for splatting, in the sample's frame.
#[derive(Debug, Clone)]
pub struct SplatCamera {
    /// The rig's camera number: seeds this camera's next-event estimates, so
    /// its image does not depend on which other cameras are rendered.
    pub id: u32,
    pub pos: Vec3,
    /// World(sample)-to-camera rotation.
    pub rot: Mat3,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub k1: f32,
    pub k2: f32,
    pub width: u32,
    pub height: u32,
    /// Divides splats so they are O(1): fx fy / 450^2.
    pub norm: f32,
}

impl SplatCamera {
    /// Pixel index and 1 / (pixel solid angle * distance^2) for a point.
    #[inline]
    fn project(&self, p: Vec3) -> Option<(usize, f32, Vec3)> {
        let v = p - self.pos;
        let pc = self.rot * v;
        if pc.z <= 1e-3 {
            return None;
        }
        let (x, y) = (pc.x / pc.z, pc.y / pc.z);
        let r2 = x * x + y * y;
        let dist = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        let u = self.fx * x * dist + self.cx;
        let w = self.fy * y * dist + self.cy;
        if !(u >= 0.0 && w >= 0.0 && u < self.width as f32 && w < self.height as f32) {
            return None;
        }
        let d2 = v.length_squared();
        let d = d2.sqrt();
        let cos_c = pc.z / d;
        // pixel solid angle: cos^3 / (fx fy) (pinhole; distortion's area change neglected)
        let inv = self.fx * self.fy / (cos_c * cos_c * cos_c * d2);
        Some(((w as usize) * self.width as usize + u as usize, inv, -v / d))
    }
}

/// Where the photons come from.
#[derive(Debug, Clone, Copy)]
pub enum Source {
    /// A laser fan from `origin` onto the segment centre + s dir, |s| <= length/2.
    Stripe {
        origin: Vec3,
        centre: Vec3,
        dir: Vec3,
        length: f32,
    },
    /// A directional lamp; `to_lamp` is the unit direction towards it. Photons
    /// fall uniformly (in horizontal area) over the sample footprint.
    Lamp { to_lamp: Vec3 },
    /// A thin beam.
    Pencil { origin: Vec3, dir: Vec3 },
}

/// How photons ended, counted (integers, so sums are exact).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Tally {
    pub launched: u64,
    /// Missed the sample (fell on the black turntable).
    pub missed: u64,
    /// Reflected by the top surface on entry (specular / Lambertian target).
    pub reflected: u64,
    /// Left through the top after subsurface transport.
    pub exited: u64,
    /// Absorbed in the volume (or by a target).
    pub absorbed: u64,
    /// Lost at the black sides and bottom.
    pub escaped: u64,
    /// Killed at the rough boundary by microfacet shadowing-masking.
    pub surface_loss: u64,
    /// Scattered more than MAX_EVENTS times.
    pub truncated: u64,
    /// Real collisions (scattering or absorption).
    pub events: u64,
    /// Null collisions of delta tracking.
    pub null_events: u64,
    /// Photons that entered the volume (crossed into it at least once):
    /// over `launched`, the entrance share of the incident light.
    pub entered: u64,
    /// Reflections and refractions at the cell walls of a cellular medium.
    pub wall_events: u64,
}

impl std::ops::Add for Tally {
    type Output = Tally;
    fn add(mut self, o: Tally) -> Tally {
        self.launched += o.launched;
        self.missed += o.missed;
        self.reflected += o.reflected;
        self.exited += o.exited;
        self.absorbed += o.absorbed;
        self.escaped += o.escaped;
        self.surface_loss += o.surface_loss;
        self.truncated += o.truncated;
        self.events += o.events;
        self.null_events += o.null_events;
        self.entered += o.entered;
        self.wall_events += o.wall_events;
        self
    }
}

impl Tally {
    /// Every launched photon is accounted for exactly once.
    pub fn balanced(&self) -> bool {
        self.launched
            == self.missed
                + self.reflected
                + self.exited
                + self.absorbed
                + self.escaped
                + self.surface_loss
                + self.truncated
    }
}

/// A histogram of where photons exit the top, on a square grid centred at
/// the origin (for tests and profiles; integer counts).
#[derive(Debug)]
pub struct ExitGrid {
    pub n: usize,
    pub cell: f32,
    pub counts: Vec<AtomicU32>,
}

impl ExitGrid {
    pub fn new(n: usize, cell: f32) -> Self {
        ExitGrid {
            n,
            cell,
            counts: (0..n * n).map(|_| AtomicU32::new(0)).collect(),
        }
    }
    pub(crate) fn record(&self, p: Vec3) {
        let half = self.n as f32 * self.cell / 2.0;
        let (i, j) = ((p.x + half) / self.cell, (p.y + half) / self.cell);
        if i >= 0.0 && j >= 0.0 && (i as usize) < self.n && (j as usize) < self.n {
            self.counts[j as usize * self.n + i as usize].fetch_add(1, Ordering::Relaxed);
        }
    }
    /// Counts as plain numbers, row-major in y.
    pub fn values(&self) -> Vec<u32> {
        self.counts
            .iter()
            .map(|c| c.load(Ordering::Relaxed))
            .collect()
    }
}

/// Fixed-point accumulation images, one per camera: one channel, or three
/// interleaved (a Lambertian target's lamp pass, see `Accum::rgb`).
pub struct Accum {
    pub images: Vec<Vec<AtomicU64>>,
    pub channels: usize,
}

impl Accum {
    /// One channel.
    pub fn new(cams: &[SplatCamera]) -> Self {
        Self::with_channels(cams, 1)
    }
    /// Three channels from one set of photons: where the surface's paths do
    /// not depend on the wavelength (an opaque Lambertian target), a photon
    /// splats its albedo in each channel rather than tracing three times.
    pub fn rgb(cams: &[SplatCamera]) -> Self {
        Self::with_channels(cams, 3)
    }
    fn with_channels(cams: &[SplatCamera], channels: usize) -> Self {
        Accum {
            images: cams
                .iter()
                .map(|c| {
                    (0..(c.width as usize * c.height as usize * channels))
                        .map(|_| AtomicU64::new(0))
                        .collect()
                })
                .collect(),
            channels,
        }
    }
    /// Unnormalised sums of channel `c` back to floats (multiply by photon
    /// flux outside).
    pub fn to_f64(&self, k: usize, c: usize, cam: &SplatCamera) -> impl Iterator<Item = f64> + '_ {
        assert!(c < self.channels, "channel {c} of {}", self.channels);
        let scale = cam.norm as f64 / QUANTUM;
        self.images[k][c..]
            .iter()
            .step_by(self.channels)
            .map(move |a| a.load(Ordering::Relaxed) as f64 * scale)
    }
}

/// Ask for the cache line of pixel `px` of camera `k`: a splat's first add to
/// a pixel misses the cache (the images are tens of MB), and a locked add
/// waits for its line, so a photon's adds into several cameras would wait
/// one after another; prefetched together, their misses overlap.
#[inline(always)]
fn prefetch(accum: &Accum, k: usize, px: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(a) = accum.images[k].get(px * accum.channels) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: a prefetch is a hint; it never faults, whatever the address.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(a.as_ptr() as *const i8) }
    }
}

/// Add one splat (already normalised by the camera) to element `i` (pixel
/// times channels plus channel) of camera `k`.
#[inline]
fn deposit(accum: &Accum, k: usize, i: usize, v: f32) {
    let q = (v as f64 * QUANTUM).min(1e18) as u64;
    accum.images[k][i].fetch_add(q, Ordering::Relaxed);
}

/// One transport run: a source, a channel, and where splats go.
pub struct Pass<'a> {
    pub scene: &'a Scene,
    pub cams: &'a [SplatCamera],
    pub accum: Option<&'a Accum>,
    pub exits: Option<&'a ExitGrid>,
    pub channel: usize,
    /// Splat the light leaving the volume by next-event estimation from
    /// every scattering vertex near the surface (smooth images) instead of
    /// at the boundary crossings themselves (unbiased too, but speckled).
    pub vertex_nee: bool,
}

pub(crate) struct Local {
    frame: Option<(Vec3, Vec3, Vec3)>,
}

impl Local {
    /// Orthonormal frame around n (Duff et al. 2017); None when n = +z.
    pub(crate) fn new(n: Vec3) -> Local {
        if n.z > 0.999_999 {
            return Local { frame: None };
        }
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Local {
            frame: Some((s, t, n)),
        }
    }
    #[inline]
    pub(crate) fn to_local(&self, v: Vec3) -> Vec3 {
        match self.frame {
            None => v,
            Some((s, t, n)) => Vec3::new(v.dot(s), v.dot(t), v.dot(n)),
        }
    }
    #[inline]
    pub(crate) fn to_world(&self, v: Vec3) -> Vec3 {
        match self.frame {
            None => v,
            Some((s, t, n)) => s * v.x + t * v.y + n * v.z,
        }
    }
}

/// A direction sampled from the rough dielectric for a particle carrying
/// importance, kept by Russian roulette on its survival weight (the
/// single-scattering lobe's masked share ends the particle): None when it
/// ends or the sample is degenerate.
#[inline]
pub(crate) fn surviving_direction(bsdf: &Dielectric, wo: Vec3, rng: &mut WalkRng) -> Option<Vec3> {
    match bsdf.sample_importance(wo, rng.uniform(), [rng.uniform(), rng.uniform()]) {
        Some((wi, weight)) if weight >= 1.0 || rng.uniform() < weight => Some(wi),
        _ => None,
    }
}

/// A direction from a boundary that keeps the share its lobe masks: drawn
/// again until one survives, so light from `wo` leaves towards wi with
/// density f(wo, wi) |cos wi| / A(wo). None only after 64 failed draws.
pub(crate) fn resampled_direction(bsdf: &Dielectric, wo: Vec3, rng: &mut WalkRng) -> Option<Vec3> {
    let lobe = ResampledLobe::new(bsdf, wo);
    (0..64)
        .find_map(|_| lobe.try_sample(rng.uniform(), [rng.uniform(), rng.uniform()], rng.uniform()))
}

/// Uniform direction on the sphere, paired with `uniform_sphere_pdf`.
#[inline(always)]
pub fn sample_uniform_sphere(u: [f32; 2]) -> Vec3 {
    let z = 1.0 - 2.0 * u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (std::f32::consts::TAU * u[1]).sin_cos();
    Vec3::new(r * c, r * s, z)
}

/// (cos phi, sin phi) for phi uniform in [0, 2 pi), from 32 random bits,
/// without a libm call: the top 8 bits pick one of 256 sectors, whose centre's
/// cosine and sine come from a table (computed at compile time); the next
/// 24 place phi within the sector, |b| <= pi/256 from the centre, and the
/// angle-sum formula adds b with cos b = 1 - b^2/2, sin b = b - b^3/6
/// (truncation below 1e-9).
#[inline(always)]
pub fn unit_circle_from_bits(bits: u32) -> (f32, f32) {
    let (c, s) = CIRCLE[(bits >> 24) as usize];
    let f = ((bits >> 6) & 0x0003_FFFF) as f32 * (1.0 / 262_144.0) - 0.5;
    let b = f * (std::f32::consts::TAU / CIRCLE.len() as f32);
    let b2 = b * b;
    let cb = 1.0 - 0.5 * b2;
    let sb = b - b * b2 * (1.0 / 6.0);
    (c * cb - s * sb, s * cb + c * sb)
}

/// cos and sin at the centres of 256 sectors of the circle.
static CIRCLE: [(f32, f32); 256] = circle_table();

const fn circle_table() -> [(f32, f32); 256] {
    let mut t = [(0.0f32, 0.0f32); 256];
    let mut i = 0;
    while i < 256 {
        // the centre angle, taken to [-pi, pi) where the series converge fast
        let mut a = std::f64::consts::TAU * (i as f64 + 0.5) / 256.0;
        if a >= std::f64::consts::PI {
            a -= std::f64::consts::TAU;
        }
        // Taylor series; 40 terms are exact in f64 for |a| <= pi
        let (mut c, mut s) = (0.0f64, 0.0f64);
        let (mut term, mut k) = (1.0f64, 0u32);
        while k < 40 {
            // term = a^k / k!
            match k % 4 {
                0 => c += term,
                1 => s += term,
                2 => c -= term,
                _ => s -= term,
            }
            k += 1;
            term *= a / k as f64;
        }
        t[i] = (c as f32, s as f32);
        i += 1;
    }
    t
}

/// Uniform direction on the sphere from 64 random bits: z uniform in (-1, 1]
/// from the high 24 bits, the azimuth from the low 32 (no rejection, no
/// libm call). Same pdf as `sample_uniform_sphere`.
#[inline(always)]
pub fn sample_uniform_sphere_bits(bits: u64) -> Vec3 {
    let z = 1.0 - 2.0 * unit_f32((bits >> 32) as u32);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (c, s) = unit_circle_from_bits(bits as u32);
    Vec3::new(r * c, r * s, z)
}

pub fn uniform_sphere_pdf() -> f32 {
    1.0 / (4.0 * std::f32::consts::PI)
}

impl Pass<'_> {
    /// Splat one surface event into every camera: `bsdf(wi_local) * cos`.
    #[inline]
    fn splat(&self, x: Vec3, local: &Local, f: impl Fn(Vec3) -> f32) {
        self.splat_with(x, local, f, |x, w| self.scene.surface.visible(x, w))
    }

    /// `splat` with a visibility test of its own (point, unit direction).
    #[inline]
    pub(crate) fn splat_with(
        &self,
        x: Vec3,
        local: &Local,
        f: impl Fn(Vec3) -> f32,
        visible: impl Fn(Vec3, Vec3) -> bool,
    ) {
        self.splat_views(x, local, f, visible, |accum, k, px, v| {
            deposit(accum, k, px * accum.channels, v)
        });
    }

    /// A Lambertian target's splat into a three-channel accumulation
    /// (`Accum::rgb`): albedo `rho` per channel.
    fn splat_lambertian_rgb(&self, x: Vec3, local: &Local, rho: [f32; 3]) {
        self.splat_views(
            x,
            local,
            |_| std::f32::consts::FRAC_1_PI,
            |x, w| self.scene.surface.visible(x, w),
            |accum, k, px, v| {
                for (c, r) in rho.iter().enumerate() {
                    if *r > 0.0 {
                        deposit(accum, k, px * 3 + c, v * r);
                    }
                }
            },
        );
    }

    /// For each camera that sees `x`: `put(accum, camera, pixel, value)`
    /// with the value f(w) cos / (distance^2 norm) of direction w to it.
    #[inline]
    fn splat_views(
        &self,
        x: Vec3,
        local: &Local,
        f: impl Fn(Vec3) -> f32,
        visible: impl Fn(Vec3, Vec3) -> bool,
        put: impl Fn(&Accum, usize, usize, f32),
    ) {
        let Some(accum) = self.accum else { return };
        // The views' pixels first, their lines prefetched; then the adds.
        const MAX_DUE: usize = 16;
        let mut due = [(0usize, 0usize, 0f32); MAX_DUE];
        let mut n = 0;
        for (k, cam) in self.cams.iter().enumerate() {
            let Some((px, inv, wc)) = cam.project(x) else {
                continue;
            };
            let wl = local.to_local(wc);
            if wl.z <= 0.0 {
                continue;
            }
            let v = f(wl) * wl.z * inv / cam.norm;
            if v.is_nan() || v <= 0.0 || !visible(x, wc) {
                continue;
            }
            if n == MAX_DUE {
                put(accum, k, px, v);
                continue;
            }
            prefetch(accum, k, px);
            due[n] = (k, px, v);
            n += 1;
        }
        for &(k, px, v) in &due[..n] {
            put(accum, k, px, v);
        }
    }

    /// Run `n` photons with seed `seed`; returns the tally. A homogeneous
    /// volume under a dielectric top takes the wide walk (`crate::lanes`).
    pub fn run(&self, source: &Source, n: u64, seed: u64) -> Tally {
        self.run_with(source, n, seed, self.wide_walk_applies())
    }

    /// `run` with the walk chosen: `wide` (where it applies) or one photon
    /// at a time. Both sample the same distribution from different streams.
    pub(crate) fn run_with(&self, source: &Source, n: u64, seed: u64, wide: bool) -> Tally {
        let blocks = n.div_ceil(BLOCK);
        let wide = wide && self.wide_walk_applies();
        (0..blocks)
            .into_par_iter()
            .map(|b| {
                let key = mix64(seed ^ ((self.channel as u64) << 60));
                let count = BLOCK.min(n - b * BLOCK);
                let table = self
                    .scene
                    .volume
                    .as_ref()
                    .map(|v| v.channel_table(self.channel))
                    .unwrap_or_default();
                if wide {
                    return self.run_block_wide(source, count, key, b, &table);
                }
                let mut rng = WalkRng::new(key, b);
                let mut t = Tally::default();
                for _ in 0..count {
                    let (o, d) = self.emit(source, &mut rng);
                    self.trace(o, d, &mut rng, &table, &mut t);
                }
                t.launched = count;
                t
            })
            .reduce(Tally::default, |a, b| a + b)
    }

    pub(crate) fn emit(&self, source: &Source, rng: &mut WalkRng) -> (Vec3, Vec3) {
        match *source {
            Source::Stripe {
                origin,
                centre,
                dir,
                length,
            } => {
                let s = (rng.uniform() - 0.5) * length;
                let target = centre + dir * s;
                (origin, (target - origin).normalize())
            }
            Source::Lamp { to_lamp } => {
                let hf = &self.scene.surface;
                let x = (rng.uniform() * 2.0 - 1.0) * hf.half[0];
                let y = (rng.uniform() * 2.0 - 1.0) * hf.half[1];
                let d = -to_lamp;
                let z0 = hf.h_max + 1.0;
                let t = (z0 - 0.0) / to_lamp.z.max(1e-3);
                (Vec3::new(x, y, 0.0) + to_lamp * t, d)
            }
            Source::Pencil { origin, dir } => (origin, dir),
        }
    }

    /// One crossing of the rough boundary: splat the light the boundary sends
    /// towards the cameras, then sample reflection or refraction, with Russian
    /// roulette on the sample's weight (or, on a top that keeps its energy,
    /// drawn again until a sample survives). `None` (counted as surface loss)
    /// ends the photon.
    #[allow(clippy::too_many_arguments)]
    fn boundary_event(
        &self,
        x: Vec3,
        local: &Local,
        wo: Vec3,
        bsdf: &Dielectric,
        splat: bool,
        rng: &mut WalkRng,
    ) -> Option<Vec3> {
        self.boundary_event_with(x, local, wo, bsdf, splat, rng, |x, w| {
            self.scene.surface.visible(x, w)
        })
    }

    /// `boundary_event` with a visibility test of its own for the splats.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn boundary_event_with(
        &self,
        x: Vec3,
        local: &Local,
        wo: Vec3,
        bsdf: &Dielectric,
        splat: bool,
        rng: &mut WalkRng,
        visible: impl Fn(Vec3, Vec3) -> bool,
    ) -> Option<Vec3> {
        if splat {
            let inv_a = self.scene.top_inv_albedo(wo);
            self.splat_with(
                x,
                local,
                |wi| bsdf.f(wo, wi, TransportMode::Importance) * inv_a,
                visible,
            );
        }
        if self.scene.top_albedo.is_some() {
            resampled_direction(bsdf, wo, rng)
        } else {
            surviving_direction(bsdf, wo, rng)
        }
    }

    /// Next-event estimate from a scattering vertex `p` (isotropic phase)
    /// into every camera: for each camera pick a direction to the surface by
    /// refracting the camera direction through a sampled microfacet (the
    /// exact refraction for a smooth surface), weigh by the transmittance to
    /// the surface point and the boundary's BTDF there. Vertices deep below
    /// the surface are skipped by Russian roulette on depth (weight 1/q), so
    /// the estimate stays unbiased at a fraction of the cost.
    /// `u`, uniform in [0, 1), decides the roulette; a vertex that passes
    /// draws one number from the walk's stream, whatever the cameras, so
    /// the walk (and so every image) is the same for any set of cameras.
    pub(crate) fn vertex_splat(
        &self,
        p: Vec3,
        st: f32,
        table: &[(f32, f32)],
        bsdf: &Dielectric,
        u: f32,
        rng: &mut WalkRng,
    ) {
        let Some(accum) = self.accum else { return };
        // q <= NEE_RATE < 1, so most vertices are turned away here, before
        // the height lookup and the exponential (same decisions as testing
        // u >= q alone)
        if u >= NEE_RATE {
            return;
        }
        let hf = &self.scene.surface;
        let depth = (hf.height(p.x, p.y) - p.z).max(0.0);
        // On a relief the nearest exit may be a pore wall, not the surface
        // straight above: the depth below the lowest surface point bounds the
        // distance from below, so 1/q stays bounded (no fireflies).
        let below_all = if hf.is_flat() {
            depth
        } else {
            (hf.h_min - p.z).max(0.0)
        };
        let q = NEE_RATE * (1.0 - st * below_all).exp().min(1.0);
        if u >= q {
            return;
        }
        let key = rng.next_u64();
        let n0 = hf.normal(p.x, p.y);
        let local0 = Local::new(n0);
        let above = Vec3::new(p.x, p.y, p.z + depth);
        let phase = 1.0 / (4.0 * std::f32::consts::PI);
        let smooth = bsdf.mf.effectively_smooth();
        for (k, cam) in self.cams.iter().enumerate() {
            let rng = &mut WalkRng::new(key, cam.id as u64);
            // camera direction from the point straight above the vertex
            let wc0 = local0.to_local((cam.pos - above).normalize());
            // On a relief the normal where the light leaves differs from n0:
            // a share of uniform directions keeps every exit direction
            // possible (all of them when the camera is below n0's horizon).
            let defensive = match (hf.is_flat(), wc0.z > 0.0) {
                (true, true) => 0.0,
                (true, false) => continue,
                (false, true) => DEFENSIVE,
                (false, false) => 1.0,
            };
            let (dir, pdf) = if smooth {
                match refract(wc0, Vec3::Z, bsdf.eta) {
                    Some((wt, _)) => (local0.to_world(-wt), 1.0),
                    None => continue,
                }
            } else {
                let u = [rng.uniform(), rng.uniform()];
                let (dir, q_bsdf) = if rng.uniform() < defensive {
                    let dir = sample_uniform_sphere(u);
                    let q = if defensive < 1.0 {
                        bsdf.pdf_transmission(wc0, local0.to_local(-dir))
                    } else {
                        0.0
                    };
                    (dir, q)
                } else {
                    match bsdf.sample_transmission(wc0, u) {
                        Some((wt, q)) => (local0.to_world(-wt), q),
                        None => continue,
                    }
                };
                (
                    dir,
                    (1.0 - defensive) * q_bsdf + defensive * uniform_sphere_pdf(),
                )
            };
            if pdf.is_nan() || pdf <= 0.0 || (hf.is_flat() && dir.z <= 0.0) {
                continue;
            }
            // beyond 40 mean free paths nothing gets through
            let Some((dist, x)) = hf.crossing_from_below(p, dir, 40.0 / st) else {
                continue;
            };
            if !hf.inside_footprint(x.x, x.y) {
                continue;
            }
            let Some((px, inv, wc)) = cam.project(x) else {
                continue;
            };
            let local = Local::new(hf.normal(x.x, x.y));
            let wl = local.to_local(wc);
            if wl.z <= 0.0 || !hf.visible(x, wc) {
                continue;
            }
            let tr = self.transmittance(p, dir, dist, st, table, rng);
            if tr <= 0.0 {
                continue;
            }
            let boundary = if smooth {
                // delta BTDF T_F / cos_c, times cos_c, times the solid-angle
                // Jacobian d w_t / d w_c = cos_c / (eta^2 cos_t)
                let wo = local.to_local(-dir);
                let tf = 1.0 - fr_dielectric(wl.z, bsdf.eta);
                tf * wl.z / (bsdf.eta * bsdf.eta * wo.z.abs())
            } else {
                let wo = local.to_local(-dir);
                let inv_a = self.scene.top_inv_albedo(wo);
                bsdf.f(wo, wl, TransportMode::Importance) * wl.z * inv_a / pdf
            };
            let v = phase * tr * boundary * inv / (cam.norm * q);
            if v.is_finite() && v > 0.0 {
                deposit(accum, k, px, v);
            }
        }
    }

    /// Transmittance from `p` along `d` over `dist`: exact in a homogeneous
    /// volume, ratio tracking against the majorant in a heterogeneous one.
    fn transmittance(
        &self,
        p: Vec3,
        d: Vec3,
        dist: f32,
        st: f32,
        table: &[(f32, f32)],
        rng: &mut WalkRng,
    ) -> f32 {
        let Some(vol) = &self.scene.volume else {
            return 0.0;
        };
        if vol.grid.is_none() {
            return (-st * dist).exp();
        }
        let maj = vol.majorant[self.channel];
        let mut tr = 1.0f32;
        let mut s = 0.0f32;
        let inv_maj = 1.0 / maj;
        loop {
            s += exp1_from_bits(rng.next_u32()) * inv_maj;
            if s >= dist {
                return tr;
            }
            let y = p + d * s;
            tr *= 1.0 - table[vol.material_at([y.x, y.y, y.z])].0 / maj;
            if tr < 1e-4 {
                // Russian roulette on negligible paths keeps ratio tracking short
                if rng.uniform() < 0.5 {
                    return 0.0;
                }
                tr *= 2.0;
            }
        }
    }

    /// One photon's whole life.
    fn trace(&self, o: Vec3, d: Vec3, rng: &mut WalkRng, table: &[(f32, f32)], t: &mut Tally) {
        if let Some(vol) = &self.scene.volume
            && let Some(cells) = &vol.cells
        {
            self.trace_cells(vol, cells, o, d, rng, table, t);
            return;
        }
        if let Some((p, d)) = self.enter(o, d, rng, t) {
            let bsdf = self
                .dielectric()
                .expect("only a dielectric top lets light in");
            self.walk(p, d, rng, table, &bsdf, t);
        }
    }

    /// The top surface of a dielectric sample, if that is what the scene is.
    pub(crate) fn dielectric(&self) -> Option<Dielectric> {
        match &self.scene.kind {
            SurfaceKind::Dielectric(b) => Some(*b),
            SurfaceKind::Lambertian(_) => None,
        }
    }

    /// A photon from `o` along `d` meets the top: a target's Lambertian
    /// event, or the dielectric's reflection or refraction. Where it enters
    /// the volume, its start just below the surface and direction; every
    /// other outcome is counted in `t`.
    pub(crate) fn enter(
        &self,
        o: Vec3,
        d: Vec3,
        rng: &mut WalkRng,
        t: &mut Tally,
    ) -> Option<(Vec3, Vec3)> {
        let hf = &self.scene.surface;
        let Some((_, x)) = hf.intersect_from_above(o, d) else {
            t.missed += 1;
            return None;
        };
        let n = hf.normal(x.x, x.y);
        let local = Local::new(n);
        let wo = local.to_local(-d);
        let bsdf = match &self.scene.kind {
            SurfaceKind::Lambertian(_) => {
                let rho = if self.accum.is_some_and(|a| a.channels == 3) {
                    let rho = [0, 1, 2].map(|c| self.scene.target_albedo(x.x, x.y, c));
                    self.splat_lambertian_rgb(x, &local, rho);
                    rho[self.channel.min(2)]
                } else {
                    let rho = self.scene.target_albedo(x.x, x.y, self.channel);
                    self.splat(x, &local, |_| rho * std::f32::consts::FRAC_1_PI);
                    rho
                };
                if rng.uniform() < rho {
                    t.reflected += 1;
                } else {
                    t.absorbed += 1;
                }
                return None;
            }
            SurfaceKind::Dielectric(b) => *b,
        };
        // entry: surface reflection towards the cameras, then reflect or refract
        let Some(wi) = self.boundary_event(x, &local, wo, &bsdf, true, rng) else {
            t.surface_loss += 1;
            return None;
        };
        if wi.z > 0.0 {
            t.reflected += 1;
            return None;
        }
        t.entered += 1;
        let d = local.to_world(wi);
        Some((x + d * 1e-4, d))
    }

    /// The random walk inside the volume, starting just below the surface.
    fn walk(
        &self,
        p: Vec3,
        d: Vec3,
        rng: &mut WalkRng,
        table: &[(f32, f32)],
        bsdf: &Dielectric,
        t: &mut Tally,
    ) {
        let Some(vol) = &self.scene.volume else {
            t.absorbed += 1;
            return;
        };
        if vol.majorant[self.channel] <= 0.0 {
            // a transparent volume: straight to a wall or the top
            t.escaped += 1;
            return;
        }
        // four copies of the loop, so the hot one (homogeneous, no vertex
        // estimates) keeps its state in registers across no call
        match (vol.grid.is_none(), self.vertex_nee && self.accum.is_some()) {
            (true, false) => self.walk_in::<true, false>(vol, p, d, rng, table, bsdf, t),
            (true, true) => self.walk_in::<true, true>(vol, p, d, rng, table, bsdf, t),
            (false, false) => self.walk_in::<false, false>(vol, p, d, rng, table, bsdf, t),
            (false, true) => self.walk_in::<false, true>(vol, p, d, rng, table, bsdf, t),
        }
    }

    /// The walk's loop, compiled once for a homogeneous volume (free flights
    /// against s_t itself, no null collisions; the event at which the photon
    /// is absorbed drawn once from its geometric distribution instead of a
    /// test per event, which is the same distribution) and once for a voxel
    /// grid (delta tracking against the majorant); `NEE`: next-event
    /// estimates from the scattering vertices.
    /// Not inlined: on its own the loop keeps more of its state in registers
    /// (measured 5 % faster).
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn walk_in<const HOMOGENEOUS: bool, const NEE: bool>(
        &self,
        vol: &Volume,
        mut p: Vec3,
        mut d: Vec3,
        rng: &mut WalkRng,
        table: &[(f32, f32)],
        bsdf: &Dielectric,
        t: &mut Tally,
    ) {
        let hf = &self.scene.surface;
        let [hx, hy, depth] = vol.half;
        let maj = vol.majorant[self.channel];
        let inv_maj = 1.0 / maj;
        let (st0, alb0) = table[0];
        // Homogeneous: the photon is absorbed at event N, P(N = k) =
        // alb^(k-1) (1 - alb); it ends at event `limit` either way.
        let absorb_at = if HOMOGENEOUS {
            geometric_events(alb0, rng.next_u64())
        } else {
            u64::MAX
        };
        let limit = absorb_at.min(MAX_EVENTS as u64);
        let mut events = 0u64;
        let mut null = 0u64;
        let mut from_vertex = false;
        let end = loop {
            // free flight against the majorant (= s_t when homogeneous); the
            // low half of the draw decides null collisions
            let bits = rng.next_u64();
            let dist = exp1_from_bits((bits >> 32) as u32) * inv_maj;
            if let Some((_, x)) = hf.crossing_from_below(p, d, dist) {
                // A segment from a scattering vertex was already splatted by
                // that vertex's next-event estimate.
                let splat = !(NEE && from_vertex);
                match self.cross_boundary(x, d, bsdf, splat, rng) {
                    Crossing::Inside(d2) => {
                        d = d2;
                        p = x + d * 1e-4;
                        from_vertex = false;
                        continue;
                    }
                    Crossing::Ended(e) => break e,
                }
            }
            p += d * dist;
            if p.x.abs() > hx || p.y.abs() > hy || p.z < -depth {
                break End::Escaped;
            }
            // Every real collision is an event, an absorbed one included.
            let st = if HOMOGENEOUS {
                events += 1;
                st0
            } else {
                let (st, alb) = table[vol.material_at([p.x, p.y, p.z])];
                if unit_f32(bits as u32) * maj >= st {
                    null += 1;
                    continue;
                }
                events += 1;
                if rng.uniform() >= alb {
                    break End::Absorbed;
                }
                st
            };
            if events >= limit {
                break if HOMOGENEOUS && events == absorb_at {
                    End::Absorbed
                } else {
                    End::Truncated
                };
            }
            if NEE {
                let u = rng.uniform();
                self.vertex_splat(p, st, table, bsdf, u, rng);
            }
            from_vertex = true;
            d = sample_uniform_sphere_bits(rng.next_u64());
        };
        t.events += events;
        t.null_events += null;
        match end {
            End::Absorbed => t.absorbed += 1,
            End::Escaped => t.escaped += 1,
            End::Truncated => t.truncated += 1,
            End::Exited => t.exited += 1,
            End::SurfaceLoss => t.surface_loss += 1,
        }
    }

    /// A walk reaching the top at `x` along `d`: leave the footprint (escape),
    /// or the boundary event (splat the transmitted light, sample reflection
    /// or refraction). Out of line: the walk's loop stays small.
    #[inline(never)]
    pub(crate) fn cross_boundary(
        &self,
        x: Vec3,
        d: Vec3,
        bsdf: &Dielectric,
        splat: bool,
        rng: &mut WalkRng,
    ) -> Crossing {
        let hf = &self.scene.surface;
        if !hf.inside_footprint(x.x, x.y) {
            return Crossing::Ended(End::Escaped);
        }
        let local = Local::new(hf.normal(x.x, x.y));
        let wo = local.to_local(-d);
        let Some(wi) = self.boundary_event(x, &local, wo, bsdf, splat, rng) else {
            return Crossing::Ended(End::SurfaceLoss);
        };
        if wi.z > 0.0 {
            if let Some(g) = self.exits {
                g.record(x);
            }
            return Crossing::Ended(End::Exited);
        }
        Crossing::Inside(local.to_world(wi))
    }
}

/// How a walk ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum End {
    Absorbed,
    Escaped,
    Truncated,
    Exited,
    SurfaceLoss,
}

/// The outcome of reaching the top from inside.
pub(crate) enum Crossing {
    /// Reflected back in, along this direction.
    Inside(Vec3),
    Ended(End),
}

/// The index of the event (1, 2, ...) at which a photon of single-scattering
/// albedo `alb` is absorbed, when each event absorbs with probability
/// 1 - alb: geometric, N = 1 + floor(ln v / ln alb) with v uniform in (0, 1]
/// (53 bits of `bits`). u64::MAX when nothing absorbs.
pub(crate) fn geometric_events(alb: f32, bits: u64) -> u64 {
    if alb >= 1.0 {
        return u64::MAX;
    }
    if alb <= 0.0 {
        return 1;
    }
    let v = ((bits >> 11) as f64 + 1.0) * (1.0 / 9_007_199_254_740_992.0);
    let k = (v.ln() / (alb as f64).ln()).floor();
    // saturating: beyond 2^63 events is "never" for any walk
    1 + (k as u64).min(u64::MAX / 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One lamp on the colour pattern, photons shared by the three channels
    /// (`Accum::rgb`): every patch, in every channel, at its own reflectance
    /// times E cos / pi; the same image read with the channels rotated (a
    /// plane landing in the wrong channel) is far off.
    #[test]
    fn colour_pattern_patches_have_their_radiance_in_each_channel() {
        use crate::sample::{COLOUR_PATTERN, SceneDesc, TargetDesc};
        use crate::world::{Illumination, SimQuality, World};
        let desc = SceneDesc::preset("colour-pattern").unwrap();
        let SceneDesc::Target {
            target: TargetDesc::ColourPattern { patch_mm },
        } = desc
        else {
            panic!("the colour-pattern preset is a colour pattern");
        };
        let q = SimQuality {
            lamp_photons: 4_000_000,
            ..SimQuality::ci()
        };
        let w = World::new(desc, crate::RigTruth::nominal(), q).unwrap();
        let illum = Illumination {
            lamps: 1 << 6,
            ..Illumination::default()
        };
        let top = 7;
        let img = w.render_pose(&illum, 1 << top, 5).unwrap();
        let img = img.image(top).unwrap();
        let (_, cam) = w.splat_cameras(0.0, 1 << top).remove(0);
        let dir = w.rig().lamp_direction(6, 0.0);
        let irradiance = w.rig().lamps[6].irradiance;
        let iw = img.width as usize;
        // Mean ratio to the expectation of each patch and channel, over the
        // 5 x 5 pixels (0.7 mm) about the patch centre.
        let ratios = |rotate: usize| -> Vec<f64> {
            let mut out = Vec::new();
            for k in 0..24 {
                let (row, col) = ((k / 6) as f64, (k % 6) as f64);
                let (cx, cy) = ((col - 2.5) * patch_mm, (1.5 - row) * patch_mm);
                assert_eq!(crate::sample::colour_patch_at(cx, cy, patch_mm), Some(k));
                let (px, ..) = cam.project(Vec3::new(cx as f32, cy as f32, 0.0)).unwrap();
                let (x0, y0) = (px % iw, px / iw);
                for ch in 0..3 {
                    let rho = COLOUR_PATTERN[k][ch];
                    if rho < 0.05 {
                        continue; // too few photons for a 5 x 5 mean
                    }
                    let got: f64 = (y0 - 2..=y0 + 2)
                        .flat_map(|y| (x0 - 2..=x0 + 2).map(move |x| y * iw + x))
                        .map(|i| img.data[i][(ch + rotate) % 3] as f64)
                        .sum::<f64>()
                        / 25.0;
                    let expect = rho * irradiance[ch] * dir.z / std::f64::consts::PI;
                    out.push(got / expect);
                }
            }
            out
        };
        let right = ratios(0);
        let mean = right.iter().sum::<f64>() / right.len() as f64;
        assert!((mean - 1.0).abs() < 0.02, "mean ratio {mean}");
        for r in &right {
            assert!((r - 1.0).abs() < 0.15, "a patch at {r} of its radiance");
        }
        let off = ratios(1).iter().filter(|r| (*r - 1.0).abs() > 0.15).count();
        assert!(
            off > right.len() / 2,
            "rotated channels: only {off} patches off"
        );
    }

    #[test]
    fn uniform_sphere_is_uniform() {
        let mut rng = WalkRng::new(1, 1);
        let n = 100_000;
        let mut mean = Vec3::ZERO;
        let mut upper = 0;
        for _ in 0..n {
            let w = sample_uniform_sphere([rng.uniform(), rng.uniform()]);
            assert!((w.length() - 1.0).abs() < 1e-5);
            mean += w;
            upper += (w.z > 0.5) as usize; // cap area fraction 1/4
        }
        assert!((mean / n as f32).length() < 0.01);
        assert!((upper as f32 / n as f32 - 0.25).abs() < 0.005);
        assert!((uniform_sphere_pdf() * 4.0 * std::f32::consts::PI - 1.0).abs() < 1e-6);
    }

    #[test]
    fn sphere_from_bits_is_uniform() {
        let mut rng = WalkRng::new(2, 5);
        let n = 400_000;
        let (mut mean, mut zz, mut xy) = (Vec3::ZERO, 0.0f64, 0.0f64);
        let mut octants = [0usize; 8];
        for _ in 0..n {
            let w = sample_uniform_sphere_bits(rng.next_u64());
            assert!((w.length() - 1.0).abs() < 1e-6, "{w}");
            mean += w;
            zz += (w.z * w.z) as f64;
            xy += (w.x * w.y) as f64;
            let o =
                (w.x > 0.0) as usize | ((w.y > 0.0) as usize) << 1 | ((w.z > 0.0) as usize) << 2;
            octants[o] += 1;
        }
        assert!((mean / n as f32).length() < 0.006);
        assert!((zz / n as f64 - 1.0 / 3.0).abs() < 0.003);
        assert!((xy / n as f64).abs() < 0.002);
        for c in octants {
            assert!((c as f64 / n as f64 - 0.125).abs() < 0.003, "{octants:?}");
        }
        // the azimuth against libm's sin and cos, over the whole circle
        // (sector centres, edges and points between)
        for k in 0..(1u32 << 14) {
            let bits = k << 18 | (k * 7919) & 0x3_FFFF;
            let (c, s) = unit_circle_from_bits(bits);
            let f = ((bits >> 6) & 0x3_FFFF) as f64 / 262_144.0;
            let phi = ((bits >> 24) as f64 + f) * std::f64::consts::TAU / 256.0;
            assert!(
                (c as f64 - phi.cos()).abs() < 2e-7,
                "{k}: {c} {}",
                phi.cos()
            );
            assert!(
                (s as f64 - phi.sin()).abs() < 2e-7,
                "{k}: {s} {}",
                phi.sin()
            );
        }
    }

    #[test]
    fn absorption_event_is_geometric() {
        let mut rng = WalkRng::new(9, 9);
        for alb in [0.3f32, 0.9, 0.999] {
            let n = 200_000;
            let ks: Vec<u64> = (0..n)
                .map(|_| geometric_events(alb, rng.next_u64()))
                .collect();
            assert!(ks.iter().all(|&k| k >= 1));
            let mean = ks.iter().sum::<u64>() as f64 / n as f64;
            let want = 1.0 / (1.0 - alb as f64);
            assert!((mean / want - 1.0).abs() < 0.01, "{alb}: {mean} vs {want}");
            // P(N = 1) = 1 - alb
            let p1 = ks.iter().filter(|&&k| k == 1).count() as f64 / n as f64;
            assert!((p1 - (1.0 - alb as f64)).abs() < 0.004, "{alb}: {p1}");
        }
        assert_eq!(geometric_events(1.0, 12345), u64::MAX);
        assert_eq!(geometric_events(0.0, 12345), 1);
        assert_eq!(geometric_events(0.5, u64::MAX), 1);
    }

    #[test]
    fn local_frame_is_orthonormal() {
        for n in [
            Vec3::new(0.3, -0.2, 0.9).normalize(),
            Vec3::new(-0.7, 0.1, 0.2).normalize(),
        ] {
            let l = Local::new(n);
            let v = Vec3::new(0.2, 0.5, -0.3);
            assert!((l.to_world(l.to_local(v)) - v).length() < 1e-5);
            assert!((l.to_local(n) - Vec3::Z).length() < 1e-5);
        }
    }
}
