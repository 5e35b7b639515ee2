//! `qhm view`'s HTTP API against the real binary: bad requests get a 4xx
//! with a message and leave the server running; it listens on 127.0.0.1
//! only; pass 1 is reused for camera moves and re-lit for light moves; a
//! newer request supersedes a render in flight; and a saved scene makes
//! `qhm render` reproduce the saved EXR bit for bit (also from a re-lit
//! pass 1), under names that never overwrite.

mod view_common;

use std::net::TcpStream;
use std::process::Command;
use std::time::Duration;

use view_common::{Server, write_model};

/// A request body: the sphere at 32 x 32 unless `extra` sets the size.
fn view(extra: &str) -> String {
    let size = if extra.contains("width") || extra.contains("height") {
        ""
    } else {
        r#", "width": 32, "height": 32"#
    };
    format!(r#"{{"mesh": "sphere"{size}{extra}}}"#)
}

#[test]
fn bad_requests_get_a_4xx_with_a_message_and_the_server_lives_on() {
    let tmp = tempfile::tempdir().unwrap();
    let model = write_model(tmp.path());
    let mut srv = Server::start(&model, &["--save-dir", tmp.path().to_str().unwrap()]);
    let cases: [(&str, &str, &str, u16, &str); 12] = [
        (
            "POST",
            "/api/render",
            r#"{"mesh": "cube"}"#,
            400,
            "unknown mesh",
        ),
        (
            "POST",
            "/api/render",
            &view(r#", "width": 8"#),
            400,
            "width 8",
        ),
        (
            "POST",
            "/api/render",
            &view(r#", "height": 4096"#),
            400,
            "height 4096",
        ),
        (
            "POST",
            "/api/render",
            r#"{"mesh": "sphere", "#,
            400,
            "malformed",
        ),
        ("POST", "/api/render", "not json at all", 400, "malformed"),
        ("POST", "/api/render", "", 400, "malformed"),
        (
            "POST",
            "/api/render",
            &view(r#", "mode": "x-ray""#),
            400,
            "x-ray",
        ),
        (
            "POST",
            "/api/render",
            &view(r#", "env": "moon""#),
            400,
            "unknown env",
        ),
        (
            "POST",
            "/api/render",
            &view(r#", "level": 4"#),
            400,
            "level 4",
        ),
        (
            "POST",
            "/api/save",
            &view(r#", "exposure": -1"#),
            400,
            "exposure",
        ),
        (
            "POST",
            "/api/render",
            &view(r#", "width": -5"#),
            400,
            "malformed",
        ),
        ("GET", "/no/such/page", "", 404, "no such page"),
    ];
    for (method, path, body, status, needle) in cases {
        let r = view_common::http(srv.port, method, path, body.as_bytes());
        assert_eq!(r.status, status, "{method} {path} {body}: {}", r.text());
        let msg = r.json()["error"].as_str().unwrap_or_default().to_string();
        assert!(msg.contains(needle), "{body}: {msg}");
        assert!(srv.alive(), "the server died on {body}");
    }
    // A wrong method is a 4xx too.
    assert_eq!(srv.get("/api/render").status, 405);
    let ok = srv.post("/api/render", &view(""));
    assert_eq!(ok.status, 200, "{}", ok.text());
    assert_eq!(ok.header("content-type"), Some("image/png"));
    assert!(ok.body.starts_with(b"\x89PNG"));
    let st = srv.stats();
    assert_eq!(st["client_errors"], 13, "{st}");
    assert_eq!(st["server_errors"], 0, "{st}");
}

#[test]
fn listens_on_loopback_127_0_0_1_only() {
    let tmp = tempfile::tempdir().unwrap();
    let srv = Server::start(&write_model(tmp.path()), &[]);
    assert!(TcpStream::connect(("127.0.0.1", srv.port)).is_ok());
    // All of 127/8 is loopback: a server bound to 0.0.0.0 would answer
    // 127.0.0.2 too, one bound to 127.0.0.1 refuses it.
    let t = Duration::from_secs(2);
    for addr in [
        format!("127.0.0.2:{}", srv.port),
        format!("[::1]:{}", srv.port),
    ] {
        let a = addr.parse().unwrap();
        assert!(
            TcpStream::connect_timeout(&a, t).is_err(),
            "{addr} accepted a connection"
        );
    }
    // And no other interface answers (if the machine has one).
    if let Some(ip) = non_loopback_ip() {
        let a = std::net::SocketAddr::new(ip, srv.port);
        assert!(TcpStream::connect_timeout(&a, t).is_err(), "{a} accepted");
    }
}

/// The address a UDP socket would send from to reach a public address
/// (no packet is sent).
fn non_loopback_ip() -> Option<std::net::IpAddr> {
    let s = std::net::UdpSocket::bind("0.0.0.0:0").ok()?;
    s.connect("192.0.2.1:9").ok()?;
    let ip = s.local_addr().ok()?.ip();
    (!ip.is_loopback() && !ip.is_unspecified()).then_some(ip)
}

#[test]
fn pass_one_is_kept_for_camera_moves_and_relit_for_light_moves() {
    let tmp = tempfile::tempdir().unwrap();
    let srv = Server::start(&write_model(tmp.path()), &[]);
    let render = |extra: &str| {
        let r = srv.post("/api/render", &view(&format!(r#", "level": 1{extra}"#)));
        assert_eq!(r.status, 200, "{}", r.text());
        (r.header("x-qhm-pass-one").unwrap().to_string(), r.body)
    };
    let cam = |az: f32| {
        format!(r#", "camera": {{"azimuth_deg": {az}, "elevation_deg": 20, "distance": 1}}"#)
    };
    let light = r#", "light": {"azimuth_deg": 30, "elevation_deg": 10}"#;
    let (p0, a) = render(&cam(-70.0));
    assert_eq!(p0, "prepared");
    let (p1, b) = render(&cam(-40.0));
    assert_eq!(p1, "reused");
    assert_ne!(a, b, "the camera moved but the image did not change");
    let (p2, c) = render(&format!("{}{light}", cam(-40.0)));
    assert_eq!(p2, "relit");
    assert_ne!(b, c);
    // lrf-only has no dipole term, so no surface samples: its own pass 1.
    let lrf = r#", "mode": "lrf-only""#;
    assert_eq!(render(&format!("{}{light}{lrf}", cam(-40.0))).0, "prepared");
    assert_eq!(render(&format!("{}{light}{lrf}", cam(10.0))).0, "reused");
    // Back to full with the first light: the dipole's pass 1 is re-lit.
    assert_eq!(render(&cam(-40.0)).0, "relit");
}

#[test]
fn a_newer_request_supersedes_the_render_in_flight() {
    let tmp = tempfile::tempdir().unwrap();
    let srv = Server::start(&write_model(tmp.path()), &[]);
    let port = srv.port;
    // The final level at 1024 x 1024 takes seconds; the preview after it
    // stops it at its next tile.
    let slow = std::thread::spawn(move || {
        let body = r#"{"mesh": "sphere", "width": 1024, "height": 1024, "level": 3}"#;
        view_common::http(port, "POST", "/api/render", body.as_bytes())
    });
    std::thread::sleep(Duration::from_millis(300));
    let quick = srv.post("/api/render", &view(""));
    assert_eq!(quick.status, 200, "{}", quick.text());
    let slow = slow.join().unwrap();
    assert_eq!(slow.status, 204, "{}", slow.text());
    assert_eq!(srv.stats()["superseded"], 1);
}

#[test]
fn a_saved_scene_reproduces_the_image_with_qhm_render_and_never_overwrites() {
    let tmp = tempfile::tempdir().unwrap();
    let model = write_model(tmp.path());
    let saves = tmp.path().join("saves");
    let srv = Server::start(&model, &["--save-dir", saves.to_str().unwrap()]);
    let body = view(
        r#", "mode": "full", "env": "sky", "exposure": 2,
        "camera": {"azimuth_deg": 30, "elevation_deg": 15, "distance": 1.2},
        "light": {"azimuth_deg": 160, "elevation_deg": -20, "irradiance": 3}"#,
    );
    // Pass 1 made for another light first, so the save re-lights it: the
    // re-lit image must still be qhm render's.
    let other = srv.post("/api/render", &view(r#", "level": 3, "env": "sky""#));
    assert_eq!(other.header("x-qhm-pass-one"), Some("prepared"));
    let first = srv.post("/api/save", &body);
    assert_eq!(first.status, 200, "{}", first.text());
    let first = first.json();
    // Someone else's file takes number 002: the next save skips it.
    std::fs::write(saves.join("qhm-view-002.png"), b"not ours").unwrap();
    let second = srv.post("/api/save", &body).json();
    let name = |v: &serde_json::Value, k: &str| v[k].as_str().unwrap().to_string();
    assert!(
        name(&first, "scene").ends_with("qhm-view-001.toml"),
        "{first}"
    );
    assert!(
        name(&second, "exr").ends_with("qhm-view-003.exr"),
        "{second}"
    );
    assert_eq!(
        std::fs::read(saves.join("qhm-view-002.png")).unwrap(),
        b"not ours"
    );
    for k in ["scene", "exr", "png"] {
        assert!(std::path::Path::new(&name(&first, k)).is_file(), "{k}");
    }
    let toml = std::fs::read_to_string(name(&first, "scene")).unwrap();
    assert!(toml.contains(&name(&first, "command")), "{toml}");

    let again = tmp.path().join("again.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_qhm"))
        .args([
            "render",
            "--model",
            model.to_str().unwrap(),
            "--builtin",
            "sphere",
        ])
        .args(["--scene", &name(&first, "scene"), "--quiet", "-o"])
        .arg(&again)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let saved = std::fs::read(name(&first, "exr")).unwrap();
    assert!(
        std::fs::read(&again).unwrap() == saved,
        "qhm render --scene {} did not reproduce the saved EXR",
        name(&first, "scene")
    );
}
