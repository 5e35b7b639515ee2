//! Capture runs on the built-in simulated rig survive interruptions: the run
//! future dropped at random moments (Ctrl-C, a host crash), a journal torn
//! mid-line with a half-written frame left behind (kill -9 during a write),
//! MCU resets injected through the emulator, and cameras that deliver
//! damaged buffers; each time the resumed capture directory is byte-for-byte
//! the uninterrupted one.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use protocol::LaserColour;
use qhm_acquire::camera::{BoxFuture, Camera, CameraError, CameraInfo, CameraSettings, Frame};
use qhm_acquire::{
    CaptureDir, Manifest, NoProgress, Plan, PlanConfig, Progress, RunOptions, RunReport, Scale,
    run_capture,
};
use sha2::{Digest, Sha256};
use sim_devices::{SimRig, SimRigConfig};

const SAMPLE: &str = "two-material";
const SEED: u64 = 11;

/// The ci plan, thinned so three captures fit in the test suite.
fn plan() -> Plan {
    let mut c = PlanConfig::for_scale(Scale::Ci);
    c.laser_colours = vec![LaserColour::Red, LaserColour::Blue];
    c.entrance_arc_rotations = 1;
    c.lamps = vec![4];
    Plan::new(c).unwrap()
}

fn manifest(plan: &Plan) -> Manifest {
    Manifest::new("sim", SAMPLE, SEED, plan)
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

/// The ci rig with a sixteenth of its photons per pose. What is compared
/// here is frames byte for byte, and a frame is a function of the run seed
/// and its pose at any photon budget (the Monte Carlo and noise seeds never
/// depend on it): noisier images check the same, at a sixteenth of the light.
fn rig_config() -> SimRigConfig {
    let mut cfg = SimRigConfig::new(SAMPLE, Scale::Ci, SEED);
    cfg.quality.laser_photons /= 16;
    cfg.quality.lamp_photons /= 16;
    cfg
}

async fn start_rig() -> SimRig {
    SimRig::start_with(rig_config())
        .await
        .expect("simulated rig")
}

fn options(rig: &SimRig) -> RunOptions {
    RunOptions {
        time_scale: rig.handle.rig().speed(),
        frame_timeout: Duration::from_secs(60),
        ..RunOptions::default()
    }
}

/// Counts frames written in this run and wakes the interrupter at a target.
struct Countdown {
    left: usize,
    hit: Option<tokio::sync::oneshot::Sender<()>>,
}

impl Progress for Countdown {
    fn frame(&mut self, _step: &qhm_acquire::plan::Step, _done: usize) {
        self.left = self.left.saturating_sub(1);
        if self.left == 0
            && let Some(tx) = self.hit.take()
        {
            let _ = tx.send(());
        }
    }
}

/// Resets the MCU `delay` after the n-th frame written, for each `(n, delay)`.
struct ResetAfter {
    mcu: sim::RigHandle,
    at: Vec<(usize, Duration)>,
    frames: usize,
    injected: Vec<tokio::task::JoinHandle<()>>,
}

impl Progress for ResetAfter {
    fn frame(&mut self, _step: &qhm_acquire::plan::Step, _done: usize) {
        self.frames += 1;
        for &(n, delay) in &self.at {
            if n == self.frames {
                let mcu = self.mcu.clone();
                self.injected.push(tokio::spawn(async move {
                    tokio::time::sleep(delay).await;
                    mcu.reset_mcu();
                }));
            }
        }
    }
}

/// One run (or continuation) on a fresh simulated rig, as a new host process
/// would do it. With `stop = Some((n, delay))` the run future is dropped
/// `delay` after its n-th new frame (mid-step, mid-sweep or mid-move, as
/// Ctrl-C or a crash would); returns None if it was dropped.
async fn run_once(root: &Path, fresh: bool, stop: Option<(usize, Duration)>) -> Option<RunReport> {
    let plan = plan();
    let mut dir = if fresh {
        CaptureDir::create(root, manifest(&plan)).unwrap()
    } else {
        CaptureDir::open(root, Some(&manifest(&plan))).unwrap()
    };
    let mut rig = start_rig().await;
    let opts = options(&rig);
    let mut op = rig.handle.operator();
    let (tx, rx) = tokio::sync::oneshot::channel();
    let mut countdown = Countdown {
        left: stop.map_or(usize::MAX, |s| s.0),
        hit: Some(tx),
    };
    let run = run_capture(
        &rig.link,
        &mut rig.cameras,
        &mut op,
        &mut dir,
        &opts,
        &mut countdown,
    );
    let delay = stop.map_or(Duration::ZERO, |s| s.1);
    tokio::select! {
        r = run => Some(r.expect("capture run")),
        _ = async {
            if rx.await.is_err() {
                std::future::pending::<()>().await;
            }
            tokio::time::sleep(delay).await;
        } => None,
    }
}

/// `root` holds exactly the files of `want`, byte for byte; names the ones that differ.
fn assert_same_files(root: &Path, want: &BTreeMap<String, String>, what: &str) {
    let got = hash_dir(root);
    let differing: Vec<&String> = want
        .keys()
        .chain(got.keys())
        .filter(|k| got.get(*k) != want.get(*k))
        .collect();
    assert!(differing.is_empty(), "{what} differs in {differing:?}");
}

/// A small deterministic generator for the interruption times.
struct Lcg(u64);
impl Lcg {
    fn below(&mut self, n: u64) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 33) % n
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interrupted_and_reset_captures_equal_the_uninterrupted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = plan();

    // Reference: uninterrupted.
    let reference = tmp.path().join("reference");
    let report = run_once(&reference, true, None).await.unwrap();
    assert!(report.complete);
    assert_eq!(report.frames_written, plan.frames());
    let want = hash_dir(&reference);
    assert_eq!(
        want.keys().filter(|k| k.ends_with(".png")).count(),
        plan.frames()
    );

    // Dropped at random moments, and twice "killed" in the middle of a write.
    let seed = std::env::var("QHM_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x5eed_u64);
    eprintln!("interruption seed {seed} (QHM_TEST_SEED)");
    let mut rng = Lcg(seed);
    let resumed = tmp.path().join("resumed");
    let mut fresh = true;
    let mut interruptions = 0;
    for round in 0.. {
        assert!(round < 40, "the capture never finished");
        let stop = (
            1 + rng.below(30) as usize,
            Duration::from_millis(rng.below(400)),
        );
        match run_once(&resumed, fresh, Some(stop)).await {
            Some(r) => {
                assert!(r.complete);
                break;
            }
            None => interruptions += 1,
        }
        fresh = false;
        if round % 2 == 1 {
            // kill -9 mid-write: a torn journal line and a half-written frame.
            let jpath = resumed.join("journal");
            let mut j = std::fs::OpenOptions::new()
                .append(true)
                .open(&jpath)
                .unwrap();
            use std::io::Write;
            j.write_all(b"frame 9999 0 3 deadbeef").unwrap();
            let half = resumed.join("frames/p2/s009999_k000_c3.tmp");
            std::fs::create_dir_all(half.parent().unwrap()).unwrap();
            std::fs::write(half, b"\x89PN").unwrap();
        }
    }
    assert!(interruptions >= 2, "only {interruptions} interruptions");
    assert_same_files(&resumed, &want, "resumed capture");

    // MCU resets injected at random moments of one run: recovered in place.
    let reset_dir = tmp.path().join("reset");
    let mut dir = CaptureDir::create(&reset_dir, manifest(&plan)).unwrap();
    let mut rig = start_rig().await;
    let opts = options(&rig);
    // Two resets, each a random few milliseconds after a random frame (so
    // mid-step, mid-sweep or mid-move), the first after homing.
    let first = 1 + rng.below(plan.frames() as u64 / 2) as usize;
    let second = first + 1 + rng.below(plan.frames() as u64 / 3) as usize;
    let mut resets = ResetAfter {
        mcu: rig.handle.rig().clone(),
        at: vec![
            (first, Duration::from_millis(rng.below(20))),
            (second, Duration::from_millis(rng.below(20))),
        ],
        frames: 0,
        injected: Vec::new(),
    };
    let mut op = rig.handle.operator();
    let report = run_capture(
        &rig.link,
        &mut rig.cameras,
        &mut op,
        &mut dir,
        &opts,
        &mut resets,
    )
    .await
    .expect("run with MCU resets");
    for r in resets.injected {
        r.await.unwrap();
    }
    assert!(report.complete);
    assert!(
        report.resets_recovered >= 1,
        "no reset was seen: {report:?}"
    );
    drop(dir);
    assert_same_files(&reset_dir, &want, "capture with resets");

    // Damaged frames (a cleared or incomplete buffer): retaken in place.
    let flaky_dir = tmp.path().join("flaky");
    let mut dir = CaptureDir::create(&flaky_dir, manifest(&plan)).unwrap();
    let mut rig = start_rig().await;
    let opts = options(&rig);
    let bad_at: Vec<usize> = vec![
        1 + rng.below(plan.frames() as u64 / 2) as usize,
        plan.frames() / 2 + 1 + rng.below(plan.frames() as u64 / 3) as usize,
    ];
    let calls = Arc::new(AtomicUsize::new(0));
    let mut cameras: Vec<Box<dyn Camera>> = std::mem::take(&mut rig.cameras)
        .into_iter()
        .map(|inner| {
            Box::new(Flaky {
                inner,
                calls: calls.clone(),
                bad_at: bad_at.clone(),
            }) as Box<dyn Camera>
        })
        .collect();
    let mut op = rig.handle.operator();
    let report = run_capture(
        &rig.link,
        &mut cameras,
        &mut op,
        &mut dir,
        &opts,
        &mut NoProgress,
    )
    .await
    .expect("run with damaged frames");
    assert!(report.complete);
    assert_eq!(report.retakes, 2, "{report:?}");
    drop(dir);
    assert_same_files(&flaky_dir, &want, "capture with damaged frames");
}

/// A camera whose `next_frame` calls number `bad_at` (counted over all the
/// cameras sharing `calls`, from 1) take their frame and report it damaged,
/// as Aravis does for a buffer that comes back cleared or incomplete.
struct Flaky {
    inner: Box<dyn Camera>,
    calls: Arc<AtomicUsize>,
    bad_at: Vec<usize>,
}

impl Camera for Flaky {
    fn info(&self) -> CameraInfo {
        self.inner.info()
    }
    fn configure(&mut self, settings: CameraSettings) -> BoxFuture<'_, Result<(), CameraError>> {
        self.inner.configure(settings)
    }
    fn arm(&mut self, tags: Vec<u64>) -> BoxFuture<'_, Result<(), CameraError>> {
        self.inner.arm(tags)
    }
    fn next_frame(&mut self, timeout: Duration) -> BoxFuture<'_, Result<Frame, CameraError>> {
        let n = self.calls.fetch_add(1, Ordering::SeqCst) + 1;
        let bad = self.bad_at.contains(&n);
        Box::pin(async move {
            let frame = self.inner.next_frame(timeout).await?;
            if bad {
                return Err(CameraError::BadFrame(format!(
                    "camera {}: buffer status Cleared",
                    frame.meta.camera
                )));
            }
            Ok(frame)
        })
    }
    fn disarm(&mut self) -> BoxFuture<'_, Result<(), CameraError>> {
        self.inner.disarm()
    }
}

