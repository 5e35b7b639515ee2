//! Rectifying a capture in shares, on many machines or cores, with an
//! existing scheduler (a Slurm job array, GNU parallel) running one process
//! per share:
//!
//! ```text
//! CAPTURE_DIR/rectified/stripes/NNNNNN.exr, lamps/NNNNNN.exr   each share writes its own images
//! CAPTURE_DIR/rectified/shards/K-of-N.toml                     what share K of N wrote
//! CAPTURE_DIR/rectified/index.toml                             written by the merge, as an unsharded run would
//! ```
//!
//! Share K of N takes the shots whose position in the capture's shot list
//! mod N is K - 1. An image's file is numbered by its place in the whole
//! dataset, not the share's, so the shares' images together are the
//! unsharded run's, file for file. A share's partial index is written last
//! (a share killed midway has none and counts as missing). [`merge`] checks
//! that all N partial indexes are there and agree (the same capture,
//! calibration, settings and grid), writes index.toml byte for byte as
//! [`crate::pipeline::rectify_capture`] would, and removes the partial
//! indexes and any image no entry names (left by an earlier run).

use std::collections::BTreeSet;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::image::ImageF;
use crate::rectified::{
    self, CalibrationSummary, Index, LampEntry, StripeEntry, VERSION, check_size, grid_entry,
    lamp_file, stripe_file,
};
use crate::rectify::Grid;
use crate::{Error, Result, exr_io};

/// `format` of a partial index.
pub const SHARD_FORMAT: &str = "qhm-rectified-shard";
/// Folder of the partial indexes inside the rectified dataset.
pub const SHARDS_DIR: &str = "shards";

/// Share `k` (1-based) of `n`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub k: usize,
    pub n: usize,
}

impl Shard {
    /// Whether the item at `index` (0-based) belongs to this share.
    pub fn takes(&self, index: usize) -> bool {
        index % self.n == self.k - 1
    }

    /// File name of its partial index: `K-of-N.toml`.
    pub fn file_name(&self) -> String {
        format!("{}-of-{}.toml", self.k, self.n)
    }

    /// The share a partial index's file name names, if it is one.
    fn from_file_name(name: &str) -> Option<Shard> {
        let (k, n) = name.strip_suffix(".toml")?.split_once("-of-")?;
        let s = Shard {
            k: k.parse().ok()?,
            n: n.parse().ok()?,
        };
        (s.n >= 1 && (1..=s.n).contains(&s.k)).then_some(s)
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

impl FromStr for Shard {
    type Err = String;

    /// `K/N` with 1 <= K <= N.
    fn from_str(s: &str) -> std::result::Result<Shard, String> {
        let bad = || format!("{s:?} is not K/N with 1 <= K <= N (e.g. 2/3)");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let k: usize = k.trim().parse().map_err(|_| bad())?;
        let n: usize = n.trim().parse().map_err(|_| bad())?;
        if n == 0 || k == 0 || k > n {
            return Err(bad());
        }
        Ok(Shard { k, n })
    }
}

/// What a share's images depend on besides its shots, as the caller names
/// it; every share of a merge, and the merge itself, must agree on all.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardSource {
    /// The capture (its plan, seed and sample).
    pub capture: String,
    /// The calibration file (a digest of it).
    pub calibration: String,
    /// The rectification settings.
    pub settings: String,
}

/// `rectified/shards/K-of-N.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardIndex {
    pub format: String,
    pub version: u32,
    pub shard: usize,
    pub shards: usize,
    pub source: ShardSource,
    /// Stripe and lamp images of the whole dataset.
    pub stripes_total: usize,
    pub lamps_total: usize,
    /// This share's part of index.toml.
    pub index: Index,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
    move |source| Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn remove_if_there(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io(path)(e)),
        _ => Ok(()),
    }
}

