//! Known answers for the object estimator: the white furnace, single
//! scattering below a flat smooth boundary in closed form, determinism.

use std::f32::consts::PI;

use glam::Vec3;

use super::*;
use crate::medium::Volume;
use crate::sample::{Coefficients, MaterialDesc, SampleDesc, SurfaceDesc, VolumeDesc};

/// An axis-aligned box with per-face vertices and normals.
pub fn box_mesh(lo: Vec3, hi: Vec3) -> ObjectMesh {
    let mut m = ObjectMesh {
        positions: vec![],
        normals: vec![],
        triangles: vec![],
    };
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            let base = m.positions.len() as u32;
            for (a, b) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                let mut p = Vec3::ZERO;
                p[axis] = if sign > 0.0 { hi[axis] } else { lo[axis] };
                p[u] = if a == 1 { hi[u] } else { lo[u] };
                p[v] = if b == 1 { hi[v] } else { lo[v] };
                m.positions.push(p);
                m.normals.push(n);
            }
            m.triangles.push([base, base + 1, base + 2]);
            m.triangles.push([base, base + 2, base + 3]);
        }
    }
    m
}

/// A UV sphere of radius r at the origin with exact vertex normals.
pub fn sphere_mesh(r: f32, n_phi: usize, n_theta: usize) -> ObjectMesh {
    let mut m = ObjectMesh {
        positions: vec![],
        normals: vec![],
        triangles: vec![],
    };
    for j in 0..=n_theta {
        let th = PI * j as f32 / n_theta as f32;
        for i in 0..=n_phi {
            let ph = 2.0 * PI * i as f32 / n_phi as f32;
            let n = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
            m.positions.push(n * r);
            m.normals.push(n);
        }
    }
    let row = (n_phi + 1) as u32;
    for j in 0..n_theta as u32 {
        for i in 0..n_phi as u32 {
            let (a, b) = (j * row + i, j * row + i + 1);
            let (c, d) = (a + row, b + row);
            if j > 0 {
                m.triangles.push([a, c, b]);
            }
            if j + 1 < n_theta as u32 {
                m.triangles.push([b, c, d]);
            }
        }
    }
    m
}

pub fn homogeneous(albedo: f64, sigma_t: f64, eta: f64) -> SampleDesc {
    SampleDesc {
        name: "test".into(),
        size_mm: [60.0, 60.0, 20.0],
        seed: 0,
        surface: SurfaceDesc {
            eta,
            roughness: 0.0,
            ..SurfaceDesc::default()
        },
        volume: VolumeDesc {
            material: MaterialDesc::Coefficients(Coefficients::from_albedo(
                [albedo; 3],
                [sigma_t; 3],
            )),
            inclusions: vec![],
        },
    }
}

fn uniform_env(l: f32) -> EnvImage {
    EnvImage {
        width: 8,
        height: 4,
        texels: vec![Vec3::splat(l); 32],
        rotation: 0.0,
    }
}

/// A 2 mm sphere of `sample` under a uniform sky of radiance 1, and the
/// options of its 16 x 16 render.
fn furnace(sample: SampleDesc) -> (ObjectScene, RenderOptions) {
    let scene = ObjectScene {
        mesh: sphere_mesh(2.0, 48, 24),
        sample,
        camera: PinholeCamera {
            eye: Vec3::new(0.0, -12.0, 0.0),
            target: Vec3::ZERO,
            up: Vec3::Z,
            fov_y: 0.3,
        },
        lights: vec![],
        env: Some(uniform_env(1.0)),
        env_visible: true,
    };
    let opts = RenderOptions {
        width: 16,
        height: 16,
        spp: 16,
        seed: 3,
        ..RenderOptions::default()
    };
    (scene, opts)
}

