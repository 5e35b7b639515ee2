//! The texture on a surface, measured (docs/render.md, "Texture on the
//! surface"): the tangent field's frame jumps on a built-in object, and
//! the seam energy of a model's texture synthesized on it under ten
//! (light, view) pairs that no capture uses.
//!
//!   cargo run --release -p qhm-render --example surface_texture -- MODEL_DIR [BUILTIN]
//!
//! BUILTIN: slab, sphere, teapot (default) or bread.

use std::path::Path;
use std::time::Instant;

use qhm_render::builtin::builtin_mesh;
use qhm_render::tangent_field::TangentField;
use qhm_render::texture_synthesis::{Features, SurfaceTexture, SynthSettings};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(dir) = args.first() else {
        eprintln!("usage: surface_texture MODEL_DIR [slab|sphere|teapot|bread]");
        std::process::exit(2);
    };
    let object = args.get(1).map_or("teapot", String::as_str);
    let model = qhm_model::MaterialModel::load(Path::new(dir)).unwrap_or_else(|e| {
        eprintln!("error: {dir}: {e}");
        std::process::exit(1)
    });
    let mesh = builtin_mesh(object).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(1)
    });
    let t = Instant::now();
    let field = TangentField::new(&mesh);
    let secs_field = t.elapsed().as_secs_f64();
    let jumps = field.frame_jumps(&mesh, 10.0);
    println!(
        "{object}: {} inner edges off creases, {} turn the frame by more than 10 deg ({:.2} %), {} on creases; field {secs_field:.3} s",
        jumps.edges,
        jumps.over,
        100.0 * jumps.share(),
        jumps.creases
    );
    let t = Instant::now();
    let features = Features::of_material(&model);
    let tex = SurfaceTexture::synthesize(
        &mesh,
        &field,
        &features,
        model.texel_mm(),
        &SynthSettings::default(),
    );
    println!(
        "synthesis: {} points {:.3} mm apart from a {}x{} texture in {:.2} s",
        tex.pos.len(),
        tex.spacing,
        tex.src_width,
        tex.src_height,
        t.elapsed().as_secs_f64()
    );
    println!(
        "light (theta, phi)  view (theta, phi)  cut pairs  cut   interior  seam energy (cut / interior)"
    );
    let t = Instant::now();
    let mut worst: f64 = 0.0;
    for k in 0..10 {
        // Azimuths off the capture's steps, elevations between its arcs.
        let (li, lp) = (12.0 + 6.5 * k as f32, 17.0 + 37.0 * k as f32);
        let (vi, vp) = (8.0 + 4.5 * k as f32, 203.0 + 53.0 * k as f32);
        let dir = |theta: f32, phi: f32| {
            let (t, p) = (theta.to_radians(), phi.to_radians());
            [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
        };
        let e = tex.seam_energy(&model, dir(li, lp), dir(vi, vp));
        worst = worst.max(e.ratio());
        println!(
            "({li:4.1}, {:5.1})      ({vi:4.1}, {:5.1})      {:8}   {:.3} {:.3}     {:.3}",
            lp % 360.0,
            vp % 360.0,
            e.cut_pairs,
            e.cut,
            e.inner,
            e.ratio()
        );
    }
    println!(
        "worst seam energy {worst:.3}; measured in {:.2} s",
        t.elapsed().as_secs_f64()
    );
}
