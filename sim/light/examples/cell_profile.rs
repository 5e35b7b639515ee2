//! The laser-stripe exit profile of a preset on a large slab (300 x 300 x
//! 100 mm), as tests/tests/model_mc_profile.rs measures it, written for
//! `qhm fit-profile`:
//! `cargo run --release -p sim-light --example cell_profile -- bread 1 400000 out.csv`
//! prints R (exited over incident photons, specular excluded) and the top's eta;
//! then `qhm fit-profile out.csv --reflectance R --eta ETA`.
//!
//! Options after the four arguments:
//! - `--lines N`: N parallel lines, evenly across one tile of the sample's
//!   cells (or 10 mm), `PHOTONS` each; the profile and R are their means. A
//!   cellular sample's R changes from line to line by several per cent
//!   (docs/sim.md), so one line is no measure of the material.
//! - `--slab X,Y,DEPTH` (mm, default 300,300,100), `--length L` (mm of lit
//!   line, default 80), `--offset O` (mm of the line, or the lines' middle,
//!   from the centre, across it), `--along-x` (lines along x instead of y):
//!   one line of the rig's own slab.
use glam::Vec3;
use sim_light::*;

/// Exit grid: cells of 0.25 mm over 40 mm around the slab's centre.
const GRID: (usize, f32) = (160, 0.25);

fn main() -> Result<(), Error> {
    let mut a = std::env::args().skip(1);
    let name = a.next().unwrap_or("bread".into());
    let ch: usize = a.next().and_then(|s| s.parse().ok()).unwrap_or(1);
    let photons: u64 = a.next().and_then(|s| s.parse().ok()).unwrap_or(400_000);
    let out = a.next().unwrap_or("profile.csv".into());
    let (mut slab, mut length, mut offset, mut along_x, mut lines) =
        ([300.0, 300.0, 100.0], 80.0f32, 0.0f32, false, 1usize);
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
            "--length" => {
                length = value()?
                    .parse()
                    .ok()
                    .filter(|l: &f32| *l > 0.0)
                    .ok_or_else(|| usage("--length takes mm above 0"))?
            }
            "--offset" => offset = value()?.parse().map_err(|_| usage("--offset takes mm"))?,
            "--lines" => {
                lines = value()?
                    .parse()
                    .ok()
                    .filter(|n| (1..=200).contains(n))
                    .ok_or_else(|| usage("--lines takes 1 to 200"))?
            }
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
    let tile = s
        .volume
        .inclusions
        .iter()
        .find(|i| i.interface_eta.is_some())
        .map_or(10.0, |i| i.period_mm) as f32;
    let world = World::new(desc, RigTruth::nominal(), SimQuality::ci())?;
    let (dir, across) = if along_x {
        (Vec3::X, Vec3::Y)
    } else {
        (Vec3::Y, Vec3::X)
    };
    let (n, cell) = GRID;
    // Lines on whole grid cells, so their profiles add bin by bin.
    let shifts: Vec<i64> = (0..lines)
        .map(|k| {
            let o = offset + (k as f32 + 0.5 - lines as f32 / 2.0) * tile / lines as f32;
            (o / cell).round() as i64
        })
        .collect();
    // Every line on the slab and inside the exit grid.
    let half = (slab[if along_x { 1 } else { 0 }] as f32 / 2.0).min(n as f32 * cell / 2.0);
    if shifts.iter().any(|&k| (k as f32 * cell).abs() >= half) {
        return Err(usage(&format!(
            "--offset puts a line beyond {half} mm of the centre (the slab or the exit grid)"
        )));
    }
    // Bins of distance from each line, over the grid's central 20 mm along it.
    let reach = n as i64;
    let mut sum = vec![0f64; 2 * reach as usize];
    let mut hits = vec![0u32; 2 * reach as usize];
    let (mut exited, mut incident) = (0u64, 0f64);
    let (j0, j1) = (n / 2 - 40, n / 2 + 40);
    let area = (cell * cell) as f64 * (j1 - j0) as f64;
    for (k, &shift) in shifts.iter().enumerate() {
        let centre = across * (shift as f32 * cell);
        let stripe = Source::Stripe {
            origin: centre + Vec3::Z * 800.0,
            centre,
            dir,
            length,
        };
        let grid = ExitGrid::new(n, cell);
        let t = world.trace(&stripe, ch, photons, 7 + k as u64, Some(&grid));
        let line_incident = (t.launched - t.missed) as f64;
        exited += t.exited;
        incident += line_incident;
        let counts = grid.values();
        let per_mm = line_incident / length as f64;
        for i in 0..n {
            let at = |j: usize| {
                if along_x {
                    counts[i * n + j]
                } else {
                    counts[j * n + i]
                }
            };
            let c: u64 = (j0..j1).map(|j| at(j) as u64).sum();
            let b = (i as i64 - shift + reach - n as i64 / 2) as usize;
            sum[b] += c as f64 / area / per_mm;
            hits[b] += 1;
        }
        println!("line {k}: offset {:.2} mm, {t:?}", shift as f32 * cell);
    }
    let mut csv = String::from("distance_mm,intensity_per_mm\n");
    // Only the distances every line's grid covers.
    for (b, (&s, &h)) in sum.iter().zip(&hits).enumerate() {
        if h as usize == lines {
            let x = (b as f64 - reach as f64 + 0.5) * cell as f64;
            csv += &format!("{x},{}\n", s / lines as f64);
        }
    }
    std::fs::write(&out, csv).map_err(|e| Error::Io {
        path: out.clone(),
        source: e,
    })?;
    println!("R {} eta {eta}", exited as f64 / incident);
    Ok(())
}

fn usage(why: &str) -> Error {
    Error::InvalidIllumination(format!(
        "{why}; usage: cell_profile PRESET CHANNEL PHOTONS OUT.csv [--lines N] [--slab X,Y,DEPTH] [--length L] [--offset O] [--along-x]"
    ))
}
