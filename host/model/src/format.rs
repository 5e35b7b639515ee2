//! The on-disk material model: a versioned directory with a TOML manifest
//! and EXR data (specified in docs/model-format.md). The loader validates
//! everything it reads and names the offending file and field.
//!
//! ```text
//! MODEL_DIR/manifest.toml          format, version, units, texture, dipole, entrance table, directions
//! MODEL_DIR/fv/view_NNN.exr        f_v for view NNN (width × height, RGB f32)
//! MODEL_DIR/lrf/sample_NNN.exr     LRF for (light, view) sample NNN       (encoding = "raw")
//! MODEL_DIR/lrf/pca_basis.exr      row 0 mean, rows 1..=k basis vectors   (encoding = "pca")
//! MODEL_DIR/lrf/pca_coeff_M.exr    coefficients 3M..3M+2 per texel         (encoding = "pca")
//! MODEL_DIR/fit.json               optional fit diagnostics for the report
//! ```

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::ModelError;
use crate::exrio::{read_rgb, write_rgb};
use crate::model::{
    EntranceFunction, ExitingFunction, FitDiagnostics, LocalReflectance, LrfSample, MaterialModel,
    Texture, norm,
};
use crate::subsurface::DipoleParams;
use crate::subsurface::ProfileModel;

/// The `format` string of a manifest.
pub const FORMAT: &str = "qhm-material";
/// The manifest version this code writes and reads. Version 2: a' and s'_t
/// are per entered flux (fitted from R / T(0)); version 1 fitted them per
/// incident flux, which reads 4 % too little light at eta 1.5.
pub const VERSION: u32 = 2;

#[derive(Serialize, Deserialize)]
struct Manifest {
    format: String,
    version: u32,
    units: Units,
    texture: TextureInfo,
    dipole: DipoleSection,
    entrance: EntranceSection,
    exiting: ExitingSection,
    lrf: LrfSection,
}

#[derive(Serialize, Deserialize)]
struct Units {
    length: String,
    coefficients: String,
    directions: String,
    fv: String,
    lrf: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            length: "mm".into(),
            coefficients: "mm^-1".into(),
            directions:
                "unit vectors, sample frame, z = surface normal, pointing away from the surface"
                    .into(),
            fv: "dimensionless; L = f_v / pi * diffuse exitance".into(),
            lrf: "sr^-1; outgoing radiance per irradiance normal to the light".into(),
        }
    }
}

#[derive(Serialize, Deserialize)]
struct TextureInfo {
    width: u32,
    height: u32,
    texel_mm: f32,
}

#[derive(Serialize, Deserialize)]
struct DipoleSection {
    eta: f64,
    /// The light transport R_d(r) comes from (files before it: "dipole").
    #[serde(default = "ProfileModel::recorded_before_choice")]
    model: ProfileModel,
    alpha_prime: [f64; 3],
    sigma_t_prime: [f64; 3],
    /// Informative: s'_s = a' s'_t.
    sigma_s_prime: [f64; 3],
    /// Informative: s_a = (1 - a') s'_t.
    sigma_a: [f64; 3],
}

#[derive(Serialize, Deserialize)]
struct EntranceSection {
    n_theta: usize,
    n_phi: usize,
    values: Vec<[f32; 3]>,
}

#[derive(Serialize, Deserialize)]
struct ExitingSection {
    views: Vec<[f32; 3]>,
    files: Vec<String>,
}

#[derive(Serialize, Deserialize)]
struct LrfSection {
    encoding: String,
    samples: Vec<LrfSample>,
    #[serde(default)]
    files: Vec<String>,
    #[serde(default)]
    components: usize,
}

/// How to write a model.
#[derive(Clone, Copy, Debug, Default)]
pub struct SaveOptions {
    /// Compress the LRF to this many PCA components (None = raw).
    pub lrf_components: Option<usize>,
}

/// What [`MaterialModel::save_with`] wrote.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SaveReport {
    /// Floats of LRF data uncompressed and as written.
    pub lrf_floats_raw: usize,
    pub lrf_floats_written: usize,
    /// Relative RMS error of the compressed LRF (0 when raw).
    pub lrf_rel_rms_error: f64,
}

fn write_text(path: &Path, text: &str) -> Result<(), ModelError> {
    std::fs::write(path, text).map_err(|e| ModelError::io(path, e))
}