/// The partial indexes in `root/shards`, by share, in file-name order.
fn partials(root: &Path) -> Result<Vec<(Shard, PathBuf)>> {
    let dir = root.join(SHARDS_DIR);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Ok(Vec::new());
    };
    let mut out = Vec::new();
    for e in entries {
        let e = e.map_err(io(&dir))?;
        if let Some(s) = e.file_name().to_str().and_then(Shard::from_file_name) {
            out.push((s, e.path()));
        }
    }
    out.sort_by_key(|(s, _)| (s.n, s.k));
    Ok(out)
}

fn read_partial(path: &Path) -> Result<ShardIndex> {
    let text = std::fs::read_to_string(path).map_err(io(path))?;
    let p: ShardIndex = toml::from_str(&text).map_err(|e| Error::Format {
        path: path.into(),
        msg: e.to_string(),
    })?;
    if p.format != SHARD_FORMAT || p.version != VERSION {
        return Err(Error::Format {
            path: path.into(),
            msg: format!(
                "format {:?} version {}, want {SHARD_FORMAT:?} version {VERSION}",
                p.format, p.version
            ),
        });
    }
    Ok(p)
}

/// Writes one share of a rectified dataset; [`ShardWriter::finish`] writes
/// its partial index last.
pub struct ShardWriter {
    root: PathBuf,
    shard: Shard,
    partial: ShardIndex,
}

impl ShardWriter {
    /// Starts share `shard` of the dataset in `root` (CAPTURE_DIR/rectified),
    /// of `stripes_total` stripe and `lamps_total` lamp images in all.
    /// Refused without `force`: a finished dataset (index.toml), this share
    /// already done, or partial indexes of another split or source (which
    /// `force` removes; images are overwritten, and the merge drops the
    /// ones no entry names).
    pub fn create(
        root: &Path,
        grid: Grid,
        shard: Shard,
        source: ShardSource,
        stripes_total: usize,
        lamps_total: usize,
        force: bool,
    ) -> Result<ShardWriter> {
        let grid_entry = grid_entry(grid)?;
        let refuse = |path: PathBuf, msg: String| Err(Error::Format { path, msg });
        let index = root.join("index.toml");
        if index.exists() {
            if !force {
                return refuse(
                    index,
                    "the rectified dataset is complete; pass --force to rectify it again".into(),
                );
            }
            remove_if_there(&index)?;
        }
        let mine = root.join(SHARDS_DIR).join(shard.file_name());
        for (other, path) in partials(root)? {
            let same_run = other.n == shard.n
                && read_partial(&path)
                    .is_ok_and(|p| p.source == source && p.index.grid == grid_entry);
            if other == shard {
                if !force {
                    return refuse(
                        path,
                        format!("shard {shard} is already rectified; pass --force to redo it"),
                    );
                }
                // Gone before the work starts: a redo killed midway leaves no stale claim.
                remove_if_there(&path)?;
            } else if !same_run {
                if !force {
                    return refuse(
                        path,
                        format!(
                            "is shard {other} of another split or other settings than shard {shard}; merge those shards first, or pass --force to drop it"
                        ),
                    );
                }
                remove_if_there(&path)?;
            }
        }
        for sub in ["stripes", "lamps", SHARDS_DIR] {
            let d = root.join(sub);
            std::fs::create_dir_all(&d).map_err(io(&d))?;
        }
        debug_assert!(!mine.exists());
        Ok(ShardWriter {
            root: root.to_path_buf(),
            shard,
            partial: ShardIndex {
                format: SHARD_FORMAT.into(),
                version: VERSION,
                shard: shard.k,
                shards: shard.n,
                source,
                stripes_total,
                lamps_total,
                index: Index::new(grid_entry),
            },
        })
    }

    /// Records the calibration the images are rectified with.
    pub fn set_calibration(&mut self, cal: CalibrationSummary) {
        self.partial.index.calibration = Some(cal);
    }

    fn check(&self, img: &ImageF, n: usize, total: usize) -> Result<()> {
        check_size(img, &self.partial.index.grid)?;
        if n >= total {
            return Err(Error::Input(format!("image {n} of a dataset of {total}")));
        }
        Ok(())
    }

