//! Running the `qhm` binary in a test: a time limit, the exit code and
//! stderr, and a fingerprint of a directory tree to prove a run changed
//! nothing in it.

#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use std::hash::{Hash, Hasher};

pub const QHM: &str = env!("CARGO_BIN_EXE_qhm");

/// What one run of qhm did.
#[derive(Debug)]
pub struct Run {
    /// None when killed by a signal or by the time limit.
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
    pub timed_out: bool,
    pub secs: f64,
}

/// Runs qhm with `args` in `dir`, stdin closed, killed after `limit`.
pub fn qhm(dir: &Path, args: &[String], limit: Duration) -> Run {
    let t = Instant::now();
    let mut child = Command::new(QHM)
        .args(args)
        .current_dir(dir)
        .env_remove("QHM_LOG")
        .env_remove("RUST_BACKTRACE")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start qhm");
    // Read both pipes on threads so a chatty child never blocks on a full pipe.
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    let out_t = std::thread::spawn(move || {
        let mut s = Vec::new();
        let _ = out.read_to_end(&mut s);
        s
    });
    let err_t = std::thread::spawn(move || {
        let mut s = Vec::new();
        let _ = err.read_to_end(&mut s);
        s
    });
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait for qhm") {
            break s;
        }
        if t.elapsed() > limit {
            timed_out = true;
            let _ = child.kill();
            break child.wait().expect("wait for killed qhm");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let text = |v: Vec<u8>| String::from_utf8_lossy(&v).into_owned();
    Run {
        code: if timed_out { None } else { status.code() },
        stdout: text(out_t.join().unwrap()),
        stderr: text(err_t.join().unwrap()),
        timed_out,
        secs: t.elapsed().as_secs_f64(),
    }
}

/// `["a", "b"]` from `"a b"`; `'...'` keeps spaces (no other quoting).
pub fn words(s: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = s.trim();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix('\'') {
            let end = r.find('\'').expect("closing quote");
            out.push(r[..end].to_string());
            rest = r[end + 1..].trim_start();
        } else {
            let end = rest.find(' ').unwrap_or(rest.len());
            out.push(rest[..end].to_string());
            rest = rest[end..].trim_start();
        }
    }
    out
}

/// Every file under `root` (relative path -> size and hash; directories as "dir").
pub fn fingerprint(root: &Path) -> BTreeMap<PathBuf, String> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, String>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for p in entries {
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            let meta = std::fs::symlink_metadata(&p).unwrap();
            if meta.is_dir() {
                out.insert(rel, "dir".into());
                walk(root, &p, out);
            } else {
                // A change detector, not a checksum anyone stores.
                let bytes = std::fs::read(&p).unwrap_or_default();
                let mut h = std::collections::hash_map::DefaultHasher::new();
                bytes.hash(&mut h);
                out.insert(
                    rel,
                    format!("{} bytes, hash {:016x}", bytes.len(), h.finish()),
                );
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(root, root, &mut out);
    out
}

/// Copies the tree at `from` into `to` (created).
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

/// The one-line `qhm: ...` error rule: Err(why) when stderr breaks it.
pub fn one_qhm_line(stderr: &str) -> Result<&str, String> {
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    if stderr.contains("panicked") || stderr.contains("RUST_BACKTRACE") {
        return Err("panicked".into());
    }
    match lines.as_slice() {
        [line] if line.starts_with("qhm: ") && line.len() > 6 => Ok(line),
        [] => Err("no message on stderr".into()),
        [line] => Err(format!("not a `qhm: ` line: {line:?}")),
        _ => Err(format!("{} lines on stderr", lines.len())),
    }
}

/// Every file under `root` (hidden ones too), by its path relative to `root`, with its bytes.
pub fn snapshot(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

/// Runs qhm in the current directory; returns (success, stdout + stderr),
/// and fails the test on a panic.
pub fn run(args: &[impl AsRef<std::ffi::OsStr> + std::fmt::Debug]) -> (bool, String) {
    let out = Command::new(QHM).args(args).output().expect("qhm runs");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(!text.contains("panicked"), "qhm panicked: {text}");
    (out.status.success(), text)
}
