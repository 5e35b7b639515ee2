//! Executing a capture plan (or one share of it) through the link and the cameras.
//!
//! [`run_capture`] continues from the capture directory's last finished step
//! (so a fresh run and `--resume` are the same code), and for each step:
//! asks the operator to move the laser clamp if the step needs another
//! elevation; moves both axes at once and waits for them to stop and settle;
//! sets the light; configures and arms the cameras with the step's frame
//! tags; fires (a galvo sweep whose dwells pulse the trigger lines, or one
//! trigger for a lamp image); and writes the step's frames, in trigger and
//! camera order, durably into the directory before journaling them (in
//! batches: one sync of the files, their directories and the journal each).
//!
//! Triggers fire only while nothing moves (the MCU sweep waits for the galvo
//! to settle; axis moves are awaited plus their settling time). The axes are
//! homed once, or again after an MCU reset (positions are lost). A reset in the
//! middle of a step (`LinkError::DeviceReset`) re-homes and repeats the step;
//! frames already journaled are kept, not rewritten. A frame a camera
//! delivers damaged (`CameraError::BadFrame`: an incomplete or cleared
//! buffer, a software trigger whose frame never came) or out of turn is
//! retaken by repeating the step without re-homing. Anything else (a
//! disconnect, a camera that stays silent, a refused command) ends the run
//! with an error and leaves a directory that `--resume` continues.

use std::collections::BTreeMap;
use std::time::Duration;

use hardware::{LIGHT_ARC, NOMINAL_GEOMETRY, TURNTABLE};
use protocol::{Axis, LaserColour, Sweep};
use qhm_link::{Link, LinkError, LinkEvent};

use crate::camera::{Camera, CameraError, CameraSettings};
use crate::dir::{CaptureDir, DirError};
use crate::operator::{Operator, OperatorError};
use crate::plan::{Light, Pass, Plan, Step};

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error(transparent)]
    Camera(#[from] CameraError),
    #[error(transparent)]
    Dir(#[from] DirError),
    #[error(transparent)]
    Operator(#[from] OperatorError),
    /// The plan needs a camera the rig does not have.
    #[error("the plan uses camera {0}, which the rig does not provide")]
    MissingCamera(u8),
    /// A frame came back with a tag that was not asked for next.
    #[error("camera {camera}: frame tagged {got:#x}, expected {expected:#x}")]
    WrongFrame { camera: u8, got: u64, expected: u64 },
    /// The MCU kept resetting (or losing the heartbeat) during one step.
    #[error(
        "step {step}: the MCU reset or faulted {resets} times; giving up (resume when it is stable)"
    )]
    TooManyResets { step: u32, resets: u32 },
    /// The sweep ended early without a reset (aborted on the MCU).
    #[error("step {0}: the galvo sweep was aborted")]
    SweepAborted(u32),
}

/// Knobs of a run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Longest wait for one frame after its trigger (wall time; the simulated
    /// camera renders on trigger).
    pub frame_timeout: Duration,
    /// MCU resets tolerated within one step before giving up.
    pub max_resets_per_step: u32,
    /// Retakes of one step's frames after damaged frames before giving up.
    pub max_retakes_per_step: u32,
    /// Virtual seconds per wall second of the rig (1 on a real rig); scales
    /// the settling waits the host times itself.
    pub time_scale: f64,
    /// Stop (cleanly, as after Ctrl-C) once this many steps are journaled in
    /// this run; for tests and partial runs.
    pub stop_after_steps: Option<u32>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            frame_timeout: Duration::from_secs(120),
            max_resets_per_step: 3,
            max_retakes_per_step: 3,
            time_scale: 1.0,
            stop_after_steps: None,
        }
    }
}

/// Reports progress (the CLI draws bars; tests count).
pub trait Progress: Send {
    /// Before the first step: frames in the plan, frames already on disk.
    fn start(&mut self, _total_frames: usize, _done_frames: usize) {}
    /// After each frame is journaled.
    fn frame(&mut self, _step: &Step, _done_frames: usize) {}
    /// Something worth telling the user (a reset, an operator step).
    fn note(&mut self, _message: &str) {}
}

