//! sim-light's object ground truth against Mitsuba 3's volumetric path
//! tracer (`volpathmis`): a homogeneous sphere and a 4 mm slab, lit from
//! the front and from behind by an environment lobe, compared on the mean
//! radiance (within 2 % per channel) and on 8 x 8-pixel blocks (RMSE
//! within the two renderers' combined noise). Skips with a message when
//! Mitsuba is not installed (fails instead with QHM_REQUIRE_MITSUBA=1);
//! `--ignored` runs the large version.

use std::io::Write;
use std::path::Path;
use std::process::Command;

use glam::Vec3;
use qhm_render::{EnvMap, Image, Mesh};
use sim_light::object::{
    EnvImage, ObjectImage, ObjectMesh, ObjectScene, PinholeCamera, RenderOptions, render_object,
};
use sim_light::{SampleDesc, SceneDesc};

fn mitsuba_available() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import mitsuba, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        if std::env::var("QHM_REQUIRE_MITSUBA").as_deref() == Ok("1") {
            panic!(
                "QHM_REQUIRE_MITSUBA=1 but python3 cannot import mitsuba and numpy (pip install mitsuba==3.9.1 numpy)"
            );
        }
        eprintln!(
            "SKIPPED: python3 cannot import mitsuba and numpy (pip install mitsuba==3.9.1 numpy)"
        );
    }
    ok
}

/// An environment lobe towards `dir`: 0.02 + 3 max(0, w . dir)^4, tinted.
fn lobe_env(dir: Vec3, w: usize, h: usize) -> Vec<Vec3> {
    let dir = dir.normalize();
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let d = qhm_render::light::dir_from_uv(
                (x as f32 + 0.5) / w as f32,
                (y as f32 + 0.5) / h as f32,
            );
            let c = d.dot(dir).max(0.0).powi(4);
            Vec3::new(0.02, 0.02, 0.025) + Vec3::new(3.0, 2.8, 2.5) * c
        })
        .collect()
}

fn write_ply(path: &Path, m: &Mesh) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    write!(
        f,
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.positions.len(),
        m.triangles.len()
    )
    .unwrap();
    for (p, n) in m.positions.iter().zip(&m.normals) {
        writeln!(f, "{} {} {} {} {} {}", p.x, p.y, p.z, n.x, n.y, n.z).unwrap();
    }
    for t in &m.triangles {
        writeln!(f, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
    }
}

struct Case {
    name: &'static str,
    mesh: Mesh,
    eye: Vec3,
    target: Vec3,
    fov_y_deg: f32,
    light: Vec3,
}

struct Sizes {
    width: u32,
    spp_sim: u32,
    spp_mitsuba: u32,
    runs: u32,
}

fn sample(name: &str) -> SampleDesc {
    match SceneDesc::preset(name).unwrap() {
        SceneDesc::Sample(s) => s,
        _ => unreachable!(),
    }
}

/// Per-channel (mean ratio - 1, its noise) and (block RMSE / combined
/// block noise, relative block noise).
struct Agreement {
    mean_err: [f64; 3],
    mean_noise: [f64; 3],
    block_ratio: f64,
    block_rel_noise: f64,
}

fn compare(sim: &ObjectImage, mit: &[Vec3], mit_var: &[Vec3]) -> Agreement {
    let (w, h) = (sim.width as usize, sim.height as usize);
    let n = (w * h) as f64;
    let mut mean_err = [0.0; 3];
    let mut mean_noise = [0.0; 3];
    for c in 0..3 {
        let ms: f64 = sim.radiance.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let mm: f64 = mit.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let vs: f64 = sim.variance.iter().map(|p| p[c] as f64).sum::<f64>() / (n * n);
        let vm: f64 = mit_var.iter().map(|p| p[c] as f64).sum::<f64>() / (n * n);
        mean_err[c] = ms / mm - 1.0;
        mean_noise[c] = (vs + vm).sqrt() / mm;
    }
    // 8 x 8 blocks, all channels; blocks of the background (no signal) skipped
    let (mut d2, mut v2, mut s2, mut blocks) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for by in 0..h / 8 {
        for bx in 0..w / 8 {
            for c in 0..3 {
                let (mut a, mut b, mut va, mut vb) = (0.0f64, 0.0, 0.0, 0.0);
                for y in by * 8..by * 8 + 8 {
                    for x in bx * 8..bx * 8 + 8 {
                        let i = y * w + x;
                        a += sim.radiance[i][c] as f64;
                        va += sim.variance[i][c] as f64;
                        b += mit[i][c] as f64;
                        vb += mit_var[i][c] as f64;
                    }
                }
                if b <= 0.0 {
                    continue;
                }
                let k = 64.0;
                d2 += (a / k - b / k).powi(2);
                v2 += (va + vb) / (k * k);
                s2 += (b / k).powi(2);
                blocks += 1;
            }
        }
    }
    assert!(blocks > 0);
    Agreement {
        mean_err,
        mean_noise,
        block_ratio: (d2 / v2).sqrt(),
        block_rel_noise: (v2 / s2).sqrt(),
    }
}

