//! What `qhm` says when it refuses or warns: each case of the "numbers and
//! messages" review pinned by the message or the refusal it must give.
//! The bad-input sweep (bad_inputs.rs) checks the form of every message;
//! these check what a few of them say.

mod cli_util;

use std::path::Path;
use std::time::Duration;

use cli_util::{Run, one_qhm_line, qhm, words};

const LIMIT: Duration = Duration::from_secs(60);
const TINY: &str = "--width 8 --height 8 --spp 1 --samples 100";

fn run(dir: &Path, line: &str) -> Run {
    qhm(dir, &words(line), LIMIT)
}

/// The run failed with one `qhm:` line; returns it.
fn refused(dir: &Path, line: &str) -> String {
    let r = run(dir, line);
    assert!(
        r.code.is_some_and(|c| c != 0),
        "qhm {line}: exit {:?}\n{}",
        r.code,
        r.stderr
    );
    one_qhm_line(&r.stderr)
        .unwrap_or_else(|e| panic!("qhm {line}: {e}\n{}", r.stderr))
        .to_string()
}

fn succeeded(dir: &Path, line: &str) -> Run {
    let r = run(dir, line);
    assert_eq!(r.code, Some(0), "qhm {line}\n{}", r.stderr);
    r
}

fn profile(dir: &Path, name: &str, intensity: impl Fn(f64) -> f64) {
    let mut s = String::from("distance_mm,intensity_per_mm\n");
    for k in 0..60 {
        let d = k as f64 * 0.2;
        s += &format!("{d},{}\n", intensity(d));
    }
    std::fs::write(dir.join(name), s).unwrap();
}

#[test]
fn fit_profile_that_overflows_is_an_error_not_nan() {
    let t = tempfile::tempdir().unwrap();
    profile(t.path(), "huge.csv", |_| 1e300);
    for json in ["", " --json"] {
        let line = format!("fit-profile huge.csv --reflectance 0.5{json}");
        let r = run(t.path(), &line);
        assert_eq!(r.code, Some(1), "{line}: {}", r.stderr);
        let msg = one_qhm_line(&r.stderr).unwrap();
        assert!(msg.contains("no finite s'_t"), "{msg}");
        assert!(msg.contains("1.000e300 mm^-1"), "{msg}");
        assert!(
            !r.stdout.contains("NaN") && !r.stdout.contains("null"),
            "{}",
            r.stdout
        );
    }
}

#[test]
fn fit_profile_states_the_reflectance_limit_in_the_users_terms() {
    let t = tempfile::tempdir().unwrap();
    profile(t.path(), "p.csv", |d| 0.2 * (-1.2 * d).exp() / (d + 0.5));
    for r in ["1", "0.999999", "0.983"] {
        let msg = refused(t.path(), &format!("fit-profile p.csv --reflectance {r}"));
        assert!(msg.contains(&format!("R = {r} is above 0.982987")), "{msg}");
        assert!(
            msg.contains("R must be in (0, 0.982987] at eta = 1.3"),
            "{msg}"
        );
        assert!(!msg.contains("T(0)") && !msg.contains("R /"), "{msg}");
    }
    // At another index the limit moves with it: 1 - ((1.5 - 1) / 2.5)² = 0.96.
    let msg = refused(t.path(), "fit-profile p.csv --reflectance 0.97 --eta 1.5");
    assert!(msg.contains("(0, 0.960000] at eta = 1.5"), "{msg}");
    let help = succeeded(t.path(), "fit-profile --help").stdout;
    assert!(
        help.contains("(0, 1 - F(0)]") && help.contains("0.98299"),
        "{help}"
    );
    assert!(!help.contains("in (0, 1]"), "{help}");
}