/// Ignores progress.
pub struct NoProgress;
impl Progress for NoProgress {}

/// What a run did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RunReport {
    pub steps_run: u32,
    pub frames_written: usize,
    pub frames_kept: usize,
    pub resets_recovered: u32,
    /// Steps repeated to retake damaged frames.
    pub retakes: u32,
    pub complete: bool,
}

/// What the host last made the rig do (forgotten on reset).
#[derive(Default)]
struct RigCache {
    homed: bool,
    turntable: f64,
    light_arc: f64,
    /// The arc's angle before its last move: a reset mid-move leaves the
    /// carriage anywhere between this and `light_arc`.
    light_arc_from: f64,
    clamp: Option<f64>,
    /// The pass the operator was last told of.
    pass: Option<Pass>,
    /// The calibration target the operator last put on the turntable.
    target: Option<String>,
    laser: Option<LaserColour>,
    lamps: u8,
}

/// Runs the rest of `dir`'s plan; see the module docs.
pub async fn run_capture(
    link: &Link,
    cameras: &mut [Box<dyn Camera>],
    operator: &mut dyn Operator,
    dir: &mut CaptureDir,
    opts: &RunOptions,
    progress: &mut dyn Progress,
) -> Result<RunReport, RunError> {
    let plan = dir.plan()?;
    let mut by_index = BTreeMap::new();
    for (i, c) in cameras.iter().enumerate() {
        by_index.insert(c.info().index, i);
    }
    for s in plan.steps.iter().filter(|s| dir.takes(s.index)) {
        for c in s.cameras.iter().copied() {
            by_index.get(&c).ok_or(RunError::MissingCamera(c))?;
        }
    }
    let mut report = RunReport::default();
    progress.start(dir.planned_frames(&plan), dir.frame_count());
    let mut rig = RigCache::default();
    let mut settings: BTreeMap<u8, CameraSettings> = BTreeMap::new();
    let start = dir.steps_done() as usize;
    // A share of the capture runs only its own steps (dir module docs).
    let manifest = dir.manifest().clone();
    for step in plan.steps[start..]
        .iter()
        .filter(|s| manifest.takes(s.index))
    {
        if opts.stop_after_steps.is_some_and(|n| report.steps_run >= n) {
            break;
        }
        let (mut resets, mut retakes) = (0, 0);
        loop {
            let r = run_step(
                link,
                cameras,
                &by_index,
                operator,
                dir,
                &plan,
                step,
                opts,
                &mut rig,
                &mut settings,
                &mut report,
                progress,
            )
            .await;
            match r {
                Ok(()) => break,
                Err(e) if recoverable(&e) => {
                    resets += 1;
                    report.resets_recovered += 1;
                    progress.note(&format!(
                        "step {}: {e}; re-homing and repeating the step",
                        step.index
                    ));
                    // A lost heartbeat latched a fault (the host was too slow,
                    // e.g. under load); its cause is gone, clear it.
                    let status = match link.status().await {
                        Err(LinkError::DeviceReset { .. }) => link.status().await?,
                        r => r?,
                    };
                    if status.fault == Some(protocol::FaultCause::HeartbeatLost) {
                        link.clear_fault().await?;
                    }
                    // A reset mid-move leaves the arc anywhere between the
                    // move's ends, as last sent.
                    let lo = rig.light_arc.min(rig.light_arc_from);
                    let hi = rig.light_arc.max(rig.light_arc_from);
                    bring_arc_over_home(link, lo, hi).await?;
                    if resets > opts.max_resets_per_step {
                        return Err(RunError::TooManyResets {
                            step: step.index,
                            resets,
                        });
                    }
                    // The clamp and the target are mechanical: a reset moves neither.
                    rig = RigCache {
                        clamp: rig.clamp,
                        pass: rig.pass,
                        target: rig.target.take(),
                        ..RigCache::default()
                    };
                    for c in cameras.iter_mut() {
                        c.disarm().await?;
                    }
                }
                Err(e) if retakeable(&e) && retakes < opts.max_retakes_per_step => {
                    retakes += 1;
                    report.retakes += 1;
                    progress.note(&format!(
                        "step {}: {e}; retaking the step's frames",
                        step.index
                    ));
                    for c in cameras.iter_mut() {
                        c.disarm().await?;
                    }
                }
                Err(e) => {
                    safe_off(link).await;
                    return Err(e);
                }
            }
        }
        dir.step_done(step.index)?;
        report.steps_run += 1;
    }
    safe_off(link).await;
    if dir.steps_done() as usize == plan.steps.len() && !dir.is_complete() {
        dir.finish()?;
    }
    report.complete = dir.is_complete();
    Ok(report)
}

