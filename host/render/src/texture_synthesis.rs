//! Texture synthesis of the material texture T(x, y) onto the surface
//! (paper section 5). Every texel of T holds the LRF and f_v of one point of
//! the sample, so the synthesis works on *texel coordinates*, never on
//! colours: the output is an index map from output texels to source texels,
//! and all shading looks f_v and the LRF up through it. The look therefore
//! stays consistent under every light and view (the idea of Liu et al. 2004).
//!
//! Method: image quilting (Efros & Freeman 2001) on a torus. Blocks of the
//! source are laid in raster order with overlaps; each block is chosen among
//! random candidates by the squared error of per-texel *feature vectors*
//! (f_v at five views and the LRF at three light directions, each dimension
//! normalised by its spread) in the overlaps with blocks already placed, and
//! pasted along minimum-error boundary cuts. The last row and column also
//! cut against the first ones, so the synthesized texture tiles seamlessly.

use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::material::Material;

/// Per-texel feature vectors of a source texture.
#[derive(Clone, Debug)]
pub struct Features {
    pub width: usize,
    pub height: usize,
    pub dim: usize,
    pub data: Vec<f32>,
}

impl Features {
    fn at(&self, x: usize, y: usize) -> &[f32] {
        let k = (y * self.width + x) * self.dim;
        &self.data[k..k + self.dim]
    }

    /// Feature vectors of a material's texture: f_v at five views and the
    /// LRF for three lights seen from above, normalised per dimension.
    pub fn of_material<M: Material>(m: &M) -> Features {
        let (w, h) = m.texture_size();
        let (w, h) = (w.max(1) as usize, h.max(1) as usize);
        let s = 0.5f32;
        let c = (1.0 - s * s).sqrt();
        let views = [
            [0.0, 0.0, 1.0],
            [s, 0.0, c],
            [-s, 0.0, c],
            [0.0, s, c],
            [0.0, -s, c],
        ];
        let lights = [[0.0, 0.0, 1.0], [0.7, 0.0, 0.714], [0.0, 0.7, 0.714]];
        let dim = 3 * (views.len() + lights.len());
        let mut data: Vec<f32> = (0..w * h)
            .into_par_iter()
            .flat_map_iter(|k| {
                let uv = [
                    ((k % w) as f32 + 0.5) / w as f32,
                    ((k / w) as f32 + 0.5) / h as f32,
                ];
                let mut f = Vec::with_capacity(dim);
                for wo in views {
                    f.extend(m.exiting(uv, wo));
                }
                for wi in lights {
                    f.extend(m.lrf(uv, wi, [0.0, 0.0, 1.0]));
                }
                f
            })
            .collect();
        normalise(&mut data, dim);
        Features {
            width: w,
            height: h,
            dim,
            data,
        }
    }
}

/// Scales every dimension to unit standard deviation (constant ones to 0).
fn normalise(data: &mut [f32], dim: usize) {
    let n = (data.len() / dim).max(1) as f64;
    for d in 0..dim {
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for v in data.iter().skip(d).step_by(dim) {
            let v = if v.is_finite() { *v as f64 } else { 0.0 };
            s += v;
            s2 += v * v;
        }
        let mean = s / n;
        let sd = (s2 / n - mean * mean).max(0.0).sqrt();
        for v in data.iter_mut().skip(d).step_by(dim) {
            *v = if sd > 1e-12 && v.is_finite() {
                ((*v as f64 - mean) / sd) as f32
            } else {
                0.0
            };
        }
    }
}

/// Quilting parameters.
#[derive(Clone, Copy, Debug)]
pub struct SynthSettings {
    /// Block edge in texels (clamped to the source size).
    pub block: usize,
    /// Overlap in texels.
    pub overlap: usize,
    /// Output size as a multiple of the source size (per axis).
    pub scale: usize,
    /// Random candidate blocks tried per placement.
    pub candidates: usize,
    /// Accept candidates within (1 + tolerance) of the best error.
    pub tolerance: f32,
    pub seed: u64,
}

impl Default for SynthSettings {
    fn default() -> Self {
        SynthSettings {
            block: 24,
            overlap: 6,
            scale: 4,
            candidates: 300,
            tolerance: 0.1,
            seed: 1,
        }
    }
}

/// The synthesized texture: a seamless, periodic map from output texels to
/// source texels, and the texel pitch on the surface.
#[derive(Clone, Debug)]
pub struct SynthTexture {
    pub width: usize,
    pub height: usize,
    pub src_width: usize,
    pub src_height: usize,
    /// Source texel (x, y) of every output texel.
    pub map: Vec<[u32; 2]>,
    pub texel_mm: f32,
}

impl SynthTexture {
    /// Plain periodic tiling of the source (no synthesis).
    pub fn tiled(src_width: usize, src_height: usize, texel_mm: f32) -> SynthTexture {
        let (w, h) = (src_width.max(1), src_height.max(1));
        SynthTexture {
            width: w,
            height: h,
            src_width: w,
            src_height: h,
            map: (0..w * h)
                .map(|k| [(k % w) as u32, (k / w) as u32])
                .collect(),
            texel_mm,
        }
    }

