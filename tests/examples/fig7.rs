//! Paper Fig. 7: the simulated sample rendered directly by the world's
//! Monte Carlo path tracer (sim-light) and from the material model acquired
//! from it (qhm-render), with the same camera, the same lamp and the same
//! radiometric units, under a lamp the capture did not use.
//!
//! ```text
//! cargo run --release -p tests --example fig7 -- [--sample two-material] [--scale default]
//!     [--seed 3] [-o /tmp/qhm-fig7] [--camera 5] [--lamp 4] [--arc-deg 90]
//!     [--turntable-deg 0] [--downscale 4] [--photons 8000000] [--spp 16]
//!     [--png docs/img/fig7.png]
//! ```
//!
//! 1. The model: `OUT/model` if it exists, else `qhm demo` (capture on the
//!    simulated rig of `--seed`, rectify, fit) into `OUT` first.
//! 2. Path tracer: `World::render_pose` of the same sample and the same
//!    rig truth (`RigTruth::perturbed(seed)`, what the capture ran on), lamp
//!    `--lamp` at light-arc angle `--arc-deg`, turntable `--turntable-deg`,
//!    camera `--camera`, in two halves with different seeds (their
//!    difference gives the Monte Carlo noise). Radiance in W sr^-1 m^-2.
//! 3. Model: the slab's top face (the sim's lamps light only the top; its
//!    sides and bottom are black) as a plane in the sample frame, the texture
//!    registered to the rectified texels it was measured on (the model's
//!    texel (i, j) is rectified texel (i0 + i, j0 + j), fit.json's window;
//!    tiled outside, no quilting), a directional
//!    light with the lamp's true direction and irradiance (W m^-2 normal to
//!    the light), rendered through the true camera (pose, intrinsics, radial
//!    distortion) with `render_scene_camera`. The model's LRF is per unit
//!    irradiance and R_d per unit incident flux, so the render is in W sr^-1
//!    m^-2 as well: no scale factor anywhere.
//! 4. Compare over the pixels that see the patch the model covers (one
//!    texel in from its edge): RMSE absolute and relative, mean ratio,
//!    Monte Carlo noise of the path tracer, RMSE of 4 x 4 and 8 x 8 pixel
//!    block means, the model's local (LRF) share. Writes `OUT/fig7/` (EXR of
//!    both, `compare.png`, `summary.json`) and `--png` if given.

use std::error::Error;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{DVec2, DVec3, Vec3};
use qhm_acquire::{Manifest, Scale};
use qhm_model::MaterialModel;
use qhm_render::bvh::Ray;
use qhm_render::light::luminance;
use qhm_render::mesh::Mesh;
use qhm_render::mesh_input::MeshInput;
use qhm_render::{Image, Light, Mode, RenderSettings, Scene, render_scene_camera};
use sim_devices::SimTruth;
use sim_light::{Illumination, RigTruth, SceneDesc, SimQuality, World};

type Res<T> = Result<T, Box<dyn Error>>;

struct Args {
    sample: String,
    scale: String,
    seed: u64,
    out: PathBuf,
    camera: usize,
    lamp: usize,
    arc_deg: f64,
    turntable_deg: f64,
    downscale: u32,
    photons: u64,
    spp: u32,
    png: Option<PathBuf>,
}

