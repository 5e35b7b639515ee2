//! The built-in simulated rig (`--sim`, `qhm demo`): the emulated MCU behind
//! an in-process link, and simulated cameras fired by its trigger lines.
//!
//! [`SimRig::start`] returns what a real rig gives the host: a [`Link`] and
//! cameras. Only [`SimHandle`] (the operator's hands: the laser clamp, the
//! turntable load; and fault injection for tests) knows it is simulated.
//!
//! The cameras: one thread (the "hub") receives every [`TriggerEvent`] the
//! emulated MCU publishes with the physical rig state at the rising edge,
//! renders that pose once with the sim-light Monte Carlo (rayon inside) for
//! every camera on the trigger mask, caches the radiance (so the exposures of
//! a bracket and all cameras share it), and exposes each armed camera's
//! sensor with the exposure and gain the host set. Rig, sample and cameras
//! share the emulator's virtual clock: a frame's `trigger_us` is the edge's
//! virtual time.
//!
//! Determinism: the Monte Carlo seed derives from the run seed and the pose
//! (angles, light, trigger mask, scene), the sensor noise seed from the run
//! seed, the frame's tag (its plan position) and the camera, never from time or
//! arrival order; so a resumed capture reproduces the frames of an
//! uninterrupted one bit for bit.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::time::Duration;

use qhm_link::{Link, LinkConfig, LinkError};
use sim::{FaultConfig, RigHandle, RigState, SimConfig, TriggerEvent};
use sim_light::sample::TargetDesc;
use sim_light::{Illumination, LaserOn, PoseRadiance, RigTruth, SceneDesc, SimQuality, World};
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};

use qhm_acquire::{
    BoxFuture, Camera, CameraError, CameraInfo, CameraSettings, Frame, FrameMeta, Operator,
    OperatorError, Pass, PixelFormat, Scale,
};

