//! `qhm view MODEL_DIR`: a local web page to look at a material model on
//! a mesh, relit interactively with its subsurface part. The server binds
//! 127.0.0.1 only and serves one static page (`view.html`, embedded) and a
//! small JSON/PNG API; every image comes from qhm's own renderer,
//! progressively (see [`engine::LEVELS`]):
//!
//! - `GET /` the page; `GET /api/info` the model, meshes, modes, env maps,
//!   limits and levels; `GET /api/stats` request and render counters;
//! - `POST /api/render` a view as JSON -> PNG (headers `x-qhm-level`,
//!   `x-qhm-levels`, `x-qhm-ms`, `x-qhm-pass-one`), or 204 when a newer
//!   render request superseded it before it finished;
//! - `POST /api/save` a view -> the final image as EXR and PNG and the
//!   scene TOML that `qhm render --scene` reproduces it from, under
//!   `--save-dir`, never overwriting.
//!
//! Bad requests get a 4xx with a JSON `{"error": ...}` message.

mod engine;
mod request;

use std::io::Write as _;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use anyhow::Context;
use axum::body::Bytes;
use axum::extract::{Request, State};
use axum::http::{StatusCode, Uri, header};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use clap::Args;
use qhm_render::Mode;
use serde_json::json;

use engine::{Engine, Frame, LEVELS};
use request::{ENV_NAMES, SIZE_MAX, SIZE_MIN, View, parse_view};

const PAGE: &str = include_str!("../view.html");

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Material model directory, or `builtin:NAME` for a homogeneous preset.
    pub model: String,
    /// Port on 127.0.0.1 (0 picks a free one); the URL is printed on stdout.
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Open the page in the desktop's browser (xdg-open).
    #[arg(long)]
    pub open: bool,
    /// An OBJ or PLY mesh to offer beside the built-in objects.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// mm per mesh-file unit.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f32,
    /// Where "save" writes qhm-view-NNN.{exr,png,toml} (never overwriting).
    #[arg(long, default_value = ".")]
    pub save_dir: PathBuf,
}

struct App {
    engine: Mutex<Engine>,
    meshes: Vec<String>,
    model_spec: String,
    model_name: String,
    save_dir: PathBuf,
    /// The cancel flag of the render in flight: a newer request sets it.
    current: Mutex<Arc<AtomicBool>>,
    /// The view (without its level) whose refinement is timed, and when
    /// its first request arrived.
    refining: Mutex<Option<(String, Instant)>>,
    stats: Counters,
}

#[derive(Default)]
struct Counters {
    requests: AtomicU64,
    client_errors: AtomicU64,
    server_errors: AtomicU64,
    renders: AtomicU64,
    superseded: AtomicU64,
    saves: AtomicU64,
}

pub fn run(args: ViewArgs) -> anyhow::Result<ExitCode> {
    if !(args.scale.is_finite() && args.scale > 0.0) {
        anyhow::bail!("--scale must be > 0");
    }
    let (model_name, model) = super::render::load_model(&args.model)?;
    let model_spec = match args.model.strip_prefix("builtin:") {
        Some(_) => args.model.clone(),
        None => absolute(Path::new(&args.model)),
    };
    let mesh = args
        .mesh
        .as_ref()
        .map(|p| (PathBuf::from(absolute(p)), args.scale));
    let engine = Engine::new(model, mesh)?;
    std::fs::create_dir_all(&args.save_dir)
        .with_context(|| format!("creating --save-dir {}", args.save_dir.display()))?;
    let app = Arc::new(App {
        meshes: engine.mesh_names(),
        engine: Mutex::new(engine),
        model_spec,
        model_name,
        save_dir: args.save_dir.clone(),
        current: Mutex::new(Arc::new(AtomicBool::new(false))),
        refining: Mutex::new(None),
        stats: Counters::default(),
    });
    let rt = tokio::runtime::Runtime::new().context("starting the async runtime")?;
    rt.block_on(serve(app, args.port, args.open))?;
    Ok(ExitCode::SUCCESS)
}

async fn serve(app: Arc<App>, port: u16, open: bool) -> anyhow::Result<()> {
    // Loopback only: the page can write files into --save-dir.
    let addr = SocketAddr::from((Ipv4Addr::LOCALHOST, port));
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("binding {addr}"))?;
    let url = format!("http://{}/", listener.local_addr()?);
    println!("qhm view: {url}");
    std::io::stdout().flush()?;
    if open && let Err(e) = std::process::Command::new("xdg-open").arg(&url).spawn() {
        eprintln!("qhm view: could not start xdg-open ({e}); open {url} yourself");
    }
    let router = Router::new()
        .route("/", get(|| async { Html(PAGE) }))
        .route("/api/info", get(info))
        .route("/api/stats", get(stats))
        .route("/api/render", post(render))
        .route("/api/save", post(save))
        .fallback(not_found)
        .layer(middleware::from_fn_with_state(app.clone(), count))
        .with_state(app);
    axum::serve(listener, router)
        .with_graceful_shutdown(async {
            let _ = tokio::signal::ctrl_c().await;
        })
        .await?;
    Ok(())
}

