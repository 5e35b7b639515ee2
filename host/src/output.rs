//! The output rule every `qhm` command follows, so no command loses data
//! without being asked:
//!
//! - A **file** output that exists is replaced only with `--force`
//!   ([`check_file_output`]); `-` (stdout) is always fine.
//! - A **directory** output ([`StagedDir`]) is written only into an absent or
//!   empty directory, or, with `--force`, over a directory that holds the same
//!   kind of qhm output ([`OutputKind`], recognised by its marker file). Any
//!   other directory is refused, even with `--force`. The output is written
//!   into a temporary sibling `.<name>.tmp-<pid>` and renamed into place by
//!   [`StagedDir::commit`], so an interrupted command never leaves a half
//!   output, and a replaced output keeps no stale files of the old one.
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! use host::output::{OutputKind, StagedDir};
//! let out = std::path::Path::new("report");
//! let staged = StagedDir::begin(out, OutputKind::Report, false)?;
//! std::fs::write(staged.path().join("index.html"), "<html></html>")?;
//! staged.commit()?; // `report/` now holds index.html and the marker
//! # Ok(())
//! # }
//! ```

use std::ffi::OsString;
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// Marker file a [`StagedDir`] writes for kinds without a marker of their own.
pub const MARKER: &str = ".qhm-output";

/// Refuses an existing `path` unless `force`. `-` means stdout and always passes.
pub fn check_file_output(path: &Path, force: bool) -> Result<()> {
    if path == Path::new("-") || force {
        return Ok(());
    }
    if path.is_dir() {
        bail!("{} is a directory, not a file", path.display());
    }
    if path.exists() {
        bail!("{} exists; pass --force to replace it", path.display());
    }
    Ok(())
}

/// A kind of directory output, and how to recognise one on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputKind {
    /// A material model (`qhm fit`): `manifest.toml` with `format = "qhm-material"`.
    Model,
    /// A model report (`qhm report`): the [`MARKER`] file saying `report`
    /// (reports older than the marker: an `index.html` titled "qhm model report").
    Report,
}

impl OutputKind {
    /// What the kind is called in messages.
    pub fn name(self) -> &'static str {
        match self {
            OutputKind::Model => "material model",
            OutputKind::Report => "qhm report",
        }
    }

    /// The marker this kind gets from [`StagedDir`] (`None`: it writes its own).
    fn marker_text(self) -> Option<&'static str> {
        match self {
            OutputKind::Model => None,
            OutputKind::Report => Some("kind = \"report\"\n"),
        }
    }

    /// Whether `dir` holds an output of this kind.
    pub fn is_in(self, dir: &Path) -> bool {
        let read = |f: &str| fs::read_to_string(dir.join(f)).unwrap_or_default();
        match self {
            OutputKind::Model => read("manifest.toml")
                .lines()
                .any(|l| l.replace(' ', "") == format!("format=\"{}\"", qhm_model::format::FORMAT)),
            OutputKind::Report => {
                self.marker_text().is_some_and(|m| read(MARKER) == m)
                    || read("index.html").contains("<title>qhm model report</title>")
            }
        }
    }
}

/// A directory output being written: write into [`StagedDir::path`], then
/// [`StagedDir::commit`]. Dropped without a commit, it removes what it wrote
/// and leaves the target as it was.
#[derive(Debug)]
pub struct StagedDir {
    target: PathBuf,
    staging: PathBuf,
    kind: OutputKind,
    committed: bool,
}

impl StagedDir {
    /// Checks the rule for `target` (see the module docs) and creates the
    /// empty staging directory beside it. Call it before the long work, so a
    /// refused output costs nothing.
    pub fn begin(target: &Path, kind: OutputKind, force: bool) -> Result<StagedDir> {
        let target = resolve(target)?;
        if target.exists() {
            if !target.is_dir() {
                bail!("{} exists and is not a directory", target.display());
            }
            if !is_empty(&target)? {
                if !kind.is_in(&target) {
                    bail!(
                        "{} is not empty and does not hold a {}; refusing to write into it (choose an empty or new directory)",
                        target.display(),
                        kind.name()
                    );
                }
                if !force {
                    bail!(
                        "{} already holds a {}; pass --force to replace it",
                        target.display(),
                        kind.name()
                    );
                }
            }
        }
        let parent = target.parent().unwrap_or(Path::new("."));
        fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
        let name = target.file_name().unwrap_or_default();
        remove_stale_staging(parent, name);
        let staging = sibling(&target, "tmp", std::process::id());
        if staging.exists() {
            fs::remove_dir_all(&staging)
                .with_context(|| format!("removing {}", staging.display()))?;
        }
        fs::create_dir(&staging).with_context(|| format!("creating {}", staging.display()))?;
        if let Some(text) = kind.marker_text() {
            fs::write(staging.join(MARKER), text)
                .with_context(|| format!("writing {}", staging.join(MARKER).display()))?;
        }
        Ok(StagedDir {
            target,
            staging,
            kind,
            committed: false,
        })
    }

