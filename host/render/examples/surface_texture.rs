//! The texture on a surface, measured (docs/render.md, "Texture on the
//! surface"): the tangent field's frame jumps on a built-in object, and
//! the seam energy of a model's texture synthesized on it under two sets of
//! ten (light, view) pairs that no capture uses, with the share of
//! neighbour pairs across a cut and the mean contrast between neighbours.
//!
//!   cargo run --release -p qhm-render --example surface_texture -- MODEL_DIR [BUILTIN] [--seam-passes N] [--seed N]
//!
//! BUILTIN: slab, sphere, teapot (default) or bread. `--seam-passes` sets
//! the synthesis's seam passes (the default unless given; 0 for none),
//! `--seed` its random seed.

use std::path::Path;
use std::time::Instant;

use qhm_render::builtin::builtin_mesh;
use qhm_render::tangent_field::TangentField;
use qhm_render::texture_synthesis::{Features, SurfaceTexture, SynthSettings, direction};

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let usage = || -> ! {
        eprintln!(
            "usage: surface_texture MODEL_DIR [slab|sphere|teapot|bread] [--seam-passes N] [--seed N]"
        );
        std::process::exit(2)
    };
    let mut settings = SynthSettings::default();
    let mut option = |name: &str| -> Option<u64> {
        let k = args.iter().position(|a| a == name)?;
        let value = match args.get(k + 1).map(|v| v.parse()) {
            Some(Ok(n)) => n,
            _ => usage(),
        };
        args.drain(k..k + 2);
        Some(value)
    };
    if let Some(n) = option("--seam-passes") {
        settings.seam_passes = n as usize;
    }
    if let Some(seed) = option("--seed") {
        settings.seed = seed;
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
        "set  light (theta, phi)  view (theta, phi)  cut pairs (share)  cut   interior  seam energy (cut / interior)  neighbours"
    );
    let t = Instant::now();
    let mut worst = [0.0f64; 2];
    let mut contrast = [0.0f64; 2];
    for (s, (name, pair)) in sets.iter().enumerate() {
        for k in 0..10 {
            let [li, lp, vi, vp] = pair(k as f32);
            let e = tex.seam_energy(&model, direction(li, lp), direction(vi, vp));
            worst[s] = worst[s].max(e.ratio());
            contrast[s] += e.neighbour / 10.0;
            println!(
                "{name}    ({li:4.1}, {:5.1})      ({vi:4.1}, {:5.1})      {:8} ({:.2})    {:.3} {:.3}     {:.3}                         {:.3}",
                lp % 360.0,
                vp % 360.0,
                e.cut_pairs,
                e.cut_pairs as f64 / e.pairs.max(1) as f64,
                e.cut,
                e.inner,
                e.ratio(),
                e.neighbour
            );
        }
    }
    println!(
        "worst seam energy {:.3} (set A), {:.3} (set B); mean neighbour contrast {:.3} (A), {:.3} (B); measured in {:.2} s",
        worst[0],
        worst[1],
        contrast[0],
        contrast[1],
        t.elapsed().as_secs_f64()
    );
}
