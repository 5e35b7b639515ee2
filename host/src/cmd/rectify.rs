//! `qhm rectify CAPTURE_DIR`: HDR-merge every exposure bracket of a capture
//! with the calibrated responses, resample it onto the reference plane, fit
//! the laser stripe lines, and write CAPTURE_DIR/rectified/ (format in
//! docs/imaging.md; read by the model fitter).
//!
//! `--shard K/N` does one deterministic share of the shots (for a Slurm job
//! array or GNU parallel), `--merge` completes the dataset from the N
//! shares, byte for byte as one unsharded run writes it (qhm_imaging::shards).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use host::pipeline::{StripeWindow, calibrated_shots, find_calibration, rectify_options, shots};
use qhm_acquire::dir::sha256_hex;
use qhm_acquire::{CaptureDir, Manifest};
use qhm_imaging::Calibration;
use qhm_imaging::pipeline::{rectify_capture, rectify_shard};
use qhm_imaging::shards::{self, SHARDS_DIR, Shard, ShardSource};

#[derive(clap::Args, Debug)]
pub struct RectifyArgs {
    /// Capture directory written by `qhm capture run`.
    pub capture_dir: PathBuf,
    /// Calibration file from `qhm calibrate` [default: the one capture.toml
    /// records, else CAPTURE_DIR/calibration.toml, else
    /// CAPTURE_DIR/../calibration.toml].
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Width of the rectified area on the sample, mm (texel = width / the plan's rectified size).
    #[arg(long, default_value_t = 32.0)]
    pub width_mm: f64,
    /// Stripe texels: intensity threshold as a fraction of the brightest texel.
    #[arg(long, default_value_t = 0.3)]
    pub threshold: f64,
    /// Keep stripe texels at least this far from the fitted line, mm (0 keeps
    /// the core, which the fit needs for R).
    #[arg(long, default_value_t = 0.0)]
    pub d_min: f64,
    /// Keep stripe texels at most this far from the fitted line, mm.
    #[arg(long, default_value_t = 12.0)]
    pub d_max: f64,
    /// Rectify only share K of N of the shots (1 <= K <= N), into
    /// CAPTURE_DIR/rectified/ and its partial index rectified/shards/K-of-N.toml.
    #[arg(long, value_name = "K/N", conflicts_with = "merge")]
    pub shard: Option<Shard>,
    /// Complete the rectified dataset from the N shares of `--shard K/N`
    /// (all must be done, with the same capture, calibration and settings).
    #[arg(long)]
    pub merge: bool,
    /// Replace a rectified dataset (or this share, or a merge) already there.
    #[arg(long)]
    pub force: bool,
}

pub fn run(args: RectifyArgs) -> anyhow::Result<ExitCode> {
    let root = &args.capture_dir;
    // Shares and the merge read the capture beside each other (a shared
    // lock); a share checks its own frames below, not all of them.
    let sharded = args.shard.is_some() || args.merge;
    let dir = if sharded {
        CaptureDir::open_read(root)
    } else {
        CaptureDir::open(root, None)
    }
    .with_context(|| format!("opening capture {}", root.display()))?;
    if !dir.is_complete() {
        bail!(
            "{}: the capture is not complete; finish it with `qhm capture run --resume`",
            root.display()
        );
    }
    let manifest: &Manifest = dir.manifest();
    let plan = dir.plan()?;
    let cal_path = find_calibration(root, manifest, args.calibration.as_deref())?;
    let cal = Calibration::load(&cal_path)
        .with_context(|| "run `qhm calibrate all` first, or pass --calibration")?;
    let window = StripeWindow {
        width_mm: args.width_mm,
        threshold: args.threshold,
        d_min: args.d_min,
        d_max: args.d_max,
    };
    window.validate().map_err(|e| anyhow::anyhow!("{e}"))?;
    let n = plan.config.rectified_size as usize;
    let opts = rectify_options(&plan, &window);
    let out = root.join("rectified");
    let cal_bytes =
        std::fs::read(&cal_path).with_context(|| format!("reading {}", cal_path.display()))?;
    // Shares must come from the same capture, calibration and settings.
    let source = ShardSource {
        capture: format!(
            "plan {} seed {} sample {:?}",
            &manifest.plan_sha256[..16],
            manifest.seed,
            manifest.sample
        ),
        calibration: format!("sha256 {}", &sha256_hex(&cal_bytes)[..16]),
        settings: format!(
            "width {} mm, threshold {}, distances [{}, {}] mm",
            args.width_mm, args.threshold, args.d_min, args.d_max
        ),
    };
    if args.merge {
        let idx = shards::merge(&out, &source, args.force)
            .with_context(|| format!("merging the shards of {}", out.display()))?;
        println!(
            "{}: merged {} stripe and {} lamp images -> {}",
            root.display(),
            idx.stripe.len(),
            idx.lamp.len(),
            out.join("index.toml").display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let (shots, skipped) = calibrated_shots(shots(&plan, root), &cal);
    if !skipped.is_empty() {
        eprintln!(
            "note: cameras {skipped:?} have no geometric calibration; their frames are left out"
        );
    }
    if shots.is_empty() {
        bail!("no camera of the capture has a geometric calibration");
    }
    if let Some(shard) = args.shard {
        let mine: std::collections::BTreeSet<PathBuf> = (shots.iter().enumerate())
            .filter(|(i, _)| shard.takes(*i))
            .flat_map(|(_, s)| s.frames.iter().map(|(p, _)| p.clone()))
            .collect();
        dir.verify_frames_where(|rel| mine.contains(&root.join(rel)))
            .with_context(|| format!("checking the frames of shard {shard}"))?;
        let total = shots
            .iter()
            .enumerate()
            .filter(|(i, _)| shard.takes(*i))
            .count();
        let bar = qhm_progress::Bar::new(&format!("rectify {shard}"), total as u64, false);
        let part = rectify_shard(
            &shots,
            &cal,
            &opts,
            &out,
            shard,
            source,
            args.force,
            &|done, _| bar.set_position(done as u64),
        )
        .with_context(|| format!("rectifying shard {shard} of {}", root.display()))?;
        bar.finish();
        println!(
            "{}: shard {shard}: {} stripe and {} lamp images of {} and {} -> {}; complete the dataset with `qhm rectify {} --merge` once all {} shards are done",
            root.display(),
            part.index.stripe.len(),
            part.index.lamp.len(),
            part.stripes_total,
            part.lamps_total,
            out.display(),
            root.display(),
            shard.n
        );
        return Ok(ExitCode::SUCCESS);
    }
    if args.force {
        remove_dataset(&out)?;
    } else if out.join(SHARDS_DIR).is_dir() {
        bail!(
            "{} holds shards of a sharded run; complete it with `qhm rectify {} --merge`, or pass --force to rectify it whole",
            out.display(),
            root.display()
        );
    }
    let bar = qhm_progress::Bar::new("rectify", shots.len() as u64, false);
    let idx = rectify_capture(&shots, &cal, &opts, &out, &|done, _| {
        bar.set_position(done as u64)
    })
    .with_context(|| format!("rectifying {}", root.display()))?;
    bar.finish();
    println!(
        "{}: {} stripe and {} lamp images, {}x{} texels of {:.3} mm (sample {:?}) -> {}",
        root.display(),
        idx.stripe.len(),
        idx.lamp.len(),
        n,
        n,
        opts.grid.texel_mm,
        manifest.sample,
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// Removes what qhm wrote into `out` (CAPTURE_DIR/rectified) and nothing
/// else: the index, the images and the shards' partial indexes.
fn remove_dataset(out: &std::path::Path) -> anyhow::Result<()> {
    for f in ["index.toml", "index.toml.tmp"] {
        let p = out.join(f);
        if p.is_file() {
            std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }
    for d in ["stripes", "lamps", SHARDS_DIR] {
        let p = out.join(d);
        if p.is_dir() {
            std::fs::remove_dir_all(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }
    Ok(())
}