/// Renders `case` with sim-light (sample `desc`, sigma_t scaled by
/// `sim_st_scale`) and with Mitsuba (the preset's coefficients).
fn run_case(
    dir: &Path,
    case: &Case,
    desc: &SampleDesc,
    sim_st_scale: f64,
    sizes: &Sizes,
    mitsuba: Option<&(Vec<Vec3>, Vec<Vec3>, f64)>,
) -> (ObjectImage, (Vec<Vec3>, Vec<Vec3>, f64)) {
    let (ew, eh) = (512, 256);
    let texels = lobe_env(case.light, ew, eh);
    let env_path = dir.join(format!("{}-env.exr", case.name));
    let mesh_path = dir.join(format!("{}.ply", case.name));
    let mut img = Image::new(ew as u32, eh as u32);
    img.pixels = texels.iter().map(|t| t.to_array()).collect();
    img.write_exr(&env_path).unwrap();
    write_ply(&mesh_path, &case.mesh);
    let coeffs = sim_light::sample::resolve(&desc.volume.material);
    let mut sim_desc = desc.clone();
    let scaled = sim_light::Coefficients {
        sigma_s: coeffs.sigma_s.map(|v| v * sim_st_scale),
        sigma_a: coeffs.sigma_a.map(|v| v * sim_st_scale),
    };
    sim_desc.volume.material = sim_light::MaterialDesc::Coefficients(scaled);
    let scene = ObjectScene {
        mesh: ObjectMesh {
            positions: case.mesh.positions.clone(),
            normals: case.mesh.normals.clone(),
            triangles: case.mesh.triangles.clone(),
        },
        sample: sim_desc,
        camera: PinholeCamera {
            eye: case.eye,
            target: case.target,
            up: Vec3::Z,
            fov_y: case.fov_y_deg.to_radians(),
        },
        lights: vec![],
        env: Some(EnvImage {
            width: ew,
            height: eh,
            texels,
            rotation: 0.0,
        }),
        env_visible: false,
    };
    let opts = RenderOptions {
        width: sizes.width,
        height: sizes.width,
        spp: sizes.spp_sim,
        seed: 7,
        ..RenderOptions::default()
    };
    let sim = render_object(&scene, &opts, &|_| {}, None).unwrap();
    if let Some(m) = mitsuba {
        return (sim, m.clone());
    }
    let out = dir.join(format!("{}-mitsuba", case.name));
    let json = serde_json::json!({
        "mesh": mesh_path,
        "camera": {"eye": case.eye.to_array(), "target": case.target.to_array(), "up": [0, 0, 1], "fov_y_deg": case.fov_y_deg},
        "width": sizes.width, "height": sizes.width,
        "spp": sizes.spp_mitsuba, "runs": sizes.runs, "seed": 1,
        "env": {"file": env_path},
        "env_visible": false,
        "sigma_t": coeffs.sigma_t(), "albedo": coeffs.albedo(), "eta": desc.surface.eta,
        "variant": "scalar_rgb",
        "out": out,
    });
    let case_path = dir.join(format!("{}.json", case.name));
    std::fs::write(&case_path, json.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("interop/object_mitsuba.py");
    let o = Command::new("python3")
        .arg(&script)
        .arg(&case_path)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "mitsuba failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let load = |p: &Path| EnvMap::load(p, 0.0, 1.0).unwrap().texels;
    let mean = load(&out.with_extension("exr"));
    let var = load(&dir.join(format!("{}-mitsuba.var.exr", case.name)));
    let secs: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.with_extension("json")).unwrap())
            .unwrap();
    (sim, (mean, var, secs["seconds"].as_f64().unwrap()))
}

fn cases(radius: f32) -> Vec<Case> {
    let sphere = qhm_render::builtin::sphere(radius, 96, 48).unwrap();
    let slab = qhm_render::builtin::box_mesh(
        Vec3::new(-2.5 * radius, -2.0, 0.0),
        Vec3::new(2.5 * radius, 2.0, 5.0 * radius),
    )
    .unwrap();
    let c = Vec3::new(0.0, 0.0, radius);
    let eye = c + Vec3::new(0.0, -8.0 * radius, 0.0);
    let front = Vec3::new(0.4, -1.0, 0.5);
    let back = Vec3::new(-0.3, 1.0, 0.2);
    vec![
        Case {
            name: "sphere-front",
            mesh: sphere.clone(),
            eye,
            target: c,
            fov_y_deg: 16.0,
            light: front,
        },
        Case {
            name: "sphere-back",
            mesh: sphere,
            eye,
            target: c,
            fov_y_deg: 16.0,
            light: back,
        },
        Case {
            name: "slab-front",
            mesh: slab.clone(),
            eye,
            target: c,
            fov_y_deg: 36.0,
            light: front,
        },
        Case {
            name: "slab-back",
            mesh: slab,
            eye,
            target: c,
            fov_y_deg: 36.0,
            light: back,
        },
    ]
}

