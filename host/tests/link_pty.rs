//! End to end across two processes: `qhm sim --pty` serves an emulated rig
//! on a pseudo-terminal, and separate `qhm rig --port <path> ...` processes
//! drive it as they would a real rig on a USB serial port.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Output, Stdio};

const QHM: &str = env!("CARGO_BIN_EXE_qhm");
const SPEED: &str = "5";

/// The server process; killed on drop so a failing test leaves nothing behind.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn rig(port: &str, args: &[&str]) -> Output {
    Command::new(QHM)
        .args([
            "rig",
            "--port",
            port,
            "--time-scale",
            SPEED,
            "--timeout",
            "60",
        ])
        .args(args)
        .output()
        .expect("run qhm rig")
}

fn ok(out: Output) -> String {
    assert!(
        out.status.success(),
        "qhm failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn qhm_rig_drives_qhm_sim_pty_in_another_process() {
    let mut child = Command::new(QHM)
        .args(["sim", "--pty", "--speed", SPEED, "--seed", "5"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start qhm sim --pty");
    let stdout = child.stdout.take().unwrap();
    let server = Server(child);
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line).unwrap();
    let port = line.trim().to_string();
    assert!(port.starts_with("/dev/"), "pty path, got {port:?}");

    let json = ok(rig(&port, &["status", "--json"]));
    let v: serde_json::Value = serde_json::from_str(&json).expect("status --json is JSON");
    assert_eq!(v["protocol_version"], 1);
    assert_eq!(v["host_protocol_version"], 1);
    assert!(v["firmware_version"].as_str().unwrap().contains('.'));
    let boot_id = v["boot_id"].as_u64().expect("boot id");
    assert!(v["status"]["fault"].is_null());

    let ping = ok(rig(&port, &["ping", "--count", "5"]));
    assert!(ping.contains("round trip median"), "{ping}");

    ok(rig(&port, &["lamps", "0b101"]));
    ok(rig(&port, &["galvo", "set", "-2.5"]));
    ok(rig(&port, &["trigger", "3", "--pulse-us", "200"]));
    let moved = ok(rig(&port, &["move", "arc", "10", "--relative"]));
    assert!(moved.contains("light arc at"), "{moved}");
    let swept = ok(rig(
        &port,
        &[
            "galvo",
            "sweep",
            "--from",
            "-1",
            "--to",
            "1",
            "--steps",
            "3",
            "--dwell-ms",
            "5",
            "--trigger",
            "1",
        ],
    ));
    assert!(swept.contains("sweep completed"), "{swept}");

    // The state survives between processes: the same boot, the lamps still on.
    let v: serde_json::Value =
        serde_json::from_str(&ok(rig(&port, &["status", "--json"]))).unwrap();
    assert_eq!(v["boot_id"].as_u64(), Some(boot_id));
    assert_eq!(v["status"]["lamps"], 0b101);
    let arc = v["positions_deg"]["light_arc"].as_f64().unwrap();
    assert!((arc - 10.0).abs() < 0.01, "light arc at {arc}");

    // E-stop latches a fault; a refused command is one clear line; clear.
    ok(rig(&port, &["estop"]));
    let refused = rig(&port, &["lamps", "1"]);
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("fault is latched"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    ok(rig(&port, &["clear"]));
    let v: serde_json::Value =
        serde_json::from_str(&ok(rig(&port, &["status", "--json"]))).unwrap();
    assert!(v["status"]["fault"].is_null());
    drop(server);
}

#[test]
fn bad_ports_and_arguments_are_one_clear_line() {
    let out = Command::new(QHM)
        .args(["rig", "--port", "/dev/qhm-missing", "status"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cannot open /dev/qhm-missing"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    let out = Command::new(QHM).args(["rig", "status"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--port PATH") && err.contains("--sim"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    let out = Command::new(QHM)
        .args(["rig", "--sim", "lamps", "0x1ff"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad mask"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");

    let out = Command::new(QHM)
        .args(["flash", "--elf", "/nonexistent/firmware.elf"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no firmware ELF"), "{err}");
}
