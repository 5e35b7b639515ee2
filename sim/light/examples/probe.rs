//! Scratch probe: render one pose and print sums (development aid).
use sim_light::*;
use std::time::Instant;
fn main() -> Result<(), Error> {
    let name = std::env::args().nth(1).unwrap_or("whole-milk".into());
    let q = SimQuality::by_name(&std::env::args().nth(2).unwrap_or("ci".into()))?;
    let t0 = Instant::now();
    let world = World::new(SceneDesc::load(&name)?, RigTruth::perturbed(1), q)?;
    println!("build {:?}", t0.elapsed());
    for illum in [
        Illumination {
            laser: Some(LaserOn {
                channel: 0,
                power: 1.0,
            }),
            ..Default::default()
        },
        Illumination {
            lamps: 1 << 4,
            ..Default::default()
        },
    ] {
        let t0 = Instant::now();
        let r = world.render_pose(&illum, 0xFE, 1)?;
        println!("render {:?} {:?}", t0.elapsed(), r.tally);
        for k in 1..8 {
            let img = r.image(k).unwrap();
            let max = img
                .data
                .iter()
                .map(|p| p[0].max(p[1]).max(p[2]))
                .fold(0.0f32, f32::max);
            println!(
                "cam {k}: sum {:.3e} {:.3e} {:.3e} max {:.3e}",
                img.sum(0),
                img.sum(1),
                img.sum(2),
                max
            );
        }
    }
    Ok(())
}
