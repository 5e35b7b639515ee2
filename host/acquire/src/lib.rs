//! Acquisition: the camera interface and its backends, the capture plan (paper
//! Fig. 4, Table 1), and capture runs into a crash-safe capture directory.
//! Whether the rig is real or simulated is not known here: the simulated
//! rig (crate `sim-devices`) implements [`Camera`] and [`Operator`] from outside.
//!
//! Main types: [`Camera`] (a trigger-fired camera), [`Plan`] (ordered steps of
//! the three passes), [`CaptureDir`] (capture.toml, journal, frames),
//! [`run_capture`] (executes the rest of a directory's plan through a
//! [`qhm_link::Link`] and cameras), [`Operator`] (the person at the rig).

#[cfg(feature = "aravis")]
pub mod aravis_camera;
pub mod cal_plan;
pub mod camera;
pub mod dir;
pub mod operator;
pub mod plan;
pub mod run;

/// The link client the runs use, re-exported so callers need no second dependency.
pub use qhm_link;

pub use camera::{
    BoxFuture, Camera, CameraError, CameraInfo, CameraSettings, Frame, FrameMeta, PixelFormat,
};
pub use dir::{CaptureDir, DirError, Manifest};
pub use operator::{ConsoleOperator, Operator, OperatorError};
pub use plan::{Plan, PlanConfig, PlanError, Scale};
pub use run::{NoProgress, Progress, RunError, RunOptions, RunReport, run_capture, safe_off};

/// Opens real cameras from `N=DEVICE` specs (arc position N, GenICam device
/// ID, serial or IP address), triggered by hardware line `Line1`. Needs the
/// `aravis` feature; without it, says so.
pub fn open_genicam_cameras(specs: &[String]) -> Result<Vec<Box<dyn Camera>>, CameraError> {
    let mut parsed = Vec::new();
    for spec in specs {
        let bad = || CameraError::Unsupported {
            camera: 0,
            what: format!("camera spec {spec:?} (expected N=DEVICE, N in 0..8)"),
        };
        let (n, dev) = spec.split_once('=').ok_or_else(bad)?;
        let n: u8 = n.trim().parse().map_err(|_| bad())?;
        if n >= 8 || dev.trim().is_empty() {
            return Err(bad());
        }
        parsed.push((n, dev.trim().to_string()));
    }
    open_parsed(parsed)
}

#[cfg(feature = "aravis")]
fn open_parsed(parsed: Vec<(u8, String)>) -> Result<Vec<Box<dyn Camera>>, CameraError> {
    parsed
        .into_iter()
        .map(|(n, dev)| {
            aravis_camera::AravisCamera::open(aravis_camera::AravisConfig::new(n, Some(dev)))
                .map(|c| Box::new(c) as Box<dyn Camera>)
        })
        .collect()
}

#[cfg(not(feature = "aravis"))]
fn open_parsed(_parsed: Vec<(u8, String)>) -> Result<Vec<Box<dyn Camera>>, CameraError> {
    Err(CameraError::Unsupported {
        camera: 0,
        what: "real cameras need qhm-acquire built with the `aravis` feature \
               (cargo build --features qhm-acquire/aravis)"
            .into(),
    })
}