#[derive(Debug, thiserror::Error)]
pub enum SimRigError {
    #[error("simulated world: {0}")]
    World(#[from] sim_light::Error),
    #[error("emulated rig: {0}")]
    Rig(#[from] sim::SimError),
    #[error("link to the emulated rig: {0}")]
    Link(#[from] LinkError),
    #[error("starting the camera thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// How to build the simulated rig.
#[derive(Debug, Clone)]
pub struct SimRigConfig {
    /// Sample preset name or TOML file (sim-light `SceneDesc::load`).
    pub sample: String,
    /// Photon budget and image binning follow the capture scale.
    pub quality: SimQuality,
    /// Seed of everything random in the world (rig errors, boot ids, MC, noise).
    pub seed: u64,
    /// Virtual seconds per wall second, at most (the rig runs in lockstep
    /// with the host, see `host_lead_us`).
    pub speed: f64,
    /// The emulated rig's lockstep lead (`sim::SimConfig::host_lead_us`):
    /// a host late for its heartbeat holds the rig back instead of losing
    /// it. `None` runs the rig free, as `qhm sim --pty` does.
    pub host_lead_us: Option<u64>,
    /// Faults on the link (tests).
    pub faults: FaultConfig,
    /// Radiance cache budget, bytes.
    pub cache_bytes: usize,
}

impl SimRigConfig {
    pub fn new(sample: &str, scale: Scale, seed: u64) -> SimRigConfig {
        let quality = capture_quality(scale);
        SimRigConfig {
            sample: sample.to_string(),
            quality,
            seed,
            speed: SIM_SPEED,
            host_lead_us: Some(HOST_LEAD_US),
            faults: FaultConfig::none(),
            cache_bytes: 1 << 30,
        }
    }

    /// The simulated rig for the calibration capture of `scale`
    /// (`qhm_acquire::cal_plan`): the same rig (seed) as the capture's, the
    /// colour pattern on the turntable to begin with, at
    /// [`calibration_quality`].
    pub fn calibration(scale: Scale, seed: u64) -> SimRigConfig {
        SimRigConfig {
            quality: calibration_quality(scale),
            ..SimRigConfig::new(qhm_acquire::cal_plan::COLOUR_PATTERN, scale, seed)
        }
    }
}

/// The simulated rig's sim quality at each capture scale. sim-light's
/// quality ladder (`SimQuality::ci`, `preview`, `default_scale`, `final_scale`)
/// names image sizes and photon budgets, not capture scales: the default
/// capture renders at its `preview` rung and the paper capture at its
/// `default_scale` rung. These functions say which, by the capture's name.
pub fn capture_quality(scale: Scale) -> SimQuality {
    match scale {
        Scale::Ci => ci_capture_quality(),
        Scale::Default => default_capture_quality(),
        Scale::Paper => paper_capture_quality(),
    }
}

/// The ci capture's: sim-light's ci photon budget binned 4, not its ci 8
/// (at 0.7 mm pixels the stripe's near field blurs into the fitted profile:
/// a' and s'_t biased), with a quarter of the photons for pass 1's stripes.
pub fn ci_capture_quality() -> SimQuality {
    let ci = SimQuality::ci();
    SimQuality {
        downscale: 4,
        entrance_laser_photons: Some(ci.laser_photons / 4),
        ..ci
    }
}

/// The default capture's (the demo's): sim-light's `preview` rung, 256 x 192,
/// with a sixteenth of the photons for each of pass 1's stripes: four times
/// as many lines as pass 2's, with the photons a quarter would give at its
/// six (`SimQuality::entrance_laser_photons`).
pub fn default_capture_quality() -> SimQuality {
    let preview = SimQuality::preview();
    SimQuality {
        entrance_laser_photons: Some(preview.laser_photons / 16),
        ..preview
    }
}

/// The paper capture's: sim-light's full-frame `default_scale` rung,
/// 1024 x 768, every stripe at the full photon budget.
pub fn paper_capture_quality() -> SimQuality {
    SimQuality::default_scale()
}

/// The calibration capture's for `scale`: the default capture's image size
/// or better whatever the scale (checkerboard corners need pixels), every
/// stripe at the full photon budget (laser planes are fitted at every clamp
/// position), and at least [`CALIBRATION_LAMP_PHOTONS`] per lamp.
pub fn calibration_quality(scale: Scale) -> SimQuality {
    let quality = match scale {
        Scale::Ci | Scale::Default => SimQuality::preview(),
        Scale::Paper => paper_capture_quality(),
    };
    SimQuality {
        lamp_photons: quality.lamp_photons.max(CALIBRATION_LAMP_PHOTONS),
        ..quality
    }
}

/// How much faster than real time the built-in rig's clock runs, at most.
/// The rig moves, dwells and times out in rig time as a real one would;
/// only the wall time shrinks. At 200x a default capture's sweeps (a
/// 3.75 fps camera dwells 273 ms per trigger) take 40 ms of wall time each;
/// the host's 1 ms timer ticks are then 200 ms of rig time, which
/// [`HOST_LEAD_US`] covers.
pub const SIM_SPEED: f64 = 200.0;

/// The built-in rig's lockstep lead, virtual µs: 80 % of the MCU's 250 ms
/// heartbeat timeout. Any host frame resets that timeout, and a heartbeat
/// frame takes about 1 ms of rig time on the line, so a host the rig waits
/// for can never lose it, however the host's process is scheduled; and one
/// host timer tick (1 ms of wall time, 200 ms of rig time at [`SIM_SPEED`])
/// fits in the lead, so a host on time does not hold the rig back.
pub const HOST_LEAD_US: u64 = 200_000;

/// Lamp photons of a calibration frame, at least (on a calibration target
/// the three channels share them, `sim_light::walk::Accum::rgb`): the patch
/// means of two cameras share photons only where their pixels cover the same
/// texels, so at 40 k (ci) the colour gains were off by up to 4 %; Monte Carlo
/// noise sets the checkerboard corners' reprojection RMS (0.12 px at 1 M,
/// binning 2).
pub const CALIBRATION_LAMP_PHOTONS: u64 = 1_000_000;

/// The operator's hands on the simulated rig, and fault injection.
#[derive(Clone)]
pub struct SimHandle {
    rig: RigHandle,
    world: Arc<RwLock<World>>,
    sample: SceneDesc,
    stats: Arc<Mutex<RenderStats>>,
}

/// The Monte Carlo the simulated cameras have run so far (cache misses only).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RenderStats {
    /// Poses rendered.
    pub poses: u64,
    /// Photons launched.
    pub photons: u64,
    /// Real collisions (scattering or absorption) of those photons.
    pub events: u64,
    /// Wall time spent rendering, s.
    pub seconds: f64,
}

impl RenderStats {
    /// Scattering events per wall second of rendering.
    pub fn events_per_s(&self) -> f64 {
        if self.seconds > 0.0 {
            self.events as f64 / self.seconds
        } else {
            0.0
        }
    }
}

impl SimHandle {
    /// The Monte Carlo run so far: poses, photons, events and render time.
    pub fn render_stats(&self) -> RenderStats {
        *self.stats.lock().unwrap_or_else(|e| e.into_inner())
    }
    /// The emulated MCU (fault injection: `reset_mcu`, `disconnect`, interlock).
    pub fn rig(&self) -> &RigHandle {
        &self.rig
    }
    /// Where the laser clamp is now, radians.
    pub fn laser_mount(&self) -> f64 {
        self.world
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .laser_mount()
    }
    pub fn set_laser_mount(&self, elevation: f64) {
        self.world
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .set_laser_mount(elevation);
    }
    /// Whether the capture is in its entrance pass (`World::set_entrance_scan`).
    pub fn set_entrance_scan(&self, on: bool) {
        self.world
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .set_entrance_scan(on);
    }
    /// Put the sample (`"sample"`), a target preset, or the checkerboard on
    /// a spacer (`qhm_acquire::cal_plan::checkerboard_on_spacer`) on the turntable.
    pub fn place(&self, what: &str) -> Result<(), sim_light::Error> {
        let desc = if what == "sample" {
            self.sample.clone()
        } else if let Some(mm) = qhm_acquire::cal_plan::spacer_of(what) {
            let mut desc = SceneDesc::preset(qhm_acquire::cal_plan::CHECKERBOARD)?;
            if let SceneDesc::Target {
                target: TargetDesc::Checkerboard { height_mm, .. },
            } = &mut desc
            {
                *height_mm = mm;
            }
            desc
        } else {
            SceneDesc::preset(what)?
        };
        let mut w = self.world.write().unwrap_or_else(|e| e.into_inner());
        let mut next = World::new(desc, w.rig().clone(), *w.quality())?;
        next.set_laser_mount(w.laser_mount());
        next.set_entrance_scan(w.entrance_scan());
        *w = next;
        Ok(())
    }
    /// The true rig (for reports of recovered against true calibration).
    pub fn truth(&self) -> RigTruth {
        self.world
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .rig()
            .clone()
    }
    /// An operator that acts at once.
    pub fn operator(&self) -> SimOperator {
        SimOperator {
            handle: self.clone(),
        }
    }
}

/// The simulated operator: moves the clamp and swaps targets instantly.
pub struct SimOperator {
    handle: SimHandle,
}

impl Operator for SimOperator {
    fn move_laser_clamp(&mut self, elevation: f64) -> BoxFuture<'_, Result<(), OperatorError>> {
        let ok = elevation.is_finite()
            && (0.0..=std::f64::consts::FRAC_PI_2 + 1e-9).contains(&elevation);
        if ok {
            self.handle.set_laser_mount(elevation);
        }
        Box::pin(async move {
            ok.then_some(()).ok_or_else(|| {
                OperatorError::Failed(format!("no clamp position at {elevation} rad"))
            })
        })
    }
    fn place_on_turntable(&mut self, what: &str) -> BoxFuture<'_, Result<(), OperatorError>> {
        let r = self
            .handle
            .place(what)
            .map_err(|e| OperatorError::Failed(e.to_string()));
        Box::pin(async move { r })
    }
    fn begin_pass(&mut self, pass: Pass) {
        self.handle.set_entrance_scan(pass == Pass::Entrance);
    }
}

/// A started simulated rig.
pub struct SimRig {
    pub link: Link,
    pub cameras: Vec<Box<dyn Camera>>,
    pub handle: SimHandle,
    stop: Arc<AtomicBool>,
}

impl SimRig {
    /// Starts the emulated MCU, the link and the cameras (within a tokio runtime).
    pub async fn start(sample: &str, scale: Scale, seed: u64) -> Result<SimRig, SimRigError> {
        Self::start_with(SimRigConfig::new(sample, scale, seed)).await
    }