    /// Image quilting on a torus over the feature vectors.
    pub fn quilt(f: &Features, texel_mm: f32, s: &SynthSettings) -> SynthTexture {
        let b = s.block.min(f.width).min(f.height);
        let o = s.overlap.min(b / 3);
        if b < 4 || o < 1 {
            return SynthTexture::tiled(f.width, f.height, texel_mm);
        }
        let step = b - o;
        let nx = (f.width * s.scale).div_ceil(step).max(2);
        let ny = (f.height * s.scale).div_ceil(step).max(2);
        let (w, h) = (nx * step, ny * step);
        let mut map: Vec<Option<[u32; 2]>> = vec![None; w * h];
        let mut rng = Pcg64Mcg::seed_from_u64(s.seed);
        let dist =
            |a: &[f32], c: &[f32]| a.iter().zip(c).map(|(x, y)| (x - y) * (x - y)).sum::<f32>();
        for by in 0..ny {
            for bx in 0..nx {
                let (x0, y0) = (bx * step, by * step);
                let at = |i: usize, j: usize| ((y0 + j) % h) * w + (x0 + i) % w;
                // Candidate sources: random block origins fully inside the source.
                let cands: Vec<[usize; 2]> = (0..s.candidates.max(1))
                    .map(|_| {
                        [
                            rng.random_range(0..=f.width - b),
                            rng.random_range(0..=f.height - b),
                        ]
                    })
                    .collect();
                let errors: Vec<f32> = cands
                    .par_iter()
                    .map(|&[sx, sy]| {
                        let mut e = 0.0;
                        for j in 0..b {
                            for i in 0..b {
                                if let Some([ox, oy]) = map[at(i, j)] {
                                    e += dist(f.at(sx + i, sy + j), f.at(ox as usize, oy as usize));
                                }
                            }
                        }
                        e
                    })
                    .collect();
                let best = errors.iter().cloned().fold(f32::INFINITY, f32::min);
                let ok: Vec<usize> = (0..cands.len())
                    .filter(|&k| errors[k] <= best * (1.0 + s.tolerance) + 1e-9)
                    .collect();
                let [sx, sy] = cands[ok[rng.random_range(0..ok.len())]];
                // Overlap error surface of the chosen block.
                let err = |i: usize, j: usize| match map[at(i, j)] {
                    Some([ox, oy]) => dist(f.at(sx + i, sy + j), f.at(ox as usize, oy as usize)),
                    None => 0.0,
                };
                let written = |i: usize, j: usize| map[at(i, j)].is_some();
                let mut keep_old = vec![false; b * b];
                // Left and right strips: vertical cuts; top and bottom: horizontal.
                let sides: [(bool, bool, bool); 4] = [
                    (true, false, (0..b).any(|j| written(0, j))),
                    (true, true, (0..b).any(|j| written(b - 1, j))),
                    (false, false, (0..b).any(|i| written(i, 0))),
                    (false, true, (0..b).any(|i| written(i, b - 1))),
                ];
                for (vertical, far, active) in sides {
                    if !active {
                        continue;
                    }
                    // Strip coordinates: `a` runs along the cut, `c` across it (0..o).
                    let px = |a: usize, c: usize| {
                        let c = if far { b - o + c } else { c };
                        if vertical { (c, a) } else { (a, c) }
                    };
                    let cut = min_cut(b, o, |a, c| {
                        let (i, j) = px(a, c);
                        err(i, j)
                    });
                    for a in 0..b {
                        for c in 0..o {
                            // Old pixels stay on the outer side of the cut.
                            let old_side = if far { c > cut[a] } else { c < cut[a] };
                            if old_side {
                                let (i, j) = px(a, c);
                                keep_old[j * b + i] = true;
                            }
                        }
                    }
                }
                for j in 0..b {
                    for i in 0..b {
                        let k = at(i, j);
                        if map[k].is_none() || !keep_old[j * b + i] {
                            map[k] = Some([(sx + i) as u32, (sy + j) as u32]);
                        }
                    }
                }
            }
        }
        SynthTexture {
            width: w,
            height: h,
            src_width: f.width,
            src_height: f.height,
            map: map.into_iter().map(|m| m.unwrap_or([0, 0])).collect(),
            texel_mm,
        }
    }

    /// Source texture coordinate in [0, 1)^2 for a surface coordinate in mm.
    pub fn lookup(&self, uv_mm: Vec2) -> [f32; 2] {
        let t = uv_mm / self.texel_mm;
        let (fx, fy) = (
            t.x.rem_euclid(self.width as f32),
            t.y.rem_euclid(self.height as f32),
        );
        let (x, y) = (
            (fx as usize).min(self.width - 1),
            (fy as usize).min(self.height - 1),
        );
        let [sx, sy] = self.map[y * self.width + x];
        [
            ((sx as f32 + fx.fract()) / self.src_width as f32).min(1.0 - f32::EPSILON),
            ((sy as f32 + fy.fract()) / self.src_height as f32).min(1.0 - f32::EPSILON),
        ]
    }

