//! The laser-stripe exit profile of a preset on a large slab (300 x 300 x
//! 100 mm), as tests/tests/model_mc_profile.rs measures it, written for
//! `qhm fit-profile`:
//! `cargo run --release -p sim-light --example cell_profile -- bread 1 400000 out.csv`
//! prints R (exited over incident photons, specular excluded) and the top's eta;
//! then `qhm fit-profile out.csv --reflectance R --eta ETA`.
use glam::Vec3;
use sim_light::*;
use std::io::Write;

fn main() -> Result<(), Error> {
    let mut a = std::env::args().skip(1);
    let name = a.next().unwrap_or("bread".into());
    let ch: usize = a.next().and_then(|s| s.parse().ok()).unwrap_or(1);
    let photons: u64 = a.next().and_then(|s| s.parse().ok()).unwrap_or(400_000);
    let out = a.next().unwrap_or("profile.csv".into());
    let mut desc = SceneDesc::load(&name)?;
    let SceneDesc::Sample(s) = &mut desc else {
        return Err(Error::InvalidIllumination("a sample".into()));
    };
    s.size_mm = [300.0, 300.0, 100.0];
    let eta = s.surface.eta;
    let world = World::new(desc, RigTruth::nominal(), SimQuality::ci())?;
    let length = 80.0f32;
    let stripe = Source::Stripe {
        origin: Vec3::new(0.0, 0.0, 800.0),
        centre: Vec3::ZERO,
        dir: Vec3::Y,
        length,
    };
    let (n, cell) = (160usize, 0.25f32);
    let grid = ExitGrid::new(n, cell);
    let t = world.trace(&stripe, ch, photons, 7, Some(&grid));
    let incident = (t.launched - t.missed) as f64;
    let counts = grid.values();
    let (j0, j1) = (n / 2 - 40, n / 2 + 40);
    let per_mm = incident / length as f64;
    let area = (cell * cell) as f64 * (j1 - j0) as f64;
    let mut f = std::fs::File::create(&out).map_err(|e| Error::Io {
        path: out.clone(),
        source: e,
    })?;
    writeln!(f, "distance_mm,intensity_per_mm").unwrap();
    for i in 0..n {
        let x = (i as f64 + 0.5) * cell as f64 - n as f64 * cell as f64 / 2.0;
        let c: u64 = (j0..j1).map(|j| counts[j * n + i] as u64).sum();
        writeln!(f, "{x},{}", c as f64 / area / per_mm).unwrap();
    }
    println!("{t:?}");
    println!("R {} eta {eta}", t.exited as f64 / incident);
    Ok(())
}
