//! `qhm report`'s page in headless Chromium, loaded from disk with no
//! network: no console or script errors, every image decodes, and a
//! screenshot is not blank. The model is fitted from a small synthetic
//! capture (qhm_model::synthetic_dataset) in well under a second. The checker itself is
//! proven on a deliberately broken copy of the page (a corrupt image and a
//! console error) and on a blank page. Skips, saying so, without Chromium.
//!
//! Set QHM_KEEP_REPORT=DIR to keep the report and its screenshot in DIR.

use std::path::{Path, PathBuf};
use std::process::Command;

use qhm_model::ProfileModel;
use qhm_model::fit::{FitOptions, fit_capture};
use qhm_model::synthetic_dataset::{SynthSpec, write_synthetic};
use qhm_model::{DipoleParams, MaterialModel};

fn chromium() -> Option<PathBuf> {
    let p =
        std::env::var_os("QHM_CHROMIUM").map_or(PathBuf::from("/usr/bin/chromium"), PathBuf::from);
    p.is_file().then_some(p)
}

/// Chromium with the flags that keep it off the network and out of $HOME.
fn browser(chromium: &Path, profile: &Path) -> Command {
    let mut c = Command::new(chromium);
    c.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--no-default-browser-check",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-extensions",
        "--disable-dev-shm-usage",
        "--hide-scrollbars",
        "--enable-logging=stderr",
        "--v=0",
    ])
    .arg(format!("--user-data-dir={}", profile.display()));
    c
}

fn url(page: &Path) -> String {
    format!("file://{}", page.canonicalize().unwrap().display())
}

/// What the page's own check (#qhm-check) and Chromium's console log say.
#[derive(Debug)]
struct PageStatus {
    images: usize,
    broken: Vec<String>,
    errors: Vec<String>,
    /// Console messages in Chromium's log.
    console_errors: Vec<String>,
}

impl PageStatus {
    fn clean(&self) -> bool {
        self.broken.is_empty() && self.errors.is_empty() && self.console_errors.is_empty()
    }
}

fn unescape(s: &str) -> String {
    s.replace("&quot;", "\"")
        .replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&#39;", "'")
        .replace("&amp;", "&")
}

/// Loads `page`, lets its scripts run, and reads the status it wrote.
fn check_page(chromium: &Path, page: &Path) -> PageStatus {
    let profile = tempfile::tempdir().unwrap();
    let out = browser(chromium, profile.path())
        .args(["--virtual-time-budget=10000", "--dump-dom"])
        .arg(url(page))
        .output()
        .expect("running chromium");
    let dom = String::from_utf8_lossy(&out.stdout);
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "chromium --dump-dom failed: {}\n{log}",
        out.status
    );
    let start = dom
        .find("data-status=\"")
        .unwrap_or_else(|| panic!("the page wrote no status (did its script run?):\n{log}"));
    let rest = &dom[start + "data-status=\"".len()..];
    let json = unescape(&rest[..rest.find('"').unwrap()]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let strings = |k: &str| -> Vec<String> {
        v[k].as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_str().unwrap_or("?").to_string())
            .collect()
    };
    // Chromium logs every console message of the page, whatever its level,
    // as `[...:INFO:CONSOLE:line] "text", source: ...`. The report logs
    // nothing, so any such line is a problem.
    let console_errors = log
        .lines()
        .filter(|l| l.contains(":CONSOLE"))
        .map(str::to_string)
        .collect();
    PageStatus {
        images: v["images"].as_u64().unwrap() as usize,
        broken: strings("broken"),
        errors: strings("errors"),
        console_errors,
    }
}

