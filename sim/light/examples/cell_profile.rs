//! The laser-stripe exit profile of a preset on a large slab (300 x 300 x
//! 100 mm), as tests/tests/model_mc_profile.rs measures it, written for
//! `qhm fit-profile`:
//! `cargo run --release -p sim-light --example cell_profile -- bread 1 400000 out.csv`
//! prints R (exited over incident photons, specular excluded) and the top's eta;
//! then `qhm fit-profile out.csv --reflectance R --eta ETA`.
//!
//! Options after the four arguments, for one line of the rig's own slab:
//! `--slab X,Y,DEPTH` (mm, default 300,300,100), `--length L` (mm of lit
//! line, default 80), `--offset O` (mm of the line from the centre, across
//! it, default 0; the profile stays on the exit grid's 40 mm around the
//! slab's centre), `--along-x` (the line along x instead of y). R of a
//! cellular sample changes from line to line: docs/sim.md.
use glam::Vec3;
use sim_light::*;
use std::io::Write;

fn main() -> Result<(), Error> {
    let mut a = std::env::args().skip(1);
    let name = a.next().unwrap_or("bread".into());
    let ch: usize = a.next().and_then(|s| s.parse().ok()).unwrap_or(1);
    let photons: u64 = a.next().and_then(|s| s.parse().ok()).unwrap_or(400_000);
    let out = a.next().unwrap_or("profile.csv".into());
    let (mut slab, mut length, mut offset, mut along_x) =
        ([300.0, 300.0, 100.0], 80.0f32, 0.0f32, false);
    while let Some(flag) = a.next() {
        let mut value = || {
            a.next()
                .ok_or_else(|| usage(&format!("{flag} needs a value")))
        };
        match flag.as_str() {
            "--slab" => {
                let v: Vec<f64> = value()?.split(',').filter_map(|x| x.parse().ok()).collect();
                slab = v
                    .try_into()
                    .map_err(|_| usage("--slab takes X,Y,DEPTH in mm"))?;
            }
            "--length" => length = value()?.parse().map_err(|_| usage("--length takes mm"))?,
            "--offset" => offset = value()?.parse().map_err(|_| usage("--offset takes mm"))?,
            "--along-x" => along_x = true,
            _ => return Err(usage(&format!("unknown option {flag}"))),
        }
    }
    let mut desc = SceneDesc::load(&name)?;
    let SceneDesc::Sample(s) = &mut desc else {
        return Err(Error::InvalidIllumination("a sample".into()));
    };
    s.size_mm = slab;
    let eta = s.surface.eta;
    let world = World::new(desc, RigTruth::nominal(), SimQuality::ci())?;
    let (dir, across) = if along_x {
        (Vec3::X, Vec3::Y)
    } else {
        (Vec3::Y, Vec3::X)
    };
    let centre = across * offset;
    let stripe = Source::Stripe {
        origin: centre + Vec3::Z * 800.0,
        centre,
        dir,
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
    // Across the line (x for a line along y), over its central 20 mm; the
    // distance from the line.
    for i in 0..n {
        let x = (i as f64 + 0.5) * cell as f64 - n as f64 * cell as f64 / 2.0;
        let at = |j: usize| {
            if along_x {
                counts[i * n + j]
            } else {
                counts[j * n + i]
            }
        };
        let c: u64 = (j0..j1).map(|j| at(j) as u64).sum();
        writeln!(f, "{},{}", x - offset as f64, c as f64 / area / per_mm).unwrap();
    }
    println!("{t:?}");
    println!("R {} eta {eta}", t.exited as f64 / incident);
    Ok(())
}

fn usage(why: &str) -> Error {
    Error::InvalidIllumination(format!(
        "{why}; usage: cell_profile PRESET CHANNEL PHOTONS OUT.csv [--slab X,Y,DEPTH] [--length L] [--offset O] [--along-x]"
    ))
}
