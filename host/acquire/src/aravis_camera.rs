//! GenICam cameras (GigE Vision, USB3 Vision) through Aravis 0.8 (feature
//! `aravis`, Debian's libaravis-dev).
//!
//! Aravis objects are not `Send`, so each camera lives on its own thread that
//! owns the `ArvCamera` and its stream; the [`Camera`] methods send it
//! requests and await the answer. Frames come from a pool of stream buffers
//! (`timeout_pop_buffer`), are copied out, and the buffer goes back to the
//! pool. Tags are matched to frames in trigger order, as the trait promises.
//!
//! Trigger source: a hardware line on the rig (`Line1` by default: the
//! Dragonfly-class cameras' opto-isolated input the MCU drives), or
//! `Software`, for a camera with no wire to the MCU's trigger lines (a USB3
//! camera without trigger wiring, Aravis's fake GigE camera). A software
//! camera is fired by the host when the MCU reports that its line fired
//! ([`crate::soft_trigger`], through [`AravisCamera::trigger_handle`]), or
//! by [`AravisCamera::software_trigger`]. Triggers are queued and fired one
//! at a time, the next only once the previous one's frame has arrived:
//! cameras ignore (or, like the fake camera, merge) a trigger that comes
//! while a frame is being taken, and a lost frame must not shift the tags.

use std::collections::VecDeque;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use aravis::prelude::*;
use tokio::sync::oneshot;

use crate::camera::{
    BoxFuture, Camera, CameraError, CameraInfo, CameraSettings, Frame, FrameMeta, PixelFormat,
};

/// How to open one camera.
#[derive(Debug, Clone)]
pub struct AravisConfig {
    /// Position on the camera arc (which trigger line drives it).
    pub index: u8,
    /// GenICam device ID, serial or IP address (`None`: the first camera found).
    pub device: Option<String>,
    /// GenICam trigger source: `Line1`, `Line0`, ... or `Software`.
    pub trigger_source: String,
    /// Stream buffers in the pool (frames that may wait for the host).
    pub buffers: usize,
}

impl AravisConfig {
    pub fn new(index: u8, device: Option<String>) -> AravisConfig {
        AravisConfig {
            index,
            device,
            trigger_source: "Line1".into(),
            buffers: 16,
        }
    }
}

enum Request {
    Configure(CameraSettings, oneshot::Sender<Result<(), CameraError>>),
    Arm(Vec<u64>, oneshot::Sender<Result<(), CameraError>>),
    Next(Duration, oneshot::Sender<Result<Frame, CameraError>>),
    Disarm(oneshot::Sender<Result<(), CameraError>>),
    /// Fire a software trigger (the MCU's line fired at this time, us, if known).
    Fire(
        Option<u64>,
        Option<oneshot::Sender<Result<(), CameraError>>>,
    ),
}

/// Fires one software-triggered camera from another thread or task.
#[derive(Clone)]
pub struct TriggerHandle {
    tx: mpsc::Sender<Request>,
}

impl crate::soft_trigger::SoftwareTrigger for TriggerHandle {
    fn fire(&self, at_us: u64) {
        // A closed camera has nothing to fire.
        let _ = self.tx.send(Request::Fire(Some(at_us), None));
    }
}

/// A GenICam camera on its worker thread.
pub struct AravisCamera {
    info: CameraInfo,
    tx: mpsc::Sender<Request>,
}

fn driver(e: glib::Error) -> CameraError {
    CameraError::Driver(e.to_string())
}

use aravis::glib;

impl AravisCamera {
    /// Opens the camera, selects 8-bit pixels and the trigger source, and
    /// starts the stream (frames flow once triggers come).
    pub fn open(cfg: AravisConfig) -> Result<AravisCamera, CameraError> {
        let (tx, rx) = mpsc::channel();
        let (ready_tx, ready_rx) = mpsc::channel();
        let index = cfg.index;
        std::thread::Builder::new()
            .name(format!("aravis-cam{index}"))
            .spawn(move || match Worker::open(&cfg) {
                Ok((worker, info)) => {
                    let _ = ready_tx.send(Ok(info));
                    worker.serve(rx);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| CameraError::Driver(e.to_string()))?;
        let info = ready_rx.recv().map_err(|_| CameraError::Disconnected {
            camera: index,
            why: "camera thread ended".into(),
        })??;
        Ok(AravisCamera { info, tx })
    }

    fn request<T: Send + 'static>(
        &self,
        make: impl FnOnce(oneshot::Sender<Result<T, CameraError>>) -> Request,
    ) -> BoxFuture<'static, Result<T, CameraError>> {
        let (otx, orx) = oneshot::channel();
        let sent = self.tx.send(make(otx)).is_ok();
        let camera = self.info.index;
        Box::pin(async move {
            let gone = || CameraError::Disconnected {
                camera,
                why: "camera thread ended".into(),
            };
            if !sent {
                return Err(gone());
            }
            orx.await.map_err(|_| gone())?
        })
    }

