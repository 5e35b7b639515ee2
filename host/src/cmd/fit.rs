//! `qhm fit-profile`: fit a' and s'_t to a laser-stripe profile from any
//! source, and `qhm fit`: fit the whole material model from a rectified
//! capture (qhm_model::fit).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, bail};
use clap::Args;
use host::output::{OutputKind, StagedDir};
use qhm_model::ProfileModel;
use qhm_model::denoise::LrfDenoise;
use qhm_model::dipole::DEFAULT_ETA;
use qhm_model::profile::Norm;
use qhm_model::{Profile, fit_profile};

#[derive(Args, Debug)]
pub struct FitProfileArgs {
    /// CSV with header `distance_mm,intensity_per_mm`: exitance at distance d
    /// from a straight stripe per unit incident flux per mm of stripe.
    pub profile: PathBuf,
    /// Total diffuse reflectance R of the sample per incident flux, the
    /// specular reflection left out: in (0, 1 - F(0)], F(0) = ((eta - 1) /
    /// (eta + 1))² the surface's normal reflectance (R <= 0.98299 at eta 1.3).
    #[arg(long)]
    pub reflectance: f64,
    /// Relative index of refraction of the dipole.
    #[arg(long, default_value_t = DEFAULT_ETA)]
    pub eta: f64,
    /// Distance range MIN:MAX in mm (default: automatic, printed).
    #[arg(long, value_parser = parse_range)]
    pub range: Option<(f64, f64)>,
    /// Misfit of the s'_t search: Poisson-weighted Σ(I_D - I)²/Ĩ (Ĩ the
    /// smoothed profile), or absolute Σ(I_D - I)² (the paper's eq. 6).
    #[arg(long, value_enum, default_value_t = NormArg::Poisson)]
    pub norm: NormArg,
    /// Light transport of I_D(d) and R_total(a'): radiative transfer solved
    /// in the half-space, or the paper's classic dipole.
    #[arg(long, value_enum, default_value_t = ModelArg::Transport)]
    pub model: ModelArg,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `--model` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum ModelArg {
    Transport,
    Dipole,
}

impl From<ModelArg> for ProfileModel {
    fn from(m: ModelArg) -> ProfileModel {
        match m {
            ModelArg::Transport => ProfileModel::Transport,
            ModelArg::Dipole => ProfileModel::Dipole,
        }
    }
}

/// `--norm` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum NormArg {
    Poisson,
    Absolute,
}

impl From<NormArg> for Norm {
    fn from(n: NormArg) -> Norm {
        match n {
            NormArg::Poisson => Norm::Poisson,
            NormArg::Absolute => Norm::Absolute,
        }
    }
}

fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("`{s}` is not MIN:MAX (mm)"))?;
    let num = |x: &str| -> Result<f64, String> {
        x.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| format!("`{x}` is not a distance in mm"))
    };
    let (lo, hi) = (num(a)?, num(b)?);
    if hi <= lo {
        return Err(format!("MAX {hi} must exceed MIN {lo}"));
    }
    Ok((lo, hi))
}

