//! The simulated world seen through the rig: laser stripes land where the
//! rig's true geometry says (through the turntable, the laser plane and the
//! camera model with distortion), the two-height target shows the offset the
//! laser-plane calibration measures, and a CI-scale pass renders in seconds.

use glam::DVec3;
use sim_light::*;

const CAM: usize = 7; // straight down: world x runs down the image, y to the right

/// Intensity-weighted row of the stripe in a band of columns, binned pixels.
fn stripe_row(img: &RadianceImage, ch: usize, cols: std::ops::Range<usize>) -> f64 {
    let w = img.width as usize;
    let rows: Vec<f64> = (0..img.height as usize)
        .map(|y| cols.clone().map(|x| img.data[y * w + x][ch] as f64).sum())
        .collect();
    let peak = (0..rows.len())
        .max_by(|&a, &b| rows[a].total_cmp(&rows[b]))
        .unwrap();
    let (lo, hi) = (peak.saturating_sub(2), (peak + 3).min(rows.len()));
    let s: f64 = rows[lo..hi].iter().sum();
    (lo..hi).map(|y| (y as f64 + 0.5) * rows[y]).sum::<f64>() / s
}

/// Where the true laser plane meets z = h, at lateral position y.
fn stripe_point(g: &LaserGeometry, h: f64, y: f64) -> DVec3 {
    let q = g.origin + (g.centre - g.origin) * ((g.origin.z - h) / (g.origin.z - g.centre.z));
    q + g.stripe_dir * ((y - q.y) / g.stripe_dir.y)
}

fn predicted_row(world: &World, p: DVec3) -> (f64, usize) {
    let s = world.quality().downscale as f64;
    let [u, v] = world.rig().cameras[CAM].project(p).unwrap();
    (v / s, (u / s) as usize)
}

#[test]
fn vertical_stripe_lands_where_the_true_rig_puts_it() {
    let mut world = World::new(
        SceneDesc::preset("whole-milk").unwrap(),
        RigTruth::perturbed(3),
        SimQuality::ci(),
    )
    .unwrap();
    world.set_laser_mount(std::f64::consts::FRAC_PI_2);
    let mut rows = vec![];
    for (ch, galvo) in [(0usize, -0.02f64), (1, 0.0), (2, 0.02)] {
        let illum = Illumination {
            galvo_rad: galvo,
            laser: Some(LaserOn {
                channel: ch,
                power: 1.0,
            }),
            ..Illumination::default()
        };
        let pose = world.render_pose(&illum, 1 << CAM, 10 + ch as u64).unwrap();
        let img = pose.image(CAM).unwrap();
        let g = world.rig().laser_geometry(world.laser_mount(), 0.0, galvo);
        let (v, u) = predicted_row(&world, stripe_point(&g, 0.0, 0.0));
        let got = stripe_row(img, ch, u - 8..u + 8);
        assert!(
            (got - v).abs() < 0.75,
            "channel {ch} galvo {galvo}: row {got} vs predicted {v}"
        );
        // only the laser's channel is lit
        assert_eq!(img.sum((ch + 1) % 3), 0.0);
        rows.push(got);
    }
    // the galvo moves the stripe across the image (600 mm * 0.02 = 12 mm ~ 17 binned px)
    assert!(rows[2] - rows[0] > 10.0, "{rows:?}");
}

#[test]
fn two_height_target_shows_the_laser_plane_offset() {
    let mut world = World::new(
        SceneDesc::preset("two-height").unwrap(),
        RigTruth::perturbed(5),
        SimQuality::ci(),
    )
    .unwrap();
    let elevation = 45f64.to_radians();
    world.set_laser_mount(elevation);
    let illum = Illumination {
        laser: Some(LaserOn {
            channel: 1,
            power: 1.0,
        }),
        ..Illumination::default()
    };
    let pose = world.render_pose(&illum, 1 << CAM, 3).unwrap();
    let img = pose.image(CAM).unwrap();
    let g = world.rig().laser_geometry(elevation, 0.0, 0.0);
    let mut measured = vec![];
    for (h, y) in [(0.0, -15.0), (10.0, 15.0)] {
        let (v, u) = predicted_row(&world, stripe_point(&g, h, y));
        let got = stripe_row(img, 1, u - 3..u + 4);
        assert!(
            (got - v).abs() < 0.75,
            "step at {h} mm: row {got} vs predicted {v}"
        );
        measured.push(got);
    }
    // the offset is what calibration turns into the plane angle: ~ dh / tan(e)
    // = 10 mm = ~14 binned pixels, against the nominal 45 degrees
    let shift = (measured[0] - measured[1]).abs();
    assert!(shift > 10.0 && shift < 18.0, "{shift}");
}

#[test]
fn a_ci_scale_pass_two_sweep_is_cheap() {
    // pass 2 at the ci scale: one vertical stripe per channel and turntable
    // position, all seven cameras, then a 3-exposure bracket per frame, on
    // the sample the ci demo captures (the cellular presets' walks cost
    // 30-100 times as much per event: docs/sim.md)
    let world = World::new(
        SceneDesc::preset("two-material").unwrap(),
        RigTruth::perturbed(1),
        SimQuality::ci(),
    )
    .unwrap();
    let mut frames = 0;
    for turntable in [0.0, 1.0] {
        for ch in 0..3 {
            let illum = Illumination {
                turntable_rad: turntable,
                light_arc_rad: turntable,
                laser: Some(LaserOn {
                    channel: ch,
                    power: 1.0,
                }),
                ..Illumination::default()
            };
            let pose = world.render_pose(&illum, 0xFE, 100 + ch as u64).unwrap();
            for k in 1..8 {
                let sensor = world.sensor(k);
                let mut last = 0u64;
                for (i, t) in [0.0005, 0.002, 0.008].into_iter().enumerate() {
                    let f = sensor.expose(pose.image(k).unwrap(), t, 1.0, (k * 10 + i) as u64);
                    let total: u64 = f.rgb.iter().map(|&z| z as u64).sum();
                    assert!(total >= last, "camera {k}: longer exposure darker");
                    last = total;
                    frames += 1;
                }
                assert!(last > 0, "camera {k} saw nothing");
            }
        }
    }
    assert_eq!(frames, 2 * 3 * 7 * 3);
}
