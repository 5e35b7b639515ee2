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
//! `Software` (the fake camera, tests) where [`AravisCamera::software_trigger`]
//! fires a frame.

use std::collections::VecDeque;
use std::sync::mpsc;
use std::time::Duration;

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
    SoftwareTrigger(oneshot::Sender<Result<(), CameraError>>),
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

    /// Fires one frame (trigger source `Software` only).
    pub fn software_trigger(&mut self) -> BoxFuture<'static, Result<(), CameraError>> {
        self.request(Request::SoftwareTrigger)
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

struct Worker {
    index: u8,
    camera: aravis::Camera,
    stream: Option<aravis::Stream>,
    format: PixelFormat,
    buffers: usize,
    settings: Option<CameraSettings>,
    tags: VecDeque<u64>,
    counter: u64,
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
        camera.set_trigger(&cfg.trigger_source).map_err(driver)?;
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

    fn serve(mut self, rx: mpsc::Receiver<Request>) {
        while let Ok(req) = rx.recv() {
            match req {
                Request::Configure(s, t) => {
                    let _ = t.send(self.configure(s));
                }
                Request::Arm(tags, t) => {
                    self.drain();
                    self.tags = tags.into();
                    let _ = t.send(Ok(()));
                }
                Request::Next(timeout, t) => {
                    let _ = t.send(self.next(timeout));
                }
                Request::Disarm(t) => {
                    self.tags.clear();
                    self.drain();
                    let _ = t.send(Ok(()));
                }
                Request::SoftwareTrigger(t) => {
                    let _ = t.send(self.camera.software_trigger().map_err(driver));
                }
            }
        }
        let _ = self.camera.stop_acquisition();
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
                self.camera.stop_acquisition().map_err(driver)?;
                self.camera
                    .set_binning(s.binning as i32, s.binning as i32)
                    .map_err(driver)?;
                // Finalising a GigE stream resets the camera's stream channel:
                // drop the old one before the new one is set up.
                self.stream = None;
                self.stream = Some(self.camera.create_stream().map_err(driver)?);
                self.refill(self.buffers)?;
                self.camera.start_acquisition().map_err(driver)?;
            } else if s.binning != 1 {
                return Err(unsupported(format!("binning {}", s.binning)));
            }
        }
        self.settings = Some(s);
        Ok(())
    }

    /// Returns finished buffers to the pool without using them.
    fn drain(&self) {
        while let Some(b) = self.stream().try_pop_buffer() {
            self.stream().push_buffer(b);
        }
    }

    fn next(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let camera = self.index;
        let Some(&tag) = self.tags.front() else {
            return Err(CameraError::NotArmed(camera));
        };
        let settings = self.settings.ok_or(CameraError::NotArmed(camera))?;
        let buf = self
            .stream()
            .timeout_pop_buffer(timeout.as_micros().min(u64::MAX as u128) as u64)
            .ok_or(CameraError::Timeout { camera, timeout })?;
        let status = buf.status();
        let (w, h) = (buf.image_width() as u32, buf.image_height() as u32);
        let data = buf.image_data();
        let timestamp_ns = buf.timestamp();
        self.stream().push_buffer(buf);
        if status != aravis::BufferStatus::Success {
            return Err(CameraError::BadFrame(format!(
                "camera {camera}: buffer status {status:?}"
            )));
        }
        let expect = w as usize * h as usize * self.format.channels();
        if data.len() < expect {
            return Err(CameraError::BadFrame(format!(
                "camera {camera}: {} bytes for {w}x{h}",
                data.len()
            )));
        }
        self.tags.pop_front();
        self.counter += 1;
        Ok(Frame {
            meta: FrameMeta {
                camera,
                tag,
                trigger_us: timestamp_ns / 1000,
                exposure_s: settings.exposure_s,
                gain_db: settings.gain_db,
                frame_counter: self.counter,
            },
            width: w,
            height: h,
            format: self.format,
            data: data[..expect].to_vec(),
        })
    }
}