    pub async fn start_with(cfg: SimRigConfig) -> Result<SimRig, SimRigError> {
        let desc = SceneDesc::load(&cfg.sample)?;
        let world = World::new(desc.clone(), RigTruth::perturbed(cfg.seed), cfg.quality)?;
        let mut sim_cfg = SimConfig::seeded(cfg.seed);
        sim_cfg.speed = cfg.speed;
        sim_cfg.host_lead_us = cfg.host_lead_us;
        sim_cfg.link.faults = cfg.faults;
        let (stream, rig) = sim::spawn_in_process(&sim_cfg)?;
        let triggers = rig.subscribe_triggers();
        let link = Link::open_stream(Box::new(stream), LinkConfig::scaled(cfg.speed)).await?;
        let world = Arc::new(RwLock::new(world));
        let (width, height) = world.read().unwrap_or_else(|e| e.into_inner()).image_size();
        let stop = Arc::new(AtomicBool::new(false));
        let state = Arc::new(Mutex::new(HubState::default()));
        let mut cameras: Vec<Box<dyn Camera>> = Vec::new();
        for (k, _) in hardware::NOMINAL_GEOMETRY.cameras.iter().enumerate() {
            let (tx, rx) = unbounded_channel();
            state.lock().unwrap_or_else(|e| e.into_inner()).cams[k] = CamSlot {
                tx: Some(tx),
                ..CamSlot::default()
            };
            cameras.push(Box::new(SimCamera {
                index: k as u8,
                size: (width, height),
                downscale: cfg.quality.downscale,
                state: state.clone(),
                rx,
                rig: rig.clone(),
            }));
        }
        let stats = Arc::new(Mutex::new(RenderStats::default()));
        let hub = Hub {
            world: world.clone(),
            binned: Vec::new(),
            state,
            seed: cfg.seed,
            cache: RadianceCache {
                entries: VecDeque::new(),
                budget: cfg.cache_bytes,
                stats: stats.clone(),
            },
            stop: stop.clone(),
        };
        std::thread::Builder::new()
            .name("sim-cameras".into())
            .spawn(move || hub.run(triggers))?;
        Ok(SimRig {
            link,
            cameras,
            handle: SimHandle {
                rig,
                world,
                sample: desc,
                stats,
            },
            stop,
        })
    }
}

impl Drop for SimRig {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // The host hangs up first: a rig powered down under an open link
        // would be reported to its subscribers as a lost link.
        self.link.close();
        self.handle.rig.shutdown();
    }
}