/// A host that dies leaves the MCU running with its arc wherever it stopped
/// (a separate process on a real rig, as in tests/scripts/rehearsal.sh); the
/// next host must not home the arc from below its home cam, where homing
/// runs into the end switch.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_host_homes_an_arc_left_below_home_without_hitting_its_end_switch() {
    use protocol::Axis;
    let tmp = tempfile::tempdir().unwrap();
    let plan = plan();
    let mut rig = start_rig().await;
    rig.link.home(Axis::LightArc).await.unwrap();
    rig.link.wait_motion_done(Axis::LightArc).await.unwrap();
    rig.link
        .move_rad(Axis::LightArc, -0.6, false, 0.0, 0.0)
        .await
        .unwrap();
    rig.link.wait_motion_done(Axis::LightArc).await.unwrap();
    let mut dir = CaptureDir::create(&tmp.path().join("cap"), manifest(&plan)).unwrap();
    let opts = RunOptions {
        stop_after_steps: Some(1),
        ..options(&rig)
    };
    let mut op = rig.handle.operator();
    let report = run_capture(
        &rig.link,
        &mut rig.cameras,
        &mut op,
        &mut dir,
        &opts,
        &mut Countdown {
            left: usize::MAX,
            hit: None,
        },
    )
    .await
    .expect("the first step on a rig whose arc stopped below home");
    assert_eq!(report.steps_run, 1);
    let status = rig.link.status().await.unwrap();
    assert_eq!(status.fault, None);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn foreign_or_damaged_directories_are_refused_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = plan();
    // A directory with someone's files.
    let foreign = tmp.path().join("photos");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("a.jpg"), b"jpeg").unwrap();
    let before = hash_dir(&foreign);
    assert!(CaptureDir::create(&foreign, manifest(&plan)).is_err());
    assert!(CaptureDir::open(&foreign, Some(&manifest(&plan))).is_err());
    assert_eq!(hash_dir(&foreign), before);

    // A partial capture whose frame was altered afterwards.
    let root = tmp.path().join("cap");
    assert!(
        run_once(&root, true, Some((5, Duration::ZERO)))
            .await
            .is_none()
    );
    let dir = CaptureDir::open(&root, None).unwrap();
    let (_, rec) = dir.frames().next().expect("a frame was journaled").clone();
    let rec = rec.clone();
    drop(dir);
    std::fs::write(root.join(&rec.path), b"not the frame").unwrap();
    let before = hash_dir(&root);
    let err = CaptureDir::open(&root, Some(&manifest(&plan)))
        .err()
        .unwrap();
    assert!(err.to_string().contains("checksum"), "{err}");
    assert_eq!(hash_dir(&root), before, "refused directory was modified");

    // Another seed cannot resume this capture.
    let other = Manifest::new("sim", SAMPLE, SEED + 1, &plan);
    std::fs::remove_file(root.join(&rec.path)).unwrap();
    let err = CaptureDir::open(&root, Some(&other)).err().unwrap();
    assert!(err.to_string().contains("different seed"), "{err}");
}