    /// Queues one software trigger (trigger source `Software` only); the
    /// answer comes once it is queued, the frame through `next_frame`.
    pub fn software_trigger(&mut self) -> BoxFuture<'static, Result<(), CameraError>> {
        self.request(|t| Request::Fire(None, Some(t)))
    }

    /// A handle that fires this camera's software trigger, for the relay of
    /// the MCU's trigger-fired events ([`crate::soft_trigger::relay_triggers`]).
    pub fn trigger_handle(&self) -> TriggerHandle {
        TriggerHandle {
            tx: self.tx.clone(),
        }
    }
}

impl Camera for AravisCamera {
    fn info(&self) -> CameraInfo {
        self.info.clone()
    }
    fn configure(&mut self, settings: CameraSettings) -> BoxFuture<'_, Result<(), CameraError>> {
        self.request(|t| Request::Configure(settings, t))
    }
    fn arm(&mut self, tags: Vec<u64>) -> BoxFuture<'_, Result<(), CameraError>> {
        self.request(|t| Request::Arm(tags, t))
    }
    fn next_frame(&mut self, timeout: Duration) -> BoxFuture<'_, Result<Frame, CameraError>> {
        self.request(|t| Request::Next(timeout, t))
    }
    fn disarm(&mut self) -> BoxFuture<'_, Result<(), CameraError>> {
        self.request(Request::Disarm)
    }
}

/// How often the worker looks for new requests while it waits for a frame.
const POLL: Duration = Duration::from_millis(5);

/// Longest wait for a software trigger's frame beyond its exposure: after it
/// the frame counts as lost (and its tag with it). Long enough that a
/// camera (or its host) starved of CPU for a few seconds is late, not lost.
const TRIGGER_GRACE: Duration = Duration::from_secs(10);

struct Worker {
    index: u8,
    camera: aravis::Camera,
    stream: Option<aravis::Stream>,
    format: PixelFormat,
    buffers: usize,
    settings: Option<CameraSettings>,
    tags: VecDeque<u64>,
    counter: u64,
    /// Trigger source `Software`: the host fires the frames.
    software: bool,
    /// Software triggers not fired yet (MCU time of the line's rise, if known).
    queued: VecDeque<Option<u64>>,
    /// The software trigger whose frame is awaited, and when it was fired.
    in_flight: Option<(Option<u64>, Instant)>,
    /// A software trigger's frame was lost: the stream is set up again
    /// before the next arming (a camera left streaming by a killed host
    /// can stop delivering to this one).
    lost_frame: bool,
    /// Frames (or their failures) of the current arming not yet asked for.
    ready: VecDeque<Result<Frame, CameraError>>,
    /// A `next_frame` waiting: its deadline and where the answer goes.
    waiter: Option<(
        Instant,
        Duration,
        oneshot::Sender<Result<Frame, CameraError>>,
    )>,
}

impl Worker {
    fn open(cfg: &AravisConfig) -> Result<(Worker, CameraInfo), CameraError> {
        let camera =
            aravis::Camera::new(cfg.device.as_deref()).map_err(|e| CameraError::Disconnected {
                camera: cfg.index,
                why: format!(
                    "opening {:?}: {e}",
                    cfg.device.as_deref().unwrap_or("first camera")
                ),
            })?;
        let formats = camera
            .dup_available_pixel_formats_as_strings()
            .map_err(driver)?;
        let has = |f: &str| formats.iter().any(|g| g.as_str() == f);
        let format = if has("RGB8") || has("RGB8Packed") {
            let name = if has("RGB8") { "RGB8" } else { "RGB8Packed" };
            camera.set_pixel_format_from_string(name).map_err(driver)?;
            PixelFormat::Rgb8
        } else if has("Mono8") {
            camera
                .set_pixel_format_from_string("Mono8")
                .map_err(driver)?;
            PixelFormat::Mono8
        } else {
            return Err(CameraError::Unsupported {
                camera: cfg.index,
                what: format!("no 8-bit pixel format among {formats:?}"),
            });
        };
        camera
            .set_acquisition_mode(aravis::AcquisitionMode::Continuous)
            .map_err(driver)?;
        camera
            .set_trigger(&cfg.trigger_source)
            .map_err(|e| CameraError::Unsupported {
                camera: cfg.index,
                what: format!("trigger source {}: {e}", cfg.trigger_source),
            })?;
        let (w, h) = camera.sensor_size().map_err(driver)?;
        let info = CameraInfo {
            index: cfg.index,
            vendor: camera.vendor_name().map_err(driver)?.to_string(),
            model: camera.model_name().map_err(driver)?.to_string(),
            serial: camera
                .device_serial_number()
                .map(|s| s.to_string())
                .unwrap_or_default(),
            width: w as u32,
            height: h as u32,
        };
        let stream = camera.create_stream().map_err(driver)?;
        let worker = Worker {
            index: cfg.index,
            camera,
            stream: Some(stream),
            format,
            buffers: cfg.buffers.max(1),
            settings: None,
            tags: VecDeque::new(),
            counter: 0,
            software: cfg.trigger_source.eq_ignore_ascii_case("software"),
            queued: VecDeque::new(),
            in_flight: None,
            lost_frame: false,
            ready: VecDeque::new(),
            waiter: None,
        };
        worker.refill(worker.buffers)?;
        worker.camera.start_acquisition().map_err(driver)?;
        Ok((worker, info))
    }