fn parse_args() -> Res<Args> {
    let mut a = Args {
        sample: "two-material".into(),
        scale: "default".into(),
        seed: 3,
        out: PathBuf::from("/tmp/qhm-fig7"),
        camera: 5,
        lamp: 4,
        arc_deg: 90.0,
        turntable_deg: 0.0,
        downscale: 4,
        photons: 8_000_000,
        spp: 16,
        png: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut v = || it.next().ok_or_else(|| format!("{k} needs a value"));
        match k.as_str() {
            "--sample" => a.sample = v()?,
            "--scale" => a.scale = v()?,
            "--seed" => a.seed = v()?.parse()?,
            "-o" | "--out" => a.out = v()?.into(),
            "--camera" => a.camera = v()?.parse()?,
            "--lamp" => a.lamp = v()?.parse()?,
            "--arc-deg" => a.arc_deg = v()?.parse()?,
            "--turntable-deg" => a.turntable_deg = v()?.parse()?,
            "--downscale" => a.downscale = v()?.parse()?,
            "--photons" => a.photons = v()?.parse()?,
            "--spp" => a.spp = v()?.parse()?,
            "--png" => a.png = Some(v()?.into()),
            "-h" | "--help" => {
                println!("see the doc comment of tests/examples/fig7.rs or docs/render.md");
                std::process::exit(0);
            }
            _ => return Err(format!("unknown argument {k}").into()),
        }
    }
    if !(1..=7).contains(&a.lamp) || !(1..=7).contains(&a.camera) {
        return Err("--lamp must be 1..=7 and --camera 1..=7".into());
    }
    Ok(a)
}

/// The slab's top face z = 0 as two triangles, UV in mm from the rectified
/// grid's origin (so texel (i, j) of the model lies where it was measured).
fn top_face(half: [f32; 2], origin_mm: [f32; 2]) -> Res<Mesh> {
    let corners = [
        [-half[0], -half[1]],
        [half[0], -half[1]],
        [half[0], half[1]],
        [-half[0], half[1]],
    ];
    let input = MeshInput {
        positions: corners.iter().map(|c| [c[0], c[1], 0.0]).collect(),
        normals: Some(vec![[0.0, 0.0, 1.0]; 4]),
        uvs: Some(
            corners
                .iter()
                .map(|c| [c[0] - origin_mm[0], c[1] - origin_mm[1]])
                .collect(),
        ),
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    Ok(Mesh::build(input, Some(1.0))?)
}

fn lum(p: [f32; 3]) -> f64 {
    luminance(Vec3::from_array(p)) as f64
}

#[derive(Default, Clone)]
struct Channel {
    mean_path_tracer: f64,
    mean_model: f64,
    mean_ratio: f64,
    rmse_abs: f64,
    rmse_rel: f64,
    noise_rmse_abs: f64,
    rmse_rel_noise_removed: f64,
    rmse_rel_block4: f64,
    rmse_rel_lowpass: f64,
    rmse_rel_highpass: f64,
    model_local_share: f64,
}

impl Channel {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "mean_path_tracer": self.mean_path_tracer,
            "mean_model": self.mean_model,
            "mean_ratio": self.mean_ratio,
            "rmse_abs": self.rmse_abs,
            "rmse_rel": self.rmse_rel,
            "noise_rmse_abs": self.noise_rmse_abs,
            "rmse_rel_noise_removed": self.rmse_rel_noise_removed,
            "rmse_rel_block4": self.rmse_rel_block4,
            "rmse_rel_lowpass": self.rmse_rel_lowpass,
            "rmse_rel_highpass": self.rmse_rel_highpass,
            "model_local_share": self.model_local_share,
        })
    }
}

