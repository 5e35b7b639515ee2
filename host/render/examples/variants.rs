//! One scene TOML rendered with a homogeneous preset and a chosen global
//! term, for side-by-side measurements against a reference (the figures of
//! docs/render.md, "Against exact light transport"):
//!
//!   cargo run --release -p qhm-render --example variants -- SCENE.toml PRESET OUT.exr [OPTIONS]
//!
//! OPTIONS: `--rd dipole|transport` (R_d's light transport; default the
//! preset's), `--lambertian-exit` (f_v = 1 without the boundary's exit
//! shape), `--mesh BUILTIN|FILE.obj|FILE.ply` (default sphere).

use std::path::Path;

use qhm_model::DipoleParams;
use qhm_model::ProfileModel;
use qhm_render::Material;
use qhm_render::materials::{Homogeneous, preset};
use qhm_render::{RenderSettings, SceneFile, render_scene_stats};

/// A homogeneous material with the exit shape switchable.
struct Variant {
    inner: Homogeneous,
    smooth_boundary: bool,
}

impl Material for Variant {
    fn dipole(&self) -> DipoleParams {
        self.inner.dipole()
    }
    fn entrance(&self, wi: [f32; 3]) -> [f32; 3] {
        self.inner.entrance(wi)
    }
    fn exiting(&self, uv: [f32; 2], wo: [f32; 3]) -> [f32; 3] {
        self.inner.exiting(uv, wo)
    }
    fn lrf(&self, uv: [f32; 2], wi: [f32; 3], wo: [f32; 3]) -> [f32; 3] {
        self.inner.lrf(uv, wi, wo)
    }
    fn texture_size(&self) -> (u32, u32) {
        (1, 1)
    }
    fn texel_mm(&self) -> f32 {
        1.0
    }
    fn has_lrf(&self) -> bool {
        false
    }
    fn smooth_boundary(&self) -> bool {
        self.smooth_boundary
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: variants SCENE.toml PRESET OUT.exr [--rd dipole|transport] [--lambertian-exit] [--mesh NAME]".into());
    }
    let (toml, name, out) = (Path::new(&args[0]), &args[1], Path::new(&args[2]));
    let mut dipole = preset(name).ok_or("unknown preset")?;
    let mut smooth_boundary = true;
    let mut mesh = "sphere".to_string();
    let mut i = 3;
    while i < args.len() {
        match args[i].as_str() {
            "--rd" => {
                dipole.model = match args.get(i + 1).map(String::as_str) {
                    Some("dipole") => ProfileModel::Dipole,
                    Some("transport") => ProfileModel::Transport,
                    _ => return Err("--rd dipole|transport".into()),
                };
                i += 1;
            }
            "--lambertian-exit" => smooth_boundary = false,
            "--mesh" => {
                mesh = args.get(i + 1).ok_or("--mesh NAME")?.clone();
                i += 1;
            }
            a => return Err(format!("unknown option {a}").into()),
        }
        i += 1;
    }
    let file = SceneFile::load(toml)?;
    let mut scene = if mesh.ends_with(".obj") || mesh.ends_with(".ply") {
        let (scale, uv) = file.object()?;
        qhm_render::Scene::lit(qhm_render::Mesh::load(Path::new(&mesh), scale, uv)?)
    } else {
        file.builtin_scene(&mesh)?
    };
    file.apply_scene(&mut scene)?;
    let mut settings = RenderSettings::default();
    file.apply_settings(&mut settings)?;
    let material = Variant {
        inner: Homogeneous { dipole },
        smooth_boundary,
    };
    let (img, st) = render_scene_stats(&scene, &material, &settings)?;
    img.write_exr(out)?;
    eprintln!(
        "{}: {} samples, total {:.2} s (samples {:.2}, irradiance {:.2}, tree {:.2}, pixels {:.2})",
        out.display(),
        st.surface_samples,
        st.secs_total,
        st.secs_samples,
        st.secs_irradiance,
        st.secs_tree,
        st.secs_pixels
    );
    Ok(())
}
