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
//! jittered samples.

use std::f32::consts::PI;
use std::str::FromStr;
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
use crate::octree::{DipoleTree, QueryStats, RdTable};
use crate::points::{self, Entrance, SurfaceSamples, frame, to_local};
use crate::scene::Scene;
use crate::synth::{Features, SynthSettings, SynthTexture};

/// Which terms of eq. 4 are rendered (paper Fig. 9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Full,
    LrfOnly,
    LrfDipole,
    DipoleOnly,
}

impl Mode {
    pub const NAMES: [&str; 4] = ["full", "lrf-only", "lrf-dipole", "dipole-only"];

    fn has_lrf(self) -> bool {
        matches!(self, Mode::Full | Mode::LrfOnly | Mode::LrfDipole)
    }
    fn has_global(self) -> bool {
        !matches!(self, Mode::LrfOnly)
    }
    fn plain_dipole(self) -> bool {
        matches!(self, Mode::LrfDipole | Mode::DipoleOnly)
    }
}

impl FromStr for Mode {
    type Err = RenderError;
    fn from_str(s: &str) -> Result<Mode, RenderError> {
        Ok(match s {
            "full" => Mode::Full,
            "lrf-only" | "btf" => Mode::LrfOnly,
            "lrf-dipole" => Mode::LrfDipole,
            "dipole-only" | "dipole" => Mode::DipoleOnly,
            _ => {
                return Err(RenderError::Settings(format!(
                    "mode {s:?} (expected one of {})",
                    Mode::NAMES.join(", ")
                )));
            }
        })
    }
}

/// Quality and output settings.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Camera samples per pixel (stratified).
    pub spp: u32,
    pub mode: Mode,
    /// Target number of surface samples for the dipole (Poisson disk).
    pub surface_samples: usize,
    /// Octree solid-angle bound: a node is one sample when A / d^2 < epsilon.
    pub epsilon: f32,
    /// Environment samples per surface sample (irradiance pass).
    pub env_samples: usize,
    /// Environment samples per camera sample for the LRF.
    pub light_samples: usize,
    /// Radius of the local disk A_o left out of the dipole sum, mm (0 = none).
    pub local_radius_mm: f32,
    /// Irradiance interpolation: radius of the near field whose samples'
    /// irradiance is averaged instead of summed, in units of one sample's
    /// equal-area radius sqrt(A / pi) (0 = plain sum; see
    /// [`RdTable::with_near_field`]).
    pub near_field: f32,
    /// The dipole's exit-plane geometry factor on curved and thin objects
    /// ([`RdTable::with_geometry`]).
    pub geometry: bool,
    pub seed: u64,
    /// Quilt the material texture (else tile it periodically).
    pub synthesis: bool,
    pub synth: SynthSettings,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 512,
            height: 512,
            spp: 4,
            mode: Mode::Full,
            surface_samples: 30_000,
            epsilon: 0.1,
            env_samples: 64,
            light_samples: 8,
            local_radius_mm: 0.0,
            near_field: NEAR_FIELD_SPREAD,
            geometry: true,
            seed: 1,
            synthesis: true,
            synth: SynthSettings::default(),
            progress: false,
        }
    }
}

impl RenderSettings {
    pub fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::Settings(m));
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return bad(format!(
                "width/height {}x{} must be in 1..=16384",
                self.width, self.height
            ));
        }
        if self.spp == 0 || self.spp > 4096 {
            return bad(format!("spp {} must be in 1..=4096", self.spp));
        }
        if self.surface_samples == 0 || self.surface_samples > 5_000_000 {
            return bad(format!(
                "surface_samples {} must be in 1..=5e6",
                self.surface_samples
            ));
        }
        if !(self.epsilon.is_finite() && self.epsilon >= 0.0) {
            return bad(format!("epsilon {} must be >= 0", self.epsilon));
        }
        if !(self.local_radius_mm.is_finite() && self.local_radius_mm >= 0.0) {
            return bad(format!(
                "local_radius_mm {} must be >= 0",
                self.local_radius_mm
            ));
        }
        if !(self.near_field.is_finite() && (0.0..=100.0).contains(&self.near_field)) {
            return bad(format!("near_field {} must be in 0..=100", self.near_field));
        }
        if self.env_samples > 65536 || self.light_samples > 65536 {
            return bad("env_samples/light_samples must be <= 65536".into());
        }
        Ok(())
    }
}

