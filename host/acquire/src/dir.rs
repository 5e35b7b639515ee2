//! The capture directory and its crash-safe journal.
//!
//! ```text
//! CAPTURE_DIR/
//!   capture.toml     format, version, rig, sample, seed, the plan configuration
//!   journal          append-only, one line per event, each line checksummed
//!   frames/pN/sSSSSSS_kKKK_cC.png   8-bit frames as the cameras gave them
//! ```
//!
//! A frame is written to a temporary file, fsynced and renamed into place; only
//! then is its journal line (path, size, sha256) appended and fsynced. So a
//! frame in the journal is always complete on disk, and a crash loses at most
//! the frames after the last journal line. A torn last line (no newline: the
//! crash hit mid-write) is cut off on resume; any other damage (a bad line
//! checksum, a missing or changed frame, a foreign capture.toml) makes `open`
//! refuse the directory without touching it.
//!
//! The journal holds nothing that depends on time or arrival order (frames are
//! appended in plan order), so a resumed capture is byte-identical to an
//! uninterrupted one.
//!
//! A capture can be taken in shares (`qhm capture run --sim --shard K/N`, one
//! process or machine each): share K of N takes the steps whose index mod N
//! is K - 1, into its own capture directory `CAPTURE_DIR/shards/K-of-N/`
//! (capture.toml says `shard = [K, N]`; its journal lists only its steps).
//! [`merge_shards`] joins the N finished shares into CAPTURE_DIR, whose
//! capture.toml, journal and frames are then those of an unsharded run.

use std::collections::BTreeMap;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::plan::{Plan, PlanConfig, PlanError, Scale};

/// Value of `format` in capture.toml.
pub const FORMAT: &str = "qhm-capture";
/// Version of this directory layout.
pub const VERSION: u32 = 1;
const MANIFEST: &str = "capture.toml";
const JOURNAL: &str = "journal";
/// Folder of the shares of a capture taken in shares.
pub const SHARDS: &str = "shards";

/// What capture.toml holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    /// Where the frames came from ("sim" or the serial port); informational.
    pub rig: String,
    /// Sample preset or file the run was asked to measure.
    pub sample: String,
    /// Seed of every random process of the (simulated) world.
    pub seed: u64,
    /// sha256 of the plan's steps, hex: resume refuses a different plan.
    pub plan_sha256: String,
    /// The calibration file the capture was taken with (`qhm capture run
    /// --calibration`): relative to the (whole) capture directory where the
    /// two share a parent, else absolute. `qhm rectify` uses it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<String>,
    /// sha256 of that file as it was when the capture started, hex.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_sha256: Option<String>,
    /// `[K, N]` in a share's own directory (see the module docs); absent in a
    /// whole capture.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<[u32; 2]>,
    pub plan: PlanConfig,
}

impl Manifest {
    pub fn new(rig: &str, sample: &str, seed: u64, plan: &Plan) -> Manifest {
        Manifest {
            format: FORMAT.into(),
            version: VERSION,
            rig: rig.into(),
            sample: sample.into(),
            seed,
            plan_sha256: plan_sha256(plan),
            calibration: None,
            calibration_sha256: None,
            shard: None,
            plan: plan.config.clone(),
        }
    }

    /// Reads `root/capture.toml` (only reads: nothing is locked or repaired).
    pub fn read(root: &Path) -> Result<Manifest, DirError> {
        let mpath = root.join(MANIFEST);
        let text = fs::read_to_string(&mpath).map_err(io_err(&mpath))?;
        toml::from_str(&text).map_err(|e| DirError::BadManifest {
            path: mpath,
            why: e.to_string(),
        })
    }

    /// The named scale whose plan this manifest holds, if any.
    pub fn scale(&self) -> Option<Scale> {
        Scale::ALL.into_iter().find(|&s| {
            Plan::new(PlanConfig::for_scale(s)).is_ok_and(|p| plan_sha256(&p) == self.plan_sha256)
        })
    }

    /// The `qhm capture run` arguments that name this capture: rig, scale,
    /// sample and seed (a real rig's `--camera` and `--baud` are not recorded).
    pub fn run_args(&self) -> String {
        let rig = match self.rig.strip_prefix("serial:") {
            Some(port) => format!("--port {}", shell_word(port)),
            None if self.rig == "sim" => "--sim".into(),
            // Not written by `qhm capture run`: name the choice to make.
            None => "--sim|--port DEVICE".into(),
        };
        let scale = self
            .scale()
            .map_or("(a plan of no named scale)".into(), |s| {
                format!("--scale {}", s.name())
            });
        let shard = self
            .shard
            .map_or(String::new(), |[k, n]| format!(" --shard {k}/{n}"));
        format!(
            "{rig} {scale} --sample {} --seed {}{shard}",
            shell_word(&self.sample),
            self.seed
        )
    }

    /// Records `file` as the calibration the capture in `root` (the whole
    /// capture's directory, made or not) is taken with: its path and sha256.
    pub fn record_calibration(&mut self, root: &Path, file: &Path) -> Result<(), DirError> {
        let data = fs::read(file).map_err(io_err(file))?;
        let file_abs = fs::canonicalize(file).map_err(io_err(file))?;
        let root_abs = absolute_dir(root).map_err(io_err(root))?;
        self.calibration = Some(
            relative_path(&root_abs, &file_abs)
                .to_string_lossy()
                .into_owned(),
        );
        self.calibration_sha256 = Some(sha256_hex(&data));
        Ok(())
    }

    /// The recorded calibration file of the capture (or share) in `root`,
    /// resolved, with its recorded sha256.
    pub fn calibration_file(&self, root: &Path) -> Option<(PathBuf, &str)> {
        let file = self.calibration.as_deref()?;
        // A share's directory is CAPTURE_DIR/shards/K-of-N; the path is the whole capture's.
        let base = match self.shard {
            Some(_) => root.join("../.."),
            None => root.to_path_buf(),
        };
        Some((
            base.join(file),
            self.calibration_sha256.as_deref().unwrap_or(""),
        ))
    }

    /// Whether this capture (or share) takes plan step `index`.
    pub fn takes(&self, index: u32) -> bool {
        self.shard.is_none_or(|[k, n]| index % n == k - 1)
    }
}

/// Where share `k` of `n` of the capture in `root` is written.
pub fn shard_dir(root: &Path, k: u32, n: u32) -> PathBuf {
    root.join(SHARDS).join(format!("{k}-of-{n}"))
}