    /// Adds the dataset's `n`-th stripe image (0-based); `entry.file` is filled in.
    pub fn add_stripe(&mut self, n: usize, img: &ImageF, mut entry: StripeEntry) -> Result<()> {
        self.check(img, n, self.partial.stripes_total)?;
        entry.file = stripe_file(n);
        exr_io::write_rgb(&self.root.join(&entry.file), img)?;
        self.partial.index.stripe.push(entry);
        Ok(())
    }

    /// Adds the dataset's `n`-th lamp image (0-based); `entry.file` is filled in.
    pub fn add_lamp(&mut self, n: usize, img: &ImageF, mut entry: LampEntry) -> Result<()> {
        self.check(img, n, self.partial.lamps_total)?;
        entry.file = lamp_file(n);
        exr_io::write_rgb(&self.root.join(&entry.file), img)?;
        self.partial.index.lamp.push(entry);
        Ok(())
    }

    /// Writes the partial index (atomically): the share is done.
    pub fn finish(self) -> Result<ShardIndex> {
        let p = self.root.join(SHARDS_DIR).join(self.shard.file_name());
        let text = toml::to_string_pretty(&self.partial).map_err(|e| Error::Format {
            path: p.clone(),
            msg: e.to_string(),
        })?;
        let tmp = p.with_extension("toml.tmp");
        std::fs::write(&tmp, text).map_err(io(&tmp))?;
        std::fs::rename(&tmp, &p).map_err(io(&p))?;
        Ok(self.partial)
    }
}

