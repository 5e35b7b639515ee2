use glam::Vec3;
use sim_light::*;
#[test]
fn marble_profile() {
    let w = World::new(SceneDesc::preset("marble").unwrap(), RigTruth::nominal(), SimQuality::ci()).unwrap();
    let (n, cell) = (240usize, 0.2f32);
    for c in 0..3 {
        let g = ExitGrid::new(n, cell);
        let photons = 2_000_000u64;
        let len = 70.0f32;
        let t = w.trace(&Source::Stripe { origin: Vec3::new(0.0, 0.0, 450.0), centre: Vec3::ZERO, dir: Vec3::X, length: len }, c, photons, 9, Some(&g));
        let v = g.values();
        let mut prof = vec![0f64; n];
        let xband = 10.0f32;
        for j in 0..n { for i in 0..n {
            let x = (i as f32 + 0.5) * cell - n as f32 * cell / 2.0;
            if x.abs() < xband { prof[j] += v[j * n + i] as f64; }
        }}
        let per_mm = photons as f64 / len as f64;
        let norm = per_mm * (2.0 * xband as f64) * cell as f64;
        let mut s = String::new();
        let mut total = 0.0;
        for j in n/2..n { let d = (j - n/2) as f64 * cell as f64 + cell as f64 / 2.0; let i_d = (prof[j] + prof[n - 1 - j]) / 2.0 / norm; total += 2.0 * i_d * cell as f64;
            if [0.6,1.0,2.0,3.0,4.0,6.0,8.0,11.0].iter().any(|x| (d - x).abs() < 0.1) { s += &format!(" I({d:.1})={i_d:.4}"); } }
        eprintln!("ch {c}: R_exit {:.4} R(<24mm) {total:.4}{s}", t.exited as f64 / (t.launched - t.reflected) as f64);
    }
}
