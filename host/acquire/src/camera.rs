//! The camera interface (DESIGN.md: "a camera trait"): configure exposure and
//! gain, arm for hardware triggers, receive frames with metadata.
//!
//! Frames are fired by the rig's trigger lines, not by the host, so arming
//! says how many trigger pulses to expect and hands the camera a tag for each;
//! the tag comes back in the frame's metadata. Capture runs tag frames with
//! their plan position (`Step::frame_tag`), which lets a simulated sensor
//! derive its noise from the plan instead of from time, and lets every
//! backend's frames be matched to the step that asked for them.
//!
//! Backends: GenICam cameras through Aravis (`crate::aravis_camera`, feature
//! `aravis`), and the simulated camera (crate `sim-devices`, outside the host).

use std::future::Future;
use std::pin::Pin;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// A boxed future, so `dyn Camera` works in async code.
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// What the host sets before arming.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraSettings {
    /// Exposure time, s.
    pub exposure_s: f64,
    /// Analogue gain, dB.
    pub gain_db: f64,
    /// Sensor binning (1 = full resolution), same in x and y.
    pub binning: u32,
}

/// What a camera is.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CameraInfo {
    /// Position on the camera arc (0 = lowest), as wired to the trigger lines.
    pub index: u8,
    pub vendor: String,
    pub model: String,
    pub serial: String,
    /// Full-resolution sensor size, pixels.
    pub width: u32,
    pub height: u32,
}

/// Pixel layouts the backends deliver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PixelFormat {
    Mono8,
    Rgb8,
}

impl PixelFormat {
    pub fn channels(self) -> usize {
        match self {
            PixelFormat::Mono8 => 1,
            PixelFormat::Rgb8 => 3,
        }
    }
}

/// Metadata the camera attaches to every frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameMeta {
    pub camera: u8,
    /// The tag given at arming for this trigger.
    pub tag: u64,
    /// When the trigger line rose, on the rig controller's clock, us.
    pub trigger_us: u64,
    pub exposure_s: f64,
    pub gain_db: f64,
    /// Frames this camera delivered since it was opened.
    pub frame_counter: u64,
}

/// One image as the camera gave it (8 bits per channel).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub meta: FrameMeta,
    pub width: u32,
    pub height: u32,
    pub format: PixelFormat,
    /// Rows top to bottom, tightly packed.
    pub data: Vec<u8>,
}

impl Frame {
    /// Encodes the frame as an 8-bit PNG (deterministic for equal pixels).
    pub fn to_png(&self) -> Result<Vec<u8>, CameraError> {
        use image::ImageEncoder;
        let expect = self.width as usize * self.height as usize * self.format.channels();
        if self.data.len() != expect {
            return Err(CameraError::BadFrame(format!(
                "{} bytes for {}x{} {:?}",
                self.data.len(),
                self.width,
                self.height,
                self.format
            )));
        }
        let colour = match self.format {
            PixelFormat::Mono8 => image::ExtendedColorType::L8,
            PixelFormat::Rgb8 => image::ExtendedColorType::Rgb8,
        };
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new(&mut out)
            .write_image(&self.data, self.width, self.height, colour)
            .map_err(|e| CameraError::BadFrame(e.to_string()))?;
        Ok(out)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// No frame arrived within the timeout after arming.
    #[error("camera {camera}: no frame within {timeout:?}")]
    Timeout { camera: u8, timeout: Duration },
    /// `next_frame` was called with no trigger armed.
    #[error("camera {0}: not armed")]
    NotArmed(u8),
    /// A setting is outside what the camera supports.
    #[error("camera {camera}: {what}")]
    Unsupported { camera: u8, what: String },
    /// The frame's buffer does not match its size and format.
    #[error("bad frame: {0}")]
    BadFrame(String),
    /// The camera (or the world behind a simulated one) went away.
    #[error("camera {camera} disconnected: {why}")]
    Disconnected { camera: u8, why: String },
    /// An error reported by the camera driver.
    #[error("camera driver: {0}")]
    Driver(String),
}

/// A camera fired by a hardware trigger line.
pub trait Camera: Send {
    fn info(&self) -> CameraInfo;
    /// Sets exposure, gain and binning for the frames armed next.
    fn configure(&mut self, settings: CameraSettings) -> BoxFuture<'_, Result<(), CameraError>>;
    /// Arms for `tags.len()` trigger pulses; frame i carries `tags[i]`.
    /// Replaces any previous arming and drops frames not yet taken.
    fn arm(&mut self, tags: Vec<u64>) -> BoxFuture<'_, Result<(), CameraError>>;
    /// The next frame of the current arming, in trigger order.
    fn next_frame(&mut self, timeout: Duration) -> BoxFuture<'_, Result<Frame, CameraError>>;
    /// Forgets the current arming (after an aborted sweep or an MCU reset).
    fn disarm(&mut self) -> BoxFuture<'_, Result<(), CameraError>>;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(w: u32, h: u32, format: PixelFormat, len: usize) -> Frame {
        Frame {
            meta: FrameMeta {
                camera: 3,
                tag: 7,
                trigger_us: 0,
                exposure_s: 0.01,
                gain_db: 0.0,
                frame_counter: 0,
            },
            width: w,
            height: h,
            format,
            data: (0..len).map(|i| (i * 37 % 251) as u8).collect(),
        }
    }

    #[test]
    fn png_round_trips_pixels() {
        let f = frame(5, 4, PixelFormat::Rgb8, 60);
        let png = f.to_png().unwrap();
        assert_eq!(png, f.to_png().unwrap(), "encoding is deterministic");
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (5, 4));
        assert_eq!(img.into_raw(), f.data);
    }

    #[test]
    fn wrong_buffer_size_is_an_error() {
        assert!(matches!(
            frame(5, 4, PixelFormat::Rgb8, 59).to_png(),
            Err(CameraError::BadFrame(_))
        ));
        assert!(frame(5, 4, PixelFormat::Mono8, 20).to_png().is_ok());
    }
}
