//! LRF denoising against a second capture of the same sample:
//! `cargo run --release -p qhm-model --example lrf_denoise -- MODEL_A MODEL_B [K ...]`
//! with both models fitted with `qhm fit --lrf-denoise off` from captures
//! that differ only in their noise (the simulated rig at two seeds: the
//! same sample, independent photons).
//!
//! What is judged is the lamp response the model holds for each captured
//! light and view, LRF + global term (the lamp image per unit irradiance,
//! which the fit denoises), so an f_v that differs between the two fits
//! does not count. B's is A's truth plus independent noise, so over the
//! texels the two windows share E|X - B|² = E|X - truth|² + σ_B², and for
//! A's raw response E|A - B|² = σ_A² + σ_B². With σ_A ≈ σ_B the error of an
//! estimate X against the truth is E|X - B|² - E|A - B|² / 2. Printed per
//! channel for A raw, A denoised by the automatic rule, and A projected on
//! each K given, with the time and the texel noise of the LRF that results.

use std::path::PathBuf;
use std::time::Instant;

use qhm_model::MaterialModel;
use qhm_model::denoise::{LrfDenoise, denoise_lrf, light_ids, texel_noise};
use qhm_model::fit::LampGlobalTerm;
use qhm_model::model::Texture;

/// Each LRF sample's global term over the model's texture.
fn global_terms(m: &MaterialModel) -> Vec<Texture> {
    let g = LampGlobalTerm::new(&m.dipole, &m.entrance, &m.exiting, m.texel_mm as f64);
    m.lrf
        .samples
        .iter()
        .map(|s| g.eval(m.width as usize, m.height as usize, s))
        .collect()
}

