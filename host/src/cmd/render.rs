//! `qhm render`: render a mesh (file or built-in) made of a material model
//! (a model directory, or `builtin:NAME` for a homogeneous preset) to EXR or
//! PNG; `--bench` prints timings and the octree speed-up; `--export-pbrt` /
//! `--export-mitsuba` write the model's homogeneous part as renderer snippets.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::Args;
use host::output::check_file_output;
use qhm_model::MaterialModel;
use qhm_render::materials::{PRESET_NAMES, preset};
use qhm_render::prepare::{measure_hierarchy, prepare};
use qhm_render::{Mesh, Mode, RenderSettings, RenderStats, Scene, SceneFile, render_scene_stats};

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Material model directory, or `builtin:NAME` for a homogeneous preset
    /// (marble, apple, cream, ketchup, potato, skimmilk, skin1, skin2,
    /// wholemilk, sponge, bread, ricecake).
    #[arg(long)]
    pub model: String,
    #[command(flatten)]
    pub object: SceneArgs,
    /// full | lrf-only | lrf-dipole | dipole-only (paper Fig. 9).
    #[arg(long)]
    pub mode: Option<String>,
    #[arg(long)]
    pub width: Option<u32>,
    #[arg(long)]
    pub height: Option<u32>,
    /// Camera samples per pixel.
    #[arg(long)]
    pub spp: Option<u32>,
    /// Target number of surface samples for the dipole.
    #[arg(long)]
    pub samples: Option<usize>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// PNG exposure multiplier (default: automatic, 2 / 99th-percentile luminance).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Output image, .exr (linear) or .png (tone mapped).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Print timings, sample counts and the octree speed-up over brute force.
    #[arg(long)]
    pub bench: bool,
    /// Write the homogeneous part as a pbrt-v4 material to FILE (`-` = stdout).
    #[arg(long, value_name = "FILE")]
    pub export_pbrt: Option<PathBuf>,
    /// Write the homogeneous part as Mitsuba 3 XML to FILE (`-` = stdout).
    #[arg(long, value_name = "FILE")]
    pub export_mitsuba: Option<PathBuf>,
    /// Scene units in mm for the exports (1 = scene in mm, 1000 = metres).
    #[arg(long, default_value_t = 1.0)]
    pub export_unit_mm: f64,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Replace existing output files (-o, --export-pbrt, --export-mitsuba).
    #[arg(long)]
    pub force: bool,
}

pub(crate) fn load_model(spec: &str) -> anyhow::Result<(String, MaterialModel)> {
    if let Some(name) = spec.strip_prefix("builtin:") {
        let Some(d) = preset(name) else {
            bail!(
                "unknown preset {name:?} (known: {})",
                PRESET_NAMES.join(", ")
            );
        };
        return Ok((name.to_string(), MaterialModel::homogeneous(d)));
    }
    let dir = Path::new(spec);
    let m = MaterialModel::load(dir).with_context(|| format!("loading model {}", dir.display()))?;
    let name = dir
        .file_name()
        .map_or("qhm".into(), |n| n.to_string_lossy().into_owned());
    Ok((name, m))
}

/// The object and scene `qhm render` and `qhm sim render-object` draw.
#[derive(Args, Debug)]
pub struct SceneArgs {
    /// Mesh file (.obj or .ply; units set by the scene's [object] scale, default mm).
    #[arg(long, conflicts_with = "builtin")]
    pub mesh: Option<PathBuf>,
    /// Built-in object: slab, sphere, teapot, bread.
    #[arg(long)]
    pub builtin: Option<String>,
    /// Scene TOML (camera, lights, env map, object, render); see docs/render.md.
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

impl SceneArgs {
    /// The object from `--mesh` or `--builtin`, under the scene file's
    /// camera, lights, env map and settings (defaults without one).
    pub fn load(&self) -> anyhow::Result<(Scene, RenderSettings)> {
        let file = match &self.scene {
            Some(p) => SceneFile::load(p).with_context(|| format!("scene {}", p.display()))?,
            None => SceneFile::default(),
        };
        let mut scene = match (&self.mesh, &self.builtin) {
            (Some(path), None) => {
                let (scale, uv_scale) = file.object()?;
                let mesh = Mesh::load(path, scale, uv_scale)
                    .with_context(|| format!("mesh {}", path.display()))?;
                // Default lighting as for built-ins; the scene file may replace it.
                Scene::lit(mesh)
            }
            (None, Some(name)) => file.builtin_scene(name)?,
            _ => bail!("give --mesh FILE or --builtin NAME"),
        };
        file.apply_scene(&mut scene)?;
        let mut settings = RenderSettings::default();
        file.apply_settings(&mut settings)?;
        Ok((scene, settings))
    }
}

fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    if path == Path::new("-") {
        print!("{text}");
        Ok(())
    } else {
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
    }
}