impl MaterialModel {
    /// Writes the model uncompressed.
    pub fn save(&self, dir: &Path) -> Result<(), ModelError> {
        self.save_with(dir, &SaveOptions::default()).map(|_| ())
    }

    /// Writes the model, optionally PCA-compressing the LRF.
    pub fn save_with(&self, dir: &Path, opts: &SaveOptions) -> Result<SaveReport, ModelError> {
        self.check(dir)?;
        for sub in ["fv", "lrf"] {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| ModelError::io(&p, e))?;
        }
        let fv_files: Vec<String> = (0..self.exiting.views.len())
            .map(|v| format!("fv/view_{v:03}.exr"))
            .collect();
        fv_files
            .par_iter()
            .zip(&self.exiting.maps)
            .try_for_each(|(f, t)| write_rgb(&dir.join(f), t))?;
        let n_raw = self.lrf.maps.len() * (self.width * self.height) as usize * 3;
        let mut report = SaveReport {
            lrf_floats_raw: n_raw,
            lrf_floats_written: n_raw,
            lrf_rel_rms_error: 0.0,
        };
        let lrf = match opts.lrf_components {
            Some(k) if !self.lrf.maps.is_empty() => {
                let pca = crate::compress::Pca::fit(&self.lrf.maps, k);
                report.lrf_rel_rms_error = pca.rel_rms_error(&self.lrf.maps);
                report.lrf_floats_written = pca.floats();
                let files = pca.write(dir)?;
                LrfSection {
                    encoding: "pca".into(),
                    samples: self.lrf.samples.clone(),
                    files,
                    components: pca.k(),
                }
            }
            _ => {
                let files: Vec<String> = (0..self.lrf.maps.len())
                    .map(|s| format!("lrf/sample_{s:03}.exr"))
                    .collect();
                files
                    .par_iter()
                    .zip(&self.lrf.maps)
                    .try_for_each(|(f, t)| write_rgb(&dir.join(f), t))?;
                LrfSection {
                    encoding: "raw".into(),
                    samples: self.lrf.samples.clone(),
                    files,
                    components: 0,
                }
            }
        };
        if let Some(d) = &self.diagnostics {
            let p = dir.join("fit.json");
            let text = serde_json::to_string_pretty(d).expect("diagnostics serialise");
            write_text(&p, &text)?;
        }
        let m = Manifest {
            format: FORMAT.into(),
            version: VERSION,
            units: Units::default(),
            texture: TextureInfo {
                width: self.width,
                height: self.height,
                texel_mm: self.texel_mm,
            },
            dipole: DipoleSection {
                eta: self.dipole.eta,
                model: self.dipole.model,
                alpha_prime: self.dipole.alpha_prime,
                sigma_t_prime: self.dipole.sigma_t_prime,
                sigma_s_prime: self.dipole.sigma_s_prime(),
                sigma_a: self.dipole.sigma_a(),
            },
            entrance: EntranceSection {
                n_theta: self.entrance.n_theta,
                n_phi: self.entrance.n_phi,
                values: self.entrance.values.clone(),
            },
            exiting: ExitingSection {
                views: self.exiting.views.clone(),
                files: fv_files,
            },
            lrf,
        };
        let text = toml::to_string_pretty(&m).map_err(|e| ModelError::Toml {
            path: dir.join("manifest.toml"),
            message: e.to_string(),
        })?;
        // The manifest goes last: a directory without one is not a model.
        write_text(&dir.join("manifest.toml"), &text)?;
        Ok(report)
    }

    /// Reads and validates a model directory.
    pub fn load(dir: &Path) -> Result<Self, ModelError> {
        let mpath = dir.join("manifest.toml");
        let text = std::fs::read_to_string(&mpath).map_err(|e| ModelError::io(&mpath, e))?;
        let m: Manifest = toml::from_str(&text).map_err(|e| ModelError::Toml {
            path: mpath.clone(),
            message: e.to_string(),
        })?;
        let bad = |msg: String| ModelError::invalid(&mpath, msg);
        if m.format != FORMAT {
            return Err(bad(format!(
                "format is `{}`, expected `{FORMAT}`",
                m.format
            )));
        }
        if m.version == 1 {
            return Err(bad(
                "version 1 (a' and s'_t per incident flux) is no longer read; \
                 refit the capture with `qhm fit` to write version 2"
                    .into(),
            ));
        }
        if m.version != VERSION {
            return Err(bad(format!(
                "unsupported version {}; this qhm reads version {VERSION}",
                m.version
            )));
        }
        let (w, h) = (m.texture.width as usize, m.texture.height as usize);
        let dipole = DipoleParams {
            alpha_prime: m.dipole.alpha_prime,
            sigma_t_prime: m.dipole.sigma_t_prime,
            eta: m.dipole.eta,
            model: m.dipole.model,
        };
        let entrance = EntranceFunction {
            n_theta: m.entrance.n_theta,
            n_phi: m.entrance.n_phi,
            values: m.entrance.values,
        };
        if m.exiting.files.len() != m.exiting.views.len() {
            return Err(bad(format!(
                "exiting: {} views but {} files",
                m.exiting.views.len(),
                m.exiting.files.len()
            )));
        }
        let read_sized = |f: &String| -> Result<Texture, ModelError> {
            let p = safe_join(dir, f)
                .ok_or_else(|| bad(format!("file name `{f}` leaves the model directory")))?;
            let t = read_rgb(&p)?;
            if (t.width, t.height) != (w, h) {
                return Err(ModelError::invalid(
                    &p,
                    format!("{}×{} texels, the manifest says {w}×{h}", t.width, t.height),
                ));
            }
            Ok(t)
        };
        let fv_maps = m
            .exiting
            .files
            .par_iter()
            .map(read_sized)
            .collect::<Result<Vec<_>, _>>()?;
        let lrf_maps = match m.lrf.encoding.as_str() {
            "raw" => {
                if m.lrf.files.len() != m.lrf.samples.len() {
                    return Err(bad(format!(
                        "lrf: {} samples but {} files",
                        m.lrf.samples.len(),
                        m.lrf.files.len()
                    )));
                }
                m.lrf
                    .files
                    .par_iter()
                    .map(read_sized)
                    .collect::<Result<Vec<_>, _>>()?
            }
            "pca" => crate::compress::Pca::read(
                dir,
                &m.lrf.files,
                m.lrf.components,
                m.lrf.samples.len(),
                w,
                h,
            )?
            .expand(),
            other => return Err(bad(format!("lrf: unknown encoding `{other}` (raw, pca)"))),
        };
        let diagnostics = read_diagnostics(dir);
        let model = MaterialModel {
            dipole,
            entrance,
            exiting: ExitingFunction::new(m.exiting.views, fv_maps),
            lrf: LocalReflectance::new(m.lrf.samples, lrf_maps),
            texel_mm: m.texture.texel_mm,
            width: m.texture.width,
            height: m.texture.height,
            diagnostics,
        };
        model.check(dir)?;
        Ok(model)
    }

    /// Consistency checks shared by save and load; `dir` only names errors.
    pub fn check(&self, dir: &Path) -> Result<(), ModelError> {
        let path = dir.join("manifest.toml");
        let bad = |msg: String| ModelError::invalid(&path, msg);
        let (w, h) = (self.width as usize, self.height as usize);
        if w == 0 || h == 0 {
            return Err(bad(format!("texture size {w}×{h} must be positive")));
        }
        if !(self.texel_mm.is_finite() && self.texel_mm > 0.0) {
            return Err(bad(format!("texel_mm = {} must be > 0", self.texel_mm)));
        }
        self.dipole
            .validate()
            .map_err(|m| bad(format!("dipole: {m}")))?;
        let e = &self.entrance;
        if e.n_theta < 2 || e.n_phi < 1 || e.values.len() != e.n_theta * e.n_phi {
            return Err(bad(format!(
                "entrance: n_theta = {} (>= 2), n_phi = {} (>= 1) and {} values (need n_theta*n_phi)",
                e.n_theta,
                e.n_phi,
                e.values.len()
            )));
        }
        if let Some(k) = e
            .values
            .iter()
            .position(|v| v.iter().any(|x| !x.is_finite() || *x < 0.0))
        {
            return Err(bad(format!(
                "entrance: value {k} is negative or not finite"
            )));
        }
        let dir_ok = |d: &[f32; 3]| (norm(*d) - 1.0).abs() < 1e-3 && d[2] > -1e-4;
        if self.exiting.views.is_empty() {
            return Err(bad("exiting: no view directions".into()));
        }
        if let Some(k) = self.exiting.views.iter().position(|d| !dir_ok(d)) {
            return Err(bad(format!(
                "exiting: view {k} {:?} is not a unit vector in the upper hemisphere",
                self.exiting.views[k]
            )));
        }
        if let Some(k) = self
            .lrf
            .samples
            .iter()
            .position(|s| !dir_ok(&s.light) || !dir_ok(&s.view))
        {
            return Err(bad(format!(
                "lrf: sample {k} {:?} has a direction that is not a unit vector in the upper hemisphere",
                self.lrf.samples[k]
            )));
        }
        if self.exiting.maps.len() != self.exiting.views.len()
            || self.lrf.maps.len() != self.lrf.samples.len()
        {
            return Err(bad(
                "number of maps differs from the number of directions".into()
            ));
        }
        for (what, maps) in [("fv", &self.exiting.maps), ("lrf", &self.lrf.maps)] {
            for (k, t) in maps.iter().enumerate() {
                if (t.width, t.height) != (w, h) || t.data.len() != w * h {
                    return Err(bad(format!(
                        "{what} map {k} is {}×{}, expected {w}×{h}",
                        t.width, t.height
                    )));
                }
                if let Some(p) = t.data.iter().position(|v| v.iter().any(|x| !x.is_finite())) {
                    return Err(bad(format!(
                        "{what} map {k}: texel ({}, {}) is NaN or infinite",
                        p % w,
                        p / w
                    )));
                }
            }
        }
        Ok(())
    }
}