    /// The directory to write into (the temporary sibling).
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// Where the output goes on commit.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Puts the written output in place of the target. An old output of the
    /// same kind is removed only now; an empty target directory is kept and
    /// filled (it may be a mount point or someone's working directory).
    pub fn commit(mut self) -> Result<PathBuf> {
        let target = self.target.clone();
        if target.is_dir() && is_empty(&target)? {
            move_entries(&self.staging, &target)?;
            fs::remove_dir(&self.staging)
                .with_context(|| format!("removing {}", self.staging.display()))?;
        } else if target.exists() {
            // Re-check: something may have appeared while we worked.
            if !self.kind.is_in(&target) {
                self.committed = true; // keep the new output where it is
                bail!(
                    "{} changed while writing and no longer holds a {}; the new output is left in {}",
                    target.display(),
                    self.kind.name(),
                    self.staging.display()
                );
            }
            let old = sibling(&target, "old", std::process::id());
            fs::rename(&target, &old)
                .with_context(|| format!("moving {} aside", target.display()))?;
            if let Err(e) = fs::rename(&self.staging, &target) {
                let _ = fs::rename(&old, &target);
                return Err(e).with_context(|| format!("renaming into {}", target.display()));
            }
            self.committed = true;
            fs::remove_dir_all(&old)
                .with_context(|| format!("removing the old output {}", old.display()))?;
        } else {
            fs::rename(&self.staging, &target)
                .with_context(|| format!("renaming into {}", target.display()))?;
        }
        self.committed = true;
        Ok(target)
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
        }
    }
}

/// `target` with a real last component (`.` or `dir/..` resolved), so the
/// staging directory can be its sibling.
fn resolve(target: &Path) -> Result<PathBuf> {
    let plain = target.file_name().is_some_and(|n| n != "." && n != "..");
    if plain {
        return Ok(target.to_path_buf());
    }
    fs::canonicalize(target).with_context(|| format!("resolving {}", target.display()))
}

fn is_empty(dir: &Path) -> Result<bool> {
    Ok(fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .next()
        .is_none())
}

/// `.<name>.<what>-<pid>` beside `target`.
fn sibling(target: &Path, what: &str, pid: u32) -> PathBuf {
    let mut n = OsString::from(".");
    n.push(target.file_name().unwrap_or_default());
    n.push(format!(".{what}-{pid}"));
    target.with_file_name(n)
}

/// Moves every entry of `from` into `to`, the kind's marker last (a half
/// moved output then lacks its marker and is not taken for a whole one).
fn move_entries(from: &Path, to: &Path) -> Result<()> {
    let mut names: Vec<OsString> = fs::read_dir(from)
        .with_context(|| format!("reading {}", from.display()))?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()
        .with_context(|| format!("reading {}", from.display()))?;
    let last = |n: &OsString| n == MARKER || n == "manifest.toml";
    names.sort_by_key(|n| (last(n), n.clone()));
    for n in names {
        fs::rename(from.join(&n), to.join(&n))
            .with_context(|| format!("moving {} into {}", n.to_string_lossy(), to.display()))?;
    }
    Ok(())
}

/// Removes `.<name>.tmp-<pid>` / `.<name>.old-<pid>` siblings left by a
/// killed run (their process is gone); best effort.
fn remove_stale_staging(parent: &Path, name: &std::ffi::OsStr) {
    let Ok(entries) = fs::read_dir(parent) else {
        return;
    };
    let prefix = format!(".{}.", name.to_string_lossy());
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(rest) = file.to_str().and_then(|f| f.strip_prefix(&prefix)) else {
            continue;
        };
        let pid = rest
            .strip_prefix("tmp-")
            .or_else(|| rest.strip_prefix("old-"))
            .and_then(|p| p.parse::<u32>().ok());
        if let Some(pid) = pid
            && pid != std::process::id()
            && !process_alive(pid)
        {
            let _ = fs::remove_dir_all(e.path());
        }
    }
}

