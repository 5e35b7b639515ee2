//! qhm's homogeneous renders against exact light transport: a 20 mm
//! radius sphere of the skin1, apple, marble and ketchup presets, lit from the front, the
//! side and behind by a small sun (8° disk) and by an environment map,
//! against Mitsuba 3's volumetric path tracer on the presets' exported
//! medium in its dielectric boundary (`volpathmis`, scalar_rgb; 6 to 16
//! seeds of 1,024 spp for skin1 and apple lit by the sun and ketchup lit
//! from the front and behind, 2 x 512 spp for the others: the JSON's `reference` says
//! which, and `mean_relative_se` how uncertain its mean is). The
//! references are cached, reduced to what the comparison needs,
//! in tests/data/render_reference/CASE.json (made by
//! `mitsuba_reference.py` and the reduction described in docs/render.md;
//! the boundary's mirror reflection of the lights is taken out of them, as
//! a homogeneous preset has no LRF to render it): the pixels compared, and
//! of them the mean, the terminator band's (|n·l| < 0.25) mean and the
//! 8 x 8-pixel block means with the Monte Carlo noise of each. A 4 mm
//! apple slab lit from behind and from above is compared the same way with
//! sim-light's `qhm sim render-object` (slab-apple-back.json,
//! slab-apple-front.json, slab/), a 2 mm apple fin (slab2-apple-*.json),
//! and the closed built-in teapot of
//! apple lit from the front and from behind (teapot-apple-front.json,
//! teapot-apple-back.json, 2 x 256 spp), where the handle and spout get
//! light back from the body.
//!
//! The tolerances are what qhm reaches now (docs/render.md's table), with
//! a margin for the CI-scale render (12,000 surface samples); each case
//! also renders the global term as it was before the boundary's entry and
//! exit shapes, the geometry factor and the irradiance interpolation, and
//! checks that it fails them.

use std::path::PathBuf;

use qhm_model::{DipoleParams, MaterialModel, ProfileModel};
use qhm_render::Material;
use qhm_render::materials::preset;
use qhm_render::{Image, Mesh, RenderSettings, Scene, SceneFile, render_scene};

struct Case {
    name: String,
    toml: String,
    material: String,
    /// A mesh file under tests/data/render_reference, or `builtin:NAME`;
    /// None = the built-in sphere.
    mesh: Option<String>,
    pixels: Vec<Vec<u8>>,
    mean: [f64; 3],
    /// The reference mean's relative standard error over its seeds, where
    /// it was made from more than two.
    mean_se: Option<[f64; 3]>,
    terminator: Option<[f64; 3]>,
    /// (x0, y0, mean, noise of the mean)
    blocks: Vec<(u32, u32, [f64; 3], [f64; 3])>,
}

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/render_reference")
}