/// `strict`: means within 2 % with their noise below 0.6 %; otherwise (CI
/// scale, where the back-lit slab's blue channel is a rare-event estimate
/// with a heavy tail) within 2 % plus twice the noise, noise below 1.5 %.
fn check_all(preset: &str, radius: f32, sizes: Sizes, strict: bool) {
    if !mitsuba_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let desc = sample(preset);
    // QHM_OBJECT_CASES=sphere-front,slab-back picks cases (exploration)
    let only = std::env::var("QHM_OBJECT_CASES").ok();
    let scale: u32 = std::env::var("QHM_OBJECT_SPP_SCALE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let sizes = Sizes {
        spp_sim: sizes.spp_sim * scale,
        spp_mitsuba: sizes.spp_mitsuba * scale,
        ..sizes
    };
    for case in cases(radius) {
        if only
            .as_ref()
            .is_some_and(|o| !o.split(',').any(|c| c == case.name))
        {
            continue;
        }
        let (sim, mit) = run_case(dir.path(), &case, &desc, 1.0, &sizes, None);
        let a = compare(&sim, &mit.0, &mit.1);
        eprintln!(
            "{preset} {}: mean {:+.2} {:+.2} {:+.2} % (noise {:.2} {:.2} {:.2} %), block RMSE / noise {:.2} (block noise {:.1} %); sim {:.1} s, mitsuba {:.1} s",
            case.name,
            100.0 * a.mean_err[0],
            100.0 * a.mean_err[1],
            100.0 * a.mean_err[2],
            100.0 * a.mean_noise[0],
            100.0 * a.mean_noise[1],
            100.0 * a.mean_noise[2],
            a.block_ratio,
            100.0 * a.block_rel_noise,
            sim.secs,
            mit.2
        );
        for c in 0..3 {
            let (tol, max_noise) = if strict {
                (0.02, 0.006)
            } else {
                (0.02 + 2.0 * a.mean_noise[c], 0.015)
            };
            assert!(
                a.mean_err[c].abs() < tol,
                "{}: channel {c} mean off by {:.2} %",
                case.name,
                100.0 * a.mean_err[c]
            );
            assert!(
                a.mean_noise[c] < max_noise,
                "{}: mean noise {:.2} % too high to judge",
                case.name,
                100.0 * a.mean_noise[c]
            );
        }
        assert!(
            a.block_ratio < 1.5,
            "{}: block RMSE {:.2} x the combined noise",
            case.name,
            a.block_ratio
        );
        // the comparison sees a wrong medium: sigma_t 10 % high
        if case.name == "sphere-front" || case.name == "slab-back" {
            let (bad, _) = run_case(dir.path(), &case, &desc, 1.1, &sizes, Some(&mit));
            let b = compare(&bad, &mit.0, &mit.1);
            let fails = b.block_ratio >= 1.5 || b.mean_err.iter().any(|e| e.abs() >= 0.02);
            eprintln!(
                "{preset} {} with sigma_t x 1.1: mean {:+.2} {:+.2} {:+.2} %, block RMSE / noise {:.2}",
                case.name,
                100.0 * b.mean_err[0],
                100.0 * b.mean_err[1],
                100.0 * b.mean_err[2],
                b.block_ratio
            );
            assert!(fails, "{}: sigma_t x 1.1 passed the comparison", case.name);
        }
    }
}

#[test]
fn homogeneous_sphere_and_thin_slab_agree_with_mitsuba() {
    let sizes = Sizes {
        width: 32,
        spp_sim: 512,
        spp_mitsuba: 512,
        runs: 4,
    };
    check_all("skin1", 2.0, sizes, false);
}

/// QHM_OBJECT_PRESETS=skin1,ketchup picks the presets.
#[test]
#[ignore = "minutes: the large Mitsuba cross-check"]
fn homogeneous_objects_agree_with_mitsuba_large() {
    let presets =
        std::env::var("QHM_OBJECT_PRESETS").unwrap_or_else(|_| "skin1,marble,apple,ketchup".into());
    for preset in presets.split(',') {
        let sizes = Sizes {
            width: 64,
            spp_sim: 1024,
            spp_mitsuba: 512,
            runs: 8,
        };
        check_all(preset, 2.0, sizes, true);
    }
}