/// A screenshot of `page` at 1280 px wide.
fn screenshot(chromium: &Path, page: &Path, png: &Path) -> image::RgbImage {
    let profile = tempfile::tempdir().unwrap();
    let out = browser(chromium, profile.path())
        .args(["--window-size=1280,2400", "--virtual-time-budget=5000"])
        .arg(format!("--screenshot={}", png.display()))
        .arg(url(page))
        .output()
        .expect("running chromium");
    assert!(
        out.status.success() && png.is_file(),
        "chromium --screenshot failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    image::open(png).unwrap().to_rgb8()
}

/// Variance of the grey level (0..255) over the image.
fn grey_variance(img: &image::RgbImage) -> f64 {
    let g: Vec<f64> = img
        .pixels()
        .map(|p| (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0)
        .collect();
    let m = g.iter().sum::<f64>() / g.len() as f64;
    g.iter().map(|x| (x - m).powi(2)).sum::<f64>() / g.len() as f64
}

/// Distinct colours in the image (a page with plots and colour maps has many).
fn colours(img: &image::RgbImage) -> usize {
    let mut set = std::collections::HashSet::new();
    for p in img.pixels() {
        set.insert(p.0);
    }
    set.len()
}

/// A fitted model of a small synthetic capture, saved in `dir/model`.
fn small_model(dir: &Path) -> PathBuf {
    let truth = DipoleParams {
        alpha_prime: [0.99, 0.97, 0.9],
        sigma_t_prime: [1.0, 1.5, 2.0],
        eta: 1.3,
        model: ProfileModel::Dipole,
    };
    let capture = dir.join("capture");
    let mut spec = SynthSpec::small(truth);
    spec.width = 24;
    spec.height = 24;
    spec.scan_offsets_mm = vec![-3.0, -1.1, 0.7, 2.3];
    write_synthetic(&capture, &spec).unwrap();
    let opts = FitOptions {
        eta: 1.3,
        model: ProfileModel::Dipole,
        ..FitOptions::default()
    };
    let (model, _) = fit_capture(&capture, &opts).unwrap();
    let model_dir = dir.join("model");
    model.save(&model_dir).unwrap();
    model_dir
}

#[test]
fn the_report_page_loads_cleanly_in_headless_chromium() {
    let Some(chromium) = chromium() else {
        println!(
            "skipping the report page test: no /usr/bin/chromium (apt-get install chromium, or set QHM_CHROMIUM)"
        );
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let model_dir = small_model(tmp.path());
    let report = tmp.path().join("report");
    let out = Command::new(env!("CARGO_BIN_EXE_qhm"))
        .arg("report")
        .arg(&model_dir)
        .arg("-o")
        .arg(&report)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "qhm report failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let page = report.join("index.html");
    let html = std::fs::read_to_string(&page).unwrap();
    // Self-contained: nothing is fetched, from the network or beside the page.
    // (The SVG namespace is a name, not an address.)
    let refs = html.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for bad in ["http://", "https://", "src=\"fv.png\"", "<link"] {
        assert!(!refs.contains(bad), "the page refers to {bad}");
    }
    // Sanity of what the check covers: it must see the page's images.
    assert!(MaterialModel::load(&model_dir).is_ok());

    let status = check_page(&chromium, &page);
    assert!(status.clean(), "{status:#?}");
    // 6 x 3 Fig. 6 tiles at most, 4 f_v views, 3 LRF samples: at least 4 + 3 + 3 * 3.
    assert!(status.images >= 16, "{status:#?}");

    let shot_path = tmp.path().join("report.png");
    let shot = screenshot(&chromium, &page, &shot_path);
    let (var, n) = (grey_variance(&shot), colours(&shot));
    assert!(
        var > 500.0 && n > 200,
        "blank screenshot? variance {var:.0}, {n} colours"
    );

    if let Some(keep) = std::env::var_os("QHM_KEEP_REPORT") {
        let keep = PathBuf::from(keep);
        std::fs::create_dir_all(&keep).unwrap();
        std::fs::copy(&page, keep.join("index.html")).unwrap();
        std::fs::copy(&shot_path, keep.join("report.png")).unwrap();
    }

    // The checker fails a broken page: a corrupt image and a console error.
    let broken = tmp.path().join("broken.html");
    let corrupt = "<img alt=\"deliberately corrupt\" src=\"data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAAB\">\
                   <script>console.error('deliberate error'); no_such_function();</script></body>";
    std::fs::write(&broken, html.replace("</body>", corrupt)).unwrap();
    let status = check_page(&chromium, &broken);
    assert_eq!(
        status.broken,
        vec!["deliberately corrupt".to_string()],
        "{status:#?}"
    );
    for what in ["deliberate error", "no_such_function"] {
        assert!(
            status.errors.iter().any(|e| e.contains(what)),
            "{what}: {status:#?}"
        );
        assert!(
            status.console_errors.iter().any(|e| e.contains(what)),
            "{what}: {status:#?}"
        );
    }
    assert!(!status.clean());

    // And the screenshot check fails a blank page.
    let blank = tmp.path().join("blank.html");
    std::fs::write(&blank, "<!doctype html><html><body></body></html>").unwrap();
    let shot = screenshot(&chromium, &blank, &tmp.path().join("blank.png"));
    assert!(grey_variance(&shot) < 1.0 && colours(&shot) < 5);
}