/// Peak memory of the pixel pass per pixel: each tile's radiance and the
/// image they are gathered into (f32 RGB each, 24 B), and the tone map's
/// and encoder's buffers (a 4096 x 4096 PNG peaked at 427 MiB).
const BYTES_PER_PIXEL: u64 = 26;
/// Memory per surface sample: its position, normal, triangle, area and
/// irradiance, the octree nodes over it and the Poisson disk's candidates.
const BYTES_PER_SURFACE_SAMPLE: u64 = 256;

impl RenderSettings {
    /// Memory the render itself will take, bytes: the image and the
    /// surface samples (the mesh and the material are loaded already).
    pub fn memory_estimate(&self) -> u64 {
        let pixels = u64::from(self.width) * u64::from(self.height);
        let samples = if self.mode.has_global() {
            self.surface_samples as u64
        } else {
            0
        };
        pixels * BYTES_PER_PIXEL + samples * BYTES_PER_SURFACE_SAMPLE
    }

    /// The memory estimate, refused when it exceeds `available` bytes
    /// (None: unknown, nothing is refused).
    pub fn check_memory(&self, available: Option<u64>) -> Result<u64, RenderError> {
        let need = self.memory_estimate();
        match available {
            Some(free) if need > free => Err(RenderError::Settings(format!(
                "{} x {} pixels with {} surface samples need about {}, but only {} of memory is \
                 available; lower --width/--height or --samples",
                self.width,
                self.height,
                self.surface_samples,
                human_bytes(need),
                human_bytes(free)
            ))),
            _ => Ok(need),
        }
    }
}

/// Memory the system can give without swapping (Linux `MemAvailable`).
pub fn available_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// `1.5 GiB`, `24 MiB`.
pub fn human_bytes(b: u64) -> String {
    const MIB: f64 = 1024.0 * 1024.0;
    let mib = b as f64 / MIB;
    if mib >= 1024.0 {
        format!("{:.1} GiB", mib / 1024.0)
    } else {
        format!("{:.0} MiB", mib.max(1.0))
    }
}

/// Timings and counts of one render.
#[derive(Clone, Debug, Default)]
pub struct RenderStats {
    pub surface_samples: usize,
    pub octree_nodes: usize,
    pub secs_samples: f64,
    pub secs_irradiance: f64,
    pub secs_tree: f64,
    pub secs_synthesis: f64,
    pub secs_pixels: f64,
    pub secs_total: f64,
    /// Dipole queries made and the nodes + points they summed.
    pub queries: u64,
    pub terms: u64,
}

/// Pass-1 results, reusable across renders of the same scene and lights.
pub struct Prepared {
    pub samples: SurfaceSamples,
    pub tree: DipoleTree,
    pub rd: RdTable,
    pub texture: SynthTexture,
    /// The radius left out of `rd` (depends on the mode, not the lights).
    hole: f32,
    /// `rd`'s near field and geometry factor, as in the settings.
    near_field: f32,
    geometry: bool,
    eta: f64,
    /// F̄, the hemispherical mean of F_r: normalises the plain dipole's exit.
    fresnel_average: f64,
    /// The smooth boundary's exit shape for a material whose f_v has none
    /// ([`Material::smooth_boundary`]).
    exit_shape: Option<ExitShape>,
    /// The smooth boundary's entry shape (also [`Material::smooth_boundary`]).
    pub entry_shape: Option<EntryShape>,
}

/// g(cos θ_i) per channel: the half-space's diffuse reflectance for a beam
/// incident at θ_i over that at normal incidence, both per entered flux
/// (`qhm_model::transport::oblique_reflectance` at the refracted cosine).
/// The irradiance that enters is multiplied by it. 1 at the normal,
/// rising towards grazing incidence, more for a lower albedo.
#[derive(Clone, Debug)]
pub struct EntryShape {
    values: Vec<Vec3>,
}

impl EntryShape {
    const N: usize = 17;

