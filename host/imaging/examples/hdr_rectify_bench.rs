//! Throughput of HDR merge + rectification, and the data for the OpenCV
//! comparison (bench/hdr_opencv.py). Run:
//! `cargo run --release -p qhm-imaging --example hdr_rectify_bench -- [OUT_DIR]`
//! Writes OUT_DIR/bracket_{k}.png, OUT_DIR/exposures.txt and OUT_DIR/qhm_hdr.exr,
//! prints megapixels per second per core and the extrapolation to a
//! paper-scale capture on one core and on a 16-core node, against the
//! bound of reading the capture from disk.

use std::time::Instant;

use glam::DVec3;
use qhm_imaging::camera::{CameraModel, Intrinsics};
use qhm_imaging::hdr::{self, MergeOptions};
use qhm_imaging::image::Image8;
use qhm_imaging::rectify::{self, Grid};
use qhm_imaging::response::{self, DmOptions, MnOptions};
use qhm_imaging::{exr_io, synthetic_calibration};

/// Brackets of a paper-scale capture (qhm-acquire's `paper` plan: pass 1
/// 3 colours x 5 clamps x 12 arc x 4 turntable x 32 scan x 4 cameras; pass 2
/// 3 x 12 turntable x 32 scan x 7 cameras; pass 3 12 arc x 12 turntable x
/// 7 lamps x 7 cameras), with 6 laser and 3 lamp exposures per bracket:
/// 622,512 frames of 1024 x 768.
const PAPER_LASER_BRACKETS: f64 = (3 * 5 * 12 * 4 * 32 * 4 + 3 * 12 * 32 * 7) as f64;
const PAPER_LAMP_BRACKETS: f64 = (12 * 12 * 7 * 7) as f64;
const PAPER_FRAMES: f64 = PAPER_LASER_BRACKETS * 6.0 + PAPER_LAMP_BRACKETS * 3.0;
/// Its disk at most (`qhm capture plan --scale paper`), bytes, and a disk
/// (or parallel file system) read rate, bytes/s: the physical floor.
const PAPER_DISK_BYTES: f64 = 1469.81e9;
const DISK_READ_BYTES_PER_S: f64 = 2e9;
/// Cores of the node the extrapolation names.
const NODE_CORES: f64 = 16.0;