/// `dir` as an absolute path with symbolic links resolved as far as it
/// exists (a directory not made yet keeps its last components).
fn absolute_dir(dir: &Path) -> io::Result<PathBuf> {
    let abs = std::path::absolute(dir)?;
    let mut missing = Vec::new();
    let mut at = abs.as_path();
    loop {
        match fs::canonicalize(at) {
            Ok(mut real) => {
                real.extend(missing.iter().rev());
                return Ok(real);
            }
            Err(_) => match (at.parent(), at.file_name()) {
                (Some(parent), Some(name)) => {
                    missing.push(name.to_os_string());
                    at = parent;
                }
                _ => return Ok(abs),
            },
        }
    }
}

/// `to` relative to the directory `from` (both absolute) when they share
/// more than the root, else `to` itself.
fn relative_path(from: &Path, to: &Path) -> PathBuf {
    let (a, b): (Vec<_>, Vec<_>) = (from.components().collect(), to.components().collect());
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    if common <= 1 {
        return to.to_path_buf();
    }
    let mut rel = PathBuf::new();
    for _ in common..a.len() {
        rel.push("..");
    }
    rel.extend(&b[common..]);
    rel
}

/// `w` quoted for a POSIX shell if it needs it.
pub fn shell_word(w: &str) -> String {
    let plain = !w.is_empty()
        && w.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./:=+,@%".contains(c));
    if plain {
        w.to_string()
    } else {
        format!("'{}'", w.replace('\'', "'\\''"))
    }
}

/// sha256 of the plan's steps as JSON.
pub fn plan_sha256(plan: &Plan) -> String {
    let json = serde_json::to_vec(&plan.steps).expect("plan steps serialise");
    hex(&Sha256::digest(&json))
}

/// sha256 of `data`, hex (names a file's content, e.g. the calibration a
/// rectified shard was made with).
pub fn sha256_hex(data: &[u8]) -> String {
    hex(&Sha256::digest(data))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[derive(Debug, thiserror::Error)]
pub enum DirError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    /// The directory has files but no capture.toml: refuse to write into it.
    #[error(
        "{0} is not empty and is not a qhm capture directory (no capture.toml); refusing to write into it"
    )]
    Foreign(PathBuf),
    /// capture.toml is unreadable or of another format or version.
    #[error("{path}: not a qhm capture manifest: {why}")]
    BadManifest { path: PathBuf, why: String },
    /// A capture exists and `--resume` was not given.
    #[error(
        "{0} already holds a capture; pass --resume to continue it or choose another directory"
    )]
    Exists(PathBuf),
    /// `--resume` on a directory captured with other settings.
    #[error(
        "{path}: cannot resume: the directory was captured with a different {what} ({stored}; this run asked for {asked})"
    )]
    Mismatch {
        path: PathBuf,
        what: String,
        /// The directory's value, e.g. `--scale ci`.
        stored: String,
        /// This run's value.
        asked: String,
    },
    /// The journal is damaged beyond a torn last line.
    #[error("{path}: journal line {line}: {why}")]
    CorruptJournal {
        path: PathBuf,
        line: usize,
        why: String,
    },
    /// A frame the journal lists is missing or differs from its checksum.
    #[error("{path}: frame {frame} {why}; the capture is damaged (not overwriting it)")]
    BadFrame {
        path: PathBuf,
        frame: String,
        why: String,
    },
    /// Another run holds the journal lock.
    #[error("{0}: another capture run is writing this directory")]
    Locked(PathBuf),
    /// The stored plan does not build.
    #[error("{0}")]
    Plan(#[from] PlanError),
    /// The shares of a capture cannot be merged (missing, unfinished, of
    /// another capture, or the capture is already there).
    #[error("{path}: {why}")]
    Shards { path: PathBuf, why: String },
}

/// Key of a frame: (step, scan position, camera).
pub type FrameKey = (u32, u32, u8);

/// One journaled frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameRecord {
    pub path: String,
    pub bytes: u64,
    pub sha256: String,
}

/// An open capture directory, locked for writing.
pub struct CaptureDir {
    root: PathBuf,
    manifest: Manifest,
    journal: File,
    frames: BTreeMap<FrameKey, FrameRecord>,
    steps_done: u32,
    /// Steps in the plan.
    plan_len: u32,
    complete: bool,
}

fn io_err(path: &Path) -> impl FnOnce(io::Error) -> DirError + '_ {
    move |source| DirError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Appends ` ~` and the first 16 hex digits of the line's sha256.
fn seal(line: &str) -> String {
    format!("{line} ~{}\n", &hex(&Sha256::digest(line.as_bytes()))[..16])
}

fn unseal(line: &str) -> Option<&str> {
    let (body, sum) = line.rsplit_once(" ~")?;
    (hex(&Sha256::digest(body.as_bytes()))[..16] == *sum).then_some(body)
}

impl CaptureDir {
    /// Checks that [`CaptureDir::create`] would accept `root`, without
    /// touching anything (so a run can refuse before it starts the rig).
    pub fn check_new(root: &Path) -> Result<(), DirError> {
        if !root.exists() || Self::is_unstarted(root)? {
            return Ok(());
        }
        let mut entries = fs::read_dir(root).map_err(io_err(root))?;
        if entries.next().is_none() {
            return Ok(());
        }
        Err(if root.join(MANIFEST).exists() {
            DirError::Exists(root.to_path_buf())
        } else {
            DirError::Foreign(root.to_path_buf())
        })
    }

    /// Whether `root` holds a capture that never journaled a frame (a run
    /// that failed or was stopped before its first frame) and nothing else:
    /// such a directory is replaced by a new run, whatever its settings.
    pub fn is_unstarted(root: &Path) -> Result<bool, DirError> {
        if !root.join(MANIFEST).is_file() || !root.join(JOURNAL).is_file() {
            return Ok(false);
        }
        // A damaged or foreign manifest is refused by `open`, never replaced.
        match Manifest::read(root) {
            Ok(m) if m.format == FORMAT && m.version == VERSION => {}
            _ => return Ok(false),
        }
        for e in fs::read_dir(root).map_err(io_err(root))? {
            let name = e.map_err(io_err(root))?.file_name();
            if name != MANIFEST && name != JOURNAL && name != "frames" {
                return Ok(false);
            }
        }
        if !only_temporaries(&root.join("frames"))? {
            return Ok(false);
        }
        let jpath = root.join(JOURNAL);
        let raw = fs::read(&jpath).map_err(io_err(&jpath))?;
        let text = String::from_utf8_lossy(&raw);
        // Any line that is not the sealed header (a frame, a torn frame,
        // damage) makes it a capture worth keeping.
        Ok(text
            .lines()
            .all(|l| unseal(l).is_some_and(|body| body.starts_with("qhm-journal "))))
    }

