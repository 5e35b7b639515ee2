//! The whole fit (paper section 4.2): from a rectified capture to a
//! [`MaterialModel`]. Per colour channel:
//!
//! 1. I(d) from the vertical (pass-2) stripe images: exitance per incident
//!    flux per mm, binned by distance d from each stripe's line and averaged
//!    over views. Each view's radiance becomes exitance through the angular
//!    distribution of the light under the boundary and its Fresnel
//!    transmittance ([`ProfileModel::exitance_per_radiance`]), not Lambert's
//!    π L: isotropic for the dipole, exact for transport (at a' 0.8 the
//!    isotropic guess puts R 3 % low and a' 0.007 low).
//! 2. R = 2 ∫ I(d) dd, per view that sees the stripe's whole core (far
//!    enough from the laser's mirror direction), averaged over those views:
//!    near-field bins the capture lacks (masked as NaN) are filled from the
//!    model by iterating R -> a' -> s'_t; beyond the data the measured tail
//!    is continued at its own exponential decay.
//! 3. a' by inverting R = T(0) R_total (T(0) = 1 - F(0): the share of the
//!    stripe that enters), s'_t by the profile fit ([`crate::profile`]).
//! 4. f(w_i) from pass-1 band fluxes over views, relative to the vertical.
//! 5. f_v(p, v) = Σ_l L(p, v, l) / Σ_l T(0) I_D(d(p, l)) flux_l / π (the
//!    formula after eq. 6 with I(p, l) from the dipole of eq. 5).
//! 6. LRF = (L - f_v T(0) f(w_i) E cos θ_i (R_total - R_texel) / π) / E,
//!    negatives kept.
//!    Before the global term is taken away, the lamp images' texels are
//!    projected onto the principal components that cross-validation finds
//!    above the noise ([`crate::denoise`]).

mod bins;
mod entrance;
mod exiting;
mod global;
mod lrf;
mod stripes;

pub use lrf::LampGlobalTerm;

use std::path::Path;
use std::time::Instant;

use crate::ModelError;
use crate::denoise::LrfDenoise;
use crate::dipole;
use crate::model::{FitDiagnostics, FitTimings, MaterialModel};
use crate::profile::Norm;
use crate::rectified::Rectified;
use crate::subsurface::DipoleParams;
use crate::subsurface::ProfileModel;
use stripes::dir_key;

/// Options of [`fit_capture`].
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub eta: f64,
    /// Distance range for the s'_t fit (None: automatic per channel).
    pub range: Option<(f64, f64)>,
    /// Misfit of the s'_t search.
    pub norm: Norm,
    /// Light transport of the stripe profile and R_total(a').
    pub model: ProfileModel,
    /// Entrance table resolution.
    pub n_theta: usize,
    pub n_phi: usize,
    /// Width of the distance bins of I(d), mm (None: an eighth of a texel).
    pub bin_mm: Option<f64>,
    /// Principal components the LRF keeps ([`crate::denoise`]).
    pub lrf_denoise: LrfDenoise,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            eta: dipole::DEFAULT_ETA,
            range: None,
            norm: Norm::default(),
            model: ProfileModel::default(),
            n_theta: 10,
            n_phi: 24,
            bin_mm: None,
            lrf_denoise: LrfDenoise::default(),
        }
    }
}

/// Fits the material model of the capture in `capture_dir`.
pub fn fit_capture(
    capture_dir: &Path,
    opts: &FitOptions,
) -> Result<(MaterialModel, FitTimings), ModelError> {
    fit_capture_with_progress(capture_dir, opts, &|_, _| {})
}

/// [`fit_capture`], calling `progress(done, total)` as its steps finish: one
/// per channel's dipole, one for f(w_i), one per f_v view, one per lamp image.
pub fn fit_capture_with_progress(
    capture_dir: &Path,
    opts: &FitOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(MaterialModel, FitTimings), ModelError> {
    let data = Rectified::open(capture_dir)?;
    let total_steps = 4
        + data.index.lamp.len()
        + data
            .index
            .stripe
            .iter()
            .filter(|s| s.pass == 2)
            .map(|s| dir_key(s.view_dir))
            .collect::<std::collections::BTreeSet<_>>()
            .len();
    let steps_done = std::sync::atomic::AtomicUsize::new(0);
    let step = || {
        let done = steps_done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(done, total_steps);
    };
    let grid = data.index.grid;
    let (w, h) = (grid.width as usize, grid.height as usize);
    let bin = opts.bin_mm.unwrap_or(grid.texel_mm / 8.0);
    if !(bin.is_finite() && bin > 0.0) {
        return Err(ModelError::Domain(format!(
            "distance bin {bin} mm must be > 0"
        )));
    }
    let diag_max = grid.texel_mm * ((w * w + h * h) as f64).sqrt();
    let mut timings = FitTimings::default();
    let mut notes = Vec::new();

    // 1-3: the global dipole per channel from the vertical stripes.
    let t0 = Instant::now();
    let (channels, tables) = global::fit_global(&data, opts, bin, diag_max, &mut notes, &step)?;
    let dipole = DipoleParams {
        alpha_prime: std::array::from_fn(|c| channels[c].fit.alpha_prime),
        sigma_t_prime: std::array::from_fn(|c| channels[c].fit.sigma_t_prime),
        eta: opts.eta,
        model: opts.model,
    };
    timings.dipole = t0.elapsed().as_secs_f64();

    // 4: the entrance function.
    let t0 = Instant::now();
    let (entrance, entrance_samples) = entrance::fit_entrance(&data, opts, &mut notes)?;
    timings.entrance = t0.elapsed().as_secs_f64();
    step();

    // 5: the exiting function, per pass-2 view. The texels measured are
    // those every view and channel reaches (the window is cropped to them).
    let t0 = Instant::now();
    let (exiting, window) = exiting::fit_exiting(&data, &channels, &tables, &mut notes, &step)?;
    let [_, _, ww, wh] = window;
    timings.exiting = t0.elapsed().as_secs_f64();

    // 6, 7: the local reflectance function from the lamp images, denoised.
    let t0 = Instant::now();
    let (lrf, lrf_denoise) = lrf::fit_lrf(
        &data,
        &dipole,
        &entrance,
        &exiting,
        window,
        opts.lrf_denoise,
        &mut notes,
        &step,
    )?;
    timings.lrf = t0.elapsed().as_secs_f64();

    let model = MaterialModel {
        dipole,
        entrance,
        exiting,
        lrf,
        texel_mm: grid.texel_mm as f32,
        width: ww,
        height: wh,
        diagnostics: Some(FitDiagnostics {
            channels,
            entrance_samples,
            notes,
            timings: Some(timings.clone()),
            calibration: data.index.calibration.clone(),
            capture_dir: Some(capture_dir.display().to_string()),
            window: Some(window),
            lrf_denoise,
        }),
    };
    model.check(capture_dir)?;
    Ok((model, timings))
}