    pub fn new(d: &qhm_model::DipoleParams) -> EntryShape {
        // Tabulated in the refracted cosine mu0, from the critical angle's
        // (grazing incidence) to 1, where g is smooth.
        let mu_c = (1.0 - 1.0 / (d.eta * d.eta)).max(0.0).sqrt();
        let mu0: Vec<f64> = (0..Self::N)
            .map(|k| mu_c + (1.0 - mu_c) * k as f64 / (Self::N - 1) as f64)
            .chain(std::iter::once(1.0))
            .collect();
        let r: Vec<Vec<f64>> = (0..3)
            .map(|c| qhm_model::transport::oblique_reflectance(d.eta, d.alpha_prime[c], &mu0))
            .collect();
        let g = |c: usize, k: usize| {
            let v = r[c][k] / r[c][Self::N];
            if v.is_finite() { v as f32 } else { 1.0 }
        };
        EntryShape {
            values: (0..Self::N)
                .map(|k| Vec3::new(g(0, k), g(1, k), g(2, k)))
                .collect(),
        }
        .with_mu_c(mu_c as f32)
    }

    fn with_mu_c(mut self, mu_c: f32) -> EntryShape {
        self.values.push(Vec3::splat(mu_c));
        self
    }

    /// g at the cosine of incidence `cos_i` outside (refracted with eta).
    #[inline]
    pub fn eval(&self, cos_i: f32, eta: f32) -> Vec3 {
        let n = self.values.len() - 1;
        let mu_c = self.values[n].x;
        let s2 = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
        let mu0 = (1.0 - s2).max(0.0).sqrt();
        let x = ((mu0 - mu_c) / (1.0 - mu_c)).clamp(0.0, 1.0) * (n - 1) as f32;
        let i = (x as usize).min(n - 2);
        let t = x - i as f32;
        self.values[i] * (1.0 - t) + self.values[i + 1] * t
    }
}

/// S(cos θ_o) per channel: pi times the radiance the model's light
/// transport sends out at θ_o per unit exitance (`ProfileModel::
/// exitance_per_radiance`: for radiative transfer the emergent radiance of
/// the half-space, for the dipole the normalised Fresnel shape). ∫ S cos dw
/// / pi = 1, so the exitance Σ R_d E A is kept; S = 1 is Lambertian. It
/// falls to 0 at grazing (Fresnel) and is above 1 near the normal.
#[derive(Clone, Debug)]
pub struct ExitShape {
    values: Vec<Vec3>,
}

impl ExitShape {
    const N: usize = 129;

    pub fn new(d: &qhm_model::DipoleParams) -> ExitShape {
        let cos: Vec<f64> = (0..Self::N)
            .map(|k| k as f64 / (Self::N - 1) as f64)
            .collect();
        let per: Vec<Vec<f64>> = (0..3)
            .map(|c| d.model.exitance_per_radiance(d.alpha_prime[c], d.eta, &cos))
            .collect();
        let s = |v: f64| {
            let x = std::f64::consts::PI / v;
            if x.is_finite() {
                x.max(0.0) as f32
            } else {
                0.0
            }
        };
        ExitShape {
            values: (0..Self::N)
                .map(|k| Vec3::new(s(per[0][k]), s(per[1][k]), s(per[2][k])))
                .collect(),
        }
    }

    #[inline]
    pub fn eval(&self, cos: f32) -> Vec3 {
        let x = cos.clamp(0.0, 1.0) * (Self::N - 1) as f32;
        let i = (x as usize).min(Self::N - 2);
        let t = x - i as f32;
        self.values[i] * (1.0 - t) + self.values[i + 1] * t
    }
}