/// An MCU reset, or a heartbeat fault (the MCU stopped the motors and the
/// laser): the step is repeated after re-homing. Other faults (e-stop, limit
/// switch, interlock) need a person and end the run.
fn recoverable(e: &RunError) -> bool {
    use protocol::{CommandError, FaultCause};
    match e {
        RunError::Link(LinkError::DeviceReset { .. }) | RunError::SweepAborted(_) => true,
        RunError::Link(LinkError::Refused {
            error: CommandError::Faulted(FaultCause::HeartbeatLost),
            ..
        }) => true,
        _ => false,
    }
}

/// A frame lost or damaged on its way from the camera: the step is repeated
/// (frames already journaled are kept).
fn retakeable(e: &RunError) -> bool {
    matches!(
        e,
        RunError::Camera(CameraError::BadFrame(_)) | RunError::WrongFrame { .. }
    )
}

/// Laser off, lamps off; best effort (the MCU's own safety does the rest).
pub async fn safe_off(link: &Link) {
    let _ = link.laser_arm(false).await;
    let _ = link.lamps(0).await;
}

/// The arc homes towards negative angles and only finds its home cam from
/// the positive side (otherwise it runs into its end switch): with the
/// carriage somewhere in `lo..=hi` (rad), a relative move clears the lower
/// end without pushing the upper one past the arc's soft range (that is its
/// end switch).
async fn bring_arc_over_home(link: &Link, lo: f64, hi: f64) -> Result<(), LinkError> {
    if lo < 0.0 {
        let shift = (-lo + 0.2).min(LIGHT_ARC.soft_max - hi);
        link.move_rad(Axis::LightArc, shift, true, 0.0, 0.0).await?;
        link.wait_motion_done(Axis::LightArc).await?;
    }
    Ok(())
}

async fn home_both(link: &Link) -> Result<(), LinkError> {
    link.home(Axis::Turntable).await?;
    link.home(Axis::LightArc).await?;
    link.wait_motion_done(Axis::Turntable).await?;
    link.wait_motion_done(Axis::LightArc).await?;
    Ok(())
}

async fn settle(seconds: f64, opts: &RunOptions) {
    tokio::time::sleep(Duration::from_secs_f64(seconds / opts.time_scale.max(1e-3))).await;
}

/// Dwell per sweep position: the camera's frame period or the exposure, plus
/// the pulse and a margin for the readout.
fn dwell_us(exposure_s: f64, pulse_us: u32) -> u32 {
    let period = 1.0 / NOMINAL_GEOMETRY.sensor.frame_rate;
    (exposure_s.max(period) * 1e6).ceil() as u32 + pulse_us + 5_000
}

