//! Run every calibration step on the simulated rig and print recovered vs true:
//! `cargo run --release -p qhm-imaging --features sim --example sim_calibrate -- [quality] [seed] [steps]`.
use qhm_imaging::Calibration;
use qhm_imaging::sim_cal::SimCalibrator;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let quality = sim_light::SimQuality::by_name(args.get(1).map_or("preview", |s| s))?;
    let seed: u64 = args.get(2).map_or(Ok(7), |s| s.parse())?;
    let steps = args
        .get(3)
        .map_or("response,geometry,colour,lamps,laser", |s| s);
    let sim = SimCalibrator::new(seed, quality);
    let mut cal = Calibration::default();
    let mut rows = Vec::new();
    for step in steps.split(',') {
        let t = std::time::Instant::now();
        match step {
            "response" => sim.response(&mut cal, &mut rows)?,
            "geometry" => sim.geometry(&mut cal, &mut rows)?,
            "colour" => sim.colour(&mut cal, &mut rows)?,
            "lamps" => sim.lamps(&mut cal, &mut rows)?,
            "laser" => sim.laser(&mut cal, &mut rows)?,
            other => return Err(format!("unknown step {other}").into()),
        }
        eprintln!("{step}: {:.1} s", t.elapsed().as_secs_f64());
    }
    for r in &rows {
        println!("{r}");
    }
    Ok(())
}