/// `dir/name` if `name` is relative and stays inside `dir`.
fn safe_join(dir: &Path, name: &str) -> Option<PathBuf> {
    let p = Path::new(name);
    if p.is_absolute()
        || p.components()
            .any(|c| matches!(c, std::path::Component::ParentDir))
    {
        return None;
    }
    Some(dir.join(p))
}

/// The optional fit.json. Only the report reads it, and rendering needs
/// only the manifest and the EXRs, so a broken one is a warning: the model
/// loads without diagnostics.
fn read_diagnostics(dir: &Path) -> Option<FitDiagnostics> {
    let path = dir.join("fit.json");
    if !path.exists() {
        return None;
    }
    let parsed = std::fs::read_to_string(&path)
        .map_err(|e| ModelError::io(&path, e))
        .and_then(|t| {
            serde_json::from_str(&t).map_err(|e| ModelError::invalid(&path, e.to_string()))
        });
    match parsed {
        Ok(d) => Some(d),
        Err(e) => {
            tracing::warn!("{e}; the model is read without its fit diagnostics");
            None
        }
    }
}

/// Writes just the diagnostics (used by the fit after the model is saved).
pub fn save_diagnostics(dir: &Path, d: &FitDiagnostics) -> Result<(), ModelError> {
    let text = serde_json::to_string_pretty(d).expect("diagnostics serialise");
    write_text(&dir.join("fit.json"), &text)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_model() -> MaterialModel {
        let mut m = MaterialModel::homogeneous(DipoleParams {
            alpha_prime: [0.999, 0.99, 0.9],
            sigma_t_prime: [1.2, 1.6, 2.2],
            eta: 1.3,
            model: ProfileModel::Dipole,
        });
        let (w, h) = (4, 3);
        m.width = w as u32;
        m.height = h as u32;
        m.texel_mm = 0.5;
        let tex = |s: f32| Texture {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|p| [s + p as f32 * 0.01, s, -s * 0.1])
                .collect(),
        };
        m.exiting = ExitingFunction::new(
            vec![[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]],
            vec![tex(1.0), tex(0.9)],
        );
        m.lrf = LocalReflectance::new(
            (0..5)
                .map(|k| LrfSample {
                    light: [0.0, 0.6, 0.8],
                    view: [(k as f32 * 0.3).sin() * 0.6, 0.0, 0.8],
                })
                .map(|s| {
                    let n = norm(s.view);
                    LrfSample {
                        view: s.view.map(|x| x / n),
                        ..s
                    }
                })
                .collect(),
            (0..5).map(|k| tex(0.1 * k as f32)).collect(),
        );
        m
    }

    #[test]
    fn save_load_round_trip_raw_and_pca() {
        let m = sample_model();
        let dir = tempfile::tempdir().unwrap();
        m.save(dir.path()).unwrap();
        let back = MaterialModel::load(dir.path()).unwrap();
        assert_eq!(back, m);
        let dir2 = tempfile::tempdir().unwrap();
        let rep = m
            .save_with(
                dir2.path(),
                &SaveOptions {
                    lrf_components: Some(3),
                },
            )
            .unwrap();
        assert_eq!(rep.lrf_floats_raw, 5 * 12 * 3);
        assert!(rep.lrf_floats_written < rep.lrf_floats_raw);
        assert!(rep.lrf_rel_rms_error < 1e-3, "{rep:?}");
        let back = MaterialModel::load(dir2.path()).unwrap();
        let d = back.lrf([0.3, 0.4], [0.0, 0.6, 0.8], m.lrf.samples[2].view);
        let e = m.lrf([0.3, 0.4], [0.0, 0.6, 0.8], m.lrf.samples[2].view);
        assert!((0..3).all(|c| (d[c] - e[c]).abs() < 1e-3), "{d:?} vs {e:?}");
    }

    #[test]
    fn the_profile_model_is_kept_and_defaults_to_the_dipole() {
        let mut m = sample_model();
        m.dipole.model = ProfileModel::Transport;
        let dir = tempfile::tempdir().unwrap();
        m.save(dir.path()).unwrap();
        assert_eq!(
            MaterialModel::load(dir.path()).unwrap().dipole.model,
            ProfileModel::Transport
        );
        // Version-2 files written before the choice have no `model`: the dipole.
        edit(dir.path(), "model = \"transport\"\n", "");
        assert_eq!(
            MaterialModel::load(dir.path()).unwrap().dipole.model,
            ProfileModel::Dipole
        );
        edit(
            dir.path(),
            "[dipole]\n",
            "[dipole]\nmodel = \"diffusion\"\n",
        );
        assert!(
            load_err(dir.path()).contains("diffusion"),
            "{}",
            load_err(dir.path())
        );
    }

    fn edit(dir: &Path, from: &str, to: &str) {
        let p = dir.join("manifest.toml");
        let t = std::fs::read_to_string(&p).unwrap();
        assert!(t.contains(from), "manifest lacks `{from}`");
        std::fs::write(&p, t.replacen(from, to, 1)).unwrap();
    }

    fn load_err(dir: &Path) -> String {
        MaterialModel::load(dir).unwrap_err().to_string()
    }

    #[test]
    fn loader_rejects_inconsistent_models() {
        let m = sample_model();
        let fresh = || {
            let d = tempfile::tempdir().unwrap();
            m.save(d.path()).unwrap();
            d
        };
        let d = fresh();
        edit(d.path(), "version = 2", "version = 7");
        assert!(load_err(d.path()).contains("unsupported version 7"));
        let d = fresh();
        edit(d.path(), "version = 2", "version = 1");
        assert!(load_err(d.path()).contains("refit the capture"));
        let d = fresh();
        edit(d.path(), "format = \"qhm-material\"", "format = \"other\"");
        assert!(load_err(d.path()).contains("format is `other`"));
        let d = fresh();
        std::fs::remove_file(d.path().join("fv/view_001.exr")).unwrap();
        let e = load_err(d.path());
        assert!(e.contains("view_001.exr") && e.contains("missing"), "{e}");
        let d = fresh();
        edit(d.path(), "width = 4", "width = 5");
        assert!(load_err(d.path()).contains("the manifest says 5×3"));
        let d = fresh();
        edit(
            d.path(),
            "0.6,\n    0.0,\n    0.8,",
            "0.9,\n    0.0,\n    0.8,",
        );
        assert!(
            load_err(d.path()).contains("not a unit vector"),
            "{}",
            load_err(d.path())
        );
        let d = fresh();
        let mut t = read_rgb(&d.path().join("lrf/sample_002.exr")).unwrap();
        t.data[5][1] = f32::NAN;
        write_rgb(&d.path().join("lrf/sample_002.exr"), &t).unwrap();
        assert!(load_err(d.path()).contains("lrf map 2: texel (1, 1) is NaN"));
        let d = fresh();
        std::fs::remove_file(d.path().join("manifest.toml")).unwrap();
        assert!(load_err(d.path()).contains("manifest.toml"));
        let d = fresh();
        edit(d.path(), "fv/view_000.exr", "../view_000.exr");
        assert!(load_err(d.path()).contains("leaves the model directory"));
        let d = fresh();
        edit(d.path(), "alpha_prime = [", "alpha_prime = [1.5, ");
        assert!(
            load_err(d.path()).contains("invalid length") || load_err(d.path()).contains("alpha")
        );
    }
}
