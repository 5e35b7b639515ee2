//! Render the frames shown in docs/sim.md (docs/img/*.png), through the same
//! path as `qhm sim render`: radiance, auto exposure, sensor, PNG.
//! `cargo run --release -p sim-light --example frames [quality]`
use sim_light::*;

fn save(
    name: &str,
    world: &World,
    illum: &Illumination,
    cam: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    let t0 = std::time::Instant::now();
    let pose = world.render_pose(illum, 1 << cam, 1)?;
    let img = pose.image(cam).ok_or("no image")?;
    let sensor = world.sensor(cam);
    let mut v: Vec<f64> = img
        .data
        .iter()
        .map(|p| p.iter().fold(0.0f64, |m, &x| m.max(x as f64)))
        .collect();
    v.sort_by(|a, b| a.total_cmp(b));
    let l = v[v.len() * 995 / 1000].max(1e-9);
    let exposure = 0.8 * sensor::FULL_WELL_E / (l * sensor::SENSITIVITY);
    let f = sensor.expose(img, exposure, 1.0, 2);
    let path = format!("docs/img/{name}.png");
    image::save_buffer(&path, &f.rgb, f.width, f.height, image::ColorType::Rgb8)?;
    println!(
        "{path}: {:.2} s, exposure {:.2} ms",
        t0.elapsed().as_secs_f64(),
        exposure * 1e3
    );
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut q = SimQuality::by_name(&std::env::args().nth(1).unwrap_or("preview".into()))?;
    if let Some(p) = std::env::args().nth(2).and_then(|s| s.parse().ok()) {
        q.laser_photons = p;
        q.lamp_photons = p;
    }
    let rig = RigTruth::perturbed(1);
    let laser = |ch| Illumination {
        laser: Some(LaserOn {
            channel: ch,
            power: 1.0,
        }),
        ..Illumination::default()
    };
    let lamp = |k: u8, arc: f64| Illumination {
        lamps: 1 << k,
        light_arc_rad: arc,
        ..Illumination::default()
    };
    let w = |name: &str| World::new(SceneDesc::preset(name).unwrap(), rig.clone(), q);
    save("sim-bread-lamp", &w("bread")?, &lamp(4, 0.6), 5)?;
    save("sim-bread-laser-red", &w("bread")?, &laser(0), 5)?;
    save("sim-sponge-lamp", &w("sponge")?, &lamp(3, -0.5), 4)?;
    save(
        "sim-two-material-laser-blue",
        &w("two-material")?,
        &laser(2),
        7,
    )?;
    save(
        "sim-whole-milk-laser-green",
        &w("whole-milk")?,
        &laser(1),
        4,
    )?;
    save("sim-checkerboard", &w("checkerboard")?, &lamp(5, 0.0), 3)?;
    save(
        "sim-colour-pattern",
        &w("colour-pattern")?,
        &lamp(6, 0.0),
        7,
    )?;
    let mut two = w("two-height")?;
    two.set_laser_mount(45f64.to_radians());
    save("sim-two-height-laser", &two, &laser(1), 7)?;
    Ok(())
}
