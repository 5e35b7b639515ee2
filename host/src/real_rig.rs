//! The real rig as `qhm capture run` and `qhm calibrate` open it: the MCU on
//! a serial device and the GenICam cameras named on the command line. Cameras
//! given `,trigger=software` are fired on the MCU's trigger-fired events.

use std::path::Path;

use anyhow::{Context, Result};
use qhm_acquire::Camera;
use qhm_acquire::qhm_link::{Link, LinkConfig};

/// Open the cameras (`--camera N=DEVICE[,trigger=software]`), then the link
/// to the MCU on `port`, and relay its trigger events to the software-triggered cameras.
pub async fn open(
    port: Option<&Path>,
    baud: u32,
    cameras: &[String],
) -> Result<(Link, Vec<Box<dyn Camera>>)> {
    let port = port.context("--port is required without --sim")?;
    let opened = qhm_acquire::open_genicam_cameras(cameras)
        .context("opening the cameras (give --camera N=DEVICE for each camera the plan uses)")?;
    let link = Link::open_serial(&port.to_string_lossy(), baud, LinkConfig::default())
        .await
        .with_context(|| format!("opening the rig on {}", port.display()))?;
    qhm_acquire::soft_trigger::relay_triggers(&link, opened.software_triggers);
    Ok((link, opened.cameras))
}