pub fn run_profile(args: FitProfileArgs) -> anyhow::Result<ExitCode> {
    let profile = Profile::read_csv(&args.profile)?;
    let fit = fit_profile(
        &profile,
        args.reflectance,
        args.eta,
        args.model.into(),
        args.range,
        args.norm.into(),
    )
    .with_context(|| format!("fitting {}", args.profile.display()))?;
    if args.json {
        let v = serde_json::json!({
            "alpha_prime": fit.alpha_prime,
            "sigma_t_prime": fit.sigma_t_prime,
            "sigma_s_prime": fit.sigma_s_prime,
            "sigma_a": fit.sigma_a,
            "residual": fit.residual,
            "range_mm": fit.range_mm,
            "auto_range": fit.auto_range,
            "model": fit.model.name(),
        });
        println!("{v}");
    } else {
        let how = if fit.auto_range { "automatic" } else { "given" };
        println!(
            "range         {:.4}:{:.4} mm ({how}, {} points)",
            fit.range_mm[0], fit.range_mm[1], fit.points
        );
        println!("model         {}", fit.model.name());
        println!("alpha_prime   {:.6}", fit.alpha_prime);
        println!("sigma_t_prime {:.6} mm^-1", fit.sigma_t_prime);
        println!("sigma_s_prime {:.6} mm^-1", fit.sigma_s_prime);
        println!("sigma_a       {:.6} mm^-1", fit.sigma_a);
        println!("residual      {:.3e} (relative RMS)", fit.residual);
    }
    if fit.sigma_t_prime >= qhm_model::profile::SIGMA_T_PRIME_MAX * 0.999 {
        bail!(
            "s'_t hit the end of the search interval (10 mm^-1): the profile does not fit the {} model in range",
            fit.model.name()
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[derive(Args, Debug)]
pub struct FitArgs {
    /// Capture directory holding `rectified/index.toml`.
    pub capture_dir: PathBuf,
    /// Model directory to write (docs/model-format.md); must be new, empty,
    /// or (with --force) hold an earlier material model.
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// Replace the material model in MODEL_DIR (the whole directory, its
    /// report included; a directory that holds no model is never replaced).
    #[arg(long)]
    pub force: bool,
    /// Relative index of refraction of the dipole.
    #[arg(long, default_value_t = DEFAULT_ETA)]
    pub eta: f64,
    /// Distance range MIN:MAX in mm for the s'_t fit (default: automatic per channel).
    #[arg(long, value_parser = parse_range)]
    pub range: Option<(f64, f64)>,
    /// Misfit of the s'_t search (see `qhm fit-profile --help`).
    #[arg(long, value_enum, default_value_t = NormArg::Poisson)]
    pub norm: NormArg,
    /// Light transport of the profile fit (see `qhm fit-profile --help`).
    #[arg(long, value_enum, default_value_t = ModelArg::Transport)]
    pub model: ModelArg,
    /// Compress the LRF to this many PCA components (default: uncompressed).
    #[arg(long)]
    pub lrf_components: Option<usize>,
    /// Denoise the LRF: keep the principal components of the lamp images
    /// that cross-validation finds above the noise (`auto`), exactly N of
    /// them, or none of this (`off`: the LRF as measured).
    #[arg(long, default_value = "auto", value_parser = parse_denoise)]
    pub lrf_denoise: LrfDenoise,
}

fn parse_denoise(s: &str) -> Result<LrfDenoise, String> {
    match s {
        "auto" => Ok(LrfDenoise::Auto),
        "off" => Ok(LrfDenoise::Off),
        n => match n.parse::<usize>() {
            Ok(k) if k > 0 => Ok(LrfDenoise::Components(k)),
            _ => Err(format!(
                "`{s}` is not auto, off or a number of components (1 or more)"
            )),
        },
    }
}

pub fn run_fit(args: FitArgs) -> anyhow::Result<ExitCode> {
    let opts = qhm_model::fit::FitOptions {
        eta: args.eta,
        range: args.range,
        norm: args.norm.into(),
        model: args.model.into(),
        lrf_denoise: args.lrf_denoise,
        ..Default::default()
    };
    if !args.capture_dir.join("rectified/index.toml").is_file() {
        let what = if args.capture_dir.join("capture.toml").is_file() {
            "is not rectified yet"
        } else {
            "holds no rectified capture"
        };
        bail!(
            "{} {what} (no rectified/index.toml); run `qhm rectify {}` first",
            args.capture_dir.display(),
            args.capture_dir.display()
        );
    }
    // Refuse the output before the fit's work, not after it.
    let staged = StagedDir::begin(&args.output, OutputKind::Model, args.force)?;
    let t = std::time::Instant::now();
    let bar = qhm_progress::Bar::new("fit", 0, false);
    let (model, timings) =
        qhm_model::fit::fit_capture_with_progress(&args.capture_dir, &opts, &|done, total| {
            bar.set_total(total as u64);
            bar.set_position(done as u64)
        })
        .with_context(|| format!("fitting {}", args.capture_dir.display()))?;
    bar.finish();
    let report = model
        .save_with(
            staged.path(),
            &qhm_model::SaveOptions {
                lrf_components: args.lrf_components,
            },
        )
        .with_context(|| format!("writing {}", args.output.display()))?;
    staged.commit()?;
    let p = &model.dipole;
    println!("channel  R        a'        s'_t     s'_s     s_a       range (mm)");
    if let Some(d) = &model.diagnostics {
        for ch in &d.channels {
            let c = ch.channel;
            println!(
                "{c}        {:.5}  {:.6}  {:.4}   {:.4}   {:.5}   {:.2}:{:.2}",
                ch.reflectance,
                p.alpha_prime[c],
                p.sigma_t_prime[c],
                p.sigma_s_prime()[c],
                p.sigma_a()[c],
                ch.fit.range_mm[0],
                ch.fit.range_mm[1]
            );
        }
        for n in &d.notes {
            println!("note: {n}");
        }
        if let Some(r) = &d.lrf_denoise {
            println!("LRF: {}", r.summary());
        }
    }
    println!(
        "{} views of f_v, {} LRF samples, {}x{} texels of {} mm",
        model.exiting.views.len(),
        model.lrf.samples.len(),
        model.width,
        model.height,
        model.texel_mm
    );
    if args.lrf_components.is_some() {
        println!(
            "LRF: {} -> {} floats, relative RMS error {:.3e}",
            report.lrf_floats_raw, report.lrf_floats_written, report.lrf_rel_rms_error
        );
    }
    println!(
        "fit {:.2} s (dipole {:.2}, entrance {:.2}, exiting {:.2}, LRF {:.2}); wrote {}",
        t.elapsed().as_secs_f64(),
        timings.dipole,
        timings.entrance,
        timings.exiting,
        timings.lrf,
        args.output.display()
    );
    Ok(ExitCode::SUCCESS)
}
