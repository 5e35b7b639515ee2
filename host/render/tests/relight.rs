//! `Prepared::relight` (what `qhm view` does while a light is dragged)
//! gives the image a fresh `prepare` gives under the new light, bit for
//! bit: a saved view must be what `qhm render` makes of its scene.

use std::sync::atomic::AtomicBool;

use glam::Vec3;
use qhm_render::materials::{Homogeneous, preset};
use qhm_render::prepare::{Prepared, prepare};
use qhm_render::render::render_prepared;
use qhm_render::{Image, Light, RenderSettings, RenderStats, Scene};

fn lit(to_light: Vec3) -> Scene {
    let mut scene = Scene::builtin("teapot").unwrap();
    scene.lights = vec![Light::Directional {
        to_light: to_light.normalize(),
        irradiance: Vec3::splat(2.0),
    }];
    scene
}

/// Pass 1 for `scene`, fresh or, given one, re-lit; and its image.
fn pass_one(scene: &Scene, s: &RenderSettings, relit: Option<Prepared>) -> (Prepared, Image) {
    let material = Homogeneous {
        dipole: preset("marble").unwrap(),
    };
    let stats = &mut RenderStats::default();
    let prep = match relit {
        Some(mut p) => {
            p.relight(scene, &material, s, stats).unwrap();
            p
        }
        None => prepare(scene, &material, s, stats).unwrap(),
    };
    let image = render_prepared(scene, &material, s, &prep, &AtomicBool::new(false))
        .unwrap()
        .0;
    (prep, image)
}

#[test]
fn relit_pass_one_renders_as_a_fresh_one() {
    let settings = RenderSettings {
        width: 64,
        height: 64,
        surface_samples: 6000,
        env_samples: 4,
        progress: false,
        ..Default::default()
    };
    let (from_above, from_below) = (
        lit(Vec3::new(0.3, -0.5, 1.0)),
        lit(Vec3::new(-0.4, 0.6, -0.7)),
    );
    let (prep, before) = pass_one(&from_above, &settings, None);
    let (_, relit) = pass_one(&from_below, &settings, Some(prep));
    let (_, fresh) = pass_one(&from_below, &settings, None);
    assert!(
        relit.pixels != before.pixels,
        "the new light changes nothing"
    );
    assert!(
        relit.pixels == fresh.pixels,
        "relit and fresh pass 1 differ"
    );
}