/// Builds the surface samples, their irradiance, the octree and the
/// synthesized texture.
pub fn prepare<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    stats: &mut RenderStats,
) -> Result<Prepared, RenderError> {
    settings.validate()?;
    let dipole = material.dipole();
    dipole.validate().map_err(RenderError::Material)?;
    let texel_mm = material.texel_mm();
    if !(texel_mm.is_finite() && texel_mm > 0.0) {
        return Err(RenderError::Material(format!("texel size {texel_mm} mm")));
    }
    let t = Instant::now();
    let mut samples = if settings.mode.has_global() {
        points::poisson_disk(&scene.mesh, settings.surface_samples, settings.seed)
    } else {
        SurfaceSamples::default()
    };
    stats.secs_samples = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let entry_shape = (settings.mode.has_global()
        && (material.smooth_boundary() || settings.mode.plain_dipole()))
    .then(|| EntryShape::new(&dipole));
    stats.secs_tree += t.elapsed().as_secs_f64();
    let tree = light_pass(
        scene,
        material,
        settings,
        &mut samples,
        entry_shape.as_ref(),
        stats,
    );
    let t = Instant::now();
    let hole = rd_hole(material, settings);
    let rd = rd_table(
        material,
        &samples,
        hole,
        settings.near_field,
        settings.geometry,
    );
    stats.secs_tree += t.elapsed().as_secs_f64();
    let t = Instant::now();
    let (tw, th) = material.texture_size();
    let texture = if settings.synthesis && tw >= 8 && th >= 8 {
        let f = Features::of_material(material);
        let s = SynthSettings {
            seed: settings.seed,
            ..settings.synth
        };
        SynthTexture::quilt(&f, texel_mm, &s)
    } else {
        SynthTexture::tiled(tw as usize, th as usize, texel_mm)
    };
    stats.secs_synthesis = t.elapsed().as_secs_f64();
    Ok(Prepared {
        samples,
        tree,
        rd,
        texture,
        hole,
        near_field: settings.near_field,
        geometry: settings.geometry,
        eta: dipole.eta,
        fresnel_average: qhm_model::dipole::fresnel_hemispherical_average(dipole.eta),
        exit_shape: material.smooth_boundary().then(|| ExitShape::new(&dipole)),
        entry_shape,
    })
}

/// Pass 1 after the samples: their irradiance (from the scene's lights and
/// env map, through the mode's entrance) and the octree over them.
fn light_pass<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    samples: &mut SurfaceSamples,
    entry_shape: Option<&EntryShape>,
    stats: &mut RenderStats,
) -> DipoleTree {
    let dipole = material.dipole();
    let t = Instant::now();
    let entrance = if settings.mode.plain_dipole() {
        Entrance::Fresnel(dipole.eta, entry_shape)
    } else {
        Entrance::Model(material, entry_shape)
    };
    points::compute_irradiance(
        scene,
        samples,
        entrance,
        settings.env_samples,
        settings.seed,
    );
    stats.secs_irradiance = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let tree = DipoleTree::new(samples);
    stats.secs_tree = t.elapsed().as_secs_f64();
    stats.surface_samples = samples.pos.len();
    stats.octree_nodes = tree.node_count();
    tree
}

/// Eq. 4 sums over B_o = A - A_o: the disc A_o is the LRF's part.
fn rd_hole<M: Material>(material: &M, settings: &RenderSettings) -> f32 {
    if settings.mode.has_lrf() && material.has_lrf() {
        material.local_disc_mm()
    } else {
        0.0
    }
}

/// The R_d table for the samples' spacing: it does not depend on the lights.
fn rd_table<M: Material>(
    material: &M,
    samples: &SurfaceSamples,
    hole: f32,
    near_field: f32,
    geometry: bool,
) -> RdTable {
    // Every sample stands for an equal share A of the area; the kernel is
    // averaged over a disk of twice that radius, which hides the sample
    // pattern (the sub-mm near field is the LRF's part of eq. 4 anyway).
    let radius = samples.area.first().map_or(0.0, |a| (a / PI).sqrt());
    let rd = RdTable::with_hole(&material.dipole(), KERNEL_SPREAD * radius, hole)
        .with_near_field(near_field * radius);
    if geometry {
        rd.with_geometry(&material.dipole())
    } else {
        rd
    }
}

