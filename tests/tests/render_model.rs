//! The renderer with real `qhm_model::MaterialModel`s: a textured model
//! (f_v and LRF maps) saved to disk and loaded back renders the same as in
//! memory; `MaterialModel::homogeneous` matches the renderer's own
//! homogeneous material (the f_v / pi convention is shared); and back
//! lighting through a thin slab appears in `full` but not in `lrf-only`.

use glam::Vec3;
use qhm_model::model::{EntranceFunction, ExitingFunction, LocalReflectance, LrfSample, Texture};
use qhm_model::{DipoleParams, MaterialModel};
use qhm_render::builtin::slab;
use qhm_render::{Camera, Homogeneous, Light, Mode, RenderSettings, Scene, render_scene};

fn dipole() -> DipoleParams {
    DipoleParams {
        alpha_prime: [0.98, 0.95, 0.9],
        sigma_t_prime: [1.5, 1.5, 1.5],
        eta: 1.3,
        model: qhm_model::ProfileModel::Dipole,
    }
}

/// A 32 x 32 textured model: stripes in f_v, spots in the LRF.
fn textured() -> MaterialModel {
    let (w, h) = (32usize, 32usize);
    let tex = |f: &dyn Fn(usize, usize) -> [f32; 3]| Texture {
        width: w,
        height: h,
        data: (0..w * h).map(|k| f(k % w, k / w)).collect(),
    };
    let s = 0.5f32;
    let c = (1.0 - s * s).sqrt();
    let views = vec![[0.0, 0.0, 1.0], [s, 0.0, c], [-s, 0.0, c]];
    let fv_maps = views
        .iter()
        .enumerate()
        .map(|(v, _)| {
            tex(&|x, _y| {
                let stripe = if (x / 4) % 2 == 0 { 1.2 } else { 0.8 };
                [stripe * (1.0 + 0.1 * v as f32); 3]
            })
        })
        .collect();
    let samples = vec![
        LrfSample {
            light: [0.0, 0.0, 1.0],
            view: [0.0, 0.0, 1.0],
        },
        LrfSample {
            light: [s, 0.0, c],
            view: [0.0, 0.0, 1.0],
        },
    ];
    let lrf_maps = (0..2)
        .map(|_| {
            tex(&|x, y| {
                let d2 = ((x % 8) as f32 - 4.0).powi(2) + ((y % 8) as f32 - 4.0).powi(2);
                [0.02 + 0.03 * (-d2 / 4.0).exp(); 3]
            })
        })
        .collect();
    MaterialModel {
        dipole: dipole(),
        entrance: EntranceFunction::fresnel(1.3, 19),
        exiting: ExitingFunction::new(views, fv_maps),
        lrf: LocalReflectance::new(samples, lrf_maps),
        texel_mm: 0.5,
        width: w as u32,
        height: h as u32,
        diagnostics: None,
    }
}

fn top_down(thickness: f32, to_light: Vec3) -> Scene {
    let mut scene = Scene::new(slab(40.0, thickness).unwrap());
    scene.camera = Camera::look_at(Vec3::new(0.0, 0.0, 150.0), Vec3::ZERO, 10f32.to_radians());
    scene.camera.up = Vec3::Y;
    scene.env = None;
    scene.lights = vec![Light::Directional {
        to_light: to_light.normalize(),
        irradiance: Vec3::splat(3.0),
    }];
    scene
}

fn settings(mode: Mode) -> RenderSettings {
    RenderSettings {
        width: 24,
        height: 24,
        spp: 1,
        mode,
        surface_samples: 12_000,
        ..Default::default()
    }
}

#[test]
fn saved_and_loaded_model_renders_like_the_original() {
    let model = textured();
    let dir = tempfile::tempdir().unwrap();
    model.save(dir.path()).unwrap();
    let loaded = MaterialModel::load(dir.path()).unwrap();
    let scene = top_down(5.0, Vec3::new(0.3, 0.2, 1.0));
    let a = render_scene(&scene, &model, &settings(Mode::Full)).unwrap();
    let b = render_scene(&scene, &loaded, &settings(Mode::Full)).unwrap();
    let (ma, mb) = (a.mean(0, 0, 24, 24), b.mean(0, 0, 24, 24));
    assert!(ma.x > 0.0);
    assert!((ma - mb).length() < 0.01 * ma.length(), "{ma} vs {mb}");
    // The texture shows: pixels differ across the slab.
    let (lo, hi) = a.pixels[24 * 6..24 * 18]
        .iter()
        .fold((f32::MAX, 0f32), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
    assert!(hi > 1.2 * lo, "no texture visible: {lo}..{hi}");
}

#[test]
fn homogeneous_model_matches_the_renderer_homogeneous_material() {
    let scene = top_down(10.0, Vec3::new(0.2, -0.3, 1.0));
    let model = MaterialModel::homogeneous(dipole());
    let own = Homogeneous { dipole: dipole() };
    let a = render_scene(&scene, &model, &settings(Mode::Full))
        .unwrap()
        .mean(4, 4, 20, 20);
    let b = render_scene(&scene, &own, &settings(Mode::Full))
        .unwrap()
        .mean(4, 4, 20, 20);
    assert!((a - b).length() < 0.01 * b.length(), "{a} vs {b}");
}

#[test]
fn back_lighting_needs_the_global_term() {
    let model = textured();
    let scene = top_down(3.0, -Vec3::Z);
    let full = render_scene(&scene, &model, &settings(Mode::Full))
        .unwrap()
        .mean(6, 6, 18, 18);
    let btf = render_scene(&scene, &model, &settings(Mode::LrfOnly))
        .unwrap()
        .mean(6, 6, 18, 18);
    assert!(full.x > 1e-3, "full {full}");
    assert_eq!(btf, Vec3::ZERO, "lrf-only {btf}");
    // Front lit, the LRF alone is not black.
    let front = top_down(3.0, Vec3::Z);
    let btf_front = render_scene(&front, &model, &settings(Mode::LrfOnly))
        .unwrap()
        .mean(6, 6, 18, 18);
    assert!(btf_front.x > 0.05, "{btf_front}");
}