    /// Removes an unstarted capture (see [`CaptureDir::is_unstarted`]),
    /// unless a run holds it.
    fn remove_unstarted(root: &Path) -> Result<(), DirError> {
        let jpath = root.join(JOURNAL);
        let journal = File::open(&jpath).map_err(io_err(&jpath))?;
        lock(&journal, root)?;
        let frames = root.join("frames");
        if frames.exists() {
            fs::remove_dir_all(&frames).map_err(io_err(&frames))?;
        }
        fs::remove_file(root.join(MANIFEST)).map_err(io_err(root))?;
        fs::remove_file(&jpath).map_err(io_err(&jpath))?;
        Ok(())
    }

    /// Removes this capture's files if it never journaled a frame (a run
    /// that failed before its first frame leaves nothing behind); returns
    /// whether it did. The directory itself stays (the caller knows whether
    /// it made it).
    pub fn discard_if_unstarted(self) -> Result<bool, DirError> {
        let root = self.root.clone();
        if !self.frames.is_empty() {
            return Ok(false);
        }
        drop(self); // releases the journal lock
        if !Self::is_unstarted(&root)? {
            return Ok(false);
        }
        Self::remove_unstarted(&root)?;
        Ok(true)
    }

    /// Creates a new capture in `root` (absent, empty, or holding an
    /// unstarted capture, which it replaces).
    pub fn create(root: &Path, manifest: Manifest) -> Result<CaptureDir, DirError> {
        Self::check_new(root)?;
        if Self::is_unstarted(root)? {
            Self::remove_unstarted(root)?;
        }
        fs::create_dir_all(root.join("frames")).map_err(io_err(root))?;
        let text = toml::to_string(&manifest).map_err(|e| DirError::BadManifest {
            path: root.join(MANIFEST),
            why: e.to_string(),
        })?;
        write_durably(root, MANIFEST, text.as_bytes())?;
        let jpath = root.join(JOURNAL);
        let mut journal = OpenOptions::new()
            .create_new(true)
            .append(true)
            .open(&jpath)
            .map_err(io_err(&jpath))?;
        lock(&journal, root)?;
        let head = seal(&format!("qhm-journal {VERSION} {}", manifest.plan_sha256));
        journal
            .write_all(head.as_bytes())
            .and_then(|_| journal.sync_all())
            .map_err(io_err(&jpath))?;
        sync_dir(root)?;
        let plan_len = Plan::new(manifest.plan.clone())?.steps.len() as u32;
        let mut dir = CaptureDir {
            root: root.to_path_buf(),
            manifest,
            journal,
            frames: BTreeMap::new(),
            steps_done: 0,
            plan_len,
            complete: false,
        };
        dir.steps_done = dir.next_step(0);
        Ok(dir)
    }

    /// Opens an existing capture to resume it; `expect` must match its manifest
    /// (pass `None` to open whatever is there, e.g. for reading).
    pub fn open(root: &Path, expect: Option<&Manifest>) -> Result<CaptureDir, DirError> {
        let mpath = root.join(MANIFEST);
        if !mpath.exists() {
            let empty = fs::read_dir(root)
                .map(|mut d| d.next().is_none())
                .unwrap_or(false);
            return Err(if empty || !root.exists() {
                DirError::BadManifest {
                    path: mpath,
                    why: "missing: nothing to resume".into(),
                }
            } else {
                DirError::Foreign(root.to_path_buf())
            });
        }
        let (manifest, plan) = read_manifest_and_plan(root, mpath)?;
        if let Some(want) = expect {
            let scale = |m: &Manifest| {
                m.scale().map_or("a plan of no named scale".into(), |s| {
                    format!("--scale {}", s.name())
                })
            };
            let mismatch = if want.plan_sha256 != manifest.plan_sha256 {
                Some(("plan", scale(&manifest), scale(want)))
            } else if want.seed != manifest.seed {
                Some((
                    "seed",
                    format!("--seed {}", manifest.seed),
                    format!("--seed {}", want.seed),
                ))
            } else if want.sample != manifest.sample {
                Some((
                    "sample",
                    format!("--sample {}", shell_word(&manifest.sample)),
                    format!("--sample {}", shell_word(&want.sample)),
                ))
            } else if want.rig != manifest.rig {
                Some(("rig", manifest.rig.clone(), want.rig.clone()))
            } else if want.shard != manifest.shard {
                let share = |m: &Manifest| {
                    m.shard
                        .map_or("the whole plan".into(), |[k, n]| format!("--shard {k}/{n}"))
                };
                Some(("share", share(&manifest), share(want)))
            } else {
                None
            };
            if let Some((what, stored, asked)) = mismatch {
                return Err(DirError::Mismatch {
                    path: root.to_path_buf(),
                    what: what.into(),
                    stored,
                    asked,
                });
            }
        }
        let jpath = root.join(JOURNAL);
        let journal = OpenOptions::new()
            .read(true)
            .append(true)
            .open(&jpath)
            .map_err(io_err(&jpath))?;
        lock(&journal, root)?;
        let raw = fs::read(&jpath).map_err(io_err(&jpath))?;
        let mut dir = CaptureDir {
            root: root.to_path_buf(),
            manifest,
            journal,
            frames: BTreeMap::new(),
            steps_done: 0,
            plan_len: plan.steps.len() as u32,
            complete: false,
        };
        let keep = dir.replay(&raw, &plan)?;
        if keep < raw.len() {
            // A torn last line: the crash hit mid-append. Cut it off.
            dir.journal
                .set_len(keep as u64)
                .and_then(|_| dir.journal.sync_all())
                .map_err(io_err(&jpath))?;
        }
        dir.verify_frames()?;
        remove_temporaries(&root.join("frames"))?;
        Ok(dir)
    }