fn load(case: &str) -> Case {
    let path = data_dir().join(format!("{case}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rgb =
        |x: &serde_json::Value| -> [f64; 3] { std::array::from_fn(|c| x[c].as_f64().unwrap()) };
    let toml = v["scene_toml"].as_str().unwrap().replace(
        "\"env.exr\"",
        &format!("{:?}", data_dir().join("env.exr").display().to_string()),
    );
    Case {
        name: case.into(),
        toml,
        material: v["material"].as_str().unwrap().into(),
        mesh: v["mesh"].as_str().map(String::from),
        pixels: v["pixels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_str().unwrap().bytes().collect())
            .collect(),
        mean: rgb(&v["mean"]),
        mean_se: v["mean_relative_se"]
            .as_array()
            .map(|_| rgb(&v["mean_relative_se"])),
        terminator: v["terminator"].as_array().map(|_| rgb(&v["terminator"])),
        blocks: v["blocks"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| {
                let f = |k: usize| b[k].as_f64().unwrap();
                (
                    f(0) as u32,
                    f(1) as u32,
                    [f(2), f(3), f(4)],
                    [f(5), f(6), f(7)],
                )
            })
            .collect(),
    }
}

/// The global term as it was: f_v = 1 (Lambertian exit), f = the Fresnel
/// ratio alone, planar R_d, plain sum over the samples.
struct Before(MaterialModel);

impl Material for Before {
    fn dipole(&self) -> DipoleParams {
        self.0.dipole
    }
    fn entrance(&self, wi: [f32; 3]) -> [f32; 3] {
        self.0.entrance(wi)
    }
    fn exiting(&self, uv: [f32; 2], wo: [f32; 3]) -> [f32; 3] {
        self.0.exiting(uv, wo)
    }
    fn lrf(&self, _uv: [f32; 2], _wi: [f32; 3], _wo: [f32; 3]) -> [f32; 3] {
        [0.0; 3]
    }
    fn texture_size(&self) -> (u32, u32) {
        (1, 1)
    }
    fn texel_mm(&self) -> f32 {
        1.0
    }
    fn has_lrf(&self) -> bool {
        false
    }
}

fn render<M: Material>(case: &Case, material: &M, before: bool) -> Image {
    render_with(case, material, |s| {
        if before {
            s.near_field = 0.0;
            s.geometry = false;
        }
    })
}

fn render_with<M: Material>(
    case: &Case,
    material: &M,
    change: impl FnOnce(&mut RenderSettings),
) -> Image {
    let file = SceneFile::parse(&case.toml, None).unwrap();
    let mut scene = match case.mesh.as_deref() {
        Some(m) => match m.strip_prefix("builtin:") {
            Some(name) => file.builtin_scene(name).unwrap(),
            None => Scene::lit(Mesh::load(&data_dir().join(m), 1.0, None).unwrap()),
        },
        None => file.builtin_scene("sphere").unwrap(),
    };
    file.apply_scene(&mut scene).unwrap();
    let mut settings = RenderSettings::default();
    file.apply_settings(&mut settings).unwrap();
    change(&mut settings);
    render_scene(&scene, material, &settings).unwrap()
}

struct Metrics {
    mean: [f64; 3],
    terminator: Option<[f64; 3]>,
    block_rmse: [f64; 3],
}

fn metrics(case: &Case, img: &Image) -> Metrics {
    let px = |x: usize, y: usize| img.get(x as u32, y as u32).as_dvec3().to_array();
    let (mut sum, mut n, mut tsum, mut tn) = ([0.0; 3], 0.0, [0.0; 3], 0.0);
    for (y, row) in case.pixels.iter().enumerate() {
        for (x, &c) in row.iter().enumerate() {
            if c == b'.' {
                continue;
            }
            let p = px(x, y);
            for k in 0..3 {
                sum[k] += p[k];
                if c == b't' {
                    tsum[k] += p[k];
                }
            }
            n += 1.0;
            if c == b't' {
                tn += 1.0;
            }
        }
    }
    let mean: [f64; 3] = std::array::from_fn(|k| sum[k] / n / case.mean[k]);
    let terminator = case
        .terminator
        .map(|t| std::array::from_fn(|k| tsum[k] / tn / t[k]));
    let (mut err, mut noise, mut norm) = ([0.0; 3], [0.0; 3], [0.0; 3]);
    for &(x0, y0, r, nz) in &case.blocks {
        let q = img.mean(x0, y0, x0 + 8, y0 + 8).as_dvec3().to_array();
        for k in 0..3 {
            err[k] += (q[k] - r[k]).powi(2);
            noise[k] += nz[k].powi(2);
            norm[k] += r[k].powi(2);
        }
    }
    let block_rmse = std::array::from_fn(|k| ((err[k] - noise[k]).max(0.0) / norm[k]).sqrt());
    Metrics {
        mean,
        terminator,
        block_rmse,
    }
}

/// Over `channels`: mean within `mean`, terminator within `term`, 8 x 8 blocks
/// within `blocks` (relative RMSE, reference noise removed).
fn within(
    m: &Metrics,
    channels: &[usize],
    mean: f64,
    term: f64,
    blocks: f64,
) -> Result<(), String> {
    let off = |r: f64| (r - 1.0).abs();
    for &k in channels {
        if off(m.mean[k]) > mean {
            return Err(format!("mean ratio {:?} off by more than {mean}", m.mean));
        }
        if let Some(t) = m.terminator
            && off(t[k]) > term
        {
            return Err(format!("terminator ratio {t:?} off by more than {term}"));
        }
        if m.block_rmse[k] > blocks {
            return Err(format!("block RMSE {:?} above {blocks}", m.block_rmse));
        }
    }
    Ok(())
}

fn check(case: &str, channels: &[usize], mean: f64, term: f64, blocks: f64) {
    let c = load(case);
    let model = MaterialModel::homogeneous(preset(&c.material).unwrap());
    let now = metrics(&c, &render(&c, &model, false));
    eprintln!(
        "{}: mean {:.3?} terminator {:.3?} blocks {:.3?}",
        c.name, now.mean, now.terminator, now.block_rmse
    );
    within(&now, channels, mean, term, blocks).unwrap_or_else(|e| panic!("{}: {e}", c.name));
    let old = metrics(&c, &render(&c, &Before(model), true));
    eprintln!(
        "{} before: mean {:.3?} terminator {:.3?} blocks {:.3?}",
        c.name, old.mean, old.terminator, old.block_rmse
    );
    assert!(
        within(&old, channels, mean, term, blocks).is_err(),
        "{}: the old global term passes too",
        c.name
    );
}

#[test]
fn apple_sphere_front_lit_matches_the_path_tracer() {
    check("apple-front", &[0, 1, 2], 0.03, 0.05, 0.03);
}

#[test]
fn marble_sphere_front_lit_matches_the_path_tracer() {
    check("marble-front", &[0, 1, 2], 0.03, 0.1, 0.04);
    // The convex surface's gain over a plane (the geometry factor's
    // curvature gain) carries it: the images alone are 4.5 % dark.
    let c = load("marble-front");
    let model = MaterialModel::homogeneous(preset(&c.material).unwrap());
    let flat = metrics(&c, &render_with(&c, &model, |s| s.curvature = false));
    eprintln!("marble-front, curvature = false: mean {:.3?}", flat.mean);
    assert!(within(&flat, &[0, 1, 2], 0.03, 0.1, 0.04).is_err());
}

#[test]
fn apple_sphere_back_lit_matches_the_path_tracer() {
    // Blue is left out: apple absorbs it (s_a 0.046 / mm), and qhm gives
    // 0.80 of the reference there (whose mean is uncertain by 6 %).
    check("apple-back", &[0, 1], 0.04, 0.06, 0.13);
}

#[test]
fn skin1_sphere_back_lit_matches_the_path_tracer() {
    // Blocks are not compared: qhm's red is 20 % dark, most of it where
    // the light has crossed the sphere (docs/render.md).
    check("skin1-back", &[0, 1, 2], 0.22, 0.2, f64::INFINITY);
}

#[test]
fn apple_thin_slab_back_lit_matches_sim_light() {
    // A 4 mm slab lit from below, against `qhm sim render-object` of the
    // same mesh (tools/cache_sim.py): the light through a thin part.
    check("slab-apple-back", &[0, 1, 2], 0.05, 0.0, 0.2);
}

#[test]
fn apple_thin_slab_front_lit_matches_sim_light() {
    // The same slab lit from above: light that a half-space would send
    // back leaves through the far face (the slab's multipole images).
    check("slab-apple-front", &[0, 1, 2], 0.03, 0.0, 0.06);
}

#[test]
fn apple_fin_matches_sim_light() {
    // A 2 mm slab (slab/slab2.obj), lit from above and from below. Blue
    // through it is left out: 15 % bright (docs/render.md).
    check("slab2-apple-front", &[0, 1, 2], 0.02, 0.0, 0.04);
    check("slab2-apple-back", &[0, 1], 0.05, 0.0, 0.1);
}

/// The closed teapot against `qhm sim render-object` of the same mesh:
/// its handle and spout face the body and get light back from it, which
/// the render must carry (`indirect_rays`); without it the case fails.
fn check_teapot(case: &str, mean: f64, blocks: f64) {
    let c = load(case);
    let model = MaterialModel::homogeneous(preset(&c.material).unwrap());
    let now = metrics(&c, &render_with(&c, &model, |_| {}));
    eprintln!(
        "{case}: mean {:.3?} blocks {:.3?}",
        now.mean, now.block_rmse
    );
    within(&now, &[0, 1, 2], mean, 0.0, blocks).unwrap_or_else(|e| panic!("{case}: {e}"));
    let alone = metrics(&c, &render_with(&c, &model, |s| s.indirect_rays = 0));
    eprintln!(
        "{case} without light between parts: mean {:.3?} blocks {:.3?}",
        alone.mean, alone.block_rmse
    );
    assert!(
        within(&alone, &[0, 1, 2], mean, 0.0, blocks).is_err(),
        "{case}: passes without the light between parts too"
    );
}

#[test]
fn apple_teapot_front_lit_matches_sim_light() {
    check_teapot("teapot-apple-front", 0.03, 0.04);
}

#[test]
fn apple_teapot_back_lit_matches_sim_light() {
    check_teapot("teapot-apple-back", 0.06, 0.08);
}

/// A preset that renders with radiative transfer's R_d passes the bounds,
/// and the same medium with the paper's dipole fails them.
fn check_radiative_transfer(case: &str, channels: &[usize], mean: f64, term: f64, blocks: f64) {
    let c = load(case);
    let params = preset(&c.material).unwrap();
    assert_eq!(params.model, ProfileModel::Transport);
    let now = metrics(&c, &render(&c, &MaterialModel::homogeneous(params), false));
    eprintln!(
        "{case}: mean {:.3?} terminator {:.3?} blocks {:.3?}",
        now.mean, now.terminator, now.block_rmse
    );
    within(&now, channels, mean, term, blocks).unwrap_or_else(|e| panic!("{case}: {e}"));
    let dipole = DipoleParams {
        model: ProfileModel::Dipole,
        ..params
    };
    let old = metrics(&c, &render(&c, &MaterialModel::homogeneous(dipole), false));
    eprintln!(
        "{case}, dipole: mean {:.3?} terminator {:.3?} blocks {:.3?}",
        old.mean, old.terminator, old.block_rmse
    );
    assert!(
        within(&old, channels, mean, term, blocks).is_err(),
        "{case}: the dipole passes too"
    );
}

/// skin1 (a' 0.96, 0.84, 0.68) lit from the front: the dipole is bright by
/// 6-12 % in green and blue at these albedos.
#[test]
fn skin1_sphere_front_lit_needs_radiative_transfer() {
    check_radiative_transfer("skin1-front", &[0, 1, 2], 0.03, 0.05, 0.03);
}

/// ketchup's red (a' 0.75, s'_t 0.24 mm^-1) lit from the front and from
/// behind: the dipole's image lies 18 mm above the entry on a 20 mm sphere,
/// 21 % bright front-lit. Green and blue (a' 0.07, 0.02) are left out: the
/// reference's blocks there are noise at the 70-200 % level, and its mean
/// lit from behind is uncertain by half.
#[test]
fn ketchup_red_needs_radiative_transfer() {
    check_radiative_transfer("ketchup-front", &[0], 0.03, f64::INFINITY, 0.05);
    check_radiative_transfer("ketchup-back", &[0], 0.03, f64::INFINITY, 0.25);
}

#[test]
fn skin1_sphere_side_lit_matches_the_path_tracer() {
    check("skin1-side", &[0, 1, 2], 0.04, 0.07, 0.06);
}

/// Every cached case at `qhm render`'s default quality (30,000 surface
/// samples), with the bounds docs/render.md's table supports; prints the
/// metrics. `cargo test --release -p tests --test render_vs_reference -- --ignored --nocapture`
#[test]
#[ignore]
fn every_cached_case_at_default_quality() {
    let cases: [(&str, &[usize], f64, f64, f64); 9] = [
        ("skin1-front", &[0, 1, 2], 0.03, 0.05, 0.03),
        ("skin1-side", &[0, 1, 2], 0.04, 0.05, 0.06),
        ("skin1-back", &[0, 1, 2], 0.22, 0.2, f64::INFINITY),
        ("skin1-env", &[0, 1, 2], 0.04, 1.0, 0.04),
        ("apple-front", &[0, 1, 2], 0.03, 0.05, 0.03),
        ("apple-back", &[0, 1], 0.03, 0.05, 0.13),
        ("marble-front", &[0, 1, 2], 0.03, 0.1, 0.03),
        ("ketchup-front", &[0], 0.03, f64::INFINITY, 0.05),
        ("ketchup-back", &[0], 0.03, f64::INFINITY, 0.25),
    ];
    let mut failed = Vec::new();
    for (case, channels, mean, term, blocks) in cases {
        let mut c = load(case);
        c.toml = c
            .toml
            .replace("surface_samples = 12000", "surface_samples = 30000");
        let model = MaterialModel::homogeneous(preset(&c.material).unwrap());
        let m = metrics(&c, &render(&c, &model, false));
        eprintln!(
            "{case}: mean {:.3?} (reference's relative s.e. {:.3?}) terminator {:.3?} blocks {:.3?}",
            m.mean, c.mean_se, m.terminator, m.block_rmse
        );
        if let Err(e) = within(&m, channels, mean, term, blocks) {
            failed.push(format!("{case}: {e}"));
        }
    }
    assert!(failed.is_empty(), "{}", failed.join("; "));
}
