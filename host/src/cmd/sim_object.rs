//! `qhm sim render-object`: the simulator's ground truth for any object.
//! A mesh (file or built-in, loaded by qhm-render's loaders) filled with a
//! sample's volume, under the camera, lights and environment of the same
//! scene TOML `qhm render` reads, path-traced by sim-light (no diffusion
//! model). Writes the radiance (EXR, the units of `qhm render`) and the
//! per-pixel variance of that estimate (OUT.var.exr).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::Args;
use host::output::check_file_output;
use qhm_render::{Light, Scene};

use crate::cmd::render::SceneArgs;
use sim_light::SceneDesc;
use sim_light::object::{
    DeltaLight, EnvImage, ObjectImage, ObjectMesh, ObjectScene, PinholeCamera, RenderOptions,
    render_object,
};

#[derive(Args, Debug)]
pub struct RenderObjectArgs {
    /// A sample preset (see `qhm sim presets`) or a sample TOML file.
    #[arg(long)]
    pub sample: String,
    #[command(flatten)]
    pub object: SceneArgs,
    /// Camera paths per pixel and channel (overrides --quality).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Sample budget: ci (8 spp), preview (32), default (128), final (512).
    #[arg(long, default_value = "preview")]
    pub quality: String,
    #[arg(long)]
    pub width: Option<u32>,
    #[arg(long)]
    pub height: Option<u32>,
    /// Seed of the light transport (default: the scene's [render] seed, else 1).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output radiance, .exr; the variance goes to OUT.var.exr beside it.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also a tone-mapped PNG of the radiance (`qhm render`'s tone map).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// PNG exposure multiplier (default: automatic, 2 / 99th-percentile luminance).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Replace existing output files.
    #[arg(long)]
    pub force: bool,
}

/// The variance file next to `out`: a.exr -> a.var.exr.
pub fn variance_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{}.var.exr", stem.unwrap_or_else(|| "out".into())))
}

fn quality_spp(name: &str) -> Result<u32> {
    Ok(match name {
        "ci" => 8,
        "preview" => 32,
        "default" => 128,
        "final" => 512,
        other => bail!("unknown quality {other:?} (known: ci, preview, default, final)"),
    })
}

/// qhm-render's scene as sim-light's plain data.
pub fn object_scene(scene: &Scene, sample: sim_light::SampleDesc) -> ObjectScene {
    let m = &scene.mesh;
    ObjectScene {
        mesh: ObjectMesh {
            positions: m.positions.clone(),
            normals: m.normals.clone(),
            triangles: m.triangles.clone(),
        },
        sample,
        camera: PinholeCamera {
            eye: scene.camera.eye,
            target: scene.camera.target,
            up: scene.camera.up,
            fov_y: scene.camera.fov_y,
        },
        lights: scene
            .lights
            .iter()
            .map(|l| match *l {
                Light::Directional {
                    to_light,
                    irradiance,
                } => DeltaLight::Directional {
                    to_light,
                    irradiance,
                },
                Light::Point {
                    position,
                    intensity,
                } => DeltaLight::Point {
                    position,
                    intensity,
                },
            })
            .collect(),
        env: scene.env.as_ref().map(|e| EnvImage {
            width: e.width,
            height: e.height,
            texels: e.texels.clone(),
            rotation: e.rotation,
        }),
        env_visible: scene.env_visible,
    }
}

fn write_exr(path: &Path, w: u32, h: u32, px: &[[f32; 3]]) -> Result<()> {
    qhm_formats::exr::write_rgb_pixels(path, w as usize, h as usize, px)
        .with_context(|| format!("writing {}", path.display()))
}

pub fn run(a: RenderObjectArgs) -> Result<ExitCode> {
    let var_out = variance_path(&a.output);
    if !a
        .output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
    {
        bail!("-o {} must end in .exr", a.output.display());
    }
    check_file_output(&a.output, a.force)?;
    check_file_output(&var_out, a.force)?;
    if let Some(p) = &a.png {
        if !p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
            bail!("--png {} must end in .png", p.display());
        }
        check_file_output(p, a.force)?;
    }
    if let Some(e) = a.exposure
        && !(e.is_finite() && e > 0.0)
    {
        bail!("--exposure must be > 0");
    }
    let sample = match SceneDesc::load(&a.sample)? {
        SceneDesc::Sample(s) => s,
        SceneDesc::Target { .. } => bail!(
            "--sample {}: a calibration target is an opaque board; an object needs a sample's volume",
            a.sample
        ),
    };
    let (scene, settings) = a.object.load()?;
    let opts = RenderOptions {
        width: a.width.unwrap_or(settings.width),
        height: a.height.unwrap_or(settings.height),
        spp: match a.spp {
            Some(s) => s,
            None => quality_spp(&a.quality)?,
        },
        seed: a.seed.unwrap_or(settings.seed),
        ..RenderOptions::default()
    };
    opts.validate()?;
    let obj = object_scene(&scene, sample);
    let bar = qhm_progress::Bar::new("render-object rows", opts.height as u64, a.quiet);
    let img: ObjectImage = render_object(&obj, &opts, &|n| bar.inc(n), None)?;
    bar.finish();
    write_exr(&a.output, img.width, img.height, &img.radiance)?;
    write_exr(&var_out, img.width, img.height, &img.variance)?;
    if let Some(p) = &a.png {
        qhm_render::Image {
            width: img.width,
            height: img.height,
            pixels: img.radiance.clone(),
        }
        .write_png(p, a.exposure)
        .with_context(|| format!("writing {}", p.display()))?;
    }
    let m = img.mean();
    let e = img.mean_rel_error();
    let s = img.stats;
    eprintln!(
        "qhm sim render-object: {} x {}, {} spp in {:.1} s; mean radiance {:.5} {:.5} {:.5} (+- {:.2} {:.2} {:.2} %); {} paths, {} events, {} light estimates ({} unconverged), {} lost, {} truncated -> {}, {}",
        img.width,
        img.height,
        opts.spp,
        img.secs,
        m[0],
        m[1],
        m[2],
        100.0 * e[0],
        100.0 * e[1],
        100.0 * e[2],
        s.paths,
        s.events,
        s.nee,
        s.nee_unconverged,
        s.lost,
        s.truncated,
        a.output.display(),
        var_out.display()
    );
    Ok(ExitCode::SUCCESS)
}
