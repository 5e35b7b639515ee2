//! `qhm view`'s page in headless Chromium, driven over the DevTools
//! protocol on a pipe (`--remote-debugging-pipe`: NUL-terminated JSON on
//! the browser's fds 3 and 4). Against a running server with a CI-scale
//! quasi-homogeneous model, it drags the light with real pointer input and
//! checks that the image changes and is not blank, switches the paper's
//! Fig. 9 modes and checks that back light is darker in `lrf-only` than in
//! `full`, saves, and asserts that no request failed (the browser's network
//! events and the server's own counters). Skips, saying so, without
//! Chromium.

mod view_common;

use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use view_common::{Server, write_model};

fn find_chromium() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("QHM_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    [
        "chromium",
        "chromium-browser",
        "google-chrome",
        "google-chrome-stable",
    ]
    .iter()
    .flat_map(|n| std::env::split_paths(&path).map(move |d| d.join(n)))
    .find(|p| p.is_file())
}

/// A headless browser and one page session on it.
struct Cdp {
    child: Child,
    to_browser: ChildStdin,
    from_browser: mpsc::Receiver<Value>,
    next_id: u64,
    session: Option<String>,
    /// Events seen so far (method, params).
    events: Vec<(String, Value)>,
}

impl Cdp {
    fn start(chromium: &Path, profile: &Path) -> Cdp {
        // The shell moves the pipes to the fds the protocol uses.
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(
                r#"exec "$0" --headless --no-sandbox --disable-gpu --disable-dev-shm-usage \
                   --no-first-run --no-default-browser-check --disable-extensions \
                   --remote-debugging-pipe --user-data-dir="$1" --window-size=1100,900 \
                   about:blank 3<&0 4>&1 0</dev/null 1>/dev/null"#,
            )
            .arg(chromium)
            .arg(profile)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting chromium");
        let to_browser = child.stdin.take().unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let (tx, from_browser) = mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            let mut chunk = [0u8; 65536];
            while let Ok(n) = out.read(&mut chunk) {
                if n == 0 {
                    break;
                }
                buf.extend_from_slice(&chunk[..n]);
                while let Some(end) = buf.iter().position(|&b| b == 0) {
                    let msg: Vec<u8> = buf.drain(..=end).collect();
                    if let Ok(v) = serde_json::from_slice(&msg[..msg.len() - 1]) {
                        let _ = tx.send(v);
                    }
                }
            }
        });
        Cdp {
            child,
            to_browser,
            from_browser,
            next_id: 1,
            session: None,
            events: Vec::new(),
        }
    }

    /// Sends one command and waits for its answer, keeping the events
    /// that arrive meanwhile.
    fn call(&mut self, method: &str, params: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        let mut msg = json!({ "id": id, "method": method, "params": params });
        if let Some(s) = &self.session {
            msg["sessionId"] = json!(s);
        }
        let mut bytes = serde_json::to_vec(&msg).unwrap();
        bytes.push(0);
        self.to_browser
            .write_all(&bytes)
            .expect("writing to chromium");
        let deadline = Instant::now() + Duration::from_secs(180);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let v = self
                .from_browser
                .recv_timeout(left)
                .unwrap_or_else(|_| panic!("chromium did not answer {method}"));
            if v["id"].as_u64() == Some(id) {
                if let Some(e) = v.get("error") {
                    panic!("{method}: {e}");
                }
                return v["result"].clone();
            }
            if let Some(m) = v["method"].as_str() {
                self.events.push((m.to_string(), v["params"].clone()));
            }
        }
    }

    /// Evaluates JavaScript in the page, awaiting a promise result.
    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({ "expression": expr, "awaitPromise": true, "returnByValue": true }),
        );
        if let Some(e) = r.get("exceptionDetails") {
            panic!("{expr}: {e}");
        }
        r["result"]["value"].clone()
    }

    fn mouse(&mut self, kind: &str, x: f64, y: f64, buttons: u32) {
        self.call(
            "Input.dispatchMouseEvent",
            json!({ "type": kind, "x": x, "y": y, "button": "left",
                    "buttons": buttons, "clickCount": 1, "pointerType": "mouse" }),
        );
    }
}