impl Prepared {
    /// Pass 1 for new lights, env map or mode on the same surface samples
    /// and texture (`qhm view` while a light is dragged): redoes only the
    /// irradiance and the octree (and the R_d table if the mode changes the
    /// LRF's disc), exactly as [`prepare`] would. The mode must keep the
    /// dipole term on or off as prepared.
    pub fn relight<M: Material>(
        &mut self,
        scene: &Scene,
        material: &M,
        settings: &RenderSettings,
        stats: &mut RenderStats,
    ) -> Result<(), RenderError> {
        settings.validate()?;
        if settings.mode.has_global() == self.samples.pos.is_empty() {
            return Err(RenderError::Settings(
                "relight: the mode turns the dipole term on or off; prepare again".into(),
            ));
        }
        if self.entry_shape.is_none()
            && (material.smooth_boundary() || settings.mode.plain_dipole())
        {
            self.entry_shape = Some(EntryShape::new(&material.dipole()));
        }
        let entry = if material.smooth_boundary() || settings.mode.plain_dipole() {
            self.entry_shape.as_ref()
        } else {
            None
        };
        self.tree = light_pass(scene, material, settings, &mut self.samples, entry, stats);
        let hole = rd_hole(material, settings);
        if hole != self.hole
            || settings.near_field != self.near_field
            || settings.geometry != self.geometry
        {
            self.rd = rd_table(
                material,
                &self.samples,
                hole,
                settings.near_field,
                settings.geometry,
            );
            self.hole = hole;
            self.near_field = settings.near_field;
            self.geometry = settings.geometry;
        }
        Ok(())
    }
}

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

/// Radius of the dipole kernel's averaging disk, in units of the radius
/// of one sample's area share.
pub const KERNEL_SPREAD: f32 = 2.0;

