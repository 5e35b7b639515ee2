//! Shared by the `qhm view` tests: a small quasi-homogeneous model written
//! to disk, the server started on a free port (killed on drop), and a
//! minimal HTTP/1.1 client over a plain TCP stream.

#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use qhm_model::model::{EntranceFunction, ExitingFunction, LocalReflectance, LrfSample, Texture};
use qhm_model::{DipoleParams, MaterialModel};

/// A CI-scale quasi-homogeneous model: 32 x 32 texels of 0.5 mm with
/// striped f_v, spotted LRF maps, a Fresnel entrance function and a
/// translucent dipole (a' 0.98/0.95/0.9, s'_t 0.8/mm).
pub fn write_model(dir: &Path) -> PathBuf {
    let (w, h) = (32usize, 32usize);
    let tex = |f: &dyn Fn(usize, usize) -> [f32; 3]| Texture {
        width: w,
        height: h,
        data: (0..w * h).map(|k| f(k % w, k / w)).collect(),
    };
    let s = 0.5f32;
    let c = (1.0 - s * s).sqrt();
    let views = vec![[0.0, 0.0, 1.0], [s, 0.0, c], [-s, 0.0, c]];
    let fv = (0..views.len())
        .map(|_| tex(&|x, _| [if (x / 4) % 2 == 0 { 1.15 } else { 0.85 }; 3]))
        .collect();
    let lrf = (0..2)
        .map(|_| {
            tex(&|x, y| {
                let d2 = ((x % 8) as f32 - 4.0).powi(2) + ((y % 8) as f32 - 4.0).powi(2);
                [0.03 + 0.05 * (-d2 / 4.0).exp(); 3]
            })
        })
        .collect();
    let model = MaterialModel {
        dipole: DipoleParams {
            alpha_prime: [0.98, 0.95, 0.9],
            sigma_t_prime: [0.8, 0.8, 0.8],
            eta: 1.3,
            model: qhm_model::ProfileModel::Dipole,
        },
        entrance: EntranceFunction::fresnel(1.3, 19),
        exiting: ExitingFunction::new(views, fv),
        lrf: LocalReflectance::new(
            vec![
                LrfSample {
                    light: [0.0, 0.0, 1.0],
                    view: [0.0, 0.0, 1.0],
                },
                LrfSample {
                    light: [s, 0.0, c],
                    view: [0.0, 0.0, 1.0],
                },
            ],
            lrf,
        ),
        texel_mm: 0.5,
        width: w as u32,
        height: h as u32,
        diagnostics: None,
    };
    let out = dir.join("model");
    model.save(&out).expect("saving the test model");
    out
}

/// A running `qhm view`; killed when dropped.
pub struct Server {
    child: Child,
    pub port: u16,
    pub url: String,
    /// The server's stderr lines, as they come.
    pub log: mpsc::Receiver<String>,
}

impl Server {
    pub fn start(model: &Path, extra: &[&str]) -> Server {
        // QHM_BIN runs the tests against another build (e.g. release).
        let bin = std::env::var_os("QHM_BIN").unwrap_or(env!("CARGO_BIN_EXE_qhm").into());
        let mut child = Command::new(bin)
            .arg("view")
            .arg(model)
            .args(["--port", "0"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starting qhm view");
        let (tx, rx) = mpsc::channel();
        let stdout = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let (log_tx, log) = mpsc::channel();
        let stderr = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("[qhm view] {line}");
                let _ = log_tx.send(line);
            }
        });
        let line = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("qhm view printed no URL within 60 s");
        let url = line
            .trim()
            .strip_prefix("qhm view: ")
            .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
            .to_string();
        let port = url
            .trim_end_matches('/')
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("no port in {url:?}"));
        assert!(
            url.starts_with("http://127.0.0.1:"),
            "the server must announce loopback: {url}"
        );
        Server {
            child,
            port,
            url,
            log,
        }
    }

    pub fn get(&self, path: &str) -> Response {
        http(self.port, "GET", path, b"")
    }

    pub fn post(&self, path: &str, body: &str) -> Response {
        http(self.port, "POST", path, body.as_bytes())
    }

    /// The server is still running.
    pub fn alive(&mut self) -> bool {
        self.child.try_wait().ok().flatten().is_none()
    }

    pub fn stats(&self) -> serde_json::Value {
        self.get("/api/stats").json()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub struct Response {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.text()))
    }
}

/// One request on its own connection (`Connection: close`, so the body
/// ends where the stream does).
pub fn http(port: u16, method: &str, path: &str, body: &[u8]) -> Response {
    let mut s = TcpStream::connect(("127.0.0.1", port)).expect("connecting to qhm view");
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("reading the response");
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("response without a header end");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|c| c.parse().ok())
        .expect("status line");
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    if headers
        .iter()
        .any(|(k, v)| k.eq_ignore_ascii_case("transfer-encoding") && v.contains("chunked"))
    {
        body = dechunk(&body);
    }
    Response {
        status,
        headers,
        body,
    }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let n = usize::from_str_radix(String::from_utf8_lossy(&b[..eol]).trim(), 16).unwrap_or(0);
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 2 + n + 2..];
    }
}
