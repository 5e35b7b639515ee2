//! The texture on a surface, measured (docs/render.md, "Texture on the
//! surface"): the tangent field's frame jumps on a built-in object, and
//! the seam energy of a model's texture synthesized on it under two sets of
//! ten (light, view) pairs that no capture uses.
//!
//!   cargo run --release -p qhm-render --example surface_texture -- MODEL_DIR [BUILTIN] [--seam-passes N]
//!
//! BUILTIN: slab, sphere, teapot (default) or bread. `--seam-passes` sets
//! the synthesis's seam passes (the default unless given; 0 for none).

use std::path::Path;
use std::time::Instant;

use qhm_render::builtin::builtin_mesh;
use qhm_render::tangent_field::TangentField;
use qhm_render::texture_synthesis::{Features, SurfaceTexture, SynthSettings, direction};

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let usage = || -> ! {
        eprintln!("usage: surface_texture MODEL_DIR [slab|sphere|teapot|bread] [--seam-passes N]");
        std::process::exit(2)
    };
    let mut settings = SynthSettings::default();
    if let Some(k) = args.iter().position(|a| a == "--seam-passes") {
        settings.seam_passes = match args.get(k + 1).map(|v| v.parse()) {
            Some(Ok(n)) => n,
            _ => usage(),
        };
        args.drain(k..k + 2);
    }
    let Some(dir) = args.first() else { usage() };
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
    let tex = SurfaceTexture::synthesize(&mesh, &field, &features, model.texel_mm(), &settings);
    println!(
        "synthesis: {} points {:.3} mm apart from a {}x{} texture in {:.2} s",
        tex.pos.len(),
        tex.spacing,
        tex.src_width,
        tex.src_height,
        t.elapsed().as_secs_f64()
    );
    // Two sets of ten pairs, azimuths off the capture's steps, elevations
    // between its arcs: (light theta, phi, view theta, phi) of pair k.
    type PairOf = fn(f32) -> [f32; 4];
    let sets: [(&str, PairOf); 2] = [
        ("A", |k| {
            [
                12.0 + 6.5 * k,
                17.0 + 37.0 * k,
                8.0 + 4.5 * k,
                203.0 + 53.0 * k,
            ]
        }),
        ("B", |k| {
            [
                15.0 + 6.0 * k,
                100.0 + 71.0 * k,
                5.0 + 5.0 * k,
                40.0 + 97.0 * k,
            ]
        }),
    ];
    println!(
        "set  light (theta, phi)  view (theta, phi)  cut pairs  cut   interior  seam energy (cut / interior)"
    );
    let t = Instant::now();
    let mut worst = [0.0f64; 2];
    for (s, (name, pair)) in sets.iter().enumerate() {
        for k in 0..10 {
            let [li, lp, vi, vp] = pair(k as f32);
            let e = tex.seam_energy(&model, direction(li, lp), direction(vi, vp));
            worst[s] = worst[s].max(e.ratio());
            println!(
                "{name}    ({li:4.1}, {:5.1})      ({vi:4.1}, {:5.1})      {:8}   {:.3} {:.3}     {:.3}",
                lp % 360.0,
                vp % 360.0,
                e.cut_pairs,
                e.cut,
                e.inner,
                e.ratio()
            );
        }
    }
    println!(
        "worst seam energy {:.3} (set A), {:.3} (set B); measured in {:.2} s",
        worst[0],
        worst[1],
        t.elapsed().as_secs_f64()
    );
}