fn absolute(p: &Path) -> String {
    std::path::absolute(p)
        .unwrap_or_else(|_| p.to_path_buf())
        .to_string_lossy()
        .into_owned()
}

impl App {
    /// The engine, also after a panic in an earlier render: its pass-1
    /// cache may be half-updated then, so it is dropped.
    fn engine(&self) -> MutexGuard<'_, Engine> {
        self.engine.lock().unwrap_or_else(|poisoned| {
            let mut e = poisoned.into_inner();
            e.clear();
            self.engine.clear_poison();
            e
        })
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

fn error(status: StatusCode, message: impl Into<String>) -> Response {
    (status, Json(json!({ "error": message.into() }))).into_response()
}

async fn not_found(uri: Uri) -> Response {
    error(StatusCode::NOT_FOUND, format!("no such page: {uri}"))
}

async fn count(State(app): State<Arc<App>>, req: Request, next: Next) -> Response {
    app.stats.requests.fetch_add(1, Ordering::Relaxed);
    let res = next.run(req).await;
    if res.status().is_client_error() {
        app.stats.client_errors.fetch_add(1, Ordering::Relaxed);
    } else if res.status().is_server_error() {
        app.stats.server_errors.fetch_add(1, Ordering::Relaxed);
    }
    res
}

async fn info(State(app): State<Arc<App>>) -> Response {
    Json(json!({
        "model": app.model_name,
        "meshes": app.meshes,
        "modes": Mode::NAMES,
        "envs": ENV_NAMES,
        "size": { "min": SIZE_MIN, "max": SIZE_MAX },
        "levels": LEVELS.len(),
    }))
    .into_response()
}

async fn stats(State(app): State<Arc<App>>) -> Response {
    let s = &app.stats;
    let n = |a: &AtomicU64| a.load(Ordering::Relaxed);
    Json(json!({
        "requests": n(&s.requests),
        "client_errors": n(&s.client_errors),
        "server_errors": n(&s.server_errors),
        "renders": n(&s.renders),
        "superseded": n(&s.superseded),
        "saves": n(&s.saves),
    }))
    .into_response()
}

/// Runs `job` on the engine off the async threads; a panic becomes a 500.
async fn with_engine<T: Send + 'static>(
    app: &Arc<App>,
    job: impl FnOnce(&mut Engine) -> anyhow::Result<T> + Send + 'static,
) -> Result<T, Response> {
    let app = app.clone();
    match tokio::task::spawn_blocking(move || job(&mut app.engine())).await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(error(StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}"))),
        Err(_) => Err(error(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the renderer panicked; pass 1 is rebuilt on the next request",
        )),
    }
}

async fn render(State(app): State<Arc<App>>, body: Bytes) -> Response {
    let view = match parse_view(&body, &app.meshes, LEVELS.len()) {
        Ok(v) => v,
        Err(e) => return error(StatusCode::BAD_REQUEST, e),
    };
    let arrived = Instant::now();
    let view_key = {
        let mut v = view.clone();
        v.level = 0;
        v.exposure = 1.0;
        format!("{v:?}")
    };
    if view.level == 0 {
        *lock(&app.refining) = Some((view_key.clone(), arrived));
    }
    // One viewer at a time: a newer render request supersedes the one in
    // flight, which stops at its next tile.
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let mut current = lock(&app.current);
        current.store(true, Ordering::Relaxed);
        *current = cancel.clone();
    }
    let v = view.clone();
    let done = with_engine(&app, move |e| {
        if cancel.load(Ordering::Relaxed) {
            return Ok(None);
        }
        let Some(frame) = e.render(&v, &cancel)? else {
            return Ok(None);
        };
        let png = encode_png(&frame.image, v.exposure)?;
        Ok(Some((frame, png)))
    })
    .await;
    let (frame, png) = match done {
        Err(res) => return res,
        Ok(None) => {
            app.stats.superseded.fetch_add(1, Ordering::Relaxed);
            return StatusCode::NO_CONTENT.into_response();
        }
        Ok(Some(x)) => x,
    };
    app.stats.renders.fetch_add(1, Ordering::Relaxed);
    log_frame(&app, &view, &view_key, &frame, arrived);
    (
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (
                header::HeaderName::from_static("x-qhm-level"),
                frame.level.to_string(),
            ),
            (
                header::HeaderName::from_static("x-qhm-levels"),
                LEVELS.len().to_string(),
            ),
            (
                header::HeaderName::from_static("x-qhm-ms"),
                format!("{:.1}", frame.secs * 1e3),
            ),
            (
                header::HeaderName::from_static("x-qhm-pass-one"),
                frame.pass_one.name().to_string(),
            ),
        ],
        png,
    )
        .into_response()
}

