//! Capture directories through the real `qhm capture run`: a failed start
//! leaves nothing, a capture that never took a frame is replaced, the resume
//! command printed works as printed, an out-of-order journal is refused, and
//! `qhm fit` on an unrectified capture says to rectify it. None of these runs
//! a capture (seconds in all); crash-resume is tests/tests/capture_resume.rs.

mod cli_util;
use cli_util::{run as qhm, snapshot};

use std::path::Path;
use std::process::Command;

use qhm_acquire::{CaptureDir, Manifest, Plan, PlanConfig, Scale};

fn refused(args: &[&str], want: &[&str]) -> String {
    let (ok, text) = qhm(args);
    assert!(!ok, "qhm {args:?} should have failed: {text}");
    for w in want {
        assert!(
            text.contains(w),
            "qhm {args:?}: message lacks {w:?}: {text}"
        );
    }
    text
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ci_plan() -> Plan {
    Plan::new(PlanConfig::for_scale(Scale::Ci)).unwrap()
}

/// A ci capture of marble, seed 7, with the first step's frames journaled
/// (stand-in bytes: the directory only checks their checksums).
fn partial_capture(root: &Path) -> Manifest {
    let plan = ci_plan();
    let m = Manifest::new("sim", "marble", 7, &plan);
    let mut d = CaptureDir::create(root, m.clone()).unwrap();
    let step = &plan.steps[0];
    for k in 0..step.triggers() {
        for &c in &step.cameras {
            let data = format!("frame 0 {k} {c}");
            d.write_frame((0, k as u32, c), &step.frame_path(k, c), data.as_bytes())
                .unwrap();
        }
    }
    d.step_done(0).unwrap();
    m
}

#[test]
fn a_failed_start_leaves_nothing_and_an_unstarted_capture_is_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cap");
    // A bad sample: refused before the directory exists.
    refused(
        &[
            "capture",
            "run",
            "--sim",
            "--scale",
            "ci",
            "--sample",
            "nosuch",
            "-o",
            s(&out),
        ],
        &["nosuch"],
    );
    assert!(!out.exists(), "a failed start left {}", out.display());
    // A real rig without cameras: refused before the port is opened.
    let text = refused(
        &[
            "capture",
            "run",
            "--port",
            "/dev/null",
            "--scale",
            "ci",
            "-o",
            s(&out),
        ],
        &["--camera N=DEVICE", "missing"],
    );
    assert!(!out.exists(), "{text}");
    refused(
        &[
            "capture",
            "run",
            "--port",
            "/dev/null",
            "--camera",
            "9=x",
            "-o",
            s(&out),
        ],
        &["--camera \"9=x\": expected N=DEVICE"],
    );
    assert!(!out.exists());

    // An unstarted capture of another sample (a start that failed before
    // this fix, or a crash before the first frame) is no obstacle: the run
    // goes on to the rig (here: fails on the bad sample, after the
    // directory checks), with or without --resume.
    let plan = ci_plan();
    drop(CaptureDir::create(&out, Manifest::new("sim", "sponge", 3, &plan)).unwrap());
    for resume in [false, true] {
        let mut a = vec![
            "capture", "run", "--sim", "--scale", "ci", "--sample", "nosuch",
        ];
        if resume {
            a.push("--resume");
        }
        a.extend(["-o", s(&out)]);
        let text = refused(&a, &["nosuch"]);
        assert!(
            !text.contains("already holds") && !text.contains("different"),
            "{text}"
        );
    }
    assert!(CaptureDir::is_unstarted(&out).unwrap());
}

