//! The viewer's renderer state: the meshes with their BVHs, and pass 1
//! (surface samples, irradiance, octree, synthesized texture) kept between
//! frames. A camera move reuses pass 1 whole; a new light, env map or mode
//! re-lights the same surface samples ([`Prepared::relight`]); only a new
//! mesh or switching the dipole term on or off prepares from scratch.
//!
//! Every frame is rendered from the view's scene TOML ([`SceneToml`])
//! through `SceneFile`, as `qhm render --scene` reads it, and the last
//! level renders at `qhm render`'s default settings, so its image is the
//! one `qhm render` makes of the saved scene.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Context;
use qhm_model::MaterialModel;
use qhm_render::builtin::BUILTIN_NAMES;
use qhm_render::prepare::{Prepared, prepare};
use qhm_render::render::render_prepared;
use qhm_render::{Image, Mesh, Mode, RenderSettings, RenderStats, Scene, SceneFile};

use super::request::{Framing, SceneToml, View};

/// One step of progressive refinement.
#[derive(Clone, Copy, Debug)]
pub struct Level {
    /// Image side divisor (the page scales the image up).
    pub shrink: u32,
    /// Camera samples per pixel (None: `qhm render`'s default).
    pub spp: Option<u32>,
    /// Pass 1 at `qhm render`'s defaults (else a coarse one).
    pub full: bool,
}

/// Preview, sharp, full pass 1, final (`qhm render`'s default quality).
pub const LEVELS: [Level; 4] = [
    Level {
        shrink: 2,
        spp: Some(1),
        full: false,
    },
    Level {
        shrink: 1,
        spp: Some(1),
        full: false,
    },
    Level {
        shrink: 1,
        spp: Some(1),
        full: true,
    },
    Level {
        shrink: 1,
        spp: None,
        full: true,
    },
];

/// The coarse pass 1 of the first levels: a tenth of the surface samples
/// and a quarter of the env directions.
const COARSE_SURFACE_SAMPLES: usize = 3000;
const COARSE_ENV_SAMPLES: usize = 16;
const COARSE_LIGHT_SAMPLES: usize = 2;

/// How a frame's pass 1 was had.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PassOne {
    Reused,
    Relit,
    Prepared,
}

impl PassOne {
    pub fn name(self) -> &'static str {
        match self {
            PassOne::Reused => "reused",
            PassOne::Relit => "relit",
            PassOne::Prepared => "prepared",
        }
    }
}

pub struct Frame {
    pub image: Image,
    pub level: usize,
    pub pass_one: PassOne,
    pub secs: f64,
    /// The scene TOML at the final level (what a save writes).
    pub toml: String,
}

struct MeshEntry {
    name: String,
    /// None for a built-in object.
    file: Option<PathBuf>,
    scene: Scene,
    framing: Framing,
}

/// Pass 1 for one mesh, quality and dipole on/off, and the lighting it
/// was computed for.
struct Slot {
    lighting: String,
    prep: Prepared,
}

pub struct Engine {
    pub model: MaterialModel,
    meshes: Vec<MeshEntry>,
    /// File meshes' scale (mm per unit), written into saved scenes.
    file_scale: f32,
    slots: HashMap<(usize, bool, bool), Slot>,
    /// The last frame's scene + level and image: an exposure change or a
    /// repeated request is not rendered again.
    last: Option<(String, Image)>,
}

impl Engine {
    /// The mesh file, if any, first, then the built-in objects (each
    /// builds in milliseconds, so all are built up front).
    pub fn new(model: MaterialModel, mesh_file: Option<(PathBuf, f32)>) -> anyhow::Result<Engine> {
        let mut meshes = Vec::new();
        let mut file_scale = 1.0;
        if let Some((path, scale)) = mesh_file {
            let mesh = Mesh::load(&path, scale, None)
                .with_context(|| format!("mesh {}", path.display()))?;
            let name = path
                .file_name()
                .map_or("mesh".into(), |n| n.to_string_lossy().into_owned());
            meshes.push(MeshEntry::new(name, Some(path), Scene::lit(mesh)));
            file_scale = scale;
        }
        for name in BUILTIN_NAMES {
            meshes.push(MeshEntry::new(name.into(), None, Scene::builtin(name)?));
        }
        Ok(Engine {
            model,
            meshes,
            file_scale,
            slots: HashMap::new(),
            last: None,
        })
    }