/// The furnace's render sees the sky's radiance, 1, in every channel
/// (shading-normal losses on the 48 x 24 mesh are below 0.5 %).
fn assert_sees_the_sky(img: &ObjectImage) {
    let (m, e) = (img.mean(), img.mean_rel_error());
    for c in 0..3 {
        assert!(
            (m[c] - 1.0).abs() < 4.0 * e[c] + 0.005,
            "channel {c}: {} +- {}",
            m[c],
            e[c]
        );
    }
    assert!(e.iter().all(|&e| e < 0.02), "{e:?}");
}

#[test]
fn white_furnace_sphere_is_uniform() {
    // No absorption, uniform sky of radiance 1: every pixel sees exactly 1,
    // through the smooth boundary (eta 1.3) and the volume alike.
    let (scene, opts) = furnace(homogeneous(1.0, 2.0, 1.3));
    let img = render_object(&scene, &opts, &|_| {}, None).unwrap();
    assert_sees_the_sky(&img);
    assert_eq!(img.stats.truncated, 0);
    // and it is not trivially 1: half the albedo darkens it
    let mut dark = scene.clone();
    dark.sample = homogeneous(0.5, 2.0, 1.3);
    let img2 = render_object(&dark, &opts, &|_| {}, None).unwrap();
    assert!(img2.mean()[0] < 0.9, "{:?}", img2.mean());
}

#[test]
fn white_furnace_holds_under_a_rough_top_that_conserves_energy() {
    // The same furnace under a rough top (GGX 0.35): the camera paths'
    // weights, divided by the albedo of the light-side direction, give
    // back exactly the sky when the top keeps its masked share, and less
    // when it loses it.
    let mut sample = homogeneous(1.0, 2.0, 1.3);
    sample.surface.roughness = 0.35;
    sample.surface.conserve_energy = true;
    let (scene, opts) = furnace(sample);
    assert_sees_the_sky(&render_object(&scene, &opts, &|_| {}, None).unwrap());
    let mut lossy = scene.clone();
    lossy.sample.surface.conserve_energy = false;
    let m = render_object(&lossy, &opts, &|_| {}, None).unwrap().mean();
    assert!(m[0] < 0.97, "{m:?}");
}

/// Single scattering below a flat smooth boundary (one event, then the
/// path ends): L = a T_i T_o E cos_i / (4 pi eta^2 (cos_ti + cos_to)).
fn single_scattering(theta_i: f32, theta_o: f32, eta: f32, albedo: f32, e: f32) -> f32 {
    use crate::microfacet::fr_dielectric;
    let (ci, co) = (theta_i.cos(), theta_o.cos());
    let cti = (1.0 - theta_i.sin().powi(2) / (eta * eta)).sqrt();
    let cto = (1.0 - theta_o.sin().powi(2) / (eta * eta)).sqrt();
    let (ti, to) = (1.0 - fr_dielectric(ci, eta), 1.0 - fr_dielectric(co, eta));
    albedo * ti * to * e * ci / (4.0 * PI * eta * eta * (cti + cto))
}

fn slab_scene(theta_i: f32, theta_o: f32, point: bool) -> ObjectScene {
    let to_light = Vec3::new(theta_i.sin(), 0.0, theta_i.cos());
    let light = if point {
        // far enough that it is nearly directional over the spot, with
        // irradiance 2 at the origin facing it
        let r = 2000.0;
        DeltaLight::Point {
            position: to_light * r,
            intensity: Vec3::splat(2.0 * r * r),
        }
    } else {
        DeltaLight::Directional {
            to_light,
            irradiance: Vec3::splat(2.0),
        }
    };
    ObjectScene {
        mesh: box_mesh(
            Vec3::new(-100.0, -100.0, -40.0),
            Vec3::new(100.0, 100.0, 0.0),
        ),
        sample: homogeneous(0.6, 1.0, 1.4),
        camera: PinholeCamera {
            eye: Vec3::new(0.0, -theta_o.sin(), theta_o.cos()) * 500.0,
            target: Vec3::ZERO,
            up: Vec3::Z,
            fov_y: 0.004,
        },
        lights: vec![light],
        env: None,
        env_visible: false,
    }
}

