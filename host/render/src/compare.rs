//! A render against a ground truth in statistics, not pixels (the texture
//! of an acquired model is synthesized, so no pixel corresponds): the mean
//! per channel, the relative RMSE of the low-pass image (block means of
//! luminance), with the truth's own Monte Carlo noise taken out when a
//! second, independent truth is given, and the distance between the
//! histograms of local contrast.
//!
//! The compared pixels are those either image lights (a black background
//! in both is left out).

use qhm_formats::RgbImage;

/// The statistics of [`compare`].
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Comparison {
    /// Pixels compared.
    pub pixels: usize,
    /// Mean of the render over mean of the truth, R, G, B.
    pub mean_ratio: [f64; 3],
    /// The same in luminance.
    pub luminance_ratio: f64,
    /// Blocks (at least half covered) in the low-pass comparison.
    pub blocks: usize,
    /// RMS over the blocks of (render - truth) block-mean luminance,
    /// relative to the truth's mean luminance.
    pub block_rmse: f64,
    /// The truth's own noise in the same units (from the second truth).
    pub truth_noise: Option<f64>,
    /// `block_rmse` with that noise taken out in quadrature.
    pub block_rmse_denoised: Option<f64>,
    /// Total-variation distance between the histograms of local contrast
    /// (luminance over its 3 x 3 mean, minus 1): 0 alike, 1 disjoint.
    pub contrast_distance: f64,
}

fn luminance(c: [f32; 3]) -> f64 {
    crate::light::luminance(glam::Vec3::from(c)) as f64
}

/// Local contrast histogram bins over [-1, 1], plus one each side.
const CONTRAST_BINS: usize = 40;

fn contrast_histogram(img: &RgbImage, mask: &[bool]) -> Vec<f64> {
    let (w, h) = (img.width, img.height);
    let lum: Vec<f64> = img.data.iter().map(|c| luminance(*c)).collect();
    let mut hist = vec![0.0; CONTRAST_BINS + 2];
    let mut n = 0.0;
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let around = (y - 1..=y + 1).flat_map(|j| (x - 1..=x + 1).map(move |i| j * w + i));
            if !around.clone().all(|k| mask[k]) {
                continue;
            }
            let mean = around.map(|k| lum[k]).sum::<f64>() / 9.0;
            if mean <= 0.0 {
                continue;
            }
            let c = lum[y * w + x] / mean - 1.0;
            let bin = if c < -1.0 {
                0
            } else if c >= 1.0 {
                CONTRAST_BINS + 1
            } else {
                1 + ((c + 1.0) / 2.0 * CONTRAST_BINS as f64) as usize
            };
            hist[bin.min(CONTRAST_BINS + 1)] += 1.0;
            n += 1.0;
        }
    }
    if n > 0.0 {
        hist.iter_mut().for_each(|v| *v /= n);
    }
    hist
}

/// Block means of luminance over the masked pixels of blocks at least half
/// covered: (block index, mean).
fn block_means(img: &RgbImage, mask: &[bool], block: usize) -> Vec<(usize, f64)> {
    let (bw, bh) = (img.width / block, img.height / block);
    (0..bw * bh)
        .filter_map(|b| {
            let (bx, by) = (b % bw, b / bw);
            let (mut s, mut n) = (0.0, 0);
            for y in by * block..(by + 1) * block {
                for x in bx * block..(bx + 1) * block {
                    let k = y * img.width + x;
                    if mask[k] {
                        s += luminance(img.data[k]);
                        n += 1;
                    }
                }
            }
            (2 * n >= block * block).then(|| (b, s / n as f64))
        })
        .collect()
}