/// Statistics over the masked pixels, channel c (3 = luminance).
fn stats(
    pt: &[[f32; 3]],
    half_a: &[[f32; 3]],
    half_b: &[[f32; 3]],
    model: &[[f32; 3]],
    local: &[[f32; 3]],
    mask: &[bool],
    width: usize,
    c: usize,
) -> Channel {
    let val = |p: &[f32; 3]| {
        if c == 3 { lum(*p) } else { p[c] as f64 }
    };
    let idx: Vec<usize> = (0..mask.len()).filter(|&i| mask[i]).collect();
    let n = idx.len() as f64;
    let (mut sp, mut sm, mut sl, mut se, mut sp2, mut sn) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &i in &idx {
        let (p, m) = (val(&pt[i]), val(&model[i]));
        sp += p;
        sm += m;
        sl += val(&local[i]);
        se += (m - p) * (m - p);
        sp2 += p * p;
        let d = val(&half_a[i]) - val(&half_b[i]);
        sn += d * d / 4.0;
    }
    // Low-pass: means over b x b pixel blocks (only blocks fully inside
    // the mask); high-pass: the rest.
    let height = mask.len() / width;
    let blocks = |b: usize| {
        let (mut lo_e, mut lo_p2, mut hi_e) = (0.0, 0.0, 0.0);
        let mut nb = 0.0;
        for by in 0..height / b {
            for bx in 0..width / b {
                let cells: Vec<usize> = (0..b * b)
                    .map(|k| (by * b + k / b) * width + bx * b + k % b)
                    .collect();
                if !cells.iter().all(|&i| mask[i]) {
                    continue;
                }
                let mp = cells.iter().map(|&i| val(&pt[i])).sum::<f64>() / (b * b) as f64;
                let mm = cells.iter().map(|&i| val(&model[i])).sum::<f64>() / (b * b) as f64;
                lo_e += (mm - mp) * (mm - mp) * (b * b) as f64;
                lo_p2 += mp * mp * (b * b) as f64;
                for &i in &cells {
                    let d = (val(&model[i]) - mm) - (val(&pt[i]) - mp);
                    hi_e += d * d;
                }
                nb += (b * b) as f64;
            }
        }
        (lo_e, lo_p2, hi_e, nb)
    };
    let (lo4_e, lo4_p2, _, _) = blocks(4);
    let (lo_e, lo_p2, hi_e, nb) = blocks(8);
    let rmse = (se / n).sqrt();
    let noise = (sn / n).sqrt();
    let rms_p = (sp2 / n).sqrt();
    Channel {
        mean_path_tracer: sp / n,
        mean_model: sm / n,
        mean_ratio: sm / sp,
        rmse_abs: rmse,
        rmse_rel: rmse / rms_p,
        noise_rmse_abs: noise,
        rmse_rel_noise_removed: (rmse * rmse - noise * noise).max(0.0).sqrt() / rms_p,
        rmse_rel_block4: (lo4_e / lo4_p2.max(1e-300)).sqrt(),
        rmse_rel_lowpass: (lo_e / lo_p2.max(1e-300)).sqrt(),
        rmse_rel_highpass: (hi_e / nb.max(1.0)).sqrt() / (lo_p2 / nb.max(1.0)).sqrt(),
        model_local_share: sl / sm,
    }
}