    /// Opens a capture to read it, beside other readers (a shared lock: many
    /// `qhm rectify --shard` processes at once; refused while a run writes
    /// it). Nothing is repaired, and frames are not checked here: see
    /// [`CaptureDir::verify_frames_where`].
    pub fn open_read(root: &Path) -> Result<CaptureDir, DirError> {
        let mpath = root.join(MANIFEST);
        if !mpath.exists() {
            return Err(if root.is_dir() {
                DirError::Foreign(root.to_path_buf())
            } else {
                DirError::BadManifest {
                    path: mpath,
                    why: "missing".into(),
                }
            });
        }
        let (manifest, plan) = read_manifest_and_plan(root, mpath)?;
        let jpath = root.join(JOURNAL);
        let journal = File::open(&jpath).map_err(io_err(&jpath))?;
        journal.try_lock_shared().map_err(|e| match e {
            fs::TryLockError::WouldBlock => DirError::Locked(root.to_path_buf()),
            fs::TryLockError::Error(source) => DirError::Io {
                path: jpath.clone(),
                source,
            },
        })?;
        let raw = fs::read(&jpath).map_err(io_err(&jpath))?;
        let mut dir = CaptureDir {
            root: root.to_path_buf(),
            manifest,
            journal,
            frames: BTreeMap::new(),
            steps_done: 0,
            plan_len: plan.steps.len() as u32,
            complete: false,
        };
        dir.replay(&raw, &plan)?;
        Ok(dir)
    }

    /// Checks the size and sha256 of the journaled frames whose path
    /// (relative to the capture) `wanted` accepts.
    pub fn verify_frames_where(&self, wanted: impl Fn(&str) -> bool) -> Result<(), DirError> {
        self.verify(self.frames.values().filter(|r| wanted(&r.path)))
    }

    /// Reads the journal; returns how many bytes of it are whole lines.
    fn replay(&mut self, raw: &[u8], plan: &Plan) -> Result<usize, DirError> {
        let jpath = self.root.join(JOURNAL);
        let corrupt = |line: usize, why: &str| DirError::CorruptJournal {
            path: jpath.clone(),
            line,
            why: why.into(),
        };
        let whole = raw.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        self.steps_done = self.next_step(0);
        let text = std::str::from_utf8(&raw[..whole]).map_err(|_| corrupt(0, "not UTF-8"))?;
        for (i, line) in text.lines().enumerate() {
            let n = i + 1;
            let body = unseal(line).ok_or_else(|| corrupt(n, "checksum mismatch"))?;
            let f: Vec<&str> = body.split(' ').collect();
            if self.complete {
                return Err(corrupt(n, "lines after `complete`"));
            }
            match (n, f.as_slice()) {
                (1, ["qhm-journal", v, sha]) => {
                    if *v != VERSION.to_string() || *sha != self.manifest.plan_sha256 {
                        return Err(corrupt(n, "journal of another plan or version"));
                    }
                }
                (1, _) => return Err(corrupt(n, "missing qhm-journal header")),
                (_, ["frame", s, k, c, sha, bytes, path]) => {
                    let key: FrameKey = (
                        s.parse().map_err(|_| corrupt(n, "bad step"))?,
                        k.parse().map_err(|_| corrupt(n, "bad scan index"))?,
                        c.parse().map_err(|_| corrupt(n, "bad camera"))?,
                    );
                    let step = plan
                        .steps
                        .get(key.0 as usize)
                        .ok_or_else(|| corrupt(n, "step beyond the plan"))?;
                    // Frames of a step come trigger by trigger, cameras in
                    // the step's order (as run_step writes them).
                    let nth = self
                        .frames
                        .range((key.0, 0, 0)..=(key.0, u32::MAX, u8::MAX))
                        .count();
                    let cams = &step.cameras;
                    let next = (!cams.is_empty() && nth < step.frames())
                        .then(|| ((nth / cams.len()) as u32, cams[nth % cams.len()]));
                    if key.0 != self.steps_done
                        || next != Some((key.1, key.2))
                        || *path != step.frame_path(key.1 as usize, key.2)
                    {
                        return Err(corrupt(n, "frame out of plan order"));
                    }
                    let rec = FrameRecord {
                        path: path.to_string(),
                        bytes: bytes.parse().map_err(|_| corrupt(n, "bad size"))?,
                        sha256: sha.to_string(),
                    };
                    if self.frames.insert(key, rec).is_some() {
                        return Err(corrupt(n, "frame journaled twice"));
                    }
                }
                (_, ["step", s]) => {
                    if *s != self.steps_done.to_string() {
                        return Err(corrupt(n, "step completed out of order"));
                    }
                    let step = &plan.steps[self.steps_done as usize];
                    let have = self.frames.range((step.index, 0, 0)..).count();
                    if have != step.frames() {
                        return Err(corrupt(n, "step marked done with frames missing"));
                    }
                    self.steps_done = self.next_step(self.steps_done + 1);
                }
                (_, ["complete", count]) => {
                    if self.steps_done as usize != plan.steps.len()
                        || *count != self.frames.len().to_string()
                    {
                        return Err(corrupt(n, "complete before the plan's end"));
                    }
                    self.complete = true;
                }
                _ => return Err(corrupt(n, "unknown line")),
            }
        }
        if whole == 0 {
            return Err(corrupt(1, "empty journal"));
        }
        Ok(whole)
    }

    /// Checks every journaled frame's size and sha256.
    fn verify_frames(&self) -> Result<(), DirError> {
        self.verify(self.frames.values())
    }