#[allow(clippy::too_many_arguments)]
async fn run_step(
    link: &Link,
    cameras: &mut [Box<dyn Camera>],
    by_index: &BTreeMap<u8, usize>,
    operator: &mut dyn Operator,
    dir: &mut CaptureDir,
    plan: &Plan,
    step: &Step,
    opts: &RunOptions,
    rig: &mut RigCache,
    settings: &mut BTreeMap<u8, CameraSettings>,
    report: &mut RunReport,
    progress: &mut dyn Progress,
) -> Result<(), RunError> {
    // Subscribe first, so a reset during this step is seen while waiting for frames.
    let mut events = link.subscribe();
    if !rig.homed {
        // After a reset (or at start) the laser is off and nothing is where we think.
        rig.laser = None;
        rig.lamps = 0;
        link.laser_arm(false).await?;
        link.lamps(0).await?;
        // An MCU that kept running while the host did not (a capture
        // resumed after the host died) knows where its arc stopped.
        let status = link.status().await?;
        if status.axes[Axis::LightArc.index()].homed
            && let Some(at) = link.position_rad(&status, Axis::LightArc)
        {
            bring_arc_over_home(link, at, at).await?;
        }
        home_both(link).await?;
        rig.homed = true;
        rig.turntable = 0.0;
        rig.light_arc = 0.0;
        rig.light_arc_from = 0.0;
    }
    if rig.pass != Some(step.pass) {
        operator.begin_pass(step.pass);
        rig.pass = Some(step.pass);
    }
    // The operator's step: laser off while a person handles the unit.
    if let Some(e) = step.clamp_elevation
        && rig.clamp.is_none_or(|c| (c - e).abs() > 1e-9)
    {
        link.laser_arm(false).await?;
        rig.laser = None;
        progress.note(&format!(
            "operator: clamp the laser at {:.1} deg",
            e.to_degrees()
        ));
        operator.move_laser_clamp(e).await?;
        rig.clamp = Some(e);
    }
    // A calibration step's target, laser off while it is handled.
    if let Some(cal) = &step.calibration
        && rig.target.as_deref() != Some(cal.target.as_str())
    {
        link.laser_arm(false).await?;
        rig.laser = None;
        progress.note(&format!(
            "operator: put the {} on the turntable",
            cal.target
        ));
        operator.place_on_turntable(&cal.target).await?;
        rig.target = Some(cal.target.clone());
    }
    // Both axes at once; exposures wait until both stop and settle.
    let mut settle_s: f64 = 0.0;
    rig.light_arc_from = rig.light_arc;
    for (axis, mech, target, current) in [
        (
            Axis::Turntable,
            &TURNTABLE,
            step.turntable,
            &mut rig.turntable,
        ),
        (
            Axis::LightArc,
            &LIGHT_ARC,
            step.light_arc,
            &mut rig.light_arc,
        ),
    ] {
        if (*current - target).abs() > 1e-9 {
            link.move_rad(axis, target, false, 0.0, 0.0).await?;
            *current = target;
            settle_s = settle_s.max(mech.settle_time);
        }
    }
    if settle_s > 0.0 {
        link.wait_motion_done(Axis::Turntable).await?;
        link.wait_motion_done(Axis::LightArc).await?;
        settle(settle_s, opts).await;
    }
    // Light.
    match &step.light {
        Light::Laser { colour, .. } => {
            if rig.lamps != 0 {
                link.lamps(0).await?;
                rig.lamps = 0;
            }
            if rig.laser != Some(*colour) {
                link.laser_arm(false).await?;
                link.laser_select(*colour).await?;
                link.laser_power(plan.config.laser_power_permille).await?;
                rig.laser = Some(*colour);
            }
            link.laser_arm(true).await?;
        }
        Light::Lamp { lamp } => {
            if rig.laser.is_some() {
                link.laser_arm(false).await?;
                rig.laser = None;
            }
            let mask = 1u8 << lamp;
            if rig.lamps != mask {
                link.lamps(mask).await?;
                rig.lamps = mask;
            }
        }
    }
    // Cameras: exposure of this step, one tag per trigger.
    let want = CameraSettings {
        exposure_s: step.exposure_s,
        gain_db: plan.config.gain_db,
        binning: step.binning(&plan.config),
    };
    let tags: Vec<u64> = (0..step.triggers()).map(|k| step.frame_tag(k)).collect();
    for &c in &step.cameras {
        let cam = &mut cameras[by_index[&c]];
        if settings.get(&c) != Some(&want) {
            cam.configure(want).await?;
            settings.insert(c, want);
        }
        cam.arm(tags.clone()).await?;
    }
    // Fire.
    let mask = step.camera_mask();
    let pulse_us = plan.config.pulse_us;
    match &step.light {
        Light::Laser { galvo, .. } => {
            let urad = |a: f64| (a * 1e6).round() as i32;
            link.galvo_sweep(Sweep {
                start_urad: urad(galvo[0]),
                end_urad: urad(galvo[galvo.len() - 1]),
                steps: galvo.len() as u16,
                dwell_us: dwell_us(step.exposure_s, pulse_us),
                trigger_mask: mask,
                pulse_us,
            })
            .await?;
            let completed = link.wait_sweep_done().await?;
            // Dark while the frames come in (the simulated cameras render now).
            link.laser_arm(false).await?;
            if !completed {
                return Err(RunError::SweepAborted(step.index));
            }
        }
        Light::Lamp { .. } => link.trigger(mask, pulse_us).await?,
    }
    // Frames, trigger by trigger, cameras in index order (the journal order).
    let mut batch = FrameBatch::default();
    let received = async {
        for (k, &tag) in tags.iter().enumerate() {
            for &c in &step.cameras {
                let cam = &mut cameras[by_index[&c]];
                let frame = receive_frame(cam, &mut events, opts, c, tag).await?;
                let key = (step.index, k as u32, c);
                if dir.has_frame(key) {
                    report.frames_kept += 1;
                    continue;
                }
                batch.push(key, step.frame_path(k, c), frame.to_png()?);
                if batch.bytes >= FRAME_BATCH_BYTES {
                    batch.write(dir, step, report, progress)?;
                }
            }
        }
        Ok(())
    }
    .await;
    // What came before an error is kept too.
    batch.write(dir, step, report, progress)?;
    received
}

