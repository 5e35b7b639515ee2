//! `qhm rig ...`: talk to the rig's MCU by hand, over a serial device
//! (`--port`, also the path `qhm sim --pty` prints) or a built-in emulated
//! rig (`--sim`). Angles in degrees here; radians inside.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use protocol::{Axis, LaserColour, Status, Sweep};
use qhm_link::{DEFAULT_BAUD, Link, LinkConfig};

#[derive(Args, Debug)]
pub struct RigArgs {
    #[command(flatten)]
    pub conn: Connection,
    #[command(subcommand)]
    pub action: RigAction,
}

/// Where the rig is.
#[derive(Args, Debug, Clone)]
pub struct Connection {
    /// Serial device of the MCU (e.g. /dev/ttyACM0, or the path `qhm sim --pty` printed).
    #[arg(long, global = true, conflicts_with = "sim")]
    pub port: Option<PathBuf>,
    /// Baud rate of the serial device (50 to 12000000).
    #[arg(long, global = true, default_value_t = DEFAULT_BAUD, value_parser = parse_baud)]
    pub baud: u32,
    /// Use the built-in emulated rig (in process) instead of a serial device.
    #[arg(long, global = true)]
    pub sim: bool,
    /// Emulated rig only: virtual seconds per wall second.
    #[arg(long, global = true, default_value_t = 1.0)]
    pub sim_speed: f64,
    /// Emulated rig only: seed of its boot ids and start angles.
    #[arg(long, global = true, default_value_t = 1)]
    pub seed: u64,
    /// The rig's clock runs this many times faster than real time (an
    /// emulated rig served with `qhm sim --pty --speed X`): heartbeat and
    /// retransmission timing shrink accordingly.
    #[arg(long, global = true, default_value_t = 1.0)]
    pub time_scale: f64,
    /// Longest wait for a move, homing or sweep to finish, seconds.
    #[arg(long, global = true, default_value_t = 120.0)]
    pub timeout: f64,
}

#[derive(Subcommand, Debug)]
pub enum RigAction {
    /// Handshake and measure the command round trip.
    Ping {
        /// Round trips to time.
        #[arg(long, default_value_t = 10)]
        count: u32,
    },
    /// Print the MCU's identity and status.
    Status {
        /// Machine-readable JSON (protocol and firmware versions, boot id, status, link counters).
        #[arg(long)]
        json: bool,
    },
    /// Home an axis (or both) against its switch and wait until done.
    Home {
        #[arg(value_enum)]
        axis: AxisArg,
        /// Return once the MCU accepted the command.
        #[arg(long)]
        no_wait: bool,
    },
    /// Move an axis to an angle (degrees from home) and wait until done.
    Move {
        #[arg(value_enum)]
        axis: OneAxis,
        /// Target angle, degrees.
        #[arg(allow_hyphen_values = true)]
        angle: f64,
        /// Move by the angle instead of to it.
        #[arg(long)]
        relative: bool,
        /// Speed limit, deg/s (0 = the axis maximum).
        #[arg(long, default_value_t = 0.0)]
        speed: f64,
        /// Acceleration limit, deg/s^2 (0 = the axis maximum).
        #[arg(long, default_value_t = 0.0)]
        accel: f64,
        #[arg(long)]
        no_wait: bool,
    },
    /// Set the galvo mirror, or run a sweep.
    Galvo {
        #[command(subcommand)]
        action: GalvoAction,
    },
    /// Select a laser and its power; `--on S` emits for S seconds (the host
    /// keeps the heartbeat alive meanwhile), `off` disarms.
    Laser {
        #[arg(value_enum)]
        colour: LaserArg,
        /// Drive level, per mille of full power.
        #[arg(long, default_value_t = 100)]
        power: u16,
        /// Arm for this many seconds, then disarm.
        #[arg(long)]
        on: Option<f64>,
    },
    /// Switch lamps: a bit mask, bit i = lamp i (decimal, 0x.., 0b.., all, none).
    Lamps { mask: String },
    /// Pulse camera trigger lines (mask as for lamps).
    Trigger {
        mask: String,
        /// Pulse width, microseconds.
        #[arg(long, default_value_t = 1000)]
        pulse_us: u32,
    },
    /// Emergency stop: everything off and stopped at once; latches a fault.
    Estop,
    /// Clear a latched fault.
    Clear,
}