    fn stream(&self) -> &aravis::Stream {
        self.stream
            .as_ref()
            .expect("a stream exists outside configure")
    }

    /// Gives the stream `n` buffers of the current payload size.
    fn refill(&self, n: usize) -> Result<(), CameraError> {
        let payload = self.camera.payload().map_err(driver)? as usize;
        for _ in 0..n {
            self.stream()
                .push_buffer(aravis::Buffer::new_allocate(payload));
        }
        Ok(())
    }

    /// Serves requests; while a frame is awaited (asked for, or a software
    /// trigger in flight) it polls the stream between requests.
    fn serve(mut self, rx: mpsc::Receiver<Request>) {
        loop {
            self.fire_next();
            let busy = self.waiter.is_some() || self.in_flight.is_some();
            if busy {
                self.poll_stream(POLL);
                loop {
                    match rx.try_recv() {
                        Ok(req) => self.handle(req),
                        Err(mpsc::TryRecvError::Empty) => break,
                        Err(mpsc::TryRecvError::Disconnected) => return self.stop(),
                    }
                }
            } else {
                match rx.recv() {
                    Ok(req) => self.handle(req),
                    Err(_) => return self.stop(),
                }
            }
            self.answer_waiter();
        }
    }

    fn stop(self) {
        let _ = self.camera.stop_acquisition();
    }

    fn handle(&mut self, req: Request) {
        match req {
            Request::Configure(s, t) => {
                let _ = t.send(self.configure(s));
            }
            Request::Arm(tags, t) => {
                self.forget();
                self.tags = tags.into();
                let _ = t.send(Ok(()));
            }
            Request::Next(timeout, t) => {
                if self.ready.is_empty() && self.tags.is_empty() {
                    let _ = t.send(Err(CameraError::NotArmed(self.index)));
                } else {
                    self.waiter = Some((Instant::now() + timeout, timeout, t));
                }
            }
            Request::Disarm(t) => {
                self.forget();
                let _ = t.send(Ok(()));
            }
            Request::Fire(at_us, t) => {
                let r = if self.software {
                    self.queued.push_back(at_us);
                    Ok(())
                } else {
                    Err(CameraError::Unsupported {
                        camera: self.index,
                        what: "a software trigger: the trigger source is a hardware line".into(),
                    })
                };
                if let Some(t) = t {
                    let _ = t.send(r);
                }
            }
        }
    }

    /// Drops the arming: tags, queued triggers, frames not taken. A trigger
    /// in flight is waited for, so its frame cannot pass for the next arming's.
    fn forget(&mut self) {
        self.tags.clear();
        self.queued.clear();
        if self.in_flight.is_some() {
            let until = Instant::now() + self.trigger_wait();
            while self.in_flight.is_some() && Instant::now() < until {
                self.poll_stream(POLL);
            }
            self.in_flight = None;
        }
        self.ready.clear();
        self.drain();
        if std::mem::take(&mut self.lost_frame) {
            // Best effort: if this fails, the retake reports the camera.
            let _ = self.restart_stream(|_| Ok(()));
        }
    }

    /// Stops acquisition, applies `change` (e.g. binning, which changes
    /// the payload), and starts again on a new stream with fresh buffers.
    fn restart_stream(
        &mut self,
        change: impl FnOnce(&aravis::Camera) -> Result<(), CameraError>,
    ) -> Result<(), CameraError> {
        self.camera.stop_acquisition().map_err(driver)?;
        change(&self.camera)?;
        // Finalising a GigE stream resets the camera's stream channel:
        // drop the old one before the new one is set up.
        self.stream = None;
        self.stream = Some(self.camera.create_stream().map_err(driver)?);
        self.refill(self.buffers)?;
        self.camera.start_acquisition().map_err(driver)
    }

    /// How long a software trigger's frame may take.
    fn trigger_wait(&self) -> Duration {
        let exposure = self.settings.map_or(0.0, |s| s.exposure_s);
        Duration::from_secs_f64(exposure.clamp(0.0, 3600.0)) + TRIGGER_GRACE
    }

