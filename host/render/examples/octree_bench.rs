//! Benchmark (paper-style figure): a 512 x 512 teapot under an environment
//! map with a homogeneous preset material. Prints the total time, the number
//! of surface samples, and the octree's speed-up over the brute-force dipole
//! sum (timed on a few thousand surface points, with the relative RMS error).
//!
//!   cargo run --release -p qhm-render --example octree_bench -- [OUT.png] [preset] [size] [epsilon] [surface samples]

use std::path::PathBuf;

use qhm_render::materials::{Homogeneous, preset};
use qhm_render::prepare::{measure_hierarchy, prepare};
use qhm_render::{RenderSettings, RenderStats, Scene, render_scene_stats};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(args.first().map_or("teapot-bench.png", String::as_str));
    let name = args.get(1).map_or("marble", String::as_str);
    let size: u32 = args.get(2).map_or(Ok(512), |s| s.parse())?;
    let material = Homogeneous {
        dipole: preset(name).ok_or("unknown preset")?,
    };
    let t = std::time::Instant::now();
    let mut scene = Scene::builtin("teapot")?;
    scene.lights.clear();
    scene.env = Some(qhm_render::EnvMap::sky(glam::Vec3::new(0.4, 0.9, 0.5), 1.0));
    let t_scene = t.elapsed().as_secs_f64();
    let mut settings = RenderSettings {
        width: size,
        height: size,
        progress: true,
        ..Default::default()
    };
    if let Some(e) = args.get(3) {
        settings.epsilon = e.parse()?;
    }
    if let Some(n) = args.get(4) {
        settings.surface_samples = n.parse()?;
    }
    let (img, st) = render_scene_stats(&scene, &material, &settings)?;
    img.save(&out, None)?;
    println!("threads            {}", rayon::current_num_threads());
    println!(
        "image              {size} x {size}, {} spp, mode full, preset {name}",
        settings.spp
    );
    println!(
        "scene build        {t_scene:.3} s ({} triangles)",
        scene.mesh.triangles.len()
    );
    println!("surface samples    {}", st.surface_samples);
    println!("octree nodes       {}", st.octree_nodes);
    println!("  samples          {:.3} s", st.secs_samples);
    println!(
        "  irradiance       {:.3} s ({} env samples each)",
        st.secs_irradiance, settings.env_samples
    );
    println!("  octree           {:.3} s", st.secs_tree);
    println!(
        "  pixels           {:.3} s ({} dipole queries, {:.0} terms each)",
        st.secs_pixels,
        st.queries,
        st.terms as f64 / st.queries.max(1) as f64
    );
    println!("render total       {:.3} s", st.secs_total);
    let mut s2 = RenderStats::default();
    let prep = prepare(&scene, &material, &settings, &mut s2)?;
    let (t_tree, t_brute, rms) = measure_hierarchy(&scene, &prep, &settings, 2000);
    println!("query octree       {:.2} us", t_tree * 1e6);
    println!("query brute force  {:.2} us", t_brute * 1e6);
    println!(
        "octree speed-up    {:.1}x (relative RMS vs brute force {:.4}%)",
        t_brute / t_tree,
        rms * 100.0
    );
    println!("wrote {}", out.display());
    Ok(())
}
