//! LRF noise: a per-texel measure of it, and denoising by projecting every
//! texel's LRF (all samples and channels) onto the leading components of
//! the PCA basis the texels share ([`crate::compress::Pca`]).

use crate::model::Texture;

/// Noise per texel of `maps`, per channel: the RMS over texels and maps of
/// a texel minus the mean of its four neighbours, divided by sqrt(1.25)
/// (the factor for white noise), interior texels only. Texture finer than a
/// texel counts too, so this is an upper bound on the noise.
pub fn texel_noise(maps: &[Texture]) -> [f64; 3] {
    let mut sum = [0.0f64; 3];
    let mut n = 0usize;
    for t in maps {
        let (w, h) = (t.width, t.height);
        for j in 1..h.saturating_sub(1) {
            for i in 1..w.saturating_sub(1) {
                let c = t.get(i, j);
                let nb = [
                    t.get(i - 1, j),
                    t.get(i + 1, j),
                    t.get(i, j - 1),
                    t.get(i, j + 1),
                ];
                let d: [f64; 3] = std::array::from_fn(|ch| {
                    c[ch] as f64 - nb.iter().map(|p| p[ch] as f64).sum::<f64>() / 4.0
                });
                if d.iter().all(|x| x.is_finite()) {
                    for ch in 0..3 {
                        sum[ch] += d[ch] * d[ch];
                    }
                    n += 1;
                }
            }
        }
    }
    sum.map(|s| (s / (1.25 * n.max(1) as f64)).sqrt())
}