#[derive(Subcommand, Debug)]
pub enum GalvoAction {
    /// Set the mirror angle, degrees.
    Set {
        #[arg(allow_hyphen_values = true)]
        angle: f64,
    },
    /// Sweep the stripe and wait until done.
    Sweep {
        /// First angle, degrees.
        #[arg(long, allow_hyphen_values = true)]
        from: f64,
        /// Last angle, degrees.
        #[arg(long, allow_hyphen_values = true)]
        to: f64,
        #[arg(long)]
        steps: u16,
        /// Dwell per step, milliseconds.
        #[arg(long, default_value_t = 10.0)]
        dwell_ms: f64,
        /// Cameras to trigger at each step (mask as for lamps).
        #[arg(long, default_value = "0")]
        trigger: String,
        #[arg(long, default_value_t = 1000)]
        pulse_us: u32,
    },
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum AxisArg {
    Turntable,
    Arc,
    Both,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum OneAxis {
    Turntable,
    Arc,
}

impl From<OneAxis> for Axis {
    fn from(a: OneAxis) -> Axis {
        match a {
            OneAxis::Turntable => Axis::Turntable,
            OneAxis::Arc => Axis::LightArc,
        }
    }
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum LaserArg {
    Red,
    Green,
    Blue,
    Off,
}

fn parse_baud(s: &str) -> Result<u32, String> {
    let baud: u32 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a baud rate: give a whole number of bits/s"))?;
    qhm_link::check_baud(baud)
}

/// Parse a line mask: decimal, 0x.., 0b.., `all` or `none`.
pub fn parse_mask(s: &str) -> Result<u8> {
    let s = s.trim();
    let v = match s {
        "all" => Ok(0xff),
        "none" => Ok(0),
        _ => {
            if let Some(h) = s.strip_prefix("0x") {
                u8::from_str_radix(h, 16)
            } else if let Some(b) = s.strip_prefix("0b") {
                u8::from_str_radix(b, 2)
            } else {
                s.parse()
            }
        }
    };
    v.ok().with_context(|| {
        format!("bad mask {s:?}: give 0-255, 0x.., 0b.., all or none (bit i = line i)")
    })
}

pub fn run(args: RigArgs) -> Result<ExitCode> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    // Bad arguments fail before any port is opened.
    match &args.action {
        RigAction::Lamps { mask } | RigAction::Trigger { mask, .. } => {
            parse_mask(mask)?;
        }
        RigAction::Galvo {
            action: GalvoAction::Sweep { trigger, .. },
        } => {
            parse_mask(trigger)?;
        }
        _ => {}
    }
    rt.block_on(async move {
        let (link, _sim) = connect(&args.conn).await?;
        let connected = (Instant::now(), link.last_status().map(|s| s.uptime_us));
        let timeout = Duration::from_secs_f64(args.conn.timeout.max(0.0));
        let r = act(&link, args.action, timeout).await;
        let r = match r {
            Err(e) if args.conn.port.is_some() => {
                match clock_hint(&link, connected, args.conn.time_scale).await {
                    Some(hint) => Err(anyhow::anyhow!("{e:#}; {hint}")),
                    None => Err(e),
                }
            }
            r => r,
        };
        link.close();
        r
    })
}

/// After a failure on a serial rig: if the MCU's clock runs at another rate
/// than `--time-scale` says (an emulated rig served with `--speed`), the
/// heartbeat was too slow for it; say what to pass.
async fn clock_hint(
    link: &Link,
    (t0, uptime0): (Instant, Option<u64>),
    time_scale: f64,
) -> Option<String> {
    let uptime0 = uptime0?;
    // A rate needs some wall time to be measured against.
    let wait = Duration::from_millis(300).saturating_sub(t0.elapsed());
    tokio::time::sleep(wait).await;
    let status = tokio::time::timeout(Duration::from_secs(2), link.status())
        .await
        .ok()?
        .ok()?;
    if status.uptime_us < uptime0 {
        return None; // rebooted meanwhile
    }
    let rate = (status.uptime_us - uptime0) as f64 * 1e-6 / t0.elapsed().as_secs_f64();
    let ratio = rate / time_scale;
    (!(0.67..=1.5).contains(&ratio)).then(|| {
        format!(
            "the rig's clock runs {rate:.1} times as fast as real time but --time-scale is {time_scale}, \
             so the heartbeat is too slow for it: pass --time-scale {:.0} (the --speed of `qhm sim --pty`)",
            rate.round().max(1.0)
        )
    })
}

/// The emulated rig stays alive as long as this guard.
pub struct SimGuard(#[allow(dead_code)] Option<sim::RigHandle>);

/// Open the link the flags describe.
pub async fn connect(conn: &Connection) -> Result<(Link, SimGuard)> {
    if !(conn.time_scale.is_finite() && conn.time_scale > 0.0) {
        bail!("--time-scale {} must be a positive number", conn.time_scale);
    }
    if !(conn.timeout.is_finite() && conn.timeout > 0.0) {
        bail!(
            "--timeout {} must be a positive number of seconds",
            conn.timeout
        );
    }
    if conn.sim {
        let mut cfg = sim::SimConfig::seeded(conn.seed);
        cfg.speed = conn.sim_speed;
        let (stream, handle) =
            sim::spawn_in_process(&cfg).context("cannot start the emulated rig")?;
        let link = Link::open_stream(Box::new(stream), LinkConfig::scaled(conn.sim_speed))
            .await
            .context("handshake with the emulated rig failed")?;
        return Ok((link, SimGuard(Some(handle))));
    }
    let Some(port) = &conn.port else {
        bail!("say where the rig is: --port PATH (serial device) or --sim (built-in emulated rig)");
    };
    let path = port.to_string_lossy();
    // A dead port fails within the silence bound (3 s), a damaged line is
    // retried; timeouts cover a full-size frame each way at the baud rate.
    let config = LinkConfig::for_line(conn.baud, conn.time_scale);
    let link = Link::open_serial(&path, conn.baud, config)
        .await
        .with_context(|| format!("rig on {path}"))?;
    Ok((link, SimGuard(None)))
}

async fn bounded<T>(
    timeout: Duration,
    what: &str,
    f: impl Future<Output = Result<T, qhm_link::LinkError>>,
) -> Result<T> {
    match tokio::time::timeout(timeout, f).await {
        Ok(r) => Ok(r?),
        Err(_) => bail!(
            "{what} did not finish within {} s (see --timeout)",
            timeout.as_secs_f64()
        ),
    }
}

async fn act(link: &Link, action: RigAction, timeout: Duration) -> Result<ExitCode> {
    match action {
        RigAction::Ping { count } => {
            let id = link.identity().context("no identity after the handshake")?;
            let mut rtts = Vec::new();
            for _ in 0..count.max(1) {
                let t = Instant::now();
                link.heartbeat().await?;
                rtts.push(t.elapsed().as_secs_f64() * 1e3);
            }
            rtts.sort_by(f64::total_cmp);
            println!(
                "{} firmware {}, protocol {}, boot {:#010x}: round trip median {:.2} ms, max {:.2} ms ({} pings)",
                id.board.as_str(),
                version(&id.firmware_version),
                id.protocol_version,
                id.boot_id,
                rtts[rtts.len() / 2],
                rtts[rtts.len() - 1],
                rtts.len()
            );
        }
        RigAction::Status { json } => {
            let status = link.status().await?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&status_json(link, &status))?
                );
            } else {
                print_status(link, &status);
            }
        }
        RigAction::Home { axis, no_wait } => {
            let axes: &[Axis] = match axis {
                AxisArg::Turntable => &[Axis::Turntable],
                AxisArg::Arc => &[Axis::LightArc],
                AxisArg::Both => &Axis::ALL,
            };
            for &a in axes {
                link.home(a).await?;
            }
            if !no_wait {
                for &a in axes {
                    let done = bounded(timeout, "homing", link.wait_motion_done(a)).await?;
                    if !done.homed {
                        bail!("{} stopped without being homed", axis_name(a));
                    }
                    println!("{} homed", axis_name(a));
                }
            }
        }
        RigAction::Move {
            axis,
            angle,
            relative,
            speed,
            accel,
            no_wait,
        } => {
            let axis = Axis::from(axis);
            link.move_deg(axis, angle, relative, speed, accel).await?;
            if !no_wait {
                bounded(timeout, "the move", link.wait_motion_done(axis)).await?;
                let status = link.status().await?;
                let deg = link
                    .position_rad(&status, axis)
                    .unwrap_or(f64::NAN)
                    .to_degrees();
                println!("{} at {deg:.3} deg", axis_name(axis));
            }
        }
        RigAction::Galvo { action } => match action {
            GalvoAction::Set { angle } => link.galvo_set_rad(angle.to_radians()).await?,
            GalvoAction::Sweep {
                from,
                to,
                steps,
                dwell_ms,
                trigger,
                pulse_us,
            } => {
                let urad = |deg: f64| -> Result<i32> {
                    let u = (deg.to_radians() * 1e6).round();
                    if !u.is_finite() || u.abs() > i32::MAX as f64 {
                        bail!("galvo angle {deg} deg out of range");
                    }
                    Ok(u as i32)
                };
                let dwell_us = (dwell_ms * 1e3).round();
                if !(dwell_us.is_finite() && dwell_us >= 0.0 && dwell_us <= u32::MAX as f64) {
                    bail!("--dwell-ms {dwell_ms} out of range");
                }
                link.galvo_sweep(Sweep {
                    start_urad: urad(from)?,
                    end_urad: urad(to)?,
                    steps,
                    dwell_us: dwell_us as u32,
                    trigger_mask: parse_mask(&trigger)?,
                    pulse_us,
                })
                .await?;
                let completed = bounded(timeout, "the sweep", link.wait_sweep_done()).await?;
                println!("sweep {}", if completed { "completed" } else { "aborted" });
            }
        },
        RigAction::Laser { colour, power, on } => {
            let colour = match colour {
                LaserArg::Off => {
                    link.laser_arm(false).await?;
                    return Ok(ExitCode::SUCCESS);
                }
                LaserArg::Red => LaserColour::Red,
                LaserArg::Green => LaserColour::Green,
                LaserArg::Blue => LaserColour::Blue,
            };
            link.laser_select(colour).await?;
            link.laser_power(power).await?;
            if let Some(secs) = on {
                if !(secs.is_finite() && secs >= 0.0) {
                    bail!("--on {secs}: give seconds >= 0");
                }
                link.laser_arm(true).await?;
                let status = link.status().await?;
                if !status.laser.emitting {
                    link.laser_arm(false).await?;
                    bail!(
                        "laser armed but not emitting (interlock closed: {}, fault: {:?})",
                        status.interlock_closed,
                        status.fault
                    );
                }
                // The heartbeat task keeps the MCU's laser permission alive;
                // a link that dies meanwhile ends the wait at once.
                let mut events = link.subscribe();
                let lost = async {
                    loop {
                        match events.recv().await {
                            Ok(qhm_link::LinkEvent::Disconnected { reason }) => break reason,
                            Err(qhm_link::LinkError::Disconnected { reason }) => break reason,
                            _ => {}
                        }
                    }
                };
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs_f64(secs)) => {}
                    reason = lost => bail!("link to the MCU lost while the laser was on: {reason}"),
                }
                link.laser_arm(false).await?;
            }
        }
        RigAction::Lamps { mask } => link.lamps(parse_mask(&mask)?).await?,
        RigAction::Trigger { mask, pulse_us } => link.trigger(parse_mask(&mask)?, pulse_us).await?,
        RigAction::Estop => link.estop().await?,
        RigAction::Clear => link.clear_fault().await?,
    }
    Ok(ExitCode::SUCCESS)
}