#[test]
fn the_printed_resume_command_passes_the_directory_checks() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cap");
    partial_capture(&out);
    let before = snapshot(&out);
    let expected = format!(
        "qhm capture run --sim --scale ci --sample marble --seed 7 --resume -o {}",
        s(&out)
    );
    // Without --resume, and with the default scale, sample and seed.
    let text = refused(
        &["capture", "run", "--sim", "-o", s(&out)],
        &["already holds a capture", &expected],
    );
    assert_eq!(text.trim().lines().count(), 1, "{text}");
    let text = refused(
        &["capture", "run", "--sim", "--resume", "-o", s(&out)],
        &[
            "different plan (--scale ci; this run asked for --scale default)",
            &expected,
        ],
    );
    assert_eq!(
        snapshot(&out),
        before,
        "refused directory was modified: {text}"
    );
    let text = refused(
        &[
            "capture",
            "run",
            "--sim",
            "--scale",
            "ci",
            "--resume",
            "-o",
            s(&out),
        ],
        &[
            "different seed (--seed 7; this run asked for --seed 1)",
            &expected,
        ],
    );
    assert_eq!(text.trim().lines().count(), 1, "{text}");

    // The command as printed: while this test holds the capture's lock, it
    // gets past every setting check and stops at the lock (no capture runs).
    let held = CaptureDir::open(&out, None).unwrap();
    let words: Vec<&str> = expected.split(' ').skip(1).collect();
    refused(&words, &["another capture run is writing this directory"]);
    drop(held);
    assert_eq!(snapshot(&out), before);
}

#[test]
fn swapped_frame_lines_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cap");
    partial_capture(&out);
    let journal = out.join("journal");
    let text = std::fs::read_to_string(&journal).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    assert!(lines[1].starts_with("frame 0 ") && lines[2].starts_with("frame 0 "));
    lines.swap(1, 2);
    std::fs::write(&journal, lines.join("\n") + "\n").unwrap();
    let before = snapshot(&out);
    refused(
        &[
            "capture",
            "run",
            "--sim",
            "--scale",
            "ci",
            "--sample",
            "marble",
            "--seed",
            "7",
            "--resume",
            "-o",
            s(&out),
        ],
        &["journal line 2", "out of plan order"],
    );
    assert_eq!(snapshot(&out), before);
}

#[test]
fn fit_of_an_unrectified_capture_says_to_rectify_it() {
    let tmp = tempfile::tempdir().unwrap();
    let cap = tmp.path().join("cap");
    partial_capture(&cap);
    let model = tmp.path().join("model");
    let text = refused(
        &["fit", s(&cap), "-o", s(&model)],
        &[
            &format!("run `qhm rectify {}` first", s(&cap)),
            "not rectified",
        ],
    );
    assert_eq!(text.trim().lines().count(), 1, "{text}");
    assert!(!model.exists());
}

/// Ctrl-C before the first frame leaves nothing; after it, the message
/// gives the exact command that resumes (about 8 s: one frame is captured).
#[cfg(unix)]
#[test]
fn ctrl_c_before_the_first_frame_leaves_nothing_and_after_it_prints_the_resume_command() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    use std::time::{Duration, Instant};

    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cap");
    let journal = out.join("journal");
    let frames = || {
        std::fs::read_to_string(&journal)
            .map(|j| j.lines().filter(|l| l.starts_with("frame ")).count())
            .unwrap_or(0)
    };
    for after_a_frame in [false, true] {
        // Before the first frame: a rig at 5x real time homes its axes for
        // seconds of wall time, so the first frame is surely that far away.
        let speed = if after_a_frame { "200" } else { "5" };
        let child = Command::new(env!("CARGO_BIN_EXE_qhm"))
            .args([
                "capture",
                "run",
                "--sim",
                "--sim-speed",
                speed,
                "--scale",
                "ci",
                "--quiet",
                "-o",
                s(&out),
            ])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let t = Instant::now();
        let ready = || {
            if after_a_frame {
                frames() > 0
            } else {
                journal.exists()
            }
        };
        while !ready() {
            assert!(
                t.elapsed() < Duration::from_secs(120),
                "capture did not start"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        if !after_a_frame {
            // The first frame is seconds away; the Ctrl-C handler is up.
            std::thread::sleep(Duration::from_millis(300));
            assert_eq!(frames(), 0, "a frame came too early for this test");
        }
        kill(Pid::from_raw(child.id() as i32), Signal::SIGINT).unwrap();
        let res = child.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&res.stderr).into_owned();
        assert_eq!(res.status.code(), Some(130), "{text}");
        if after_a_frame {
            let cmd = format!(
                "continue with `qhm capture run --sim --scale ci --sample two-material --seed 1 --resume -o {}`",
                s(&out)
            );
            assert!(text.contains(&cmd), "{text}");
            assert!(frames() > 0);
        } else {
            assert!(text.contains("no frame was taken"), "{text}");
            assert!(!out.exists(), "an interrupted start left {}", out.display());
        }
    }
}