    fn verify<'a>(&self, records: impl Iterator<Item = &'a FrameRecord>) -> Result<(), DirError> {
        for rec in records {
            let path = self.root.join(&rec.path);
            let bad = |why: String| DirError::BadFrame {
                path: self.root.clone(),
                frame: rec.path.clone(),
                why,
            };
            let data = fs::read(&path).map_err(|e| bad(format!("unreadable: {e}")))?;
            if data.len() as u64 != rec.bytes || hex(&Sha256::digest(&data)) != rec.sha256 {
                return Err(bad("does not match its journal checksum".into()));
            }
        }
        Ok(())
    }

    pub fn root(&self) -> &Path {
        &self.root
    }
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }
    /// The plan the manifest describes.
    pub fn plan(&self) -> Result<Plan, DirError> {
        Ok(Plan::new(self.manifest.plan.clone())?)
    }
    /// The next step to run (all before it are finished, or another
    /// share's): resume starts at this index; the plan's length when done.
    pub fn steps_done(&self) -> u32 {
        self.steps_done
    }
    /// Whether this capture (or share) takes plan step `index`.
    pub fn takes(&self, index: u32) -> bool {
        self.manifest.takes(index)
    }
    /// Frames this capture (or share) takes of its plan.
    pub fn planned_frames(&self, plan: &Plan) -> usize {
        (plan.steps.iter())
            .filter(|s| self.takes(s.index))
            .map(|s| s.frames())
            .sum()
    }
    /// The first step at or after `from` that this capture takes.
    fn next_step(&self, from: u32) -> u32 {
        (from..self.plan_len)
            .find(|&i| self.takes(i))
            .unwrap_or(self.plan_len)
    }
    pub fn is_complete(&self) -> bool {
        self.complete
    }
    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }
    pub fn has_frame(&self, key: FrameKey) -> bool {
        self.frames.contains_key(&key)
    }
    /// The journaled frames in plan order.
    pub fn frames(&self) -> impl Iterator<Item = (&FrameKey, &FrameRecord)> {
        self.frames.iter()
    }

    /// Writes a frame durably and journals it. Frames of a step must be
    /// written in (scan position, camera) order.
    pub fn write_frame(
        &mut self,
        key: FrameKey,
        rel_path: &str,
        png: &[u8],
    ) -> Result<(), DirError> {
        self.write_frames(&[(key, rel_path, png)])
    }

    /// Writes frames durably, then journals them, in the order given (as
    /// [`CaptureDir::write_frame`] one by one would): every file first, then
    /// one sync of each file, of each directory and of the journal for all
    /// of them, instead of three per frame.
    pub fn write_frames(&mut self, frames: &[(FrameKey, &str, &[u8])]) -> Result<(), DirError> {
        write_all_durably(&self.root, frames.iter().map(|&(_, rel, data)| (rel, data)))?;
        let mut lines = String::new();
        for &(key, rel_path, png) in frames {
            let sha = hex(&Sha256::digest(png));
            lines.push_str(&seal(&format!(
                "frame {} {} {} {sha} {} {rel_path}",
                key.0,
                key.1,
                key.2,
                png.len()
            )));
            self.frames.insert(
                key,
                FrameRecord {
                    path: rel_path.into(),
                    bytes: png.len() as u64,
                    sha256: sha,
                },
            );
        }
        self.append_sealed(&lines)
    }

    /// Marks the next step finished.
    pub fn step_done(&mut self, step: u32) -> Result<(), DirError> {
        debug_assert_eq!(step, self.steps_done);
        self.append(&format!("step {step}"))?;
        self.steps_done = self.next_step(step + 1);
        Ok(())
    }

    /// Marks the capture finished.
    pub fn finish(&mut self) -> Result<(), DirError> {
        self.append(&format!("complete {}", self.frames.len()))?;
        self.complete = true;
        Ok(())
    }

    fn append(&mut self, line: &str) -> Result<(), DirError> {
        self.append_sealed(&seal(line))
    }

    /// Appends sealed lines and syncs the journal.
    fn append_sealed(&mut self, lines: &str) -> Result<(), DirError> {
        let path = self.root.join(JOURNAL);
        self.journal
            .write_all(lines.as_bytes())
            .and_then(|_| self.journal.sync_data())
            .map_err(io_err(&path))
    }
}

/// The share directories `K-of-N` in `root/shards`, as (k, n, path).
pub fn list_shards(root: &Path) -> Result<Vec<(u32, u32, PathBuf)>, DirError> {
    let dir = root.join(SHARDS);
    let Ok(entries) = fs::read_dir(&dir) else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for e in entries {
        let e = e.map_err(io_err(&dir))?;
        let name = e.file_name();
        let parsed = name.to_str().and_then(|n| {
            let (k, n) = n.split_once("-of-")?;
            Some((k.parse::<u32>().ok()?, n.parse::<u32>().ok()?))
        });
        if let Some((k, n)) = parsed.filter(|&(k, n)| k >= 1 && k <= n)
            && e.path().is_dir()
        {
            out.push((k, n, e.path()));
        }
    }
    out.sort();
    Ok(out)
}

