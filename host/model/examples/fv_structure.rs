//! Structure along the sweep and LRF noise of a fitted model:
//! `cargo run --release -p qhm-model --example fv_structure -- MODEL_DIR CAPTURE_DIR`.
//! Prints [`qhm_model::streaks::SweepStructure`] of the f_v and LRF maps
//! (sweep axis from the capture's pass-2 stripe lines) and the LRF noise
//! per texel ([`qhm_model::denoise::texel_noise`]), and the same structure
//! measure on the capture's lamp images over the model's window: what the
//! cameras' own resolution (foreshortened along an oblique view's tilt)
//! puts into a map with no sweep in it, the yardstick of the f_v figure.

use std::path::PathBuf;

use qhm_model::MaterialModel;
use qhm_model::model::Texture;
use qhm_model::rectified::Rectified;
use qhm_model::streaks::{sweep_axis, sweep_structure};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() != 2 {
        eprintln!("usage: fv_structure MODEL_DIR CAPTURE_DIR");
        std::process::exit(2);
    }
    let model = MaterialModel::load(&PathBuf::from(&args[0])).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(1)
    });
    let data = Rectified::open(&PathBuf::from(&args[1])).unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(1)
    });
    let axis = sweep_axis(
        data.index
            .stripe
            .iter()
            .filter(|s| s.pass == 2)
            .map(|s| s.line_dir),
    );
    let fv: Vec<_> = model.exiting.maps.iter().collect();
    let lrf: Vec<_> = model.lrf.maps.iter().collect();
    println!("sweep axis (texel i, j): [{:.4}, {:.4}]", axis[0], axis[1]);
    println!("texture {}x{}", model.width, model.height);
    println!("f_v: {}", sweep_structure(&fv, axis));
    println!("LRF: {}", sweep_structure(&lrf, axis));
    let lamps = lamp_images(&model, &data);
    let refs: Vec<&Texture> = lamps.iter().collect();
    println!("lamp images: {}", sweep_structure(&refs, axis));
    if std::env::var_os("ROWS").is_some() {
        for (k, t) in fv.iter().enumerate() {
            println!(
                "f_v view {k} {:?}: {}",
                model.exiting.views[k],
                sweep_structure(&[*t], axis)
            );
            let rows: Vec<String> = (0..t.height)
                .map(|j| {
                    let m: Vec<f64> = (0..t.width)
                        .map(|i| t.get(i, j).iter().map(|x| *x as f64).sum::<f64>() / 3.0)
                        .collect();
                    let mean = m.iter().sum::<f64>() / m.len() as f64;
                    let sd =
                        (m.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / m.len() as f64).sqrt();
                    format!("{mean:.2}/{sd:.2}")
                })
                .collect();
            println!("  rows mean/sd: {}", rows.join(" "));
        }
        for (name, maps) in [("f_v", &fv), ("LRF", &lrf)] {
            let t = maps[0];
            let rows: Vec<String> = (0..t.height)
                .map(|j| {
                    let m: f64 =
                        (0..t.width).map(|i| t.get(i, j)[0] as f64).sum::<f64>() / t.width as f64;
                    format!("{m:.3}")
                })
                .collect();
            println!("{name} map 0 red row means: {}", rows.join(" "));
        }
    }
    let noise = qhm_model::denoise::texel_noise(&model.lrf.maps);
    println!(
        "LRF noise per texel (1/sr, RMS of a texel minus the mean of its 4 neighbours, over sqrt(1.25)): R {:.4e} G {:.4e} B {:.4e}",
        noise[0], noise[1], noise[2]
    );
}

/// The capture's lamp images cut to the model's window.
fn lamp_images(model: &MaterialModel, data: &Rectified) -> Vec<Texture> {
    let grid = data.index.grid;
    let [i0, j0, w, h] = model
        .window()
        .unwrap_or([0, 0, grid.width, grid.height])
        .map(|x| x as usize);
    data.index
        .lamp
        .iter()
        .map(|e| {
            let t = data.read_image(&e.file).unwrap_or_else(|e| {
                eprintln!("error: {e}");
                std::process::exit(1)
            });
            Texture {
                width: w,
                height: h,
                data: (0..w * h).map(|p| t.get(i0 + p % w, j0 + p / w)).collect(),
            }
        })
        .collect()
}