type FrameMsg = (u64, Result<Frame, CameraError>);

#[derive(Default)]
struct CamSlot {
    settings: Option<CameraSettings>,
    tags: VecDeque<u64>,
    /// Trigger edges before this virtual time belong to an older arming.
    armed_after_us: u64,
    generation: u64,
    counter: u64,
    tx: Option<UnboundedSender<FrameMsg>>,
}

#[derive(Default)]
struct HubState {
    cams: [CamSlot; 8],
}

/// A simulated camera on the arc.
struct SimCamera {
    index: u8,
    size: (u32, u32),
    downscale: u32,
    state: Arc<Mutex<HubState>>,
    rx: UnboundedReceiver<FrameMsg>,
    rig: RigHandle,
}

impl SimCamera {
    fn slot<R>(&self, f: impl FnOnce(&mut CamSlot) -> R) -> R {
        f(&mut self.state.lock().unwrap_or_else(|e| e.into_inner()).cams[self.index as usize])
    }
}

impl Camera for SimCamera {
    fn info(&self) -> CameraInfo {
        CameraInfo {
            index: self.index,
            vendor: "qhm".into(),
            model: "simulated".into(),
            serial: format!("sim-{}", self.index),
            width: self.size.0 * self.downscale,
            height: self.size.1 * self.downscale,
        }
    }