/// Joins the N finished shares in `root/shards/` into the capture `root`
/// (module docs): its capture.toml, journal and frames (hard links, or
/// copies) become those of an unsharded run, and the shares are removed.
/// Refuses, naming what is wrong, a `root` that already holds a capture,
/// missing or unfinished shares, shares of several splits, and shares of
/// another capture.
pub fn merge_shards(root: &Path) -> Result<CaptureDir, DirError> {
    let refuse = |path: &Path, why: String| DirError::Shards {
        path: path.to_path_buf(),
        why,
    };
    if root.join(MANIFEST).exists() {
        return Err(refuse(
            root,
            "already holds a capture (capture.toml); nothing to merge".into(),
        ));
    }
    let found = list_shards(root)?;
    let splits: std::collections::BTreeSet<u32> = found.iter().map(|s| s.1).collect();
    let shards_dir = root.join(SHARDS);
    let n = match splits.len() {
        0 => {
            return Err(refuse(
                &shards_dir,
                "no shares to merge; run `qhm capture run --sim --shard K/N` into this directory for K = 1..N first".into(),
            ));
        }
        1 => *splits.first().expect("one split"),
        _ => {
            let ns: Vec<String> = splits.iter().map(|n| n.to_string()).collect();
            return Err(refuse(
                &shards_dir,
                format!(
                    "holds shares of several splits (N = {}); remove the ones not wanted",
                    ns.join(", ")
                ),
            ));
        }
    };
    let missing: Vec<String> = (1..=n)
        .filter(|k| !found.iter().any(|s| s.0 == *k))
        .map(|k| format!("{k}/{n}"))
        .collect();
    if !missing.is_empty() {
        return Err(refuse(
            &shards_dir,
            format!(
                "missing share{} {} of {n}; run `qhm capture run --sim --shard K/{n}` for each",
                if missing.len() == 1 { "" } else { "s" },
                missing.join(", ")
            ),
        ));
    }
    let mut shares = Vec::new();
    for (k, n, path) in &found {
        let d = CaptureDir::open(path, None)?;
        if d.manifest.shard != Some([*k, *n]) {
            return Err(refuse(
                path,
                format!("is not share {k}/{n} (its capture.toml says otherwise)"),
            ));
        }
        if !d.is_complete() {
            return Err(refuse(
                path,
                format!(
                    "share {k}/{n} is not finished; continue it with `qhm capture run {} --resume -o {}`",
                    d.manifest.run_args(),
                    shell_word(&root.to_string_lossy())
                ),
            ));
        }
        shares.push(d);
    }
    let whole = |m: &Manifest| Manifest {
        shard: None,
        ..m.clone()
    };
    let manifest = whole(&shares[0].manifest);
    for (d, (k, n, path)) in shares.iter().zip(&found) {
        if whole(&d.manifest) != manifest {
            return Err(refuse(
                path,
                format!(
                    "share {k}/{n} is of another capture (plan, seed, sample or rig) than share 1/{n}"
                ),
            ));
        }
    }
    let plan = Plan::new(manifest.plan.clone())?;
    // The journal an unsharded run writes: every step's frames trigger by
    // trigger in the step's camera order, then the step; then `complete`.
    let mut journal = seal(&format!("qhm-journal {VERSION} {}", manifest.plan_sha256));
    let mut count = 0;
    let mut dirs = std::collections::BTreeSet::new();
    for step in &plan.steps {
        let share = &shares[(step.index % n) as usize];
        for k in 0..step.triggers() {
            for &c in &step.cameras {
                let key = (step.index, k as u32, c);
                let rec = share.frames.get(&key).ok_or_else(|| {
                    refuse(
                        share.root(),
                        format!("frame {key:?} is missing from its journal"),
                    )
                })?;
                journal += &seal(&format!(
                    "frame {} {} {} {} {} {}",
                    key.0, key.1, key.2, rec.sha256, rec.bytes, rec.path
                ));
                let (from, to) = (share.root.join(&rec.path), root.join(&rec.path));
                let parent = to.parent().unwrap_or(root).to_path_buf();
                if dirs.insert(parent.clone()) {
                    fs::create_dir_all(&parent).map_err(io_err(&parent))?;
                }
                // A merge interrupted before its journal may have linked it already.
                let _ = fs::remove_file(&to);
                if fs::hard_link(&from, &to).is_err() {
                    fs::copy(&from, &to).map_err(io_err(&to))?;
                }
                count += 1;
            }
        }
        journal += &seal(&format!("step {}", step.index));
    }
    journal += &seal(&format!("complete {count}"));
    for d in &dirs {
        sync_dir(d)?;
    }
    // capture.toml last: until it is there, the merge can simply be run again.
    write_durably(root, JOURNAL, journal.as_bytes())?;
    let text = toml::to_string(&manifest).map_err(|e| DirError::BadManifest {
        path: root.join(MANIFEST),
        why: e.to_string(),
    })?;
    write_durably(root, MANIFEST, text.as_bytes())?;
    drop(shares);
    fs::remove_dir_all(&shards_dir).map_err(io_err(&shards_dir))?;
    sync_dir(root)?;
    CaptureDir::open(root, None)
}

/// Whether `dir` (if it exists) holds no files but `*.tmp` ones.
fn only_temporaries(dir: &Path) -> Result<bool, DirError> {
    let Ok(entries) = fs::read_dir(dir) else {
        return Ok(!dir.exists());
    };
    for e in entries {
        let path = e.map_err(io_err(dir))?.path();
        let ok = if path.is_dir() {
            only_temporaries(&path)?
        } else {
            path.extension().is_some_and(|x| x == "tmp")
        };
        if !ok {
            return Ok(false);
        }
    }
    Ok(true)
}

/// Deletes `*.tmp` files a crash left mid-write (never a journaled frame).
fn remove_temporaries(dir: &Path) -> Result<(), DirError> {
    let Ok(entries) = fs::read_dir(dir) else {
        return Ok(());
    };
    for e in entries {
        let path = e.map_err(io_err(dir))?.path();
        if path.is_dir() {
            remove_temporaries(&path)?;
        } else if path.extension().is_some_and(|x| x == "tmp") {
            fs::remove_file(&path).map_err(io_err(&path))?;
        }
    }
    Ok(())
}

fn lock(journal: &File, root: &Path) -> Result<(), DirError> {
    journal.try_lock().map_err(|e| match e {
        fs::TryLockError::WouldBlock => DirError::Locked(root.to_path_buf()),
        fs::TryLockError::Error(source) => DirError::Io {
            path: root.join(JOURNAL),
            source,
        },
    })
}

/// Write to a temporary name, fsync, rename, fsync the directory.
fn write_durably(root: &Path, rel: &str, data: &[u8]) -> Result<(), DirError> {
    write_all_durably(root, [(rel, data)])
}

/// [`write_durably`] for several files at once: every file written first,
/// then one fsync of each, the renames, and one fsync of each directory.
fn write_all_durably<'a>(
    root: &Path,
    files: impl IntoIterator<Item = (&'a str, &'a [u8])>,
) -> Result<(), DirError> {
    let mut written = Vec::new();
    for (rel, data) in files {
        let path = root.join(rel);
        let parent = path.parent().unwrap_or(root).to_path_buf();
        fs::create_dir_all(&parent).map_err(io_err(&parent))?;
        let tmp = path.with_extension("tmp");
        let mut f = File::create(&tmp).map_err(io_err(&tmp))?;
        f.write_all(data).map_err(io_err(&tmp))?;
        written.push((f, tmp, path, parent));
    }
    for (f, tmp, ..) in &written {
        f.sync_all().map_err(io_err(tmp))?;
    }
    let mut parents: Vec<&Path> = Vec::new();
    for (_, tmp, path, parent) in &written {
        fs::rename(tmp, path).map_err(io_err(path))?;
        if !parents.contains(&parent.as_path()) {
            parents.push(parent);
        }
    }
    parents.into_iter().try_for_each(sync_dir)
}

fn sync_dir(dir: &Path) -> Result<(), DirError> {
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(io_err(dir))
}