/// Frames of a step held for one durable write: at most this many bytes of
/// PNG (a paper-scale step's frames would not fit in memory).
const FRAME_BATCH_BYTES: usize = 32 << 20;

#[derive(Default)]
struct FrameBatch {
    frames: Vec<(crate::dir::FrameKey, String, Vec<u8>)>,
    bytes: usize,
}

impl FrameBatch {
    fn push(&mut self, key: crate::dir::FrameKey, path: String, png: Vec<u8>) {
        self.bytes += png.len();
        self.frames.push((key, path, png));
    }

    /// Writes the held frames durably, journals them and reports them.
    fn write(
        &mut self,
        dir: &mut CaptureDir,
        step: &Step,
        report: &mut RunReport,
        progress: &mut dyn Progress,
    ) -> Result<(), RunError> {
        if self.frames.is_empty() {
            return Ok(());
        }
        let frames: Vec<_> = (self.frames.iter())
            .map(|(key, path, png)| (*key, path.as_str(), png.as_slice()))
            .collect();
        dir.write_frames(&frames)?;
        let n = frames.len();
        report.frames_written += n;
        for done in dir.frame_count() + 1 - n..=dir.frame_count() {
            progress.frame(step, done);
        }
        self.frames.clear();
        self.bytes = 0;
        Ok(())
    }
}

/// The next frame of camera `c`, which must be tagged `tag`.
async fn receive_frame(
    cam: &mut Box<dyn Camera>,
    events: &mut qhm_link::EventStream,
    opts: &RunOptions,
    c: u8,
    tag: u64,
) -> Result<crate::camera::Frame, RunError> {
    let frame = tokio::select! {
        f = cam.next_frame(opts.frame_timeout) => f?,
        e = wait_reset(events) => return Err(e.into()),
    };
    if frame.meta.tag != tag {
        return Err(RunError::WrongFrame {
            camera: c,
            got: frame.meta.tag,
            expected: tag,
        });
    }
    Ok(frame)
}

/// Resolves only when the link reports a reset or a disconnect.
async fn wait_reset(events: &mut qhm_link::EventStream) -> LinkError {
    loop {
        match events.recv().await {
            Ok(LinkEvent::DeviceReset {
                interrupted,
                status,
            }) => {
                return LinkError::DeviceReset {
                    interrupted,
                    status,
                };
            }
            Ok(LinkEvent::Disconnected { reason }) => return LinkError::Disconnected { reason },
            Ok(_) | Err(LinkError::Lagged(_)) => {}
            Err(e) => return e,
        }
    }
}