pub fn run(args: RenderArgs) -> anyhow::Result<ExitCode> {
    let (name, model) = load_model(&args.model)?;
    let exporting = args.export_pbrt.is_some() || args.export_mitsuba.is_some();
    if !(args.export_unit_mm.is_finite() && args.export_unit_mm > 0.0) {
        bail!("--export-unit-mm must be > 0");
    }
    // Every output is checked before any is written or the render starts.
    for p in [&args.output, &args.export_pbrt, &args.export_mitsuba]
        .into_iter()
        .flatten()
    {
        check_file_output(p, args.force)?;
    }
    if let Some(p) = &args.export_pbrt {
        write_text(
            p,
            &qhm_render::export::pbrt_snippet(&name, &model.dipole, args.export_unit_mm),
        )?;
    }
    if let Some(p) = &args.export_mitsuba {
        write_text(
            p,
            &qhm_render::export::mitsuba_snippet(&name, &model.dipole, args.export_unit_mm),
        )?;
    }
    let Some(output) = &args.output else {
        if exporting {
            return Ok(ExitCode::SUCCESS);
        }
        bail!("give -o OUT.exr|OUT.png (or --export-pbrt/--export-mitsuba)");
    };
    let ext = output
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("exr" | "png")) {
        bail!("output {} must end in .exr or .png", output.display());
    }
    let (scene, mut settings) = args.object.load()?;
    if let Some(m) = &args.mode {
        settings.mode = m.parse::<Mode>()?;
    }
    settings.width = args.width.unwrap_or(settings.width);
    settings.height = args.height.unwrap_or(settings.height);
    settings.spp = args.spp.unwrap_or(settings.spp);
    settings.surface_samples = args.samples.unwrap_or(settings.surface_samples);
    settings.seed = args.seed.unwrap_or(settings.seed);
    settings.progress = !args.quiet;
    settings.validate()?;
    // Before anything is allocated: a render larger than the free memory
    // is refused, and a large one says what it will take.
    let need = settings.check_memory(qhm_render::settings::available_memory())?;
    if !args.quiet && (need >= 1 << 30 || args.bench) {
        eprintln!(
            "qhm render: {} x {} pixels, {} spp, {} surface samples: about {} of memory",
            settings.width,
            settings.height,
            settings.spp,
            settings.surface_samples,
            qhm_render::settings::human_bytes(need)
        );
    }
    if let Some(e) = args.exposure
        && !(e.is_finite() && e > 0.0)
    {
        bail!("--exposure must be > 0");
    }
    let (img, st) = render_scene_stats(&scene, &model, &settings)?;
    img.save(output, args.exposure)
        .with_context(|| format!("writing {}", output.display()))?;
    if args.bench {
        print_bench(&scene, &model, &settings, &st)?;
    }
    eprintln!(
        "qhm render: {} x {} {:?} in {:.2} s -> {}",
        settings.width,
        settings.height,
        settings.mode,
        st.secs_total,
        output.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn print_bench(
    scene: &Scene,
    model: &MaterialModel,
    settings: &RenderSettings,
    st: &RenderStats,
) -> anyhow::Result<()> {
    println!("threads          {}", rayon_threads());
    println!("triangles        {}", scene.mesh.triangles.len());
    println!("surface samples  {}", st.surface_samples);
    println!("octree nodes     {}", st.octree_nodes);
    println!("samples          {:.3} s", st.secs_samples);
    println!("irradiance       {:.3} s", st.secs_irradiance);
    println!(
        "interreflection  {:.3} s ({} rays came back)",
        st.secs_interreflection, st.rays_returned
    );
    println!("octree build     {:.3} s", st.secs_tree);
    println!("synthesis        {:.3} s", st.secs_synthesis);
    println!(
        "pixels           {:.3} s ({} dipole queries)",
        st.secs_pixels, st.queries
    );
    println!("total            {:.3} s", st.secs_total);
    if st.surface_samples > 0 {
        let prep = prepare(scene, model, settings, &mut RenderStats::default())?;
        let (t_tree, t_brute, rms) = measure_hierarchy(scene, &prep, settings, 2000);
        println!(
            "octree speed-up  {:.1}x ({:.1} us vs {:.1} us per query, relative RMS {:.3}%)",
            t_brute / t_tree,
            t_tree * 1e6,
            t_brute * 1e6,
            rms * 100.0
        );
    }
    Ok(())
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
