//! `qhm capture run --shard K/N` and `--merge` refusals on the real binary,
//! each one `qhm:` line that leaves the directory as it was (the sharded
//! capture itself is tests/tests/capture_shards.rs: it takes seconds of
//! simulation).

use std::path::Path;
use std::process::Command;

fn refused(dir: &Path, args: &str, want: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_qhm"))
        .args(args.split_whitespace())
        .current_dir(dir)
        .output()
        .expect("qhm runs");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "qhm {args} should be refused: {text}"
    );
    assert!(!text.contains("panicked"), "{text}");
    assert_eq!(text.trim().lines().count(), 1, "one line: {text}");
    for w in want {
        assert!(text.contains(w), "qhm {args}: lacks {w:?}: {text}");
    }
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = walk(dir);
    v.sort();
    v
}

fn walk(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        out.push(p.to_string_lossy().into_owned());
        if p.is_dir() {
            out.extend(walk(&p));
        }
    }
    out
}

#[test]
fn shard_and_merge_refusals_are_one_line_and_touch_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::create_dir_all(d.join("photos")).unwrap();
    std::fs::write(d.join("photos/holiday.jpg"), b"x").unwrap();
    std::fs::create_dir_all(d.join("whole")).unwrap();
    std::fs::write(d.join("whole/capture.toml"), b"format = \"qhm-capture\"\n").unwrap();
    std::fs::create_dir_all(d.join("empty")).unwrap();
    let before = listing(d);
    for bad in ["0/2", "3/2", "1/0", "a/b", "2", "1/2/3"] {
        refused(
            d,
            &format!("capture run --sim --scale ci --shard {bad} -o new"),
            &["--shard", "K/N"],
        );
    }
    refused(d, "capture run --scale ci --shard 1/2 -o new", &["--sim"]);
    refused(d, "capture run --sim --merge -o new", &["--merge", "--sim"]);
    refused(d, "capture run --merge --shard 1/2 -o new", &["--merge"]);
    refused(
        d,
        "capture run --sim --scale ci --shard 1/2 -o photos",
        &["holiday.jpg", "refusing"],
    );
    refused(
        d,
        "capture run --sim --scale ci --shard 1/2 -o whole",
        &["already holds a whole capture"],
    );
    refused(
        d,
        "capture run --merge -o empty",
        &["no shares to merge", "--shard K/N"],
    );
    refused(
        d,
        "capture run --merge -o whole",
        &["already holds a capture"],
    );
    std::fs::create_dir_all(d.join("split/shards/2-of-3")).unwrap();
    let before_split = listing(d);
    refused(
        d,
        "capture run --merge -o split",
        &["missing shares 1/3, 3/3 of 3"],
    );
    assert_eq!(listing(d), before_split);
    std::fs::remove_dir_all(d.join("split")).unwrap();
    assert_eq!(listing(d), before, "refusals leave everything as it was");
}