fn axis_name(a: Axis) -> &'static str {
    match a {
        Axis::Turntable => "turntable",
        Axis::LightArc => "light arc",
    }
}

fn version(v: &[u8; 3]) -> String {
    format!("{}.{}.{}", v[0], v[1], v[2])
}

fn status_json(link: &Link, status: &Status) -> serde_json::Value {
    let id = link.identity();
    let deg = |a: Axis| link.position_rad(status, a).map(f64::to_degrees);
    serde_json::json!({
        "protocol_version": id.as_ref().map(|i| i.protocol_version),
        "host_protocol_version": protocol::PROTOCOL_VERSION,
        "schema_hash": id.as_ref().map(|i| format!("{:#010x}", i.schema_hash)),
        "firmware_version": id.as_ref().map(|i| version(&i.firmware_version)),
        "board": id.as_ref().map(|i| i.board.as_str().to_string()),
        "boot_id": status.boot_id,
        "positions_deg": {
            "turntable": deg(Axis::Turntable),
            "light_arc": deg(Axis::LightArc),
        },
        "galvo_deg": (status.galvo_urad as f64 * 1e-6).to_degrees(),
        "status": status,
        "link": link.stats(),
    })
}

fn print_status(link: &Link, s: &Status) {
    if let Some(id) = link.identity() {
        println!(
            "board {}  firmware {}  protocol {}  boot {:#010x}",
            id.board.as_str(),
            version(&id.firmware_version),
            id.protocol_version,
            s.boot_id
        );
    }
    println!("uptime {:.3} s", s.uptime_us as f64 * 1e-6);
    for a in Axis::ALL {
        let st = s.axes[a.index()];
        let deg = link.position_rad(s, a).unwrap_or(f64::NAN).to_degrees();
        let state = if st.homing {
            "homing"
        } else if st.moving {
            "moving"
        } else {
            "idle"
        };
        println!(
            "{:<10} {deg:>9.3} deg  {}  {state}",
            axis_name(a),
            if st.homed { "homed" } else { "not homed" }
        );
    }
    println!(
        "galvo      {:>9.3} deg{}",
        (s.galvo_urad as f64 * 1e-6).to_degrees(),
        s.sweep_step
            .map(|k| format!("  sweep step {k}"))
            .unwrap_or_default()
    );
    println!(
        "laser      {:?} {} permille  {}{}",
        s.laser.selected,
        s.laser.power_permille,
        if s.laser.armed { "armed" } else { "disarmed" },
        if s.laser.emitting { ", EMITTING" } else { "" }
    );
    println!("lamps      {:#010b}", s.lamps);
    println!(
        "interlock  {}  e-stop {}  fault {}",
        if s.interlock_closed { "closed" } else { "OPEN" },
        if s.estop_pressed {
            "PRESSED"
        } else {
            "released"
        },
        s.fault
            .map(|f| qhm_link::fault_name(&f))
            .unwrap_or_else(|| "none".into())
    );
    if s.events_dropped > 0 {
        println!("events dropped by the MCU: {}", s.events_dropped);
    }
}

#[cfg(test)]
mod tests {
    use super::parse_mask;

    #[test]
    fn masks() {
        assert_eq!(parse_mask("0").unwrap(), 0);
        assert_eq!(parse_mask("5").unwrap(), 5);
        assert_eq!(parse_mask("all").unwrap(), 255);
        assert_eq!(parse_mask("0x0f").unwrap(), 15);
        assert_eq!(parse_mask("0b101").unwrap(), 5);
        assert_eq!(parse_mask("255").unwrap(), 255);
        assert!(parse_mask("256").is_err());
        assert!(parse_mask("0x100").is_err());
        assert!(parse_mask("lamp").is_err());
    }
}