/// Compares `render` with `truth` (same size); `truth2`, an independent
/// render of the same truth, gives the truth's noise.
pub fn compare(
    render: &RgbImage,
    truth: &RgbImage,
    truth2: Option<&RgbImage>,
    block: usize,
) -> Result<Comparison, String> {
    let size = |i: &RgbImage| (i.width, i.height);
    if size(render) != size(truth) {
        return Err(format!(
            "the render is {}x{} and the truth {}x{}: they must be the same size",
            render.width, render.height, truth.width, truth.height
        ));
    }
    if let Some(t2) = truth2
        && size(t2) != size(truth)
    {
        return Err(format!(
            "the second truth is {}x{} and the truth {}x{}: they must be the same size",
            t2.width, t2.height, truth.width, truth.height
        ));
    }
    if block == 0 || block > render.width.min(render.height) {
        return Err(format!(
            "block size {block} must be 1 to {} pixels",
            render.width.min(render.height)
        ));
    }
    let finite = |i: &RgbImage| i.data.iter().all(|c| c.iter().all(|v| v.is_finite()));
    if !finite(render) || !finite(truth) || truth2.is_some_and(|t| !finite(t)) {
        return Err("an image holds NaN or infinite values".into());
    }
    let mask: Vec<bool> = render
        .data
        .iter()
        .zip(&truth.data)
        .map(|(r, t)| luminance(*r) > 0.0 || luminance(*t) > 0.0)
        .collect();
    let pixels = mask.iter().filter(|m| **m).count();
    if pixels == 0 {
        return Err("both images are black: nothing to compare".into());
    }
    let mean = |img: &RgbImage| -> [f64; 3] {
        let mut s = [0.0; 3];
        for (c, _) in img.data.iter().zip(&mask).filter(|(_, m)| **m) {
            for k in 0..3 {
                s[k] += c[k] as f64;
            }
        }
        s.map(|v| v / pixels as f64)
    };
    let (mr, mt) = (mean(render), mean(truth));
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
    let lum_t = luminance(mt.map(|v| v as f32));
    let lum_r = luminance(mr.map(|v| v as f32));
    let (br, bt) = (
        block_means(render, &mask, block),
        block_means(truth, &mask, block),
    );
    let blocks = bt.len();
    let rms = |a: &[(usize, f64)], b: &[(usize, f64)]| -> f64 {
        let s: f64 = a
            .iter()
            .zip(b)
            .map(|((_, x), (_, y))| (x - y).powi(2))
            .sum();
        (s / a.len().max(1) as f64).sqrt() / lum_t.max(f64::MIN_POSITIVE)
    };
    let block_rmse = rms(&br, &bt);
    // Two independent truths differ by twice the variance of one.
    let truth_noise = truth2.map(|t2| rms(&block_means(t2, &mask, block), &bt) / 2f64.sqrt());
    let block_rmse_denoised =
        truth_noise.map(|n| (block_rmse * block_rmse - n * n).max(0.0).sqrt());
    let (hr, ht) = (
        contrast_histogram(render, &mask),
        contrast_histogram(truth, &mask),
    );
    let contrast_distance = 0.5 * hr.iter().zip(&ht).map(|(a, b)| (a - b).abs()).sum::<f64>();
    Ok(Comparison {
        pixels,
        mean_ratio: std::array::from_fn(|k| ratio(mr[k], mt[k])),
        luminance_ratio: ratio(lum_r, lum_t),
        blocks,
        block_rmse,
        truth_noise,
        block_rmse_denoised,
        contrast_distance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lit disc with a texture of bumps on black, plus noise of `noise`.
    fn disc(n: usize, gain: f32, noise: f32, seed: u32) -> RgbImage {
        let mut state = seed.wrapping_mul(747_796_405).wrapping_add(1);
        let mut rnd = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        let data = (0..n * n)
            .map(|k| {
                let (x, y) = (
                    (k % n) as f32 - n as f32 / 2.0,
                    (k / n) as f32 - n as f32 / 2.0,
                );
                if x * x + y * y > (0.4 * n as f32).powi(2) {
                    return [0.0; 3];
                }
                let v = gain * (1.0 + 0.3 * (x * 0.8).sin() * (y * 0.7).cos()) + noise * rnd();
                [v, 0.8 * v, 0.5 * v]
            })
            .collect();
        RgbImage {
            width: n,
            height: n,
            data,
        }
    }

    #[test]
    fn an_image_against_itself_and_against_a_brighter_or_flatter_one() {
        let t = disc(64, 1.0, 0.0, 1);
        let same = compare(&t, &t, None, 8).unwrap();
        assert_eq!(same.mean_ratio, [1.0; 3]);
        assert_eq!(same.block_rmse, 0.0);
        assert_eq!(same.contrast_distance, 0.0);
        // 10 % brighter: the means and the blocks say so, the contrast not.
        let b = disc(64, 1.1, 0.0, 1);
        let c = compare(&b, &t, None, 8).unwrap();
        assert!(c.mean_ratio.iter().all(|r| (r - 1.1).abs() < 1e-5), "{c:?}");
        assert!(c.block_rmse > 0.08 && c.block_rmse < 0.12, "{c:?}");
        assert!(c.contrast_distance < 0.05, "{c:?}");
        // Without the texture the local contrast histogram is far off.
        let mut flat = t.clone();
        for (p, q) in flat.data.iter_mut().zip(&t.data) {
            if q[0] > 0.0 {
                *p = [1.0, 0.8, 0.5];
            }
        }
        let f = compare(&flat, &t, None, 8).unwrap();
        assert!(f.contrast_distance > 0.5, "{f:?}");
    }

    #[test]
    fn the_truths_noise_is_taken_out() {
        let clean = disc(128, 1.0, 0.0, 1);
        let (t1, t2) = (disc(128, 1.0, 0.6, 2), disc(128, 1.0, 0.6, 3));
        let c = compare(&clean, &t1, Some(&t2), 8).unwrap();
        let noise = c.truth_noise.unwrap();
        assert!(noise > 0.005, "{c:?}");
        // The render is the noiseless truth: what is left is (nearly) 0.
        assert!(c.block_rmse_denoised.unwrap() < 0.5 * c.block_rmse, "{c:?}");
    }

    #[test]
    fn mismatched_or_empty_images_are_errors() {
        let t = disc(64, 1.0, 0.0, 1);
        let small = disc(32, 1.0, 0.0, 1);
        assert!(
            compare(&small, &t, None, 8)
                .unwrap_err()
                .contains("same size")
        );
        assert!(compare(&t, &t, None, 0).unwrap_err().contains("block size"));
        let black = RgbImage::filled(64, 64, [0.0; 3]);
        assert!(
            compare(&black, &black, None, 8)
                .unwrap_err()
                .contains("black")
        );
        let mut nan = t.clone();
        nan.data[0][1] = f32::NAN;
        assert!(compare(&nan, &t, None, 8).unwrap_err().contains("NaN"));
    }
}