#[cfg(unix)]
fn process_alive(pid: u32) -> bool {
    use nix::errno::Errno;
    use nix::sys::signal::kill;
    use nix::unistd::Pid;
    let Ok(pid) = i32::try_from(pid) else {
        return true;
    };
    !matches!(kill(Pid::from_raw(pid), None), Err(Errno::ESRCH))
}

#[cfg(not(unix))]
fn process_alive(_pid: u32) -> bool {
    true // unknown: keep it
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absent_target_is_created_and_drop_leaves_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("rep");
        let s = StagedDir::begin(&out, OutputKind::Report, false).unwrap();
        fs::write(s.path().join("index.html"), "x").unwrap();
        drop(s);
        assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 0);
        let s = StagedDir::begin(&out, OutputKind::Report, false).unwrap();
        fs::write(s.path().join("index.html"), "x").unwrap();
        s.commit().unwrap();
        assert!(OutputKind::Report.is_in(&out));
        assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 1);
    }

    #[test]
    fn same_kind_needs_force_and_keeps_no_stale_files() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("rep");
        let s = StagedDir::begin(&out, OutputKind::Report, false).unwrap();
        fs::write(s.path().join("old.png"), "old").unwrap();
        s.commit().unwrap();
        let e = StagedDir::begin(&out, OutputKind::Report, false).unwrap_err();
        assert!(e.to_string().contains("--force"), "{e}");
        assert!(out.join("old.png").exists());
        let s = StagedDir::begin(&out, OutputKind::Report, true).unwrap();
        fs::write(s.path().join("new.png"), "new").unwrap();
        s.commit().unwrap();
        assert!(out.join("new.png").exists() && !out.join("old.png").exists());
        assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 1);
    }

    #[test]
    fn foreign_dir_is_refused_even_with_force() {
        let tmp = tempfile::tempdir().unwrap();
        fs::write(tmp.path().join("index.html"), "mine").unwrap();
        for kind in [OutputKind::Report, OutputKind::Model] {
            let e = StagedDir::begin(tmp.path(), kind, true).unwrap_err();
            assert!(e.to_string().contains("refusing"), "{e}");
        }
        assert_eq!(
            fs::read_to_string(tmp.path().join("index.html")).unwrap(),
            "mine"
        );
        assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 1);
    }

    #[test]
    fn empty_dir_is_kept_and_filled() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("m");
        fs::create_dir(&out).unwrap();
        let s = StagedDir::begin(&out, OutputKind::Model, false).unwrap();
        fs::write(
            s.path().join("manifest.toml"),
            "format = \"qhm-material\"\n",
        )
        .unwrap();
        s.commit().unwrap();
        assert!(OutputKind::Model.is_in(&out));
        assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 1);
    }

    #[cfg(unix)]
    #[test]
    fn a_killed_run_s_staging_is_cleaned_up() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("model");
        // No process has this pid (above Linux's pid_max of 2^22).
        let stale = tmp.path().join(".model.tmp-99999999");
        fs::create_dir(&stale).unwrap();
        fs::write(stale.join("half.exr"), "x").unwrap();
        let other = tmp.path().join(".modelx.tmp-99999999");
        fs::create_dir(&other).unwrap();
        let s = StagedDir::begin(&out, OutputKind::Model, false).unwrap();
        assert!(!stale.exists());
        assert!(other.exists(), "another output's staging is not ours");
        drop(s);
    }

    #[test]
    fn files_need_force() {
        let tmp = tempfile::tempdir().unwrap();
        let f = tmp.path().join("a.png");
        check_file_output(&f, false).unwrap();
        fs::write(&f, "x").unwrap();
        let e = check_file_output(&f, false).unwrap_err().to_string();
        assert!(e.contains("a.png") && e.contains("--force"), "{e}");
        check_file_output(&f, true).unwrap();
        check_file_output(Path::new("-"), false).unwrap();
    }
}
