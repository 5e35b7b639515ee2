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
pub mod soft_trigger;

/// The link client the runs use, re-exported so callers need no second dependency.
pub use qhm_link;

pub use camera::{
    BoxFuture, Camera, CameraError, CameraInfo, CameraSettings, Frame, FrameMeta, PixelFormat,
};
pub use dir::{CaptureDir, DirError, Manifest};
pub use operator::{ConsoleOperator, Operator, OperatorError};
pub use plan::{Pass, Plan, PlanConfig, PlanError, Scale};
pub use run::{NoProgress, Progress, RunError, RunOptions, RunReport, run_capture, safe_off};

/// How a real camera is fired.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CameraTrigger {
    /// A GenICam hardware line wired to the MCU's trigger output (`Line1`).
    Line(String),
    /// No wire: the host fires a software trigger on the MCU's trigger-fired event.
    Software,
}

/// One `--camera` value: `N=DEVICE[,trigger=software|LineK]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraSpec {
    /// Arc position (which of the MCU's trigger lines it belongs to).
    pub index: u8,
    /// GenICam device ID, serial or IP address.
    pub device: String,
    pub trigger: CameraTrigger,
}

impl std::str::FromStr for CameraSpec {
    type Err = CameraError;
    fn from_str(spec: &str) -> Result<CameraSpec, CameraError> {
        let bad = |why: &str| CameraError::Unsupported {
            camera: 0,
            what: format!(
                "camera spec {spec:?}: {why} (expected N=DEVICE[,trigger=software|LineK], N in 0..8)"
            ),
        };
        let (n, rest) = spec.split_once('=').ok_or_else(|| bad("no `=`"))?;
        let index: u8 = n.trim().parse().map_err(|_| bad("N is not a number"))?;
        if index >= 8 {
            return Err(bad("N is not in 0..8"));
        }
        let mut parts = rest.split(',');
        let device = parts.next().unwrap_or("").trim().to_string();
        if device.is_empty() {
            return Err(bad("no DEVICE"));
        }
        let mut trigger = CameraTrigger::Line("Line1".into());
        for opt in parts {
            match opt.trim().split_once('=') {
                Some(("trigger", v)) if v.trim().eq_ignore_ascii_case("software") => {
                    trigger = CameraTrigger::Software;
                }
                Some(("trigger", v))
                    if v.trim().len() > 4
                        && v.trim()[..4].eq_ignore_ascii_case("line")
                        && v.trim()[4..].chars().all(|c| c.is_ascii_digit()) =>
                {
                    trigger = CameraTrigger::Line(format!("Line{}", &v.trim()[4..]));
                }
                Some(("trigger", v)) => {
                    return Err(bad(&format!(
                        "unknown trigger {v:?}, expected software or LineK"
                    )));
                }
                _ => return Err(bad(&format!("unknown option {opt:?}"))),
            }
        }
        Ok(CameraSpec {
            index,
            device,
            trigger,
        })
    }
}

/// Real cameras as opened: the cameras, and the software triggers the MCU's
/// trigger-fired events must fire ([`soft_trigger::relay_triggers`]).
pub struct GenicamCameras {
    pub cameras: Vec<Box<dyn Camera>>,
    pub software_triggers: Vec<(u8, Box<dyn soft_trigger::SoftwareTrigger>)>,
}

/// Opens real cameras from `--camera` specs ([`CameraSpec`]). Needs the
/// `aravis` feature; without it, says so.
pub fn open_genicam_cameras(specs: &[String]) -> Result<GenicamCameras, CameraError> {
    let parsed = specs
        .iter()
        .map(|s| s.parse())
        .collect::<Result<Vec<CameraSpec>, _>>()?;
    open_parsed(parsed)
}

#[cfg(feature = "aravis")]
fn open_parsed(parsed: Vec<CameraSpec>) -> Result<GenicamCameras, CameraError> {
    use aravis_camera::{AravisCamera, AravisConfig};
    let mut out = GenicamCameras {
        cameras: Vec::new(),
        software_triggers: Vec::new(),
    };
    for spec in parsed {
        let mut cfg = AravisConfig::new(spec.index, Some(spec.device));
        if let CameraTrigger::Line(l) = &spec.trigger {
            cfg.trigger_source = l.clone();
        } else {
            cfg.trigger_source = "Software".into();
        }
        let cam = AravisCamera::open(cfg)?;
        if spec.trigger == CameraTrigger::Software {
            out.software_triggers
                .push((spec.index, Box::new(cam.trigger_handle())));
        }
        out.cameras.push(Box::new(cam));
    }
    Ok(out)
}

#[cfg(not(feature = "aravis"))]
fn open_parsed(_parsed: Vec<CameraSpec>) -> Result<GenicamCameras, CameraError> {
    Err(CameraError::Unsupported {
        camera: 0,
        what: "real cameras need qhm built with the `aravis` feature \
               (cargo build --release -p host --features aravis)"
            .into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_specs_parse() {
        let s: CameraSpec = "3=127.0.0.2,trigger=software".parse().unwrap();
        assert_eq!(
            s,
            CameraSpec {
                index: 3,
                device: "127.0.0.2".into(),
                trigger: CameraTrigger::Software
            }
        );
        let s: CameraSpec = "7=Aravis-GV07".parse().unwrap();
        assert_eq!(s.trigger, CameraTrigger::Line("Line1".into()));
        let s: CameraSpec = "0=cam,trigger=line2".parse().unwrap();
        assert_eq!(s.trigger, CameraTrigger::Line("Line2".into()));
        for bad in [
            "3",
            "8=cam",
            "x=cam",
            "3=",
            "3=cam,trigger=sometimes",
            "3=cam,speed=2",
            "3=cam,trigger=line",
        ] {
            let e = bad.parse::<CameraSpec>().unwrap_err().to_string();
            assert!(e.contains(bad) && !e.contains('\n'), "{bad}: {e}");
        }
    }
}