/// One line per frame on stderr with `QHM_LOG=debug`; always one line when
/// a view reaches the final level, timed from its first request.
fn log_frame(app: &App, view: &View, view_key: &str, frame: &Frame, arrived: Instant) {
    tracing::debug!(
        "level {} {}x{} {} in {:.0} ms (pass 1 {}, waited {:.0} ms)",
        frame.level,
        frame.image.width,
        frame.image.height,
        view.mode_name,
        frame.secs * 1e3,
        frame.pass_one.name(),
        arrived.elapsed().as_secs_f64() * 1e3 - frame.secs * 1e3,
    );
    let mut refining = lock(&app.refining);
    if frame.level + 1 == LEVELS.len()
        && let Some((key, t0)) = refining.as_ref()
        && key == view_key
    {
        eprintln!(
            "qhm view: {} {}x{} {} on {}: final level (qhm render's default quality) {:.2} s after the first request",
            app.model_name,
            view.width,
            view.height,
            view.mode_name,
            view.mesh,
            t0.elapsed().as_secs_f64()
        );
        *refining = None;
    }
}

fn encode_png(img: &qhm_render::Image, exposure: f32) -> anyhow::Result<Vec<u8>> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub).write_image(
        &img.tone_mapped(Some(exposure)),
        img.width,
        img.height,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

async fn save(State(app): State<Arc<App>>, body: Bytes) -> Response {
    let mut view = match parse_view(&body, &app.meshes, LEVELS.len()) {
        Ok(v) => v,
        Err(e) => return error(StatusCode::BAD_REQUEST, e),
    };
    view.level = LEVELS.len() - 1;
    let dir = app.save_dir.clone();
    let spec = app.model_spec.clone();
    let saved = with_engine(&app, move |e| {
        // A save finishes whatever the page asks meanwhile.
        let never = AtomicBool::new(false);
        let frame = e
            .render(&view, &never)?
            .context("the save's render was cancelled")?;
        let mesh = match e.mesh_file(&view.mesh) {
            Some(p) => format!("--mesh {}", shell_word(&p.to_string_lossy())),
            None => format!("--builtin {}", view.mesh),
        };
        write_saved(&dir, &frame, &view, &spec, &mesh)
    })
    .await;
    match saved {
        Ok(v) => {
            app.stats.saves.fetch_add(1, Ordering::Relaxed);
            Json(v).into_response()
        }
        Err(res) => res,
    }
}

/// Writes qhm-view-NNN.toml, .exr and .png under the first NNN none of
/// whose three files exists.
fn write_saved(
    dir: &Path,
    frame: &Frame,
    view: &View,
    model_spec: &str,
    mesh_arg: &str,
) -> anyhow::Result<serde_json::Value> {
    for n in 1..100_000 {
        let stem = dir.join(format!("qhm-view-{n:03}"));
        let [toml, exr, png] = ["toml", "exr", "png"].map(|e| stem.with_extension(e));
        if exr.exists() || png.exists() {
            continue;
        }
        // create_new claims the number even against another writer.
        let mut f = match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&toml)
        {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e).with_context(|| format!("writing {}", toml.display())),
        };
        let q = |p: &Path| shell_word(&p.to_string_lossy());
        // Into new names: `qhm render` does not overwrite the saved files.
        let again = |e: &str| q(&stem.with_extension(format!("render.{e}")));
        let command = format!(
            "qhm render --model {} {mesh_arg} --scene {} -o {}",
            shell_word(model_spec),
            q(&toml),
            again("exr")
        );
        let text = format!(
            "# qhm view: {model_spec} on {}. Reproduce {} with\n#   {command}\n\
             # and {} with -o {} --exposure {}\n\n{}",
            view.mesh,
            q(&exr),
            q(&png),
            again("png"),
            view.exposure,
            frame.toml
        );
        f.write_all(text.as_bytes())
            .with_context(|| format!("writing {}", toml.display()))?;
        frame.image.write_exr(&exr)?;
        frame.image.write_png(&png, Some(view.exposure))?;
        eprintln!("qhm view: saved {}", stem.display());
        return Ok(json!({
            "scene": toml,
            "exr": exr,
            "png": png,
            "command": command,
        }));
    }
    anyhow::bail!("{}: no free qhm-view-NNN name", dir.display())
}

/// `s` as one shell word (quoted only when it needs it).
fn shell_word(s: &str) -> String {
    let plain = |c: char| c.is_ascii_alphanumeric() || "-_./:=+@%,".contains(c);
    if !s.is_empty() && s.chars().all(plain) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}