    fn configure(&mut self, settings: CameraSettings) -> BoxFuture<'_, Result<(), CameraError>> {
        let camera = self.index;
        let r = if ![1, 2, 4, 8, 16].contains(&settings.binning) {
            Err(CameraError::Unsupported {
                camera,
                what: format!("binning {} (1, 2, 4, 8 or 16)", settings.binning),
            })
        } else if !(settings.exposure_s.is_finite() && settings.exposure_s > 0.0) {
            Err(CameraError::Unsupported {
                camera,
                what: format!("exposure {} s", settings.exposure_s),
            })
        } else if !(0.0..=48.0).contains(&settings.gain_db) {
            Err(CameraError::Unsupported {
                camera,
                what: format!("gain {} dB", settings.gain_db),
            })
        } else {
            self.slot(|s| s.settings = Some(settings));
            Ok(())
        };
        Box::pin(async move { r })
    }

    fn arm(&mut self, tags: Vec<u64>) -> BoxFuture<'_, Result<(), CameraError>> {
        let now = self.rig.now_us();
        let camera = self.index;
        let r = self.slot(|s| {
            if s.settings.is_none() {
                return Err(CameraError::Unsupported {
                    camera,
                    what: "arm before configure".into(),
                });
            }
            s.tags = tags.into();
            s.armed_after_us = now;
            s.generation += 1;
            Ok(())
        });
        while self.rx.try_recv().is_ok() {}
        Box::pin(async move { r })
    }

    fn next_frame(&mut self, timeout: Duration) -> BoxFuture<'_, Result<Frame, CameraError>> {
        Box::pin(async move {
            let camera = self.index;
            let generation = self.slot(|s| s.generation);
            let deadline = tokio::time::Instant::now() + timeout;
            loop {
                match tokio::time::timeout_at(deadline, self.rx.recv()).await {
                    Err(_) => return Err(CameraError::Timeout { camera, timeout }),
                    Ok(None) => {
                        return Err(CameraError::Disconnected {
                            camera,
                            why: "the simulated world stopped".into(),
                        });
                    }
                    Ok(Some((g, frame))) if g == generation => return frame,
                    Ok(Some(_)) => {} // from an older arming
                }
            }
        })
    }

    fn disarm(&mut self) -> BoxFuture<'_, Result<(), CameraError>> {
        self.slot(|s| {
            s.tags.clear();
            s.generation += 1;
        });
        while self.rx.try_recv().is_ok() {}
        Box::pin(async { Ok(()) })
    }
}

/// A frame to expose on a trigger edge.
struct Job {
    camera: u8,
    tag: u64,
    settings: CameraSettings,
    generation: u64,
    counter: u64,
    tx: UnboundedSender<FrameMsg>,
}

/// The current world rendered at binning `b` (built once per scene and binning).
fn binned_world<'a>(
    binned: &'a mut Vec<(u32, String, World)>,
    world: &World,
    b: u32,
) -> Result<&'a World, sim_light::Error> {
    let scene = world.desc().to_toml_string();
    binned.retain(|(_, s, _)| *s == scene);
    let i = match binned.iter().position(|(x, _, _)| *x == b) {
        Some(i) => i,
        None => {
            let quality = SimQuality {
                downscale: b,
                ..*world.quality()
            };
            let w = World::new(world.desc().clone(), world.rig().clone(), quality)?;
            binned.push((b, scene, w));
            binned.len() - 1
        }
    };
    binned[i].2.set_laser_mount(world.laser_mount());
    binned[i].2.set_entrance_scan(world.entrance_scan());
    Ok(&binned[i].2)
}

/// Rendered poses, most recently used last, within a byte budget.
struct RadianceCache {
    entries: VecDeque<(u64, Arc<PoseRadiance>, usize)>,
    budget: usize,
    stats: Arc<Mutex<RenderStats>>,
}

impl RadianceCache {
    /// The radiance of the pose `key` names, from the cache or rendered with `mc_seed`.
    fn radiance(
        &mut self,
        world: &World,
        ev: &TriggerEvent,
        mc_seed: u64,
        key: u64,
    ) -> Result<Arc<PoseRadiance>, sim_light::Error> {
        if let Some(i) = self.entries.iter().position(|(k, _, _)| *k == key) {
            let hit = self.entries.remove(i).expect("index from position");
            let r = hit.1.clone();
            self.entries.push_back(hit);
            return Ok(r);
        }
        let t = std::time::Instant::now();
        let radiance = Arc::new(world.render_pose(&illumination(&ev.state), ev.mask, mc_seed)?);
        {
            let mut st = self.stats.lock().unwrap_or_else(|e| e.into_inner());
            st.poses += 1;
            st.photons += radiance.tally.launched;
            st.events += radiance.tally.events;
            st.seconds += t.elapsed().as_secs_f64();
        }
        let bytes = radiance
            .images
            .iter()
            .flatten()
            .map(|i| i.data.len() * 12)
            .sum();
        self.entries.push_back((key, radiance.clone(), bytes));
        while self.entries.iter().map(|c| c.2).sum::<usize>() > self.budget
            && self.entries.len() > 1
        {
            self.entries.pop_front();
        }
        Ok(radiance)
    }
}