impl Drop for Cdp {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Waits for the shown image to reach the last level for the current view
/// and returns (mean, std, max) luminance and a 16 x 16 grid of means.
const FINAL_STATS: &str = r#"
(async () => {
  await qhm.whenFinal();
  const s = qhm.imageStats();
  const c = document.getElementById("view"), g = c.getContext("2d");
  const d = g.getImageData(0, 0, c.width, c.height).data, n = 16, grid = [];
  for (let by = 0; by < n; by++) for (let bx = 0; bx < n; bx++) {
    let sum = 0, k = 0;
    for (let y = Math.floor(by * c.height / n); y < Math.floor((by + 1) * c.height / n); y++)
      for (let x = Math.floor(bx * c.width / n); x < Math.floor((bx + 1) * c.width / n); x++) {
        const i = 4 * (y * c.width + x); sum += d[i] + d[i + 1] + d[i + 2]; k++;
      }
    grid.push(sum / (3 * k));
  }
  return { mean: s.mean, std: s.std, max: s.max, grid,
           latencyMs: qhm.latencyMs, firstMs: qhm.firstMs, finalMs: qhm.finalMs,
           errors: qhm.errors };
})()"#;

fn mean_abs_diff(a: &Value, b: &Value) -> f64 {
    let (a, b) = (a["grid"].as_array().unwrap(), b["grid"].as_array().unwrap());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x.as_f64().unwrap() - y.as_f64().unwrap()).abs())
        .sum::<f64>()
        / a.len() as f64
}

fn assert_not_blank(s: &Value, what: &str) {
    assert!(
        s["std"].as_f64().unwrap() > 2.0 && s["max"].as_f64().unwrap() > 30.0,
        "{what}: the image is blank: {s}"
    );
}