/// Path tracer | model | difference, each upscaled 2x; both renders with
/// one exposure, the difference of 4 x 4 pixel block means in luminance as
/// red (model brighter) or blue (darker), full colour at +-25 % of the
/// patch's mean luminance; outside the compared patch it is dimmed.
fn side_by_side(pt: &Image, model: &Image, mask: &[bool], mean_lum: f64, path: &Path) -> Res<()> {
    let (w, h) = (pt.width as usize, pt.height as usize);
    let up = 2;
    let gap = 4;
    let pw = w * up;
    let total_w = 3 * pw + 2 * gap;
    let total_h = h * up;
    let mut buf = vec![255u8; total_w * total_h * 3];
    let k = (1.0 / (2.5 * mean_lum.max(1e-30))) as f32;
    let (pt_srgb, model_srgb) = (pt.tone_mapped(Some(k)), model.tone_mapped(Some(k)));
    // Luminance difference of 4 x 4 pixel block means (pixel-level Monte
    // Carlo noise of both images would hide everything else).
    let bw = w.div_ceil(4);
    let mut blocks = vec![(0.0f64, 0.0f64); bw * h.div_ceil(4)];
    for (i, (m, p)) in model.pixels.iter().zip(&pt.pixels).enumerate() {
        let b = &mut blocks[(i / w / 4) * bw + (i % w) / 4];
        b.0 += lum(*m) - lum(*p);
        b.1 += 1.0;
    }
    let diff4: Vec<f64> = blocks.into_iter().map(|(d, n)| d / n).collect();
    for y in 0..total_h {
        for x in 0..pw {
            let i = (y / up) * w + x / up;
            let mut put = |panel: usize, rgb: &[u8]| {
                let o = (y * total_w + panel * (pw + gap) + x) * 3;
                buf[o..o + 3].copy_from_slice(rgb);
            };
            put(0, &pt_srgb[3 * i..3 * i + 3]);
            put(1, &model_srgb[3 * i..3 * i + 3]);
            let d = diff4[(y / up / 4) * bw + x / up / 4] / (0.25 * mean_lum);
            let d = d.clamp(-1.0, 1.0);
            let a = if mask[i] { 1.0 } else { 0.35 };
            let (r, g, b) = if d >= 0.0 {
                (1.0, 1.0 - d, 1.0 - d)
            } else {
                (1.0 + d, 1.0 + d, 1.0)
            };
            let px = [r, g, b].map(|v| ((v * a + (1.0 - a) * 0.5) * 255.0) as u8);
            put(2, &px);
        }
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    image::save_buffer(
        path,
        &buf,
        total_w as u32,
        total_h as u32,
        image::ColorType::Rgb8,
    )?;
    Ok(())
}

fn main() -> Res<()> {
    let a = parse_args()?;
    let t_all = Instant::now();

    // 1. The acquired model.
    let model_dir = a.out.join("model");
    if !model_dir.join("manifest.toml").exists() {
        eprintln!("== no model in {}: running qhm demo", a.out.display());
        let scale: Scale = a.scale.parse()?;
        let opts = host::demo::DemoOptions {
            sample: a.sample.clone(),
            scale,
            out: a.out.clone(),
            force: false,
            seed: a.seed,
            quiet: true,
            skip_renders: true,
            calibration: None,
        };
        host::demo::run(&opts)?;
    }
    // The capture's sample and seed (the world must be the one measured).
    let capture: Manifest = toml::from_str(&std::fs::read_to_string(
        a.out.join("capture/capture.toml"),
    )?)?;
    let capture_scale = capture.plan.scale.name();
    if capture.sample != a.sample || capture.seed != a.seed {
        return Err(format!(
            "{} holds a capture of {:?} seed {}, not {:?} seed {}",
            a.out.display(),
            capture.sample,
            capture.seed,
            a.sample,
            a.seed
        )
        .into());
    }
    let model = MaterialModel::load(&model_dir)?;
    let index = qhm_imaging::rectified::read_index(&a.out.join("capture/rectified"))?;
    let grid = index.grid;
    // The model covers the texels every view's stripes reach (fit.json's
    // window within the rectified grid): texel (0, 0) of its texture is
    // grid texel (i0, j0).
    let [i0, j0, ww, wh] = model.window().unwrap_or([0, 0, grid.width, grid.height]);
    let tm = grid.texel_mm;
    let (ox, oy) = (
        grid.origin_mm[0] + i0 as f64 * tm,
        grid.origin_mm[1] + j0 as f64 * tm,
    );

    // 2. The world as captured, and the new light.
    let desc = SceneDesc::load(&a.sample)?;
    let size = match &desc {
        SceneDesc::Sample(s) => s.size_mm,
        _ => return Err("not a sample".into()),
    };
    let quality = SimQuality {
        downscale: a.downscale,
        lamp_photons: a.photons / 2,
        ..SimQuality::preview()
    };
    let world = World::new(desc, RigTruth::perturbed(a.seed), quality)?;
    let rig = world.rig().clone();
    let (tt, arc) = (a.turntable_deg.to_radians(), a.arc_deg.to_radians());
    let to_sample = rig.world_to_sample(tt);
    let to_light = to_sample * rig.lamp_direction(a.lamp, arc);
    let e_lamp = rig.lamps[a.lamp].irradiance;
    let nearest_captured = index
        .lamp
        .iter()
        .map(|l| {
            DVec3::from_array(l.light_dir)
                .normalize()
                .dot(to_light)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "light: lamp {} at arc {} deg, turntable {} deg: to light {:.3?} (elevation {:.1} deg), \
         {nearest_captured:.1} deg from the nearest captured lamp direction; E = {:.3?} W m^-2",
        a.lamp,
        a.arc_deg,
        a.turntable_deg,
        to_light.to_array(),
        to_light.z.asin().to_degrees(),
        e_lamp
    );
    let illum = Illumination {
        turntable_rad: tt,
        light_arc_rad: arc,
        galvo_rad: 0.0,
        laser: None,
        lamps: 1 << a.lamp,
    };
    let t = Instant::now();
    let halves: Vec<Vec<[f32; 3]>> = [0x5eed_0001u64, 0x5eed_0002]
        .iter()
        .map(|&s| -> Res<Vec<[f32; 3]>> {
            let mut pose = world.render_pose(&illum, 1 << a.camera, a.seed ^ s)?;
            let image = pose.images.get_mut(a.camera).and_then(Option::take);
            Ok(image.ok_or("no image")?.data)
        })
        .collect::<Res<_>>()?;
    let (w, h) = world.image_size();
    let secs_pt = t.elapsed().as_secs_f64();
    let pt: Vec<[f32; 3]> = halves[0]
        .iter()
        .zip(&halves[1])
        .map(|(x, y)| std::array::from_fn(|c| 0.5 * (x[c] + y[c])))
        .collect();
    eprintln!(
        "path tracer: {w} x {h}, 2 x {} photons per channel, {secs_pt:.1} s",
        a.photons / 2
    );

    // 3. The model on the slab's top face, same camera and light.
    let mesh = top_face(
        [size[0] as f32 / 2.0, size[1] as f32 / 2.0],
        [ox as f32, oy as f32],
    )?;
    let mut scene = Scene::new(mesh);
    scene.lights = vec![Light::Directional {
        to_light: to_light.as_vec3(),
        irradiance: Vec3::from_array(e_lamp.map(|e| e as f32)),
    }];
    // The true camera at the binning, in the sample frame. Its pixel centres
    // are at integers, the film's at integer + 0.5.
    let cam = SimTruth::new(a.seed).true_camera(a.camera, quality.downscale);
    let origin = (to_sample * cam.centre()).as_vec3();
    let camera_ray = |x: f64, y: f64| Ray {
        o: origin,
        d: (to_sample * cam.ray(DVec2::new(x - 0.5, y - 0.5)))
            .normalize()
            .as_vec3(),
    };
    let ray = |x: f32, y: f32| camera_ray(x as f64, y as f64);
    let mut settings = RenderSettings {
        width: w,
        height: h,
        spp: a.spp,
        surface_samples: 120_000,
        synthesis: false,
        seed: a.seed,
        ..RenderSettings::default()
    };
    let t = Instant::now();
    let (full, _) = render_scene_camera(&scene, &model, &settings, ray)?;
    settings.mode = Mode::LrfOnly;
    let (local, _) = render_scene_camera(&scene, &model, &settings, ray)?;
    let secs_model = t.elapsed().as_secs_f64();
    eprintln!("model: full + lrf-only, {secs_model:.1} s");

    // 4. The compared region: pixels whose centre sees the measured patch,
    // one texel in from its edge.
    let (x1, y1) = (ox + ww as f64 * tm - tm, oy + wh as f64 * tm - tm);
    let mask: Vec<bool> = (0..(w * h) as usize)
        .map(|i| {
            let r = camera_ray((i % w as usize) as f64 + 0.5, (i / w as usize) as f64 + 0.5);
            if r.d.z >= 0.0 {
                return false;
            }
            let t = -r.o.z / r.d.z;
            let p = r.o + r.d * t;
            let (x, y) = (p.x as f64, p.y as f64);
            x > ox + tm && x < x1 && y > oy + tm && y < y1
        })
        .collect();
    let n_mask = mask.iter().filter(|&&m| m).count();
    if n_mask < 64 {
        return Err(format!("only {n_mask} pixels see the measured patch").into());
    }
    let names = ["R", "G", "B", "luminance"];
    let chans: Vec<Channel> = (0..4)
        .map(|c| {
            stats(
                &pt,
                &halves[0],
                &halves[1],
                &full.pixels,
                &local.pixels,
                &mask,
                w as usize,
                c,
            )
        })
        .collect();
    println!(
        "Fig. 7: {} (seed {}, {} capture), camera {}, lamp {} at arc {} deg, turntable {} deg \
         ({nearest_captured:.1} deg from the nearest captured light); {n_mask} pixels on the \
         {:.1} x {:.1} mm measured patch",
        a.sample,
        a.seed,
        capture_scale,
        a.camera,
        a.lamp,
        a.arc_deg,
        a.turntable_deg,
        ww as f64 * tm,
        wh as f64 * tm
    );
    println!(
        "{:<10} {:>11} {:>11} {:>7} {:>10} {:>7} {:>10} {:>8} {:>7} {:>7} {:>7} {:>6}",
        "channel",
        "mean PT",
        "mean model",
        "ratio",
        "RMSE abs",
        "rel",
        "MC noise",
        "rel-noise",
        "4x4",
        "8x8",
        "high",
        "LRF"
    );
    for (n, c) in names.iter().zip(&chans) {
        println!(
            "{:<10} {:>11.4e} {:>11.4e} {:>7.3} {:>10.3e} {:>6.1}% {:>10.3e} {:>7.1}% {:>6.1}% {:>6.1}% {:>6.1}% {:>5.0}%",
            n,
            c.mean_path_tracer,
            c.mean_model,
            c.mean_ratio,
            c.rmse_abs,
            100.0 * c.rmse_rel,
            c.noise_rmse_abs,
            100.0 * c.rmse_rel_noise_removed,
            100.0 * c.rmse_rel_block4,
            100.0 * c.rmse_rel_lowpass,
            100.0 * c.rmse_rel_highpass,
            100.0 * c.model_local_share
        );
    }
    println!(
        "(radiance in W sr^-1 m^-2; rel = RMSE / RMS of the path tracer; rel-noise: Monte Carlo \
         noise removed in quadrature; 4x4, 8x8: RMSE of 4x4 / 8x8-pixel block means; high: \
         pixel minus 8x8 block mean; LRF: the local term's share of the model)"
    );

    let dir = a.out.join("fig7");
    std::fs::create_dir_all(&dir)?;
    let pt_img = Image {
        width: w,
        height: h,
        pixels: pt,
    };
    pt_img.write_exr(&dir.join("path_tracer.exr"))?;
    full.write_exr(&dir.join("model.exr"))?;
    local.write_exr(&dir.join("model_lrf_only.exr"))?;
    let mean_lum = chans[3].mean_path_tracer;
    let compare = dir.join("compare.png");
    side_by_side(&pt_img, &full, &mask, mean_lum, &compare)?;
    if let Some(p) = &a.png {
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::copy(&compare, p)?;
    }
    let summary = serde_json::json!({
        "sample": a.sample, "scale": capture_scale, "seed": a.seed, "camera": a.camera,
        "lamp": a.lamp, "arc_deg": a.arc_deg, "turntable_deg": a.turntable_deg,
        "to_light": to_light.to_array(), "irradiance_w_m2": e_lamp,
        "nearest_captured_light_deg": nearest_captured,
        "image": [w, h], "photons_per_channel": a.photons, "spp": a.spp,
        "pixels_compared": n_mask,
        "channels": names.iter().zip(&chans).map(|(n, c)| (n.to_string(), c.json())).collect::<serde_json::Map<_, _>>(),
        "seconds": { "path_tracer": secs_pt, "model": secs_model, "total": t_all.elapsed().as_secs_f64() },
    });
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(&summary)? + "\n",
    )?;
    eprintln!("wrote {}", dir.display());
    Ok(())
}