/// Renders and exposes on trigger edges.
struct Hub {
    world: Arc<RwLock<World>>,
    /// The current scene at binnings other than the world's: (binning, scene TOML, world).
    binned: Vec<(u32, String, World)>,
    state: Arc<Mutex<HubState>>,
    seed: u64,
    cache: RadianceCache,
    stop: Arc<AtomicBool>,
}

/// SplitMix64 finaliser: a well-mixed 64-bit hash step.
fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Sensor noise seed of a frame: from the run seed, its tag and the camera.
pub fn noise_seed(seed: u64, tag: u64, camera: u8) -> u64 {
    mix64(mix64(seed ^ 0x6e6f_6973_65) ^ mix64(tag) ^ ((camera as u64) << 56))
}

/// The pose a trigger edge saw, as sim-light takes it.
fn illumination(s: &RigState) -> Illumination {
    Illumination {
        turntable_rad: s.turntable_rad,
        light_arc_rad: s.light_arc_rad,
        // The mirror turns the beam by twice its mechanical angle.
        galvo_rad: 2.0 * s.galvo_rad,
        laser: s.laser.map(|(c, p)| LaserOn {
            channel: c.index(),
            power: p,
        }),
        lamps: s.lamps,
    }
}

/// Hash of everything the radiance depends on (angles to 1 urad).
fn pose_key(world: &World, ev: &TriggerEvent) -> u64 {
    let q = |a: f64| (a * 1e6).round() as i64 as u64;
    let s = &ev.state;
    // Lamps alone do not care where the galvo points or where the laser is
    // clamped (a resumed run may reach a lamp pose with either elsewhere).
    let laser_on = s.laser.is_some();
    let laser_only = |v: u64| if laser_on { v } else { 0 };
    let mut h = mix64(q(s.turntable_rad));
    for v in [
        q(s.light_arc_rad),
        laser_only(q(s.galvo_rad)),
        s.laser.map_or(0, |(c, p)| {
            1 + c.index() as u64 * 10_000 + (p * 1000.0).round() as u64
        }),
        s.lamps as u64,
        ev.mask as u64,
        laser_only(q(world.laser_mount())),
    ] {
        h = mix64(h ^ v);
    }
    // A vertical stripe of the entrance pass takes fewer photons than pass
    // 2's at the same pose. Oblique stripes come in pass 1 alone, so the
    // pass adds nothing to any other key.
    let vertical = (world.laser_mount() - std::f64::consts::FRAC_PI_2).abs() < 1e-6;
    if laser_on && vertical && world.entrance_scan() {
        h = mix64(h ^ 1);
    }
    for b in world.desc().to_toml_string().bytes() {
        h = mix64(h ^ b as u64);
    }
    h
}

impl Hub {
    fn run(mut self, mut triggers: UnboundedReceiver<TriggerEvent>) {
        use tokio::sync::mpsc::error::TryRecvError;
        // Poll, so the thread also ends when the SimRig is dropped while
        // someone still holds a handle on the emulated rig.
        while !self.stop.load(Ordering::SeqCst) {
            match triggers.try_recv() {
                Ok(ev) => self.on_trigger(&ev),
                Err(TryRecvError::Empty) => std::thread::sleep(Duration::from_millis(1)),
                Err(TryRecvError::Disconnected) => break,
            }
        }
        // Wake waiting cameras: the world is gone.
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        for c in st.cams.iter_mut() {
            c.tx = None;
        }
    }