#[test]
fn the_page_relights_the_model_in_headless_chromium() {
    let Some(chromium) = find_chromium() else {
        eprintln!(
            "SKIPPED view_chromium: no chromium on PATH (apt-get install chromium, or set QHM_CHROMIUM)"
        );
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let model = write_model(tmp.path());
    let saves = tmp.path().join("saves");
    let srv = Server::start(&model, &["--save-dir", saves.to_str().unwrap()]);
    let profile = tmp.path().join("chromium-profile");
    let mut b = Cdp::start(&chromium, &profile);

    let target = b.call("Target.createTarget", json!({ "url": "about:blank" }));
    let attached = b.call(
        "Target.attachToTarget",
        json!({ "targetId": target["targetId"], "flatten": true }),
    );
    b.session = Some(attached["sessionId"].as_str().unwrap().to_string());
    b.call("Network.enable", json!({}));
    b.call("Page.enable", json!({}));
    b.call("Runtime.enable", json!({}));
    b.call("Page.navigate", json!({ "url": srv.url }));
    b.eval(
        "new Promise(r => { const t = () => window.qhm && qhm.ready ? r(true) : setTimeout(t, 50); t(); })",
    );
    // CI scale: 128 x 128 (QHM_VIEW_TEST_SIZE to measure others), chosen
    // with the page's own control.
    let size = std::env::var("QHM_VIEW_TEST_SIZE").unwrap_or_else(|_| "128".into());
    b.eval(&format!(
        r#"(() => {{ const s = document.getElementById("size"); s.value = "{size}";
                    s.dispatchEvent(new Event("change")); }})()"#
    ));
    let before = b.eval(FINAL_STATS);
    assert_not_blank(&before, "first view");

    // Drag the light with pointer input: "light" under "Drag moves", then
    // press, move 120 px right in steps, release.
    b.eval(r#"document.querySelector("input[name=drag][value=light]").click()"#);
    let rect = b.eval(
        r#"(() => { const r = document.getElementById("view").getBoundingClientRect();
                    return [r.left + r.width / 2, r.top + r.height / 2]; })()"#,
    );
    let (x, y) = (rect[0].as_f64().unwrap(), rect[1].as_f64().unwrap());
    b.mouse("mouseMoved", x, y, 0);
    b.mouse("mousePressed", x, y, 1);
    for k in 1..=12 {
        b.mouse("mouseMoved", x + 10.0 * k as f64, y - 2.0 * k as f64, 1);
    }
    b.mouse("mouseReleased", x + 120.0, y - 24.0, 0);
    let after = b.eval(FINAL_STATS);
    assert_not_blank(&after, "after the light drag");
    let light = b.eval("S.light");
    assert!(
        (light["azimuth_deg"].as_f64().unwrap() - (-122.0 + 60.0)).abs() < 1e-6,
        "the drag did not move the light: {light}"
    );
    let diff = mean_abs_diff(&before, &after);
    assert!(
        diff > 1.0,
        "dragging the light changed the image by {diff:.2} / 255 only"
    );
    eprintln!(
        "view_chromium: {size} x {size} light drag: first move to first image {:.0} ms; \
         last move to its first image {:.0} ms, to the final level {:.0} ms",
        after["latencyMs"].as_f64().unwrap_or(f64::NAN),
        after["firstMs"].as_f64().unwrap_or(f64::NAN),
        after["finalMs"].as_f64().unwrap_or(f64::NAN)
    );

    // Back light on the 10 mm slab, no env map, +3 EV: light from below
    // comes through the dipole in full; the LRF alone sees none of it.
    b.eval(
        r#"(() => { const m = document.getElementById("mesh"); m.value = "slab";
                    m.dispatchEvent(new Event("change"));
                    const e = document.getElementById("env"); e.value = "none";
                    e.dispatchEvent(new Event("change"));
                    const v = document.getElementById("ev"); v.value = "3";
                    v.dispatchEvent(new Event("input"));
                    document.getElementById("backlight").click(); })()"#,
    );
    let mut means = Vec::new();
    for mode in ["full", "lrf-only", "lrf-dipole", "dipole-only"] {
        b.eval(&format!(
            r#"document.querySelector("input[name=mode][value={mode}]").click()"#
        ));
        assert_eq!(b.eval("S.mode"), json!(mode));
        let s = b.eval(FINAL_STATS);
        eprintln!(
            "view_chromium: back light, {mode}: mean {:.2} / 255",
            s["mean"]
        );
        means.push((mode, s["mean"].as_f64().unwrap()));
    }
    let (full, lrf_only) = (means[0].1, means[1].1);
    assert!(full > 1.0, "back light in full shows nothing: {means:?}");
    assert!(
        lrf_only < 0.5 * full,
        "back light in lrf-only is not darker than in full: {means:?}"
    );

    if let Some(path) = std::env::var_os("QHM_VIEW_SCREENSHOT") {
        let shot = b.call("Page.captureScreenshot", json!({ "format": "png" }));
        let png = base64_decode(shot["data"].as_str().unwrap());
        std::fs::write(path, png).unwrap();
    }

    // Save from the page.
    b.eval(r#"document.getElementById("save").click()"#);
    let saved = b.eval(
        r#"new Promise(r => { const t = () => /\.toml/.test(document.getElementById("saved").textContent)
             ? r(document.getElementById("saved").textContent) : setTimeout(t, 50); t(); })"#,
    );
    assert!(saves.join("qhm-view-001.toml").is_file(), "{saved}");

    // No request failed, as the browser and the server saw it.
    b.eval("new Promise(r => setTimeout(r, 200))");
    let failed: Vec<String> = b
        .events
        .iter()
        .filter_map(|(m, p)| match m.as_str() {
            "Network.loadingFailed" => Some(format!("failed: {p}")),
            "Network.responseReceived" if p["response"]["status"].as_u64() >= Some(400) => Some(
                format!("{} {}", p["response"]["status"], p["response"]["url"]),
            ),
            _ => None,
        })
        .collect();
    assert!(failed.is_empty(), "requests failed: {failed:?}");
    let responses = b
        .events
        .iter()
        .filter(|(m, _)| m == "Network.responseReceived")
        .count();
    assert!(responses > 10, "only {responses} responses seen");
    assert_eq!(b.eval("qhm.errors"), json!([]));
    let st = srv.stats();
    assert_eq!(st["client_errors"], 0, "{st}");
    assert_eq!(st["server_errors"], 0, "{st}");
}

/// Standard base64 (the screenshot's encoding).
fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let b: Vec<u8> = s.bytes().filter(|&c| c != b'=').map(val).collect();
    b.chunks(4)
        .flat_map(|q| {
            let n = q.iter().fold(0u32, |a, &v| a << 6 | v as u32) << (6 * (4 - q.len()));
            let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            bytes[..q.len() - 1].to_vec()
        })
        .collect()
}
