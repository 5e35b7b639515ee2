//! The bad-input sweep: some 470 bad inputs across every `qhm` command (bad
//! CLI values, unknown names, missing files, directories where files are
//! expected, empty, truncated and garbage TOML, CSV, OBJ, PLY, EXR, model
//! manifests, capture.toml, journals, calibration and sample files). Each
//! must end with a non-zero exit, exactly one `qhm: ...` line on stderr (no
//! panic, no backtrace, no multi-line dump) within the time limit, and
//! leave every file that was there before exactly as it was.
//!
//! Every case runs in its own copy of the fixture tree, so cases run in
//! parallel and a changed file is pinned on the case that changed it.
//! `cargo test -p host --test bad_inputs` runs it; `QHM_SWEEP_SHOW=1` also
//! prints every message.

mod cli_util;

use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use cli_util::{copy_tree, fingerprint, one_qhm_line, qhm, words};

/// Longest a case may take: every one is refused before any real work.
const LIMIT: Duration = Duration::from_secs(30);

/// A tiny render, so a case that is wrongly accepted ends quickly.
const TINY: &str = "--width 8 --height 8 --spp 1 --samples 100 --quiet";

/// Writes the fixture tree: files of every kind, broken in every way.
fn fixtures(root: &Path) {
    let w = |rel: &str, bytes: &[u8]| {
        let p = root.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    };
    let d = |rel: &str| std::fs::create_dir_all(root.join(rel)).unwrap();
    let garbage: Vec<u8> = (0..4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();

    // Something precious the sweep must never touch.
    w("keep/notes.txt", b"precious\n");
    w("keep/image.png", &garbage[..100]);

    for ext in ["csv", "toml", "obj", "ply", "exr", "json", "elf"] {
        w(&format!("empty.{ext}"), b"");
        w(&format!("garbage.{ext}"), &garbage);
        d(&format!("dir.{ext}"));
    }
    d("emptydir");
    w("foreign/precious.txt", b"not a qhm directory\n");

    // Profiles.
    let mut good = String::from("distance_mm,intensity_per_mm\n");
    let mut huge = good.clone();
    let mut zeros = good.clone();
    for k in 0..60 {
        let d = k as f64 * 0.2;
        good += &format!("{d},{}\n", 0.2 * (-1.2 * d).exp() / (d + 0.5));
        huge += &format!("{d},1e300\n");
        zeros += &format!("{d},0\n");
    }
    w("good.csv", good.as_bytes());
    w("huge.csv", huge.as_bytes());
    w("zeros.csv", zeros.as_bytes());
    w("negative.csv", zeros.replace(",0\n", ",-1\n").as_bytes());
    w("header_only.csv", b"distance_mm,intensity_per_mm\n");
    w("wrong_header.csv", b"d,i\n0,1\n1,2\n2,3\n");
    w(
        "two_rows.csv",
        b"distance_mm,intensity_per_mm\n0,1\n1,0.5\n",
    );
    w(
        "nan.csv",
        b"distance_mm,intensity_per_mm\n0,1\n1,NaN\n2,0.1\n",
    );
    w(
        "inf.csv",
        b"distance_mm,intensity_per_mm\n0,1\n1,inf\n2,0.1\n",
    );
    w(
        "word.csv",
        b"distance_mm,intensity_per_mm\n0,1\n1,abc\n2,0.1\n",
    );
    w("three_fields.csv", b"distance_mm,intensity_per_mm\n0,1,2\n");
    w(
        "one_point.csv",
        b"distance_mm,intensity_per_mm\n1,1\n1,1\n1,1\n1,1\n",
    );
    w(
        "binary.csv",
        b"distance_mm,intensity_per_mm\n\xff\xfe\x00,1\n",
    );

    // Meshes.
    w("no_faces.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    w("bad_index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
    w("nan.obj", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
    w("degenerate.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
    w("words.obj", b"v a b c\nf x y z\n");
    w(
        "nonmanifold.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 2 5\n",
    );
    w(
        "quad.obj",
        b"v 0 0 0\nv 10 0 0\nv 10 10 0\nv 0 10 0\nf 1 2 3 4\n",
    );
    w("mesh.stl", b"solid x\nendsolid x\n");
    let ply_head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    w("truncated.ply", ply_head.as_bytes());
    w(
        "bad_index.ply",
        format!("{ply_head}0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").as_bytes(),
    );
    w(
        "nan.ply",
        format!("{ply_head}0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n").as_bytes(),
    );
    w(
        "no_header_end.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\n",
    );
    w(
        "huge_count.ply",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 4000000000\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0",
    );
    w(
        "binary_short.ply",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0\0\0",
    );
    w(
        "bad_format.ply",
        b"ply\nformat utf9 2.0\nelement vertex 0\nend_header\n",
    );
    w("not_ply.ply", b"solid x\n");

    // Scenes.
    let scenes: &[(&str, &str)] = &[
        ("truncated", "[camera\neye = [1, 2"),
        ("unknown_table", "[camerra]\n"),
        ("unknown_key", "[camera]\nzoom = 2\n"),
        (
            "eye_is_target",
            "[camera]\neye = [0,0,0]\ntarget = [0,0,0]\n",
        ),
        ("fov_zero", "[camera]\nfov_deg = 0\n"),
        ("fov_huge", "[camera]\nfov_deg = 200\n"),
        ("fov_nan", "[camera]\nfov_deg = nan\n"),
        ("eye_nan", "[camera]\neye = [nan, 0, 0]\n"),
        ("eye_short", "[camera]\neye = [1, 2]\n"),
        ("eye_text", "[camera]\neye = \"here\"\n"),
        ("up_zero", "[camera]\nup = [0, 0, 0]\n"),
        ("light_spot", "[[lights]]\nkind = \"spot\"\n"),
        ("light_nodir", "[[lights]]\nkind = \"directional\"\n"),
        (
            "light_zero",
            "[[lights]]\nkind = \"directional\"\ndirection = [0, 0, 0]\n",
        ),
        (
            "light_negative",
            "[[lights]]\nkind = \"directional\"\ndirection = [0, 0, 1]\nirradiance = [-1, 0, 0]\n",
        ),
        ("light_nopos", "[[lights]]\nkind = \"point\"\n"),
        (
            "light_inf",
            "[[lights]]\nkind = \"point\"\nposition = [inf, 0, 0]\n",
        ),
        ("light_nokind", "[[lights]]\ndirection = [0, 0, 1]\n"),
        ("env_moon", "[env]\nbuiltin = \"moon\"\n"),
        ("env_missing", "[env]\nfile = \"missing.exr\"\n"),
        ("env_garbage", "[env]\nfile = \"garbage.exr\"\n"),
        ("env_empty", "[env]\nfile = \"empty.exr\"\n"),
        ("env_dir", "[env]\nfile = \"dir.exr\"\n"),
        ("env_both", "[env]\nbuiltin = \"sky\"\nfile = \"x.exr\"\n"),
        ("env_neither", "[env]\nscale = 1\n"),
        ("env_scale", "[env]\nbuiltin = \"sky\"\nscale = -1\n"),
        ("env_sun", "[env]\nbuiltin = \"sky\"\nsun = [0, 0, 0]\n"),
        ("scale_zero", "[object]\nscale = 0\n"),
        ("scale_negative", "[object]\nscale = -1\n"),
        ("scale_nan", "[object]\nscale = nan\n"),
        ("scale_huge", "[object]\nscale = 1e30\n"),
        ("scale_tiny", "[object]\nscale = 1e-30\n"),
        ("uv_zero", "[object]\nuv_scale_mm = 0\n"),
        ("render_mode", "[render]\nmode = \"bogus\"\n"),
        ("render_width", "[render]\nwidth = 0\n"),
        ("render_wide", "[render]\nwidth = 20000\n"),
        ("render_negative", "[render]\nwidth = -5\n"),
        ("render_text", "[render]\nwidth = \"wide\"\n"),
        ("render_spp", "[render]\nspp = 0\n"),
        ("render_spp_huge", "[render]\nspp = 5000\n"),
        ("render_samples", "[render]\nsurface_samples = 0\n"),
        ("render_epsilon", "[render]\nepsilon = -1\n"),
        ("render_radius", "[render]\nlocal_radius_mm = nan\n"),
        ("render_env_samples", "[render]\nenv_samples = 1000000\n"),
        ("render_seed", "[render]\nseed = -1\n"),
        ("render_unknown", "[render]\nresolution = 4\n"),
        ("lights_table", "[lights]\nkind = \"point\"\n"),
    ];
    for (name, text) in scenes {
        w(&format!("scenes/{name}.toml"), text.as_bytes());
    }
    // Env paths in a scene resolve against the scene's directory.
    for f in ["garbage.exr", "empty.exr"] {
        std::fs::copy(root.join(f), root.join("scenes").join(f)).unwrap();
    }
    d("scenes/dir.exr");

    // Material models: one good, then each broken one way.
    let good =
        qhm_model::MaterialModel::homogeneous(qhm_render::materials::preset("marble").unwrap());
    good.save(&root.join("model_ok")).unwrap();
    let manifest = std::fs::read_to_string(root.join("model_ok/manifest.toml")).unwrap();
    let exr = std::fs::read_dir(root.join("model_ok/fv"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .file_name()
        .to_string_lossy()
        .into_owned();
    let model = |name: &str, manifest_text: Option<&str>| {
        let dir = root.join(name);
        copy_tree(&root.join("model_ok"), &dir);
        match manifest_text {
            Some(t) => std::fs::write(dir.join("manifest.toml"), t).unwrap(),
            None => std::fs::remove_file(dir.join("manifest.toml")).unwrap(),
        }
    };
    let edit = |from: &str, to: &str| {
        assert!(
            manifest.contains(from),
            "manifest lacks {from:?}:\n{manifest}"
        );
        manifest.replacen(from, to, 1)
    };
    model("model_no_manifest", None);
    model("model_empty_manifest", Some(""));
    model(
        "model_garbage_manifest",
        Some(&String::from_utf8_lossy(&garbage)),
    );
    model("model_truncated", Some(&manifest[..manifest.len() / 2]));
    model("model_format", Some(&edit("qhm-material", "qhm-other")));
    model("model_v1", Some(&edit("version = 2", "version = 1")));
    model("model_v99", Some(&edit("version = 2", "version = 99")));
    model(
        "model_version_text",
        Some(&edit("version = 2", "version = \"two\"")),
    );
    model(
        "model_escape",
        Some(&edit(&format!("fv/{exr}"), "../../keep/notes.txt")),
    );
    model(
        "model_absent_exr",
        Some(&edit(&format!("fv/{exr}"), "fv/absent.exr")),
    );
    model("model_width", Some(&edit("width = 1", "width = 2")));
    model("model_width_zero", Some(&edit("width = 1", "width = 0")));
    model(
        "model_texel",
        Some(&edit("texel_mm = 1.0", "texel_mm = -1.0")),
    );
    model("model_eta", Some(&edit("eta = 1.5", "eta = nan")));
    model(
        "model_encoding",
        Some(&edit("encoding = \"raw\"", "encoding = \"zip\"")),
    );
    model("model_garbage_exr", Some(&manifest));
    std::fs::write(root.join("model_garbage_exr/fv").join(&exr), &garbage).unwrap();
    model("model_empty_exr", Some(&manifest));
    std::fs::write(root.join("model_empty_exr/fv").join(&exr), b"").unwrap();
    model("model_dir_exr", Some(&manifest));
    std::fs::remove_file(root.join("model_dir_exr/fv").join(&exr)).unwrap();
    d(&format!("model_dir_exr/fv/{exr}"));
    model("model_dir_manifest", None);
    d("model_dir_manifest/manifest.toml");
    for (key, bad) in [
        ("alpha_prime", "nan"),
        ("alpha_prime", "-1"),
        ("sigma_t_prime", "0"),
        ("sigma_t_prime", "inf"),
    ] {
        // The array, from its key to its closing bracket, becomes three bad values.
        let start = manifest
            .find(&format!("\n{key} = ["))
            .unwrap_or_else(|| panic!("manifest lacks {key}:\n{manifest}"))
            + 1;
        let end = start + manifest[start..].find(']').unwrap() + 1;
        let text = format!(
            "{}{key} = [{bad}, {bad}, {bad}]{}",
            &manifest[..start],
            &manifest[end..]
        );
        model(&format!("model_{key}_{bad}"), Some(&text));
    }

    // Capture directories: a started one (manifest and journal header), then
    // each broken one way.
    let plan =
        qhm_acquire::Plan::new(qhm_acquire::PlanConfig::for_scale(qhm_acquire::Scale::Ci)).unwrap();
    let m = qhm_acquire::Manifest::new("sim", "two-material", 1, &plan);
    drop(qhm_acquire::CaptureDir::create(&root.join("cap_ok"), m).unwrap());
    let cap = |name: &str, file: &str, bytes: Option<&[u8]>| {
        let dir = root.join(name);
        copy_tree(&root.join("cap_ok"), &dir);
        match bytes {
            Some(b) => std::fs::write(dir.join(file), b).unwrap(),
            None => std::fs::remove_file(dir.join(file)).unwrap(),
        }
    };
    let cap_manifest = std::fs::read_to_string(root.join("cap_ok/capture.toml")).unwrap();
    // A capture that never journaled a frame is replaced by a new run, so
    // the broken manifests sit beside a journal with more than its header.
    let journal = std::fs::read(root.join("cap_ok/journal")).unwrap();
    let kept_journal = [&journal[..], b"frame of a damaged line\n"].concat();
    let cap_kept = |name: &str, manifest: &[u8]| {
        cap(name, "capture.toml", Some(manifest));
        std::fs::write(root.join(name).join("journal"), &kept_journal).unwrap();
    };
    cap("cap_no_manifest", "capture.toml", None);
    cap_kept("cap_empty_manifest", b"");
    cap_kept("cap_garbage_manifest", &garbage);
    cap_kept(
        "cap_truncated_manifest",
        &cap_manifest.as_bytes()[..cap_manifest.len() / 2],
    );
    cap_kept(
        "cap_format",
        cap_manifest
            .replacen("qhm-capture", "qhm-other", 1)
            .as_bytes(),
    );
    cap_kept(
        "cap_version",
        cap_manifest
            .replacen("version = 1", "version = 7", 1)
            .as_bytes(),
    );
    cap("cap_garbage_journal", "journal", Some(&garbage));
    cap("cap_empty_journal", "journal", Some(b""));
    cap("cap_no_journal", "journal", None);
    cap(
        "cap_forged_journal",
        "journal",
        Some(b"qhm-journal 1 0000 ~0123456789abcdef\nframe 1 2 3 ~fedcba9876543210\n"),
    );
    // Rectified datasets that are not.
    for (name, bytes) in [
        ("rect_empty", &b""[..]),
        ("rect_garbage", &garbage[..]),
        (
            "rect_version",
            &b"format = \"qhm-rectified\"\nversion = 99\n"[..],
        ),
    ] {
        cap(name, "capture.toml", Some(cap_manifest.as_bytes()));
        w(&format!("{name}/rectified/index.toml"), bytes);
    }
    d("rect_dir/rectified/index.toml");
    w("calibration_garbage.toml", &garbage[..2000]);
    w(
        "calibration_wrong.toml",
        b"format = \"qhm-calibration\"\nversion = 99\n",
    );
    w("sample_truncated.toml", b"[sample\nkind = ");
    w("sample_unknown.toml", b"kind = \"quasar\"\n");
}

/// The table of cases: `(command line, text the error must contain)`.
fn cases() -> Vec<(String, &'static str)> {
    let mut c: Vec<(String, &'static str)> = Vec::new();
    let mut add = |args: String, needle: &'static str| c.push((args, needle));

    // Top level.
    for a in [
        "bogus",
        "--bogus",
        "render --bogus",
        "fit-profile good.csv --reflectance",
    ] {
        add(a.into(), "");
    }

    // fit-profile: files.
    for f in [
        "missing.csv",
        "dir.csv",
        "emptydir",
        "empty.csv",
        "garbage.csv",
        "header_only.csv",
        "wrong_header.csv",
        "two_rows.csv",
        "nan.csv",
        "inf.csv",
        "word.csv",
        "three_fields.csv",
        "binary.csv",
        "zeros.csv",
        "negative.csv",
        "one_point.csv",
        "huge.csv",
    ] {
        add(format!("fit-profile {f} --reflectance 0.5"), "");
        add(format!("fit-profile {f} --reflectance 0.5 --json"), "");
    }
    // fit-profile: values.
    for r in [
        "0", "-0.5", "nan", "inf", "-inf", "1", "0.999999", "0.983", "2", "abc", "''", "1e400",
    ] {
        add(format!("fit-profile good.csv --reflectance={r}"), "");
    }
    for e in ["0", "1", "3", "nan", "-1", "1e300", "abc"] {
        add(
            format!("fit-profile good.csv --reflectance 0.5 --eta={e}"),
            "",
        );
    }
    for r in [
        "''", "1", "a:b", "2:1", "-1:2", "nan:1", "1:inf", "100:200", "1:1", ":",
    ] {
        add(
            format!("fit-profile good.csv --reflectance 0.5 --range={r}"),
            "",
        );
    }
    for a in ["--norm bogus", "--model bogus", "--norm", "--json=yes"] {
        add(format!("fit-profile good.csv --reflectance 0.5 {a}"), "");
    }

    // render: models.
    let models = [
        "missing",
        "emptydir",
        "garbage.toml",
        "builtin:nope",
        "builtin:",
        "model_no_manifest",
        "model_empty_manifest",
        "model_garbage_manifest",
        "model_truncated",
        "model_format",
        "model_v1",
        "model_v99",
        "model_version_text",
        "model_escape",
        "model_absent_exr",
        "model_width",
        "model_width_zero",
        "model_texel",
        "model_eta",
        "model_encoding",
        "model_garbage_exr",
        "model_empty_exr",
        "model_dir_exr",
        "model_dir_manifest",
        "model_alpha_prime_nan",
        "model_alpha_prime_-1",
        "model_sigma_t_prime_0",
        "model_sigma_t_prime_inf",
    ];
    for m in models {
        add(
            format!("render --model {m} --builtin slab -o out.png {TINY}"),
            "",
        );
        add(format!("report {m} -o new_report"), "");
    }
    // render: meshes.
    for m in [
        "missing.obj",
        "missing.ply",
        "dir.obj",
        "dir.ply",
        "emptydir",
        "empty.obj",
        "empty.ply",
        "garbage.obj",
        "garbage.ply",
        "no_faces.obj",
        "bad_index.obj",
        "nan.obj",
        "degenerate.obj",
        "words.obj",
        "nonmanifold.obj",
        "mesh.stl",
        "truncated.ply",
        "bad_index.ply",
        "nan.ply",
        "no_header_end.ply",
        "huge_count.ply",
        "binary_short.ply",
        "bad_format.ply",
        "not_ply.ply",
    ] {
        add(
            format!("render --model builtin:marble --mesh {m} -o out.png {TINY}"),
            "",
        );
    }
    // render: scenes, with a built-in object and with a mesh file.
    let scene_names: Vec<String> = std::fs::read_dir(template_dir().join("scenes"))
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().to_string_lossy().into_owned();
            n.strip_suffix(".toml").map(str::to_string)
        })
        .collect();
    for s in &scene_names {
        add(
            format!(
                "render --model builtin:marble --builtin slab --scene scenes/{s}.toml -o out.png {TINY}"
            ),
            "",
        );
    }
    for s in [
        "scale_zero",
        "scale_negative",
        "scale_nan",
        "scale_huge",
        "scale_tiny",
        "uv_zero",
        "truncated",
        "eye_nan",
    ] {
        add(
            format!(
                "render --model builtin:marble --mesh quad.obj --scene scenes/{s}.toml -o out.png {TINY}"
            ),
            "",
        );
    }
    for s in ["missing.toml", "dir.toml", "garbage.toml", "emptydir"] {
        add(
            format!("render --model builtin:marble --builtin slab --scene {s} -o out.png {TINY}"),
            "",
        );
    }
    // render: flags.
    let base = "render --model builtin:marble --builtin slab -o out.png";
    for a in [
        "--width 0",
        "--width=-1",
        "--width abc",
        "--width 99999",
        "--width 1e3",
        "--height 0",
        "--height 16385",
        "--spp 0",
        "--spp 5000",
        "--spp=-1",
        "--samples 0",
        "--samples 1e9",
        "--samples 99999999",
        "--seed=-1",
        "--seed abc",
        "--exposure 0",
        "--exposure=-1",
        "--exposure nan",
        "--exposure inf",
        "--mode bogus",
        "--mode ''",
        "--export-unit-mm 0",
        "--export-unit-mm=-1",
        "--export-unit-mm nan",
        "--builtin nope",
        "--builtin ''",
        "--mesh quad.obj",
    ] {
        add(format!("{base} {a}"), "");
    }
    for a in [
        "render --model builtin:marble --builtin slab",
        "render --model builtin:marble -o out.png",
        "render --builtin slab -o out.png",
        "render --model builtin:marble --builtin slab -o out.bmp",
        "render --model builtin:marble --builtin slab -o out",
        "render --model builtin:marble --builtin slab -o ''",
    ] {
        add(a.into(), "");
    }

    // fit: capture directories and values.
    for dir in [
        "missing",
        "garbage.toml",
        "emptydir",
        "foreign",
        "cap_ok",
        "cap_no_manifest",
        "cap_garbage_manifest",
        "rect_empty",
        "rect_garbage",
        "rect_version",
        "rect_dir",
    ] {
        add(format!("fit {dir} -o new_model"), "");
    }
    for a in [
        "--eta 0",
        "--eta nan",
        "--eta abc",
        "--range 2:1",
        "--range x",
        "--norm bogus",
        "--model bogus",
        "--lrf-components abc",
        "--lrf-components=-1",
        "--lrf-denoise 0",
        "--lrf-denoise bogus",
        "--lrf-denoise=-3",
    ] {
        add(format!("fit rect_garbage -o new_model {a}"), "");
    }
    add("fit rect_garbage".into(), "");

    // compare: unreadable images, a bad block size.
    let ok = "model_ok/fv/view_000.exr";
    for a in [
        format!("missing.exr {ok}"),
        format!("garbage.exr {ok}"),
        format!("empty.exr {ok}"),
        format!("{ok} garbage.exr"),
        format!("{ok} {ok} --truth2 missing.exr"),
        format!("{ok} {ok} --block 0"),
        format!("{ok} {ok} --block 2"),
        format!("{ok} {ok} --block abc"),
    ] {
        add(format!("compare {a}"), "");
    }
    add(format!("compare dir.exr {ok}"), "a directory");

    // report: also a file where the model directory should be.
    for m in ["dir.toml", "keep/notes.txt"] {
        add(format!("report {m} -o new_report"), "");
    }

    // rectify.
    for dir in [
        "missing",
        "garbage.toml",
        "emptydir",
        "foreign",
        "cap_no_manifest",
        "cap_empty_manifest",
        "cap_garbage_manifest",
        "cap_truncated_manifest",
        "cap_format",
        "cap_version",
        "cap_garbage_journal",
        "cap_empty_journal",
        "cap_no_journal",
        "cap_forged_journal",
        "cap_ok",
    ] {
        add(format!("rectify {dir}"), "");
    }
    for cal in [
        "missing.toml",
        "dir.toml",
        "empty.toml",
        "calibration_garbage.toml",
        "calibration_wrong.toml",
    ] {
        add(format!("rectify cap_ok --calibration {cal}"), "");
    }
    for a in [
        "--width-mm 0",
        "--width-mm=-1",
        "--width-mm nan",
        "--width-mm abc",
        "--threshold=-1",
        "--threshold 2",
        "--threshold nan",
        "--d-min=-1",
        "--d-max 0",
        "--d-min 5 --d-max 1",
        "--d-max inf",
    ] {
        add(
            format!("rectify cap_ok --calibration calibration_garbage.toml {a}"),
            "",
        );
    }

    // capture.
    for a in [
        "capture",
        "capture bogus",
        "capture plan --scale bogus",
        "capture plan --scale ''",
        "capture plan --json=1",
        "capture run",
        "capture run -o new_cap",
        "capture run --sim",
        "capture run --sim --port /dev/null -o new_cap",
        "capture run --sim --scale bogus -o new_cap",
        "capture run --sim --scale ci --sample nope -o new_cap",
        "capture run --sim --scale ci --sample missing.toml -o new_cap",
        "capture run --sim --scale ci --sample dir.toml -o new_cap",
        "capture run --sim --scale ci --sample empty.toml -o new_cap",
        "capture run --sim --scale ci --sample garbage.toml -o new_cap",
        "capture run --sim --scale ci --sample sample_truncated.toml -o new_cap",
        "capture run --sim --scale ci --sample sample_unknown.toml -o new_cap",
        "capture run --sim --scale ci -o foreign",
        "capture run --sim --scale ci -o keep/notes.txt",
        "capture run --sim --scale ci --resume -o missing",
        "capture run --sim --scale ci --resume -o emptydir",
        "capture run --sim --scale ci --resume -o foreign",
        "capture run --sim --scale ci --resume -o cap_garbage_manifest",
        "capture run --sim --scale ci --resume -o cap_empty_manifest",
        "capture run --sim --scale ci --resume -o cap_format",
        "capture run --sim --scale ci --resume -o cap_version",
        "capture run --sim --scale ci --resume -o cap_garbage_journal",
        "capture run --sim --scale ci --resume -o cap_forged_journal",
        "capture run --sim --scale ci --resume -o cap_no_journal",
        "capture run --sim --scale ci --frame-timeout 0 -o new_cap",
        "capture run --sim --scale ci --frame-timeout=-1 -o new_cap",
        "capture run --sim --scale ci --frame-timeout nan -o new_cap",
        "capture run --sim --scale ci --sim-speed 0 -o new_cap",
        "capture run --sim --scale ci --sim-speed=-1 -o new_cap",
        "capture run --sim --scale ci --sim-speed nan -o new_cap",
        "capture run --sim --scale ci --seed=-1 -o new_cap",
        "capture run --port /nonexistent/tty --baud 0 -o new_cap",
        "capture run --port /nonexistent/tty -o new_cap",
        "capture run --port dir.toml -o new_cap",
        "capture run --port keep/notes.txt -o new_cap",
        "capture run --port /nonexistent/tty --camera x -o new_cap",
        "capture run --port /nonexistent/tty --camera 9=abc -o new_cap",
        "capture run --port /nonexistent/tty --camera =abc -o new_cap",
    ] {
        add(a.into(), "");
    }

    // rig.
    for a in [
        "rig",
        "rig ping",
        "rig --port /nonexistent/tty ping",
        "rig --port dir.toml ping",
        "rig --port keep/notes.txt status",
        "rig --port /nonexistent/tty --baud 0 ping",
        "rig --port /nonexistent/tty --baud abc ping",
        "rig --sim --port /dev/null ping",
        "rig --sim bogus",
        "rig --sim home",
        "rig --sim home sideways",
        "rig --sim move",
        "rig --sim move turntable",
        "rig --sim move turntable abc",
        "rig --sim move turntable nan",
        "rig --sim move turntable inf",
        "rig --sim move turntable 1e30",
        "rig --sim move arc 400",
        "rig --sim move arc=-400",
        "rig --sim move sideways 10",
        "rig --sim move turntable 10 --speed=-1",
        "rig --sim move turntable 10 --accel nan",
        "rig --sim galvo",
        "rig --sim galvo set nan",
        "rig --sim galvo set 1e9",
        "rig --sim galvo set abc",
        "rig --sim laser",
        "rig --sim laser purple",
        "rig --sim laser red --power 5000",
        "rig --sim laser red --power=-1",
        "rig --sim laser red --on=-1",
        "rig --sim laser red --on nan",
        "rig --sim lamps",
        "rig --sim lamps 0x1ff",
        "rig --sim lamps 0b2",
        "rig --sim lamps abc",
        "rig --sim lamps=-1",
        "rig --sim trigger 0xffff",
        "rig --sim trigger abc",
        "rig --sim --sim-speed 0 ping",
        "rig --sim --sim-speed=-1 ping",
        "rig --sim --sim-speed nan ping",
        "rig --sim --time-scale 0 ping",
        "rig --sim --time-scale nan ping",
        "rig --sim --timeout 0 home both",
        "rig --sim --timeout=-1 home both",
        "rig --sim --timeout nan home both",
        "rig --sim --seed abc ping",
    ] {
        add(a.into(), "");
    }

    // sim.
    for a in [
        "sim bogus",
        "sim --pty --drop 2",
        "sim --pty --drop=-1",
        "sim --pty --drop nan",
        "sim --pty --corrupt 1.5",
        "sim --pty --duplicate nan",
        "sim --pty --speed 0",
        "sim --pty --speed=-1",
        "sim --pty --speed nan",
        "sim --pty --line-baud=-1",
        "sim --pty --line-baud abc",
        "sim --pty --seed abc",
        "sim render",
        "sim render --sample two-material",
        "sim render --sample nope --light 4 --quality ci --out new.png",
        "sim render --sample missing.toml --light 4 --quality ci --out new.png",
        "sim render --sample dir.toml --light 4 --quality ci --out new.png",
        "sim render --sample empty.toml --light 4 --quality ci --out new.png",
        "sim render --sample garbage.toml --light 4 --quality ci --out new.png",
        "sim render --sample sample_truncated.toml --light 4 --quality ci --out new.png",
        "sim render --sample sample_unknown.toml --light 4 --quality ci --out new.png",
        "sim render --sample two-material --light 4 --quality ci --camera 0 --out new.png",
        "sim render --sample two-material --light 4 --quality ci --camera 9 --out new.png",
        "sim render --sample two-material --light 0 --out new.png",
        "sim render --sample two-material --light 8 --out new.png",
        "sim render --sample two-material --light x --out new.png",
        "sim render --sample two-material --light 4 --quality ci --laser purple --out new.png",
        "sim render --sample two-material --light 4 --quality ci --laser red --laser-power 2 --out new.png",
        "sim render --sample two-material --light 4 --quality ci --laser red --laser-power nan --out new.png",
        "sim render --sample two-material --light 4 --quality ci --laser red --laser-elevation nan --out new.png",
        "sim render --sample two-material --light 4 --quality ci --galvo nan --out new.png",
        "sim render --sample two-material --light 4 --quality ci --light-arc inf --out new.png",
        "sim render --sample two-material --light 4 --quality ci --turntable nan --out new.png",
        "sim render --sample two-material --light 4 --quality bogus --out new.png",
        "sim render --sample two-material --light 4 --quality ci --photons 0 --out new.png",
        "sim render --sample two-material --light 4 --quality ci --photons abc --out new.png",
        "sim render --sample two-material --light 4 --quality ci --exposure 0 --out new.png",
        "sim render --sample two-material --light 4 --quality ci --exposure=-1 --out new.png",
        "sim render --sample two-material --light 4 --quality ci --exposure nan --out new.png",
        "sim render --sample two-material --light 4 --quality ci --gain 0 --out new.png",
        "sim render --sample two-material --light 4 --quality ci --gain nan --out new.png",
        "sim render --sample two-material --light 4 --quality ci --out new.txt",
        "sim render --sample two-material --light 4 --quality ci --out new.png --hdr new.txt",
        "sim bench --photons 0",
        "sim bench --photons abc",
        "sim presets --bogus",
    ] {
        add(a.into(), "");
    }

    // calibrate.
    for a in [
        "calibrate",
        "calibrate bogus",
        "calibrate truth",
        "calibrate response",
        "calibrate all",
        "calibrate all --sim --scale bogus",
        "calibrate all --sim --seed abc",
        "calibrate all --sim --frame-timeout 0",
        "calibrate plan --scale bogus",
        "calibrate capture --sim",
        "calibrate compute",
        "calibrate compute missing_capture",
        "calibrate compute dir.toml",
        "calibrate compute calibration_garbage.toml",
        "calibrate compute cap_ok",
        "calibrate compute cap_no_manifest",
        "calibrate truth --sim -o dir.toml",
        "calibrate truth --sim -o calibration_garbage.toml",
        "calibrate truth --sim -o calibration_wrong.toml",
        "calibrate truth --sim -o missing_dir/cal.toml",
    ] {
        add(a.into(), "");
    }

    // flash.
    for a in [
        "flash --elf missing.elf",
        "flash --elf dir.elf",
        "flash --elf empty.elf",
        "flash --elf garbage.elf",
        "flash --chip ''",
        "flash --bogus",
    ] {
        add(a.into(), "");
    }

    // demo.
    for a in [
        "demo --scale bogus",
        "demo --scale ''",
        "demo --sample nope -o new_demo",
        "demo --sample missing.toml -o new_demo",
        "demo --sample dir.toml -o new_demo",
        "demo --sample empty.toml -o new_demo",
        "demo --sample garbage.toml -o new_demo",
        "demo --sample sample_truncated.toml -o new_demo",
        "demo -o foreign",
        "demo -o keep/notes.txt",
        "demo -o keep",
        "demo --seed abc",
        "demo --seed=-1",
    ] {
        add(a.into(), "");
    }
    c
}

/// The top-level fixture entries the arguments name (`scenes` for
/// `--scene=scenes/x.toml`), and `keep`.
fn named_entries(template: &Path, args: &[String]) -> std::collections::BTreeSet<String> {
    let mut out = std::collections::BTreeSet::from(["keep".to_string()]);
    for a in args {
        let value = a.split_once('=').map_or(a.as_str(), |(_, v)| v);
        for v in [a.as_str(), value] {
            let first = v.split('/').next().unwrap_or(v);
            if !first.is_empty() && template.join(first).exists() {
                out.insert(first.to_string());
            }
        }
    }
    out
}

/// Where the fixture tree is built once per test run.
fn template_dir() -> std::path::PathBuf {
    static DIR: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let t = tempfile::tempdir().unwrap();
        fixtures(t.path());
        t
    })
    .path()
    .to_path_buf()
}

#[test]
fn every_bad_input_is_refused_in_one_line_and_loses_nothing() {
    let template = template_dir();
    let before = fingerprint(&template);
    let cases = cases();
    assert!(cases.len() >= 350, "only {} cases", cases.len());
    let work = tempfile::tempdir().unwrap();
    let next = AtomicUsize::new(0);
    let failures = Mutex::new(Vec::new());
    let show = std::env::var_os("QHM_SWEEP_SHOW").is_some();
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get().min(4));
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some((line, needle)) = cases.get(k) else {
                        break;
                    };
                    let dir = work.path().join(format!("case{k}"));
                    let args = words(line);
                    // Only what the case names (and keep/) is copied: the
                    // whole tree for each of 350 cases is slow to copy.
                    let named = named_entries(&template, &args);
                    for e in &named {
                        let from = template.join(e);
                        if from.is_dir() {
                            copy_tree(&from, &dir.join(e));
                        } else {
                            std::fs::create_dir_all(&dir).unwrap();
                            std::fs::copy(&from, dir.join(e)).unwrap();
                        }
                    }
                    let before: std::collections::BTreeMap<_, _> = before
                        .iter()
                        .filter(|(p, _)| named.iter().any(|e| p.starts_with(e)))
                        .collect();
                    let run = qhm(&dir, &args, LIMIT);
                    let mut why = Vec::new();
                    if run.timed_out {
                        why.push(format!("still running after {LIMIT:?}"));
                    } else if run.code.is_none_or(|c| c == 0) {
                        why.push(format!("exit code {:?}", run.code));
                    }
                    match one_qhm_line(&run.stderr) {
                        Ok(msg) if !msg.contains(needle) => {
                            why.push(format!("message lacks {needle:?}"))
                        }
                        Ok(_) => {}
                        Err(e) => why.push(e),
                    }
                    let after = fingerprint(&dir);
                    for (path, sum) in &before {
                        match after.get(*path) {
                            None => why.push(format!("{} is gone", path.display())),
                            Some(s) if s != *sum => why.push(format!("{} changed", path.display())),
                            _ => {}
                        }
                    }
                    let new: Vec<_> = after.keys().filter(|p| !before.contains_key(*p)).collect();
                    if !new.is_empty() {
                        why.push(format!("left behind {new:?}"));
                    }
                    if show {
                        eprintln!(
                            "[{:.2} s] qhm {line}\n    {}",
                            run.secs,
                            run.stderr.trim_end()
                        );
                    }
                    if !why.is_empty() {
                        failures.lock().unwrap().push(format!(
                            "qhm {line}\n    {}\n    stderr: {}",
                            why.join("; "),
                            run.stderr.trim_end().replace('\n', "\n            ")
                        ));
                    }
                    let _ = std::fs::remove_dir_all(&dir);
                }
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} bad inputs were not handled:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}