#[test]
fn scene_camera_takes_defaults_and_object_scale_is_checked_with_builtins() {
    let t = tempfile::tempdir().unwrap();
    let scene = |name: &str, text: &str| std::fs::write(t.path().join(name), text).unwrap();
    scene("fov.toml", "[camera]\nfov_deg = 40\n");
    scene("empty_camera.toml", "[camera]\n");
    scene("target.toml", "[camera]\ntarget = [0, 0, 5]\n");
    for s in ["fov", "empty_camera", "target"] {
        succeeded(
            t.path(),
            &format!(
                "render --model builtin:marble --builtin sphere --scene {s}.toml -o {s}.png {TINY} --quiet"
            ),
        );
        assert!(t.path().join(format!("{s}.png")).is_file());
    }
    std::fs::write(
        t.path().join("quad.obj"),
        "v 0 0 0\nv 9 0 0\nv 9 9 0\nv 0 9 0\nf 1 2 3 4\n",
    )
    .unwrap();
    for (value, needle) in [
        ("0", "object.scale 0 must be a number > 0"),
        ("-1", "object.scale -1 must be a number > 0"),
        ("nan", "object.scale NaN must be a number > 0"),
        ("1e30", "mesh scale 1e30 (object.scale) is out of range"),
        ("1e-30", "mesh scale 1e-30 (object.scale) is out of range"),
    ] {
        scene("s.toml", &format!("[object]\nscale = {value}\n"));
        for object in ["--builtin slab", "--mesh quad.obj"] {
            let msg = refused(
                t.path(),
                &format!("render --model builtin:marble {object} --scene s.toml -o x.png {TINY}"),
            );
            assert!(msg.contains(needle), "{object} scale {value}: {msg}");
            assert!(!msg.contains("degenerate"), "{msg}");
        }
    }
    assert!(!t.path().join("x.png").exists());
}

#[test]
fn os_errors_give_their_reason_once() {
    let t = tempfile::tempdir().unwrap();
    std::fs::create_dir(t.path().join("d")).unwrap();
    for (line, reason) in [
        (
            "fit-profile d --reflectance 0.5",
            "Is a directory (os error 21)",
        ),
        (
            "render --model d --builtin slab -o x.png",
            "No such file or directory (os error 2)",
        ),
        (
            "render --model builtin:marble --builtin slab --scene d -o x.png",
            "Is a directory (os error 21)",
        ),
        ("report d -o r", "No such file or directory (os error 2)"),
    ] {
        let msg = refused(t.path(), line);
        assert_eq!(msg.matches(reason).count(), 1, "{line}: {msg}");
    }
}

/// A homogeneous model whose optional fit.json is broken.
fn model_with_broken_fit_json(dir: &Path) {
    let m = qhm_model::MaterialModel::homogeneous(qhm_render::materials::preset("marble").unwrap());
    m.save(dir).unwrap();
    std::fs::write(dir.join("fit.json"), "{ \"channels\": [ truncated").unwrap();
}

#[test]
fn a_broken_fit_json_warns_without_colour_and_the_render_goes_on() {
    let t = tempfile::tempdir().unwrap();
    model_with_broken_fit_json(&t.path().join("m"));
    let r = succeeded(
        t.path(),
        &format!("render --model m --builtin slab -o x.png {TINY} --quiet"),
    );
    assert!(t.path().join("x.png").is_file());
    let warning = r
        .stderr
        .lines()
        .find(|l| l.contains("fit.json"))
        .unwrap_or_else(|| panic!("no warning:\n{}", r.stderr));
    assert!(warning.contains("WARN"), "{warning}");
    assert!(warning.contains("without its fit diagnostics"), "{warning}");
    // stderr is a pipe here, not a terminal: no colour codes.
    assert!(!r.stderr.contains('\x1b'), "{:?}", r.stderr);
}

#[test]
fn render_shows_progress_off_a_terminal_and_its_memory_estimate() {
    let t = tempfile::tempdir().unwrap();
    let base = format!("render --model builtin:marble --builtin slab {TINY}");
    let r = succeeded(t.path(), &format!("{base} -o a.png"));
    assert!(
        r.stderr
            .lines()
            .any(|l| l.starts_with("render tiles: 1/1, done in")),
        "{}",
        r.stderr
    );
    let r = succeeded(t.path(), &format!("{base} -o b.png --quiet"));
    assert!(!r.stderr.contains("render tiles"), "{}", r.stderr);
    let r = succeeded(t.path(), &format!("{base} -o c.png --bench"));
    assert!(
        r.stderr.contains(
            "qhm render: 8 x 8 pixels, 1 spp, 100 surface samples: about 1 MiB of memory"
        ),
        "{}",
        r.stderr
    );
}

#[test]
fn usage_errors_and_missing_commands_are_one_line() {
    let t = tempfile::tempdir().unwrap();
    let msg = refused(t.path(), "capture");
    assert_eq!(
        msg,
        "qhm: qhm capture needs a command: plan, run (see --help)"
    );
    let msg = refused(t.path(), "fit-profile");
    assert!(msg.contains("--reflectance <REFLECTANCE>"), "{msg}");
    let msg = refused(t.path(), "render --model builtin:marble --widht 8");
    assert!(
        msg.contains("a similar argument exists: '--width'"),
        "{msg}"
    );
}