    /// Mean squared feature difference between neighbouring output texels
    /// (right and down neighbours, across the periodic wrap too).
    pub fn neighbour_error(&self, f: &Features) -> f32 {
        let fa = |x: usize, y: usize| {
            let [sx, sy] = self.map[(y % self.height) * self.width + x % self.width];
            f.at(sx as usize, sy as usize)
        };
        let d = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>();
        let mut s = 0.0f64;
        for y in 0..self.height {
            for x in 0..self.width {
                s += (d(fa(x, y), fa(x + 1, y)) + d(fa(x, y), fa(x, y + 1))) as f64;
            }
        }
        (s / (2 * self.width * self.height) as f64) as f32
    }
}

/// Minimum-error cut across a strip `len` long and `o` wide: dynamic
/// programming over err(a, c); returns the cut column c for each a.
fn min_cut(len: usize, o: usize, err: impl Fn(usize, usize) -> f32) -> Vec<usize> {
    let mut cost = vec![0f32; len * o];
    for c in 0..o {
        cost[c] = err(0, c);
    }
    for a in 1..len {
        for c in 0..o {
            let mut best = cost[(a - 1) * o + c];
            if c > 0 {
                best = best.min(cost[(a - 1) * o + c - 1]);
            }
            if c + 1 < o {
                best = best.min(cost[(a - 1) * o + c + 1]);
            }
            cost[a * o + c] = err(a, c) + best;
        }
    }
    let mut cut = vec![0usize; len];
    let last = &cost[(len - 1) * o..];
    cut[len - 1] = (0..o)
        .min_by(|&x, &y| last[x].total_cmp(&last[y]))
        .unwrap_or(0);
    for a in (0..len - 1).rev() {
        let c = cut[a + 1];
        let lo = c.saturating_sub(1);
        let hi = (c + 1).min(o - 1);
        cut[a] = (lo..=hi)
            .min_by(|&x, &y| cost[a * o + x].total_cmp(&cost[a * o + y]))
            .unwrap_or(c);
    }
    cut
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source with smooth structure (stripes + blobs), 1-D features.
    fn source(w: usize, h: usize) -> Features {
        let data = (0..w * h)
            .flat_map(|k| {
                let (x, y) = ((k % w) as f32, (k / w) as f32);
                [
                    (x * 0.37).sin() + 0.5 * (y * 0.23 + x * 0.1).cos(),
                    ((x * 0.11).sin() * (y * 0.17).cos()) * 2.0,
                ]
            })
            .collect();
        Features {
            width: w,
            height: h,
            dim: 2,
            data,
        }
    }

    #[test]
    fn quilted_texture_has_no_stronger_seams_than_plain_tiling() {
        let f = source(64, 64);
        let s = SynthSettings {
            seed: 3,
            ..Default::default()
        };
        let q = SynthTexture::quilt(&f, 0.1, &s);
        assert!(q.width >= 4 * 64 && q.height >= 4 * 64);
        let src = SynthTexture::tiled(64, 64, 0.1);
        // Inside the source (ignoring its own tiling seam) neighbours differ by:
        let interior = {
            let mut s = 0.0;
            let mut n = 0;
            for y in 0..63 {
                for x in 0..63 {
                    let d = |a: &[f32], b: &[f32]| {
                        a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>()
                    };
                    s += d(f.at(x, y), f.at(x + 1, y)) + d(f.at(x, y), f.at(x, y + 1));
                    n += 2;
                }
            }
            s / n as f32
        };
        let tiled = src.neighbour_error(&f);
        let quilted = q.neighbour_error(&f);
        assert!(
            tiled > 1.5 * interior,
            "tiling of this source has seams: {tiled} vs {interior}"
        );
        assert!(
            quilted < 1.3 * interior,
            "quilted {quilted} vs interior {interior}"
        );
        // Not a plain copy: many distinct source offsets are used.
        let offsets: std::collections::HashSet<_> = (0..q.height)
            .step_by(18)
            .flat_map(|y| (0..q.width).step_by(18).map(move |x| (x, y)))
            .map(|(x, y)| {
                let [sx, sy] = q.map[y * q.width + x];
                (sx as i64 - x as i64, sy as i64 - y as i64)
            })
            .collect();
        assert!(offsets.len() > 50, "{}", offsets.len());
    }

    #[test]
    fn lookup_wraps_and_stays_in_range() {
        let t = SynthTexture::tiled(8, 4, 0.5);
        assert_eq!(t.lookup(Vec2::new(0.25, 0.25)), [0.0625, 0.125]);
        let a = t.lookup(Vec2::new(-0.25, 1000.0));
        assert!(a.iter().all(|v| (0.0..1.0).contains(v)));
    }

    #[test]
    fn min_cut_follows_the_cheap_path() {
        // Cheap column 2 everywhere.
        let cut = min_cut(10, 5, |_, c| if c == 2 { 0.0 } else { 1.0 });
        assert!(cut.iter().all(|&c| c == 2));
    }
}