    fn on_trigger(&mut self, ev: &TriggerEvent) {
        let mut jobs = Vec::new();
        {
            let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            for (k, c) in st.cams.iter_mut().enumerate() {
                if ev.mask & (1 << k) == 0 || ev.at_us < c.armed_after_us {
                    continue;
                }
                let (Some(settings), Some(tx)) = (c.settings, c.tx.clone()) else {
                    continue;
                };
                let Some(tag) = c.tags.pop_front() else {
                    continue;
                };
                c.counter += 1;
                jobs.push(Job {
                    camera: k as u8,
                    tag,
                    settings,
                    generation: c.generation,
                    counter: c.counter,
                    tx,
                });
            }
        }
        // One rendering per binning the armed cameras asked for.
        let mut binnings: Vec<u32> = jobs.iter().map(|j| j.settings.binning).collect();
        binnings.sort_unstable();
        binnings.dedup();
        let shared = self.world.clone();
        let world = shared.read().unwrap_or_else(|e| e.into_inner());
        for b in binnings {
            let group: Vec<&Job> = jobs.iter().filter(|j| j.settings.binning == b).collect();
            let base = world.quality().downscale == b;
            let binned = if base {
                Ok(&*world)
            } else {
                binned_world(&mut self.binned, &world, b)
            };
            let key = if base {
                pose_key(&world, ev)
            } else {
                mix64(pose_key(&world, ev) ^ b as u64)
            };
            let cache = &mut self.cache;
            let radiance = binned.and_then(|w| {
                cache
                    .radiance(w, ev, mix64(self.seed ^ key), key)
                    .map(|r| (w, r))
            });
            match radiance {
                Ok((w, r)) => Self::expose(w, &r, ev, self.seed, &group),
                Err(e) => {
                    for j in group {
                        let _ = j.tx.send((
                            j.generation,
                            Err(CameraError::Driver(format!("simulated world: {e}"))),
                        ));
                    }
                }
            }
        }
    }

    /// Exposes each job's sensor to the radiance and sends the frame.
    fn expose(world: &World, radiance: &PoseRadiance, ev: &TriggerEvent, seed: u64, jobs: &[&Job]) {
        for j in jobs {
            let Some(img) = radiance.image(j.camera as usize) else {
                continue;
            };
            let gain = 10f64.powf(j.settings.gain_db / 20.0);
            let f = world.sensor(j.camera as usize).expose(
                img,
                j.settings.exposure_s,
                gain,
                noise_seed(seed, j.tag, j.camera),
            );
            let frame = Frame {
                meta: FrameMeta {
                    camera: j.camera,
                    tag: j.tag,
                    trigger_us: ev.at_us,
                    exposure_s: j.settings.exposure_s,
                    gain_db: j.settings.gain_db,
                    frame_counter: j.counter,
                },
                width: f.width,
                height: f.height,
                format: PixelFormat::Rgb8,
                data: f.rgb,
            };
            let _ = j.tx.send((j.generation, Ok(frame)));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Image binning, photons per stripe, per entrance-pass stripe and per lamp.
    fn budget(q: SimQuality) -> (u32, u64, Option<u64>, u64) {
        (
            q.downscale,
            q.laser_photons,
            q.entrance_laser_photons,
            q.lamp_photons,
        )
    }

    #[test]
    fn each_capture_scale_renders_at_its_named_quality() {
        assert_eq!(
            budget(capture_quality(Scale::Ci)),
            (4, 640_000, Some(160_000), 40_000)
        );
        assert_eq!(
            budget(capture_quality(Scale::Default)),
            (4, 640_000, Some(40_000), 100_000)
        );
        assert_eq!(
            budget(capture_quality(Scale::Paper)),
            (1, 1_000_000, None, 1_000_000)
        );
        assert_eq!(
            SimRigConfig::new("marble", Scale::Default, 1).quality,
            default_capture_quality()
        );
        // Calibration: the default capture's binning or finer, no
        // entrance-pass budget, at least a million lamp photons.
        for scale in [Scale::Ci, Scale::Default] {
            assert_eq!(
                budget(calibration_quality(scale)),
                (4, 640_000, None, 1_000_000)
            );
        }
        assert_eq!(
            SimRigConfig::calibration(Scale::Paper, 1).quality,
            paper_capture_quality()
        );
    }
}