/// Default [`RenderSettings::near_field`].
pub const NEAR_FIELD_SPREAD: f32 = 6.0;

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
    rng: &mut Pcg64Mcg,
    cache: &mut Option<(Vec3, Vec3)>,
    qs: &mut QueryStats,
    queries: &mut u64,
) -> Vec3 {
    let Some(hit) = scene.bvh.intersect(ray, f32::INFINITY) else {
        return match (&scene.env, scene.env_visible) {
            (Some(env), true) => env.radiance(ray.d),
            _ => Vec3::ZERO,
        };
    };
    let mesh = &scene.mesh;
    let t = hit.tri as usize;
    let p = ray.o + ray.d * hit.t;
    let wo = -ray.d;
    // Two-sided: the surface faces the viewer.
    let mut ng = mesh.face_normal(t);
    let mut ns = mesh.shading_normal(t, hit.b1, hit.b2);
    // The dipole's geometry factor takes the normals in the mesh's winding.
    let n_winding = ns;
    if ng.dot(wo) < 0.0 {
        ng = -ng;
        ns = -ns;
    }
    let fr = frame(ns, mesh.tangents[t]);
    let mut wo_l = to_local(&fr, wo);
    wo_l.z = wo_l.z.max(1e-3);
    let wo_l = wo_l.normalize();
    let uv = prep.texture.lookup(mesh.uv(t, hit.b1, hit.b2));
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
            Vec3::from(material.lrf(uv, wi_l.to_array(), wo_l.to_array())) * e
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
        // Within a pixel the dipole sum is smooth: samples that land within
        // a surface-sample radius of the previous query reuse its value.
        let r2 = prep.samples.radius * prep.samples.radius;
        let m = match *cache {
            Some((q, m)) if q.distance_squared(p) < r2 => m,
            _ => {
                let m = prep.tree.query_stats(
                    p,
                    n_winding,
                    &prep.rd,
                    settings.epsilon,
                    settings.local_radius_mm,
                    qs,
                );
                *queries += 1;
                *cache = Some((p, m));
                m
            }
        };
        let exit = if settings.mode.plain_dipole() {
            // Normalised: (1 - F_r(w_o)) / ((1 - F̄) pi) integrates to 1
            // against cos dw_o, so the exitance stays Σ R_d E A (see the
            // module comment).
            let per_radiance = qhm_model::dipole::exitance_per_radiance(
                wo_l.z as f64,
                prep.eta,
                prep.fresnel_average,
            );
            Vec3::splat((1.0 / per_radiance) as f32)
        } else {
            let fv = Vec3::from(material.exiting(uv, wo_l.to_array()));
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

/// Octree against brute force on `n` random surface points: (mean seconds
/// per hierarchical query, per brute-force query, relative RMS error).
pub fn measure_hierarchy(
    scene: &Scene,
    prep: &Prepared,
    settings: &RenderSettings,
    n: usize,
) -> (f64, f64, f64) {
    let probe = points::poisson_disk(&scene.mesh, n, settings.seed ^ 0x5eed);
    let pts: Vec<(Vec3, Vec3)> = probe
        .pos
        .iter()
        .copied()
        .zip(probe.normal.iter().copied())
        .collect();
    let t = Instant::now();
    let tree: Vec<Vec3> = pts
        .par_iter()
        .map(|&(p, n)| {
            prep.tree
                .query(p, n, &prep.rd, settings.epsilon, settings.local_radius_mm)
        })
        .collect();
    let t_tree = t.elapsed().as_secs_f64() / pts.len().max(1) as f64;
    let t = Instant::now();
    let brute: Vec<Vec3> = pts
        .par_iter()
        .map(|&(p, n)| {
            prep.tree
                .brute_force(p, n, &prep.rd, settings.local_radius_mm)
        })
        .collect();
    let t_brute = t.elapsed().as_secs_f64() / pts.len().max(1) as f64;
    (t_tree, t_brute, relative_rms(&tree, &brute))
}

/// sqrt(Σ|a - b|^2 / Σ|b|^2) over all channels.
pub fn relative_rms(a: &[Vec3], b: &[Vec3]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        num += (*x - *y).length_squared() as f64;
        den += y.length_squared() as f64;
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exit_shape_keeps_the_exitance_and_falls_to_grazing() {
        for name in ["skin1", "marble"] {
            let mut d = crate::material::preset(name).unwrap();
            for model in [
                qhm_model::profile::ProfileModel::Dipole,
                qhm_model::profile::ProfileModel::Transport,
            ] {
                d.model = model;
                let s = ExitShape::new(&d);
                // ∫ S cos dw / pi = 2 ∫ S(mu) mu dmu = 1.
                let n = 2000;
                let mut sum = Vec3::ZERO;
                for k in 0..n {
                    let mu = (k as f32 + 0.5) / n as f32;
                    sum += s.eval(mu) * (2.0 * mu / n as f32);
                }
                assert!(
                    (sum - Vec3::ONE).abs().max_element() < 0.01,
                    "{name} {model:?}: {sum}"
                );
                let (normal, grazing) = (s.eval(1.0), s.eval(0.02));
                assert!(
                    normal.min_element() > 0.95 && grazing.max_element() < 0.5,
                    "{name} {model:?}: {normal} {grazing}"
                );
            }
        }
    }

    #[test]
    fn entry_shape_is_one_at_the_normal_and_rises_obliquely() {
        let d = crate::material::preset("skin1").unwrap();
        let g = EntryShape::new(&d);
        assert!((g.eval(1.0, 1.3) - Vec3::ONE).abs().max_element() < 1e-4);
        let grazing = g.eval(0.05, 1.3);
        // Lower albedo (blue, a' 0.68) rises most.
        assert!(grazing.z > grazing.x && grazing.x > 1.05, "{grazing}");
    }

    #[test]
    fn memory_estimate_counts_pixels_and_samples_and_refuses_what_is_not_there() {
        let s = RenderSettings {
            width: 16384,
            height: 16384,
            ..RenderSettings::default()
        };
        let need = s.memory_estimate();
        assert_eq!(need, 16384 * 16384 * 26 + 30_000 * 256);
        assert_eq!(human_bytes(need), "6.5 GiB");
        assert_eq!(s.check_memory(None).unwrap(), need);
        assert_eq!(s.check_memory(Some(need)).unwrap(), need);
        let e = s.check_memory(Some(4 << 30)).unwrap_err().to_string();
        assert!(e.contains("need about 6.5 GiB, but only 4.0 GiB"), "{e}");
        assert!(e.contains("--width/--height"), "{e}");
        // lrf-only has no surface samples.
        let lrf = RenderSettings {
            mode: Mode::LrfOnly,
            ..s
        };
        assert_eq!(lrf.memory_estimate(), 16384 * 16384 * 26);
    }
}