    pub fn mesh_names(&self) -> Vec<String> {
        self.meshes.iter().map(|m| m.name.clone()).collect()
    }

    /// The mesh file's path, when `mesh` names it.
    pub fn mesh_file(&self, mesh: &str) -> Option<&PathBuf> {
        self.meshes
            .iter()
            .find(|m| m.name == mesh)
            .and_then(|m| m.file.as_ref())
    }

    /// Forgets pass 1 (after a panic left it half-updated).
    pub fn clear(&mut self) {
        self.slots.clear();
        self.last = None;
    }

    /// Renders `view` at its level; None when `cancel` was set meanwhile.
    pub fn render(&mut self, view: &View, cancel: &AtomicBool) -> anyhow::Result<Option<Frame>> {
        let t0 = Instant::now();
        let index = self
            .meshes
            .iter()
            .position(|m| m.name == view.mesh)
            .with_context(|| format!("unknown mesh {:?}", view.mesh))?;
        let entry = &mut self.meshes[index];
        let object_scale = entry.file.as_ref().map(|_| self.file_scale);
        let toml = SceneToml::new(view, entry.framing, object_scale);
        let text = toml.text();
        let level = LEVELS[view.level];
        let key = format!("{text}level {}", view.level);
        if let Some((k, img)) = &self.last
            && *k == key
        {
            return Ok(Some(Frame {
                image: img.clone(),
                level: view.level,
                pass_one: PassOne::Reused,
                secs: t0.elapsed().as_secs_f64(),
                toml: text,
            }));
        }
        let file = SceneFile::parse(&text, None)?;
        file.apply_scene(&mut entry.scene)?;
        let mut settings = RenderSettings::default();
        file.apply_settings(&mut settings)?;
        settings.width = view.width.div_ceil(level.shrink).max(1);
        settings.height = view.height.div_ceil(level.shrink).max(1);
        settings.spp = level.spp.unwrap_or(settings.spp);
        if !level.full {
            settings.surface_samples = COARSE_SURFACE_SAMPLES;
            settings.env_samples = COARSE_ENV_SAMPLES;
            settings.light_samples = COARSE_LIGHT_SAMPLES;
        }
        settings.progress = false;
        let scene = &entry.scene;
        let model = &self.model;
        let global = view.mode != Mode::LrfOnly;
        let lighting = format!("{}mode {}", toml.lighting, view.mode_name);
        let mut stats = RenderStats::default();
        let (slot, pass_one) = match self.slots.entry((index, level.full, global)) {
            std::collections::hash_map::Entry::Occupied(o) => {
                let slot = o.into_mut();
                if slot.lighting == lighting {
                    (slot, PassOne::Reused)
                } else {
                    slot.prep.relight(scene, model, &settings, &mut stats)?;
                    slot.lighting = lighting;
                    (slot, PassOne::Relit)
                }
            }
            std::collections::hash_map::Entry::Vacant(v) => {
                let prep = prepare(scene, model, &settings, &mut stats)?;
                (v.insert(Slot { lighting, prep }), PassOne::Prepared)
            }
        };
        let Some((image, _)) = render_prepared(scene, model, &settings, &slot.prep, cancel) else {
            return Ok(None);
        };
        self.last = Some((key, image.clone()));
        Ok(Some(Frame {
            image,
            level: view.level,
            pass_one,
            secs: t0.elapsed().as_secs_f64(),
            toml: text,
        }))
    }
}

impl MeshEntry {
    fn new(name: String, file: Option<PathBuf>, scene: Scene) -> MeshEntry {
        let (lo, hi) = scene.mesh.bounds();
        MeshEntry {
            name,
            file,
            framing: Framing::of_bounds(lo, hi),
            scene,
        }
    }
}
