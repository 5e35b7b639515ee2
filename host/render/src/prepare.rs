//! Pass 1 of the renderer, everything before the first camera ray: the
//! surface samples ([`crate::points`]), their irradiance through the
//! mode's entrance, the octree over them ([`crate::octree`]) and its R_d
//! table, the tangent field ([`crate::tangent_field`]) and the texture
//! synthesized on the surface ([`crate::texture_synthesis`]).
//! [`Prepared`] keeps it for the pixel pass ([`crate::render`]) and for
//! relighting.

use std::f32::consts::PI;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use crate::boundary::{EntryShape, ExitShape};
use crate::error::RenderError;
use crate::interreflection::{Exitance, Interreflection};
use crate::material::Material;
use crate::octree::{DipoleTree, RdTable};
use crate::points::{self, Entrance, SurfaceSamples};
use crate::scene::Scene;
use crate::settings::{RenderSettings, RenderStats};
use crate::tangent_field::TangentField;
use crate::texture_synthesis::{Features, SurfaceTexture, SynthSettings, TexturePlacement};

/// Pass-1 results, reusable across renders of the same scene and lights.
pub struct Prepared {
    pub samples: SurfaceSamples,
    pub tree: DipoleTree,
    pub rd: RdTable,
    /// The texture's +u direction on the surface.
    pub field: TangentField,
    pub texture: TexturePlacement,
    /// The radius left out of `rd` (depends on the mode, not the lights).
    pub(crate) hole: f32,
    /// `rd`'s near field and geometry factor, as in the settings.
    pub(crate) near_field: f32,
    pub(crate) geometry: bool,
    pub(crate) curvature: bool,
    pub(crate) eta: f64,
    /// F̄, the hemispherical mean of F_r: normalises the plain dipole's exit.
    pub(crate) fresnel_average: f64,
    /// The smooth boundary's exit shape for a material whose f_v has none
    /// ([`Material::smooth_boundary`]).
    pub(crate) exit_shape: Option<ExitShape>,
    /// The smooth boundary's entry shape (also [`Material::smooth_boundary`]).
    pub entry_shape: Option<EntryShape>,
}

/// Radius of the dipole kernel's averaging disk, in units of the radius
/// of one sample's area share.
pub const KERNEL_SPREAD: f32 = 2.0;

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
    // The tangent field and the dart throwing are both mostly serial:
    // side by side on two cores.
    let t = Instant::now();
    let (field, mut samples) = rayon::join(
        || TangentField::new(&scene.mesh),
        || {
            if settings.mode.has_global() {
                points::poisson_disk(&scene.mesh, settings.surface_samples, settings.seed)
            } else {
                SurfaceSamples::default()
            }
        },
    );
    samples.tangent = samples
        .pos
        .iter()
        .zip(&samples.tri)
        .map(|(p, &t)| {
            let (b1, b2) = scene.mesh.barycentric(t as usize, *p);
            field.at(&scene.mesh, t as usize, b1, b2)
        })
        .collect();
    // Whatever `geometry` says: `relight` may turn it on later.
    points::compute_thickness(scene, &mut samples);
    stats.secs_samples = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let (tw, th) = material.texture_size();
    let texture = if settings.synthesis && tw >= 8 && th >= 8 {
        let f = Features::of_material(material);
        let s = SynthSettings {
            seed: settings.seed,
            ..settings.synth
        };
        TexturePlacement::Surface(SurfaceTexture::synthesize(
            &scene.mesh,
            &field,
            &f,
            texel_mm,
            &s,
        ))
    } else {
        TexturePlacement::Tiled {
            width: tw.max(1) as usize,
            height: th.max(1) as usize,
            texel_mm,
        }
    };
    stats.secs_synthesis = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let entry_shape = (settings.mode.has_global()
        && (material.smooth_boundary() || settings.mode.plain_dipole()))
    .then(|| EntryShape::new(&dipole));
    stats.secs_tree += t.elapsed().as_secs_f64();
    let t = Instant::now();
    let hole = rd_hole(material, settings);
    let rd = rd_table(
        material,
        &samples,
        hole,
        settings.near_field,
        settings.geometry.then_some(settings.curvature),
    );
    stats.secs_tree += t.elapsed().as_secs_f64();
    let tree = light_pass(
        scene,
        material,
        settings,
        &mut samples,
        entry_shape.as_ref(),
        &rd,
        stats,
    );
    Ok(Prepared {
        samples,
        tree,
        rd,
        field,
        texture,
        hole,
        near_field: settings.near_field,
        geometry: settings.geometry,
        curvature: settings.curvature,
        eta: dipole.eta,
        fresnel_average: qhm_model::fresnel::fresnel_hemispherical_average(dipole.eta),
        exit_shape: material.smooth_boundary().then(|| ExitShape::new(&dipole)),
        entry_shape,
    })
}

/// Bounces of light between the object's parts: the second adds about a
/// sixth of the first on an apple teapot.
const BOUNCES: usize = 2;

/// Pass 1 after the samples: their irradiance (from the scene's lights and
/// env map, through the mode's entrance, and [`BOUNCES`] of the object's
/// own global exitance) and the octree over them.
#[allow(clippy::too_many_arguments)]
fn light_pass<M: Material>(
    scene: &Scene,
    material: &M,
    settings: &RenderSettings,
    samples: &mut SurfaceSamples,
    entry_shape: Option<&EntryShape>,
    rd: &RdTable,
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
        &entrance,
        settings.env_samples,
        settings.seed,
    );
    stats.secs_irradiance = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut tree = DipoleTree::new(samples);
    stats.secs_tree += t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut returned = 0;
    if let Some(ir) = Interreflection::trace(scene, samples, settings.indirect_rays, settings.seed)
    {
        let direct = (samples.irradiance.clone(), samples.entry.clone());
        for _ in 0..BOUNCES {
            let exitance = Exitance {
                tree: &tree,
                rd,
                epsilon: settings.epsilon,
                r_min: settings.local_radius_mm,
            };
            ir.bounce(samples, &direct, &exitance, &entrance);
            tree = DipoleTree::new(samples);
        }
        returned = ir.count();
    }
    stats.secs_interreflection = t.elapsed().as_secs_f64();
    stats.rays_returned = returned;
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
    geometry: Option<bool>,
) -> RdTable {
    // Every sample stands for an equal share A of the area; the kernel is
    // averaged over a disk of twice that radius, which hides the sample
    // pattern (the sub-mm near field is the LRF's part of eq. 4 anyway).
    let radius = (samples.mean_area() / PI).sqrt();
    let rd = RdTable::with_hole(&material.dipole(), KERNEL_SPREAD * radius, hole)
        .with_near_field(near_field * radius);
    match geometry {
        Some(true) => rd.with_geometry(&material.dipole()),
        Some(false) => rd.with_geometry_without_curvature(&material.dipole()),
        None => rd,
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
        let hole = rd_hole(material, settings);
        if hole != self.hole
            || settings.near_field != self.near_field
            || settings.geometry != self.geometry
            || settings.curvature != self.curvature
        {
            self.rd = rd_table(
                material,
                &self.samples,
                hole,
                settings.near_field,
                settings.geometry.then_some(settings.curvature),
            );
            self.hole = hole;
            self.near_field = settings.near_field;
            self.geometry = settings.geometry;
            self.curvature = settings.curvature;
        }
        self.tree = light_pass(
            scene,
            material,
            settings,
            &mut self.samples,
            entry,
            &self.rd,
            stats,
        );
        Ok(())
    }
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