#[test]
fn single_scattering_matches_the_closed_form() {
    let opts = RenderOptions {
        width: 4,
        height: 4,
        spp: 512,
        seed: 9,
        max_events: 1,
        ..RenderOptions::default()
    };
    for (ti, to, point) in [(0.7f32, 0.4f32, false), (0.2, 1.0, false), (0.7, 0.4, true)] {
        let img = render_object(&slab_scene(ti, to, point), &opts, &|_| {}, None).unwrap();
        let want = single_scattering(ti, to, 1.4, 0.6, 2.0) as f64;
        let (m, e) = (img.mean(), img.mean_rel_error());
        for c in 0..3 {
            assert!(
                (m[c] / want - 1.0).abs() < 4.0 * e[c] + 0.003,
                "theta_i {ti} theta_o {to} point {point}: {} vs {want} (+- {})",
                m[c],
                e[c]
            );
        }
        assert!(e.iter().all(|&e| e < 0.01), "{e:?}");
        assert_eq!(img.stats.nee_unconverged, 0);
    }
    // a wrong index of refraction is seen
    let mut s = slab_scene(0.7, 0.4, false);
    s.sample.surface.eta = 1.3;
    let img = render_object(&s, &opts, &|_| {}, None).unwrap();
    let want = single_scattering(0.7, 0.4, 1.4, 0.6, 2.0) as f64;
    assert!(
        (img.mean()[0] / want - 1.0).abs() > 0.05,
        "{:?} {want}",
        img.mean()
    );
}

#[test]
fn same_image_for_any_thread_count() {
    let mut scene = slab_scene(0.5, 0.3, false);
    scene.mesh = sphere_mesh(3.0, 24, 12);
    scene.camera.fov_y = 0.02;
    scene.env = Some(uniform_env(0.3));
    let opts = RenderOptions {
        width: 8,
        height: 8,
        spp: 4,
        seed: 1,
        ..RenderOptions::default()
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render_object(&scene, &opts, &|_| {}, None).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.radiance, b.radiance);
    assert_eq!(a.stats, b.stats);
    assert!(a.mean()[0] > 0.0);
}

/// A disk of angular radius `radius` (radians) around `dir` in an
/// otherwise black lat-long map, radiance `l`.
fn sun_disk_env(dir: Vec3, radius: f32, l: f32, w: usize, h: usize) -> EnvImage {
    let dir = dir.normalize();
    let texels = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (th, ph) = (
                PI * (y as f32 + 0.5) / h as f32,
                2.0 * PI * (x as f32 + 0.5) / w as f32,
            );
            let d = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
            Vec3::splat(if d.dot(dir) > radius.cos() { l } else { 0.0 })
        })
        .collect();
    EnvImage {
        width: w,
        height: h,
        texels,
        rotation: 0.0,
    }
}

/// The same disk as directional lights: rings x spokes, equal solid angle
/// each, irradiance l dOmega each.
fn sun_disk_lights(dir: Vec3, radius: f32, l: f32, rings: usize, spokes: usize) -> Vec<DeltaLight> {
    let dir = dir.normalize();
    let (s, t) = dir.any_orthonormal_pair();
    let omega = 2.0 * PI * (1.0 - radius.cos());
    let n = rings * spokes;
    let mut out = Vec::with_capacity(n);
    for i in 0..rings {
        // equal solid-angle rings: cos theta uniform in [cos r, 1]
        let c = 1.0 - (1.0 - radius.cos()) * (i as f32 + 0.5) / rings as f32;
        let sn = (1.0 - c * c).sqrt();
        for j in 0..spokes {
            let ph = 2.0 * PI * (j as f32 + 0.5 * (i % 2) as f32) / spokes as f32;
            out.push(DeltaLight::Directional {
                to_light: (dir * c + (s * ph.cos() + t * ph.sin()) * sn).normalize(),
                irradiance: Vec3::splat(l * omega / n as f32),
            });
        }
    }
    out
}