    /// Fires the next queued software trigger once the previous frame is in.
    fn fire_next(&mut self) {
        if let Some((_, fired)) = self.in_flight
            && fired.elapsed() > self.trigger_wait()
        {
            // Lost: its tag goes with it, so later frames keep theirs.
            self.in_flight = None;
            self.lost_frame = true;
            if self.tags.pop_front().is_some() {
                self.ready.push_back(Err(CameraError::BadFrame(format!(
                    "camera {}: no frame came for a software trigger within {:?}",
                    self.index,
                    self.trigger_wait()
                ))));
            }
        }
        if self.in_flight.is_some() {
            return;
        }
        let Some(at_us) = self.queued.pop_front() else {
            return;
        };
        match self.camera.software_trigger() {
            Ok(()) => self.in_flight = Some((at_us, Instant::now())),
            Err(e) => {
                if self.tags.pop_front().is_some() {
                    self.ready.push_back(Err(driver(e)));
                }
            }
        }
    }

    /// Answers a waiting `next_frame` with the next frame, or its timeout.
    fn answer_waiter(&mut self) {
        let Some((deadline, timeout, _)) = &self.waiter else {
            return;
        };
        let answer = if let Some(r) = self.ready.pop_front() {
            r
        } else if Instant::now() >= *deadline {
            Err(CameraError::Timeout {
                camera: self.index,
                timeout: *timeout,
            })
        } else {
            return;
        };
        if let Some((_, _, t)) = self.waiter.take() {
            let _ = t.send(answer);
        }
    }

    /// Returns finished buffers to the pool without using them.
    fn drain(&self) {
        while let Some(b) = self.stream().try_pop_buffer() {
            self.stream().push_buffer(b);
        }
    }

    /// Takes one finished buffer, if one comes within `wait`, as the frame
    /// of the next tag (dropped when nothing is armed).
    fn poll_stream(&mut self, wait: Duration) {
        let camera = self.index;
        let Some(buf) = self
            .stream()
            .timeout_pop_buffer(wait.as_micros().min(u64::MAX as u128) as u64)
        else {
            return;
        };
        let fired = self.in_flight.take();
        let status = buf.status();
        let (w, h) = (buf.image_width() as u32, buf.image_height() as u32);
        let data = buf.image_data();
        let timestamp_ns = buf.timestamp();
        self.stream().push_buffer(buf);
        let (Some(settings), Some(tag)) = (self.settings, self.tags.front().copied()) else {
            return;
        };
        if status != aravis::BufferStatus::Success {
            self.ready.push_back(Err(CameraError::BadFrame(format!(
                "camera {camera}: buffer status {status:?}"
            ))));
            return;
        }
        let expect = w as usize * h as usize * self.format.channels();
        if data.len() < expect {
            self.ready.push_back(Err(CameraError::BadFrame(format!(
                "camera {camera}: {} bytes for {w}x{h}",
                data.len()
            ))));
            return;
        }
        self.tags.pop_front();
        self.counter += 1;
        // A software frame's trigger time is the MCU's, as for a wired camera.
        let trigger_us = match fired {
            Some((Some(at_us), _)) => at_us,
            _ => timestamp_ns / 1000,
        };
        self.ready.push_back(Ok(Frame {
            meta: FrameMeta {
                camera,
                tag,
                trigger_us,
                exposure_s: settings.exposure_s,
                gain_db: settings.gain_db,
                frame_counter: self.counter,
            },
            width: w,
            height: h,
            format: self.format,
            data: data[..expect].to_vec(),
        }));
    }

    fn configure(&mut self, s: CameraSettings) -> Result<(), CameraError> {
        let unsupported = |what: String| CameraError::Unsupported {
            camera: self.index,
            what,
        };
        let (lo, hi) = self.camera.exposure_time_bounds().map_err(driver)?;
        let us = s.exposure_s * 1e6;
        if !(lo..=hi).contains(&us) {
            return Err(unsupported(format!(
                "exposure {us} us outside {lo}..={hi} us"
            )));
        }
        self.camera.set_exposure_time(us).map_err(driver)?;
        if self.camera.is_gain_available().unwrap_or(false) {
            self.camera.set_gain(s.gain_db).map_err(driver)?;
        } else if s.gain_db != 0.0 {
            return Err(unsupported("gain control".into()));
        }
        let current = self.camera.binning().unwrap_or((1, 1));
        if current != (s.binning as i32, s.binning as i32) {
            if self.camera.is_binning_available().unwrap_or(false) {
                // Binning changes the payload: restart the stream with new buffers.
                let b = s.binning as i32;
                self.restart_stream(|camera| camera.set_binning(b, b).map_err(driver))?;
            } else if s.binning != 1 {
                return Err(unsupported(format!("binning {}", s.binning)));
            }
        }
        self.settings = Some(s);
        Ok(())
    }
}
