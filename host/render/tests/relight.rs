//! `Prepared::relight` (what `qhm view` does while a light is dragged)
//! gives the image a fresh `prepare` gives under the new light, bit for
//! bit: a saved view must be what `qhm render` makes of its scene.

use std::sync::atomic::AtomicBool;

use glam::Vec3;
use qhm_render::materials::{Homogeneous, preset};
use qhm_render::prepare::prepare;
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

fn render(scene: &Scene, prep: &qhm_render::prepare::Prepared, s: &RenderSettings) -> Image {
    let material = Homogeneous {
        dipole: preset("marble").unwrap(),
    };
    render_prepared(scene, &material, s, prep, &AtomicBool::new(false))
        .unwrap()
        .0
}

#[test]
fn relit_pass_one_renders_as_a_fresh_one() {
    let material = Homogeneous {
        dipole: preset("marble").unwrap(),
    };
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
    let mut prep = prepare(
        &from_above,
        &material,
        &settings,
        &mut RenderStats::default(),
    )
    .unwrap();
    let before = render(&from_above, &prep, &settings);
    prep.relight(
        &from_below,
        &material,
        &settings,
        &mut RenderStats::default(),
    )
    .unwrap();
    let relit = render(&from_below, &prep, &settings);
    let fresh = prepare(
        &from_below,
        &material,
        &settings,
        &mut RenderStats::default(),
    )
    .unwrap();
    let fresh = render(&from_below, &fresh, &settings);
    assert!(
        relit.pixels != before.pixels,
        "the new light changes nothing"
    );
    assert!(
        relit.pixels == fresh.pixels,
        "relit and fresh pass 1 differ"
    );
}