#[test]
#[ignore = "about a minute: plain path tracing of a sun disk needs many paths"]
fn delta_light_estimates_match_exit_rays_on_a_curved_object() {
    // The entry-point walk and its beam area on a sphere, against plain
    // path tracing of a sun disk (exit rays that hit the disk): the disk
    // as 48 directional lights must give the same image, front- and
    // back-lit. 10 degrees of disk radius; l = 20.
    //
    // Back-lit it holds for an index-matched boundary only: at eta 1.3 the
    // delta lights gave 0.0257 against the exit rays' 0.0536. Light that
    // enters near the terminator meets the far wall near the critical angle
    // and is guided along the skin by internal reflections before it first
    // scatters; the one-refraction connection does not sample those chains.
    let (radius, l) = (10f32.to_radians(), 20.0);
    let camera = PinholeCamera {
        eye: Vec3::new(0.0, -16.0, 0.0),
        target: Vec3::ZERO,
        up: Vec3::Z,
        fov_y: 0.28,
    };
    for (sun, eta) in [
        (Vec3::new(0.6, -1.0, 0.5), 1.3),
        (Vec3::new(-0.4, 1.0, 0.3), 1.0),
    ] {
        let base = ObjectScene {
            mesh: sphere_mesh(2.0, 96, 48),
            sample: homogeneous(0.9, 1.5, eta),
            camera,
            lights: vec![],
            env: None,
            env_visible: false,
        };
        let exit_rays = ObjectScene {
            env: Some(sun_disk_env(sun, radius, l, 1024, 512)),
            ..base.clone()
        };
        let deltas = ObjectScene {
            lights: sun_disk_lights(sun, radius, l, 4, 12),
            ..base
        };
        // the disk seen through the sphere without scattering (its lens
        // image) has no counterpart in the delta lights' estimate
        let opts = |spp| RenderOptions {
            width: 12,
            height: 12,
            spp,
            seed: 5,
            unscattered_env: false,
            ..RenderOptions::default()
        };
        let a = render_object(&exit_rays, &opts(3000), &|_| {}, None).unwrap();
        let b = render_object(&deltas, &opts(48), &|_| {}, None).unwrap();
        let (ma, mb) = (a.mean(), b.mean());
        let (ea, eb) = (a.mean_rel_error(), b.mean_rel_error());
        let noise = (ea[0] * ea[0] + eb[0] * eb[0]).sqrt();
        eprintln!(
            "sun {sun}: exit rays {:.5} +- {:.2} %, delta lights {:.5} +- {:.2} % ({:?})",
            ma[0],
            100.0 * ea[0],
            mb[0],
            100.0 * eb[0],
            b.stats
        );
        assert!(noise < 0.05, "{noise}");
        assert!(
            (mb[0] / ma[0] - 1.0).abs() < 3.0 * noise + 0.01,
            "sun {sun}: {} vs {}",
            mb[0],
            ma[0]
        );
    }
}

fn cellular_preset(name: &str) -> SampleDesc {
    let crate::sample::SceneDesc::Sample(s) = crate::sample::SceneDesc::preset(name).unwrap()
    else {
        unreachable!()
    };
    assert!(Volume::build(&s).cells.is_some(), "{name} is cellular");
    s
}

