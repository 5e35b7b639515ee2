//! A simulated capture taken in shares (`qhm capture run --sim --shard K/N`),
//! each on a fresh simulated rig as its own process or machine would, and
//! joined with `merge_shards`, is byte for byte the unsharded capture: the
//! simulated frames depend on the seed, the pose and the frame's place in
//! the plan, never on the steps run before. A merge with a share missing or
//! unfinished is refused by name.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use protocol::LaserColour;
use qhm_acquire::dir::{merge_shards, shard_dir};
use qhm_acquire::{
    CaptureDir, Manifest, NoProgress, Plan, PlanConfig, RunOptions, Scale, run_capture,
};
use sha2::{Digest, Sha256};
use sim_devices::{SimRig, SimRigConfig};

const SAMPLE: &str = "two-material";
const SEED: u64 = 5;

/// The ci plan, thinned to seconds: one laser, clamp position, arc rotation
/// and lamp, two exposures.
fn plan() -> Plan {
    let mut c = PlanConfig::for_scale(Scale::Ci);
    c.laser_colours = vec![LaserColour::Green];
    c.clamp_elevations
        .retain(|e| (e - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
    c.laser_exposures = vec![0.0005, 0.004];
    c.reflectance_turntable = 1;
    c.entrance_arc_rotations = 1;
    c.exiting_turntable = 1;
    c.lamps = vec![4];
    Plan::new(c).unwrap()
}

/// sha256 of every file under `root`, by relative path.
fn hash_dir(root: &Path) -> BTreeMap<String, String> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                let h = Sha256::digest(std::fs::read(&p).unwrap());
                out.insert(rel, format!("{h:x}"));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(root, root, &mut out);
    out
}

/// Captures `manifest`'s plan (or share) into `root` on a fresh simulated rig.
async fn capture(root: &Path, manifest: Manifest) {
    let mut dir = CaptureDir::create(root, manifest).unwrap();
    // Faster than ci's virtual clock: homing dominates such a short plan.
    let cfg = SimRigConfig {
        speed: 16.0,
        ..SimRigConfig::new(SAMPLE, Scale::Ci, SEED)
    };
    let mut rig = SimRig::start_with(cfg).await.expect("simulated rig");
    let opts = RunOptions {
        time_scale: rig.handle.rig().speed(),
        frame_timeout: Duration::from_secs(60),
        ..RunOptions::default()
    };
    let mut op = rig.handle.operator();
    let report = run_capture(
        &rig.link,
        &mut rig.cameras,
        &mut op,
        &mut dir,
        &opts,
        &mut NoProgress,
    )
    .await
    .expect("capture run");
    assert!(report.complete);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shares_merged_equal_the_unsharded_capture() {
    let plan = plan();
    let whole = Manifest::new("sim", SAMPLE, SEED, &plan);
    let tmp = tempfile::tempdir().unwrap();
    let single = tmp.path().join("single");
    capture(&single, whole.clone()).await;
    let want = hash_dir(&single);
    assert!(want.len() > 20, "{} files", want.len());

    let n = 3;
    let root = tmp.path().join("sharded");
    for k in [3, 1] {
        let share = Manifest {
            shard: Some([k, n]),
            ..whole.clone()
        };
        capture(&shard_dir(&root, k, n), share).await;
    }
    let e = merge_shards(&root)
        .err()
        .expect("share 2 is missing")
        .to_string();
    assert!(e.contains("missing share 2/3 of 3"), "{e}");
    // Share 2 begun but not finished.
    let share2 = Manifest {
        shard: Some([2, n]),
        ..whole.clone()
    };
    drop(CaptureDir::create(&shard_dir(&root, 2, n), share2.clone()).unwrap());
    let e = merge_shards(&root)
        .err()
        .expect("share 2 is unfinished")
        .to_string();
    assert!(
        e.contains("share 2/3 is not finished") && e.contains("--shard 2/3 --resume"),
        "{e}"
    );
    std::fs::remove_dir_all(shard_dir(&root, 2, n)).unwrap();
    capture(&shard_dir(&root, 2, n), share2).await;
    let d = merge_shards(&root).expect("merge");
    assert!(d.is_complete());
    drop(d);
    let got = hash_dir(&root);
    let differing: Vec<&String> = want
        .keys()
        .chain(got.keys())
        .filter(|k| got.get(*k) != want.get(*k))
        .collect();
    assert!(
        differing.is_empty(),
        "the merged capture differs in {differing:?}"
    );
    let e = merge_shards(&root).err().unwrap().to_string();
    assert!(e.contains("already holds a capture"), "{e}");
}