fn time<F: FnMut()>(reps: usize, mut f: F) -> f64 {
    f(); // warm up
    let t = Instant::now();
    for _ in 0..reps {
        f();
    }
    t.elapsed().as_secs_f64() / reps as f64
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::path::PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "target/bench-hdr".into()),
    );
    std::fs::create_dir_all(&out)?;
    let (w, h) = (1024usize, 768usize);
    let times = [0.002, 0.008, 0.032, 0.128];
    let resp = synthetic_calibration::Response::gamma_s_curve(2.2, 0.08);
    // Scene scaled so the bracket covers it: ramp_irradiance spans 10^-3.5 .. 10^1.
    let scaled: Vec<f64> = times.iter().map(|t| t * 8.0).collect();
    let b = synthetic_calibration::bracket_of_ramp(w, h, &scaled, &resp, 0.5, 11);
    for (k, f) in b.frames.iter().enumerate() {
        image::save_buffer(
            out.join(format!("bracket_{k}.png")),
            &f.data,
            w as u32,
            h as u32,
            image::ColorType::Rgb8,
        )?;
    }
    std::fs::write(
        out.join("exposures.txt"),
        times.iter().map(|t| format!("{t}\n")).collect::<String>(),
    )?;

    let t_fit = Instant::now();
    let mn: Vec<_> = (0..3)
        .map(|c| response::fit_mitsunaga_nayar(&b, c, MnOptions::default()).map(|f| f.curve))
        .collect::<Result<_, _>>()?;
    let fit_s = t_fit.elapsed().as_secs_f64();
    let t_fit = Instant::now();
    let dm: Vec<_> = (0..3)
        .map(|c| response::fit_debevec_malik(&b, c, DmOptions::default()))
        .collect::<Result<_, _>>()?;
    let fit_dm_s = t_fit.elapsed().as_secs_f64();
    let frames: Vec<&Image8> = b.frames.iter().collect();
    let exps: Vec<f64> = times.to_vec();

    let cam = CameraModel::look_at(
        DVec3::new(300.0, 0.0, 340.0),
        DVec3::ZERO,
        DVec3::X,
        Intrinsics {
            fx: 5120.0,
            fy: 5120.0,
            cx: 511.5,
            cy: 383.5,
            k1: -0.1,
            k2: 0.0,
        },
    );
    let grid = Grid::centred(256, 32.0 / 256.0);
    let hdr_img = hdr::merge(&frames, &exps, &mn, MergeOptions::default())?;
    exr_io::write_rgb(&out.join("qhm_hdr.exr"), &hdr_img)?;
    let dm_img = hdr::merge(&frames, &exps, &dm, MergeOptions::default())?;
    exr_io::write_rgb(&out.join("qhm_hdr_dm.exr"), &dm_img)?;

    // Accuracy against the true irradiance (one scale per channel, median |error|).
    for (name, img) in [("MN", &hdr_img), ("DM", &dm_img)] {
        let mut errs = Vec::new();
        for c in 0..3 {
            let mut ratios: Vec<f64> = Vec::new();
            for y in (0..h).step_by(4) {
                for x in (0..w).step_by(4) {
                    let v = img.get(x, y, c) as f64;
                    let e = synthetic_calibration::ramp_irradiance(x, y, w, h, c) * 8.0;
                    // Where the longest exposure reaches Z >= 20 and the shortest is below clipping.
                    if v.is_finite() && e * 0.128 > resp.exposure_of(20.0) && e * 0.002 < 1.0 {
                        ratios.push(v / e);
                    }
                }
            }
            let mut s = ratios.clone();
            s.sort_by(|a, b| a.total_cmp(b));
            let med = s[s.len() / 2];
            errs.extend(ratios.iter().map(|r| (r / med - 1.0).abs()));
        }
        errs.sort_by(|a, b| a.total_cmp(b));
        println!(
            "{name} merge vs truth: median |rel err| {:.4}, 95th percentile {:.4} ({} samples)",
            errs[errs.len() / 2],
            errs[errs.len() * 95 / 100],
            errs.len()
        );
    }
    println!("response fit (3 channels): MN {fit_s:.3} s, DM {fit_dm_s:.3} s");

    // PNG decoding of the bracket's frames, as `qhm rectify` reads them.
    let pngs: Vec<Vec<u8>> = (0..times.len())
        .map(|k| std::fs::read(out.join(format!("bracket_{k}.png"))))
        .collect::<Result<_, _>>()?;
    let decode_s = time(5, || {
        for p in &pngs {
            drop(image::load_from_memory(p).map(|i| i.to_rgb8()));
        }
    }) / pngs.len() as f64;
    let frame_mp = (w * h) as f64 / 1e6;
    println!(
        "PNG decode: {:.1} ms per 1024x768 frame ({:.1} MP/s), one thread",
        decode_s * 1e3,
        frame_mp / decode_s
    );
    let cores = rayon::current_num_threads();
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let mp_in = (w * h * times.len()) as f64 / 1e6;
    for (label, threads) in [("1 thread", 1usize), ("all threads", cores)] {
        let measure = || {
            let merge_s = time(5, || {
                drop(hdr::merge(&frames, &exps, &mn, MergeOptions::default()))
            });
            let rect_s = time(20, || {
                drop(rectify::rectify(
                    &hdr_img,
                    &cam,
                    DVec3::Z,
                    0.3,
                    &grid,
                    &[1.0; 3],
                ))
            });
            (merge_s, rect_s)
        };
        let (merge_s, rect_s) = if threads == 1 {
            one.install(measure)
        } else {
            measure()
        };
        let per_bracket = merge_s + rect_s;
        println!(
            "{label}: merge {:.1} ms ({:.1} MP/s of input frames), rectify 256x256 {:.2} ms, bracket total {:.1} ms = {:.1} input MP/s ({:.1} MP/s per core)",
            merge_s * 1e3,
            mp_in / merge_s,
            rect_s * 1e3,
            per_bracket * 1e3,
            mp_in / per_bracket,
            mp_in / per_bracket / threads as f64
        );
        if threads == 1 {
            // The merge scales with the frames of a bracket (6 laser, 3 lamp
            // exposures), the rectification is per bracket.
            let merge_per_frame = merge_s / times.len() as f64;
            let brackets = PAPER_LASER_BRACKETS + PAPER_LAMP_BRACKETS;
            let compute = PAPER_FRAMES * merge_per_frame + brackets * rect_s;
            let with_decode = compute + PAPER_FRAMES * decode_s;
            let disk = PAPER_DISK_BYTES / DISK_READ_BYTES_PER_S;
            let input_mp = PAPER_FRAMES * frame_mp;
            println!(
                "paper-scale capture ({PAPER_FRAMES} frames in {brackets} brackets, {:.0} input MP): HDR + rectify {:.2} h on one core ({:.1} input MP/s per core), {:.2} h with PNG decoding ({:.1} MP/s per core)",
                input_mp,
                compute / 3600.0,
                input_mp / compute,
                with_decode / 3600.0,
                input_mp / with_decode
            );
            println!(
                "  on a {NODE_CORES}-core node (one shard per core): {:.1} min, {:.1} min with PNG decoding; reading {:.2} TB at {:.0} GB/s takes {:.1} min (the floor)",
                compute / NODE_CORES / 60.0,
                with_decode / NODE_CORES / 60.0,
                PAPER_DISK_BYTES / 1e12,
                DISK_READ_BYTES_PER_S / 1e9,
                disk / 60.0
            );
        }
    }
    Ok(())
}