/// The capture's manifest and its plan, checked: this format and version,
/// and a plan that still hashes to the recorded `plan_sha256`.
fn read_manifest_and_plan(root: &Path, mpath: PathBuf) -> Result<(Manifest, Plan), DirError> {
    let manifest = Manifest::read(root)?;
    if manifest.format != FORMAT || manifest.version != VERSION {
        return Err(DirError::BadManifest {
            path: mpath,
            why: format!(
                "format {:?} version {} (expected {FORMAT:?} version {VERSION})",
                manifest.format, manifest.version
            ),
        });
    }
    let plan = Plan::new(manifest.plan.clone())?;
    if plan_sha256(&plan) != manifest.plan_sha256 {
        return Err(DirError::BadManifest {
            path: mpath,
            why: "plan_sha256 does not match its plan (edited, or another qhm version)".into(),
        });
    }
    Ok((manifest, plan))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::Scale;

    fn setup() -> (tempfile::TempDir, Plan, Manifest) {
        let tmp = tempfile::tempdir().unwrap();
        let plan = Plan::new(PlanConfig::for_scale(Scale::Ci)).unwrap();
        let m = Manifest::new("sim", "marble", 7, &plan);
        (tmp, plan, m)
    }

    fn write_step(dir: &mut CaptureDir, plan: &Plan, s: usize) {
        let step = &plan.steps[s];
        for k in 0..step.triggers() {
            for &c in &step.cameras {
                let data = format!("frame {s} {k} {c}");
                dir.write_frame(
                    (s as u32, k as u32, c),
                    &step.frame_path(k, c),
                    data.as_bytes(),
                )
                .unwrap();
            }
        }
        dir.step_done(s as u32).unwrap();
    }

    #[test]
    fn create_write_reopen() {
        let (tmp, plan, m) = setup();
        let root = tmp.path().join("cap");
        let mut d = CaptureDir::create(&root, m.clone()).unwrap();
        write_step(&mut d, &plan, 0);
        write_step(&mut d, &plan, 1);
        let n = d.frame_count();
        drop(d);
        let d = CaptureDir::open(&root, Some(&m)).unwrap();
        assert_eq!(d.steps_done(), 2);
        assert_eq!(d.frame_count(), n);
        assert!(!d.is_complete());
    }

    /// A step written as one batch journals and stores what frame-by-frame
    /// writes do, and reopens the same.
    #[test]
    fn a_batch_of_frames_is_the_same_as_one_at_a_time() {
        let (tmp, plan, m) = setup();
        let one = tmp.path().join("one");
        let mut d = CaptureDir::create(&one, m.clone()).unwrap();
        write_step(&mut d, &plan, 0);
        drop(d);
        let batched = tmp.path().join("batched");
        let mut d = CaptureDir::create(&batched, m.clone()).unwrap();
        let step = &plan.steps[0];
        let frames: Vec<(FrameKey, String, String)> = (0..step.triggers())
            .flat_map(|k| step.cameras.iter().map(move |&c| (k, c)))
            .map(|(k, c)| {
                let key = (0, k as u32, c);
                (key, step.frame_path(k, c), format!("frame 0 {k} {c}"))
            })
            .collect();
        let refs: Vec<_> = (frames.iter())
            .map(|(key, path, data)| (*key, path.as_str(), data.as_bytes()))
            .collect();
        d.write_frames(&refs).unwrap();
        d.step_done(0).unwrap();
        drop(d);
        assert_eq!(
            fs::read(one.join(JOURNAL)).unwrap(),
            fs::read(batched.join(JOURNAL)).unwrap()
        );
        let d = CaptureDir::open(&batched, Some(&m)).unwrap();
        assert_eq!((d.steps_done(), d.frame_count()), (1, frames.len()));
        for (key, path, data) in &frames {
            assert!(d.has_frame(*key));
            assert_eq!(fs::read(batched.join(path)).unwrap(), data.as_bytes());
            assert!(!batched.join(path).with_extension("tmp").exists());
        }
    }

    #[test]
    fn the_calibration_is_recorded_beside_the_capture() {
        let (tmp, plan, mut m) = setup();
        let root = tmp.path().join("run/capture");
        let cal = tmp.path().join("run/calibration.toml");
        fs::create_dir_all(tmp.path().join("run")).unwrap();
        assert!(m.record_calibration(&root, &cal).is_err(), "a missing file");
        fs::write(&cal, "format = \"qhm-calibration\"\n").unwrap();
        m.record_calibration(&root, &cal).unwrap();
        assert_eq!(m.calibration.as_deref(), Some("../calibration.toml"));
        CaptureDir::create(&root, m.clone()).unwrap();
        let back = Manifest::read(&root).unwrap();
        assert_eq!(back, m);
        let (file, sha) = back.calibration_file(&root).unwrap();
        assert_eq!(fs::read(&file).unwrap(), fs::read(&cal).unwrap());
        assert_eq!(sha, sha256_hex(&fs::read(&cal).unwrap()));
        // A share resolves it from the whole capture's directory.
        let share = Manifest {
            shard: Some([1, 2]),
            ..back.clone()
        };
        fs::create_dir_all(shard_dir(&root, 1, 2)).unwrap();
        let (file, _) = share.calibration_file(&shard_dir(&root, 1, 2)).unwrap();
        assert!(fs::read(&file).is_ok(), "{}", file.display());
        // A capture.toml written before the record reads, with none.
        let old = Manifest::new("sim", "marble", 7, &plan);
        let text = toml::to_string(&old).unwrap();
        assert!(!text.contains("calibration"));
        assert_eq!(
            toml::from_str::<Manifest>(&text)
                .unwrap()
                .calibration_file(&root),
            None
        );
        assert_eq!(
            relative_path(Path::new("/a/b"), Path::new("/c/d.toml")),
            Path::new("/c/d.toml")
        );
        assert_eq!(
            relative_path(Path::new("/a/b/c"), Path::new("/a/b/c/d.toml")),
            Path::new("d.toml")
        );
    }

    #[test]
    fn unstarted_capture_is_replaced_started_one_is_not() {
        let (tmp, plan, m) = setup();
        let root = tmp.path().join("cap");
        drop(CaptureDir::create(&root, m.clone()).unwrap());
        assert!(CaptureDir::is_unstarted(&root).unwrap());
        // Another sample and seed: still replaced, it holds no frame.
        let other = Manifest::new("sim", "sponge", 9, &plan);
        let d = CaptureDir::create(&root, other.clone()).unwrap();
        assert_eq!(d.manifest().sample, "sponge");
        // Held by a run: not replaced.
        assert!(matches!(
            CaptureDir::create(&root, m.clone()),
            Err(DirError::Locked(_))
        ));
        assert!(d.discard_if_unstarted().unwrap());
        assert_eq!(
            fs::read_dir(&root).unwrap().count(),
            0,
            "a run without frames leaves nothing"
        );
        // One frame journaled: kept.
        let mut d = CaptureDir::create(&root, m.clone()).unwrap();
        let step = &plan.steps[0];
        let c = step.cameras[0];
        d.write_frame((0, 0, c), &step.frame_path(0, c), b"f")
            .unwrap();
        assert!(!d.discard_if_unstarted().unwrap());
        assert!(!CaptureDir::is_unstarted(&root).unwrap());
        assert!(matches!(
            CaptureDir::create(&root, other),
            Err(DirError::Exists(_))
        ));
        // A damaged manifest: not replaced.
        let root3 = tmp.path().join("cap3");
        drop(CaptureDir::create(&root3, m.clone()).unwrap());
        fs::write(root3.join(MANIFEST), b"format = 3").unwrap();
        assert!(!CaptureDir::is_unstarted(&root3).unwrap());
        // A user's file beside an unstarted capture: kept too.
        let root2 = tmp.path().join("cap2");
        drop(CaptureDir::create(&root2, m.clone()).unwrap());
        fs::write(root2.join("notes.txt"), b"mine").unwrap();
        assert!(!CaptureDir::is_unstarted(&root2).unwrap());
        assert!(matches!(
            CaptureDir::create(&root2, m),
            Err(DirError::Exists(_))
        ));
    }

    #[test]
    fn swapped_frames_of_a_step_are_refused() {
        let (tmp, plan, m) = setup();
        let root = tmp.path().join("cap");
        let mut d = CaptureDir::create(&root, m.clone()).unwrap();
        write_step(&mut d, &plan, 0);
        drop(d);
        let jpath = root.join(JOURNAL);
        let text = fs::read_to_string(&jpath).unwrap();
        let mut lines: Vec<&str> = text.lines().collect();
        assert!(lines[1].starts_with("frame ") && lines[2].starts_with("frame "));
        lines.swap(1, 2);
        let swapped = lines.join("\n") + "\n";
        fs::write(&jpath, &swapped).unwrap();
        let e = CaptureDir::open(&root, Some(&m)).err().unwrap();
        assert!(e.to_string().contains("out of plan order"), "{e}");
        assert!(e.to_string().contains("line 2"), "{e}");
        assert_eq!(fs::read_to_string(&jpath).unwrap(), swapped);
    }

    #[test]
    fn mismatch_names_both_settings_and_run_args_resume() {
        let (tmp, _plan, m) = setup();
        let root = tmp.path().join("cap");
        drop(CaptureDir::create(&root, m.clone()).unwrap());
        let default = Plan::new(PlanConfig::for_scale(Scale::Default)).unwrap();
        let asked = Manifest::new("sim", "marble", 7, &default);
        let e = CaptureDir::open(&root, Some(&asked))
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("different plan (--scale ci; this run asked for --scale default)"),
            "{e}"
        );
        assert_eq!(m.run_args(), "--sim --scale ci --sample marble --seed 7");
        let real = Manifest::new("serial:/dev/tty ACM0", "my sample.toml", 3, &default);
        assert_eq!(
            real.run_args(),
            "--port '/dev/tty ACM0' --scale default --sample 'my sample.toml' --seed 3"
        );
    }

    #[test]
    fn second_open_is_locked() {
        let (tmp, _plan, m) = setup();
        let root = tmp.path().join("cap");
        let _d = CaptureDir::create(&root, m.clone()).unwrap();
        assert!(matches!(
            CaptureDir::open(&root, Some(&m)),
            Err(DirError::Locked(_))
        ));
    }

    #[test]
    fn torn_last_line_is_cut_and_resumes() {
        let (tmp, plan, m) = setup();
        let root = tmp.path().join("cap");
        let mut d = CaptureDir::create(&root, m.clone()).unwrap();
        write_step(&mut d, &plan, 0);
        drop(d);
        let jpath = root.join(JOURNAL);
        let good = fs::read(&jpath).unwrap();
        let mut torn = good.clone();
        torn.extend_from_slice(b"frame 1 0 3 abc");
        fs::write(&jpath, &torn).unwrap();
        let d = CaptureDir::open(&root, Some(&m)).unwrap();
        assert_eq!(d.steps_done(), 1);
        drop(d);
        assert_eq!(fs::read(&jpath).unwrap(), good);
    }

    #[test]
    fn damage_is_refused_and_left_alone() {
        let (tmp, plan, m) = setup();
        let root = tmp.path().join("cap");
        let mut d = CaptureDir::create(&root, m.clone()).unwrap();
        write_step(&mut d, &plan, 0);
        drop(d);
        // A changed frame.
        let f = root.join(plan.steps[0].frame_path(0, plan.steps[0].cameras[0]));
        fs::write(&f, b"other bytes").unwrap();
        assert!(matches!(
            CaptureDir::open(&root, Some(&m)),
            Err(DirError::BadFrame { .. })
        ));
        // A flipped byte inside the journal.
        let jpath = root.join(JOURNAL);
        let mut j = fs::read(&jpath).unwrap();
        j[60] ^= 1;
        fs::write(&jpath, &j).unwrap();
        let e = CaptureDir::open(&root, Some(&m)).err().unwrap();
        assert!(matches!(e, DirError::CorruptJournal { .. }), "{e}");
        assert_eq!(fs::read(&jpath).unwrap(), j, "refused, not rewritten");
    }

    #[test]
    fn foreign_and_existing_dirs_are_refused() {
        let (tmp, plan, m) = setup();
        let foreign = tmp.path().join("photos");
        fs::create_dir_all(&foreign).unwrap();
        fs::write(foreign.join("holiday.jpg"), b"x").unwrap();
        assert!(matches!(
            CaptureDir::create(&foreign, m.clone()),
            Err(DirError::Foreign(_))
        ));
        assert!(matches!(
            CaptureDir::open(&foreign, Some(&m)),
            Err(DirError::Foreign(_))
        ));
        let root = tmp.path().join("cap");
        let mut d = CaptureDir::create(&root, m.clone()).unwrap();
        write_step(&mut d, &plan, 0);
        drop(d);
        assert!(matches!(
            CaptureDir::create(&root, m.clone()),
            Err(DirError::Exists(_))
        ));
        let other = Manifest::new("sim", "marble", 8, &plan);
        assert!(matches!(
            CaptureDir::open(&root, Some(&other)),
            Err(DirError::Mismatch { .. })
        ));
        fs::write(root.join(MANIFEST), "format = \"something\"\n").unwrap();
        assert!(matches!(
            CaptureDir::open(&root, None),
            Err(DirError::BadManifest { .. })
        ));
    }
}