/// "1/3, 3/3" from shares 1 and 3 of 3.
fn list(n: usize, ks: impl IntoIterator<Item = usize>) -> String {
    ks.into_iter()
        .map(|k| format!("{k}/{n}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Completes the dataset in `root` from its shares (see the module docs):
/// `expect` is the source this merge is asked for. Refuses, naming what is
/// wrong, a finished dataset (unless `force`), missing shards, shards of
/// several splits, and shards that disagree with `expect` or each other.
pub fn merge(root: &Path, expect: &ShardSource, force: bool) -> Result<Index> {
    let index_path = root.join("index.toml");
    let shards_dir = root.join(SHARDS_DIR);
    let refuse = |path: &Path, msg: String| Error::Format {
        path: path.to_path_buf(),
        msg,
    };
    if index_path.exists() && !force {
        return Err(refuse(
            &index_path,
            "the rectified dataset is already complete; pass --force to merge again".into(),
        ));
    }
    let found = partials(root)?;
    let splits: BTreeSet<usize> = found.iter().map(|(s, _)| s.n).collect();
    let n = match splits.len() {
        0 => {
            return Err(refuse(
                &shards_dir,
                "no shards to merge; run `qhm rectify CAPTURE_DIR --shard K/N` for K = 1..N first"
                    .into(),
            ));
        }
        1 => *splits.first().unwrap(),
        _ => {
            return Err(refuse(
                &shards_dir,
                format!(
                    "holds shards of {} different splits (N = {}); remove the ones not wanted",
                    splits.len(),
                    splits
                        .iter()
                        .map(|n| n.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
    };
    let have: BTreeSet<usize> = found.iter().map(|(s, _)| s.k).collect();
    let missing: Vec<usize> = (1..=n).filter(|k| !have.contains(k)).collect();
    if !missing.is_empty() {
        return Err(refuse(
            &shards_dir,
            format!(
                "missing shard{} {} of {n}; run `qhm rectify CAPTURE_DIR --shard K/{n}` for each",
                if missing.len() == 1 { "" } else { "s" },
                list(n, missing.iter().copied())
            ),
        ));
    }
    let mut parts = Vec::new();
    for (s, path) in &found {
        let p = read_partial(path)?;
        if p.shard != s.k || p.shards != s.n {
            return Err(refuse(
                path,
                format!("holds shard {}/{}, not {s}", p.shard, p.shards),
            ));
        }
        for (what, got, want) in [
            ("capture", &p.source.capture, &expect.capture),
            ("calibration", &p.source.calibration, &expect.calibration),
            ("settings", &p.source.settings, &expect.settings),
        ] {
            if got != want {
                return Err(refuse(
                    path,
                    format!(
                        "shard {s} was rectified from another {what} ({got}) than this merge's ({want})"
                    ),
                ));
            }
        }
        parts.push((*s, p));
    }
    let (s0, first) = &parts[0];
    for (s, p) in &parts[1..] {
        let same = p.stripes_total == first.stripes_total
            && p.lamps_total == first.lamps_total
            && p.index.grid == first.index.grid
            && p.index.calibration == first.index.calibration;
        if !same {
            return Err(refuse(
                &shards_dir,
                format!(
                    "shards {s0} and {s} describe different datasets (grid, image counts or calibration)"
                ),
            ));
        }
    }
    let mut merged = Index::new(first.index.grid);
    merged.calibration = first.index.calibration.clone();
    let (stripes_total, lamps_total) = (first.stripes_total, first.lamps_total);
    for (_, p) in parts {
        merged.stripe.extend(p.index.stripe);
        merged.lamp.extend(p.index.lamp);
    }
    merged.stripe.sort_by(|a, b| a.file.cmp(&b.file));
    merged.lamp.sort_by(|a, b| a.file.cmp(&b.file));
    let stripe_files: Vec<&str> = merged.stripe.iter().map(|e| e.file.as_str()).collect();
    let lamp_files: Vec<&str> = merged.lamp.iter().map(|e| e.file.as_str()).collect();
    let want_stripes: Vec<String> = (0..stripes_total).map(stripe_file).collect();
    let want_lamps: Vec<String> = (0..lamps_total).map(lamp_file).collect();
    if stripe_files != want_stripes || lamp_files != want_lamps {
        return Err(refuse(
            &shards_dir,
            format!(
                "the shards hold {} stripe and {} lamp entries, not each of the dataset's {stripes_total} and {lamps_total} once",
                stripe_files.len(),
                lamp_files.len()
            ),
        ));
    }
    for f in want_stripes.iter().chain(&want_lamps) {
        if !root.join(f).is_file() {
            return Err(refuse(
                &root.join(f),
                "missing, though a shard lists it; rectify its shard again with --force".into(),
            ));
        }
    }
    // Images of an earlier run that this dataset does not name.
    let named: BTreeSet<&str> = want_stripes
        .iter()
        .chain(&want_lamps)
        .map(String::as_str)
        .collect();
    for sub in ["stripes", "lamps"] {
        let d = root.join(sub);
        for e in std::fs::read_dir(&d).map_err(io(&d))? {
            let e = e.map_err(io(&d))?;
            let rel = format!("{sub}/{}", e.file_name().to_string_lossy());
            if !named.contains(rel.as_str()) && e.path().is_file() {
                remove_if_there(&e.path())?;
            }
        }
    }
    rectified::write_index(root, &merged)?;
    std::fs::remove_dir_all(&shards_dir).map_err(io(&shards_dir))?;
    Ok(merged)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_parses_and_splits_by_index() {
        let s: Shard = "2/3".parse().unwrap();
        assert_eq!(s, Shard { k: 2, n: 3 });
        assert_eq!((0..7).filter(|&i| s.takes(i)).collect::<Vec<_>>(), [1, 4]);
        for bad in ["0/2", "3/2", "1/0", "a/b", "1", "", "1/2/3", "-1/2"] {
            let e = bad.parse::<Shard>().unwrap_err();
            assert!(e.contains("K/N"), "{bad}: {e}");
        }
        assert_eq!(Shard::from_file_name("2-of-3.toml"), Some(s));
        assert_eq!(Shard::from_file_name("4-of-3.toml"), None);
        assert_eq!(s.to_string(), "2/3");
    }
}