/// a + sign b, map by map.
fn add(a: &[Texture], b: &[Texture], sign: f32) -> Vec<Texture> {
    a.iter()
        .zip(b)
        .map(|(x, y)| Texture {
            width: x.width,
            height: x.height,
            data: x
                .data
                .iter()
                .zip(&y.data)
                .map(|(p, q)| std::array::from_fn(|c| p[c] + sign * q[c]))
                .collect(),
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        eprintln!("usage: lrf_denoise MODEL_A MODEL_B [K ...]");
        std::process::exit(2);
    }
    let load = |p: &str| {
        MaterialModel::load(&PathBuf::from(p)).unwrap_or_else(|e| {
            eprintln!("error: {e}");
            std::process::exit(1)
        })
    };
    let (a, b) = (load(&args[0]), load(&args[1]));
    // The same plan on two rigs: the same samples up to each rig's small
    // mechanical perturbations.
    let angle = |u: [f32; 3], v: [f32; 3]| {
        let d: f32 = u.iter().zip(&v).map(|(x, y)| x * y).sum();
        d.clamp(-1.0, 1.0).acos().to_degrees()
    };
    let worst = a
        .lrf
        .samples
        .iter()
        .zip(&b.lrf.samples)
        .map(|(s, t)| angle(s.light, t.light).max(angle(s.view, t.view)))
        .fold(0.0f32, f32::max);
    if a.lrf.samples.len() != b.lrf.samples.len() || worst > 2.0 {
        eprintln!("error: the two models' LRF samples differ (not the same plan)");
        std::process::exit(1);
    }
    println!("samples: light and view directions within {worst:.2} degrees");
    let window = |m: &MaterialModel| {
        m.window()
            .unwrap_or([0, 0, m.width, m.height])
            .map(|x| x as i64)
    };
    let (wa, wb) = (window(&a), window(&b));
    // The shared texels, in rectified coordinates.
    let (i0, j0) = (wa[0].max(wb[0]), wa[1].max(wb[1]));
    let (i1, j1) = (
        (wa[0] + wa[2]).min(wb[0] + wb[2]),
        (wa[1] + wa[3]).min(wb[1] + wb[3]),
    );
    if i1 <= i0 || j1 <= j0 {
        eprintln!("error: the two models' windows do not overlap");
        std::process::exit(1);
    }
    println!(
        "A {}x{} at ({}, {}), B {}x{} at ({}, {}); {} samples, {} shared texels",
        wa[2],
        wa[3],
        wa[0],
        wa[1],
        wb[2],
        wb[3],
        wb[0],
        wb[1],
        a.lrf.samples.len(),
        (i1 - i0) * (j1 - j0)
    );
    // Registration: the correlation of the two models' f_v, averaged over
    // views, at shifts of B by a few texels peaks at (0, 0) when the
    // windows line up.
    let mean_map = |m: &MaterialModel, i: i64, j: i64| -> f64 {
        m.exiting
            .maps
            .iter()
            .map(|t| t.get(i as usize, j as usize).iter().sum::<f32>() as f64)
            .sum()
    };
    let mut best = (f64::MIN, 0, 0);
    for (di, dj) in (-3..=3).flat_map(|di| (-3..=3).map(move |dj| (di, dj))) {
        let pairs: Vec<(f64, f64)> = (j0 + 3..j1 - 3)
            .flat_map(|j| (i0 + 3..i1 - 3).map(move |i| (i, j)))
            .map(|(i, j)| {
                (
                    mean_map(&a, i - wa[0], j - wa[1]),
                    mean_map(&b, i + di - wb[0], j + dj - wb[1]),
                )
            })
            .collect();
        let n = pairs.len() as f64;
        let (mx, my) = (
            pairs.iter().map(|p| p.0).sum::<f64>() / n,
            pairs.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let cov: f64 = pairs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let vx: f64 = pairs.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let vy: f64 = pairs.iter().map(|p| (p.1 - my).powi(2)).sum();
        let r = cov / (vx * vy).sqrt();
        if (di, dj) == (0, 0) {
            println!("correlation of the view-mean f_v maps: {r:.3} at B's shift (0, 0)");
        }
        if r > best.0 {
            best = (r, di, dj);
        }
    }
    println!(
        "highest correlation {:.3} at B's shift ({}, {})",
        best.0, best.1, best.2
    );
    let (ga, gb) = (global_terms(&a), global_terms(&b));
    let (za, zb) = (add(&a.lrf.maps, &ga, 1.0), add(&b.lrf.maps, &gb, 1.0));
    let mse = |x: &[Texture]| -> [f64; 3] {
        let mut e = [0.0f64; 3];
        let mut n = 0usize;
        for (tx, tb) in x.iter().zip(&zb) {
            for j in j0..j1 {
                for i in i0..i1 {
                    let p = tx.get((i - wa[0]) as usize, (j - wa[1]) as usize);
                    let q = tb.get((i - wb[0]) as usize, (j - wb[1]) as usize);
                    for c in 0..3 {
                        e[c] += (p[c] as f64 - q[c] as f64).powi(2);
                    }
                    n += 1;
                }
            }
        }
        e.map(|v| v / n as f64)
    };
    let raw = mse(&za);
    let noise2 = raw.map(|v| v / 2.0);
    let show = |name: &str, e: [f64; 3], t: f64, maps: &[Texture]| {
        let err: Vec<String> = (0..3)
            .map(|c| format!("{:.2e}", (e[c] - noise2[c]).max(0.0).sqrt()))
            .collect();
        let rel: Vec<String> = (0..3)
            .map(|c| format!("{:.2}", ((e[c] - noise2[c]).max(0.0) / noise2[c]).sqrt()))
            .collect();
        let tn = texel_noise(&add(maps, &ga, -1.0)).map(|v| format!("{v:.2e}"));
        println!(
            "{name:>10}: RMS error against the truth {} /sr ({} of raw); LRF texel noise {}; {t:.2} s",
            err.join(", "),
            rel.join(", "),
            tn.join(", ")
        );
    };
    show("raw", raw, 0.0, &za);
    let mut options = vec![("auto".to_string(), LrfDenoise::Auto)];
    for k in &args[2..] {
        let k: usize = k.parse().unwrap_or_else(|_| {
            eprintln!("error: `{k}` is not a number of components");
            std::process::exit(2)
        });
        options.push((format!("k = {k}"), LrfDenoise::Components(k)));
    }
    let light = light_ids(&a.lrf.samples);
    for (name, how) in options {
        let mut maps = za.clone();
        let t = Instant::now();
        let r = denoise_lrf(&mut maps, &light, how).expect("an LRF to denoise");
        let secs = t.elapsed().as_secs_f64();
        show(&name, mse(&maps), secs, &maps);
        if how == LrfDenoise::Auto {
            println!("            {}", r.summary());
        }
    }
}
