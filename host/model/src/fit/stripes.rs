//! What the fit's stages share about stripe images: which light and view
//! directions count as one, the stripe's core, and the laser's mirror
//! direction (views near it see a glint, surface light, on the core).

use crate::rectified::{Grid, StripeEntry};

/// Light directions within 5 degrees of the normal count as vertical.
pub(super) const NEAR_VERTICAL_COS: f64 = 0.996_194_698_091_745_5;

/// Pass-1 light directions closer than this (radians) are one direction:
/// a laser's direction varies by about a degree across its sweep and
/// between the rows (arc and turntable angles) that aim it the same way in
/// the sample's frame, while distinct directions of a plan lie 7.5 degrees
/// apart or more.
pub(super) const SAME_LIGHT_DIR: f64 = 0.07;

/// Indices of `values` in ascending order of value, in runs whose members
/// lie within `within` of the run's first: the views or lights at one
/// elevation.
pub(super) fn ascending_runs(values: &[f64], within: f64) -> Vec<Vec<usize>> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut runs: Vec<Vec<usize>> = Vec::new();
    for i in order {
        match runs.last_mut() {
            Some(run) if values[i] - values[run[0]] <= within => run.push(i),
            _ => runs.push(vec![i]),
        }
    }
    runs
}

/// Directions are grouped when closer than this (radians).
pub(super) const SAME_DIR: f64 = 1e-3;

/// The group key of every near-vertical light (`dir_key` of the normal).
pub(super) const VERTICAL_KEY: [i64; 3] = [0, 0, (1.0 / SAME_DIR) as i64];

/// Views within 30 degrees of a stripe's mirror direction see the laser's
/// specular reflection on its core, which is surface, not subsurface,
/// light: their core is left out of I(d), they do not count for R, and the
/// entrance function leaves them out. The polished presets (GGX alpha 0.02)
/// put 10 % into a 13-degree view's R of skin1 blue (default scale) and
/// 1e-3 of R into a 26-degree view's at ci (green and blue alike, so a
/// glint's, not the material's); an oblique laser's glint is stronger still
/// (Fresnel 3.5 times at 60 degrees, BRDF over cos theta_i). With 30 degrees
/// whole milk's worst f(w_i) at the default scale went from 3.6 to 2.2 %.
pub(super) const SPECULAR_VIEW_COS: f64 = 0.866_025_403_784_438_6;

/// The stripe's core: the laser line blurred by a camera pixel and the
/// rectification's interpolation, a texel and a half either side.
pub(super) fn core_mm(grid: &Grid) -> f64 {
    1.5 * grid.texel_mm
}

/// Cosine between `s`'s view and the laser's mirror direction.
pub(super) fn cos_to_mirror(s: &StripeEntry) -> f64 {
    let (l, v) = (s.light_dir, s.view_dir);
    -l[0] * v[0] - l[1] * v[1] + l[2] * v[2]
}

pub(super) fn dir_key(v: [f64; 3]) -> [i64; 3] {
    v.map(|x| (x / SAME_DIR).round() as i64)
}

pub(super) fn f32v(v: [f64; 3]) -> [f32; 3] {
    v.map(|x| x as f32)
}