#[test]
fn cellular_object_is_the_same_for_any_thread_count() {
    let scene = ObjectScene {
        mesh: sphere_mesh(3.0, 24, 12),
        sample: cellular_preset("bread"),
        camera: PinholeCamera {
            eye: Vec3::new(0.0, -20.0, 4.0),
            target: Vec3::ZERO,
            up: Vec3::Z,
            fov_y: 0.2,
        },
        lights: vec![DeltaLight::Directional {
            to_light: Vec3::new(0.3, -0.5, 0.8).normalize(),
            irradiance: Vec3::splat(2.0),
        }],
        env: Some(uniform_env(0.2)),
        env_visible: true,
    };
    let opts = RenderOptions {
        width: 6,
        height: 6,
        spp: 2,
        seed: 3,
        ..RenderOptions::default()
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render_object(&scene, &opts, &|_| {}, None).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.radiance, b.radiance);
    assert_eq!(a.stats, b.stats);
    assert!(
        a.mean()[0] > 0.0 && a.stats.nee > 0 && a.stats.events > 0,
        "{:?}",
        a.stats
    );
}

/// A 2 mm sheet of index-matched, black walls against a uniform sky: the
/// only light that reaches the camera crosses the sheet in a straight line
/// through the air, pore to pore. Its share must be the share of straight
/// lines through the sheet that stay in the air, marched independently
/// on the cell geometry.
#[test]
fn light_crosses_a_thin_cellular_sheet_through_its_open_pores() {
    let mut sample = cellular_preset("sponge");
    sample.surface.eta = 1.0;
    sample.surface.roughness = 0.0;
    sample.volume.material =
        MaterialDesc::Coefficients(Coefficients::from_albedo([0.0; 3], [20.0; 3]));
    sample.volume.inclusions[0].interface_eta = Some(1.0);
    let half = 1.0;
    let scene = ObjectScene {
        mesh: box_mesh(Vec3::new(-30.0, -30.0, -half), Vec3::new(30.0, 30.0, half)),
        sample: sample.clone(),
        camera: PinholeCamera {
            eye: Vec3::new(0.0, 0.0, 400.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fov_y: 0.03, // 12 mm across at the sheet
        },
        lights: vec![],
        env: Some(uniform_env(1.0)),
        env_visible: false,
    };
    let opts = RenderOptions {
        width: 16,
        height: 16,
        spp: 24,
        seed: 2,
        ..RenderOptions::default()
    };
    let img = render_object(&scene, &opts, &|_| {}, None).unwrap();
    let through = img.mean()[1];
    // the march: lines parallel to z over the same 12 mm square
    let cells = Volume::build(&sample).cells.unwrap();
    let mut rng = crate::rng::Rng::new(9, 9);
    let n = 6000;
    let clear = (0..n)
        .filter(|_| {
            let (x, y) = (rng.uniform() * 12.0 - 6.0, rng.uniform() * 12.0 - 6.0);
            (0..=2000).all(|k| cells.inside(Vec3::new(x, y, half - k as f32 * 1e-3)))
        })
        .count() as f64
        / n as f64;
    let noise = (clear * (1.0 - clear) / n as f64).sqrt() + img.mean_rel_error()[1] * through;
    assert!(clear > 0.02, "some lines cross: {clear}");
    assert!(
        (through - clear).abs() < 3.0 * noise + 0.003,
        "rendered {through}, marched {clear} (+- {noise})"
    );
}

#[test]
fn delta_lights_on_smooth_cell_walls_are_refused() {
    let mut sample = cellular_preset("bread");
    sample.volume.inclusions[0].wall_roughness = 0.0;
    let scene = ObjectScene {
        mesh: sphere_mesh(2.0, 12, 6),
        sample,
        camera: PinholeCamera {
            eye: Vec3::new(0.0, -12.0, 0.0),
            target: Vec3::ZERO,
            up: Vec3::Z,
            fov_y: 0.3,
        },
        lights: vec![DeltaLight::Point {
            position: Vec3::new(0.0, -10.0, 10.0),
            intensity: Vec3::ONE,
        }],
        env: None,
        env_visible: false,
    };
    let opts = RenderOptions {
        width: 2,
        height: 2,
        spp: 2,
        ..RenderOptions::default()
    };
    let e = render_object(&scene, &opts, &|_| {}, None).unwrap_err();
    assert!(e.to_string().contains("rough"), "{e}");
}
