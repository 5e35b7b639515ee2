//! The queries' inner loops over one grid cell's list of sphere blocks, in
//! two versions: portable arrays, and AVX2 intrinsics eight spheres at a
//! time. Both do the same arithmetic in the same order (no fused
//! multiply-add), so they give the same bits.

use glam::Vec3;

use super::{Block, LANES};

/// max(x, 0) for numbers (no NaN handling, unlike `f32::max`; NaN gives 0,
/// as `_mm256_max_ps(x, 0)` does).
#[inline(always)]
fn max0(x: f32) -> f32 {
    if x > 0.0 { x } else { 0.0 }
}

/// A lane-wise value.
#[inline(always)]
fn lanes(f: impl FnMut(usize) -> f32) -> [f32; LANES] {
    std::array::from_fn(f)
}

/// Lane-wise `if m { a } else { b }`.
#[inline(always)]
fn select(m: [bool; LANES], a: [f32; LANES], b: [f32; LANES]) -> [f32; LANES] {
    std::array::from_fn(|j| if m[j] { a[j] } else { b[j] })
}

/// The inner loops.
pub(super) trait Scan {
    /// `Cells::first_entry` in one grid cell, from `o` (the line's origin
    /// relative to the blocks' frame) along `d`: per lane, lowers `best` to
    /// the entry of a sphere the line enters from outside, and sets `which`
    /// to that sphere's block index `b0 + i` (as a float).
    fn entries(
        list: &[Block],
        b0: usize,
        o: Vec3,
        d: Vec3,
        best: &mut [f32; LANES],
        which: &mut [f32; LANES],
    );

    /// `Cells::cross` in one grid cell: each block's interval of the line
    /// in its spheres, [t_in, t_out] (t_in = inf where the line misses).
    fn intervals(
        list: &[Block],
        o: Vec3,
        d: Vec3,
        t_in: &mut [[f32; LANES]],
        t_out: &mut [[f32; LANES]],
    );

    /// The furthest end of an interval that covers `s`, with its block
    /// and lane (the first of equals); None when no interval covers `s`.
    fn covering(
        t_in: &[[f32; LANES]],
        t_out: &[[f32; LANES]],
        s: f32,
    ) -> Option<(f32, usize, usize)>;

    /// The smallest lane and its index (the first of equals).
    fn first_min(v: &[f32; LANES]) -> (f32, usize);
}

/// Plain arrays, which the compiler vectorises as it can.
pub(super) struct Portable;

/// What the blocks' loops share: b = (o - c).d and r^2 - |perpendicular|^2
/// (no cancellation near tangency, unlike b^2 - |o - c|^2 + r^2).
#[inline(always)]
fn along(s: &Block, o: Vec3, d: Vec3) -> ([f32; LANES], [f32; LANES]) {
    let ox = lanes(|j| o.x - s.x[j]);
    let oy = lanes(|j| o.y - s.y[j]);
    let oz = lanes(|j| o.z - s.z[j]);
    let b = lanes(|j| ox[j] * d.x + oy[j] * d.y + oz[j] * d.z);
    let h = lanes(|j| {
        let (px, py, pz) = (ox[j] - d.x * b[j], oy[j] - d.y * b[j], oz[j] - d.z * b[j]);
        s.r2[j] - (px * px + py * py + pz * pz)
    });
    (b, h)
}

impl Scan for Portable {
    #[inline(always)]
    fn entries(
        list: &[Block],
        b0: usize,
        o: Vec3,
        d: Vec3,
        best: &mut [f32; LANES],
        which: &mut [f32; LANES],
    ) {
        for (i, s) in list.iter().enumerate() {
            let (b, disc) = along(s, o, d);
            let t = lanes(|j| -b[j] - max0(disc[j]).sqrt());
            // met, ahead: the entry point lies ahead only when the line
            // starts outside the sphere and moves towards its centre
            let ok: [bool; LANES] =
                std::array::from_fn(|j| (disc[j] > 0.0) & (t[j] > 0.0) & (t[j] < best[j]));
            *best = select(ok, t, *best);
            *which = select(ok, [(b0 + i) as f32; LANES], *which);
        }
    }

    #[inline(always)]
    fn intervals(
        list: &[Block],
        o: Vec3,
        d: Vec3,
        t_in: &mut [[f32; LANES]],
        t_out: &mut [[f32; LANES]],
    ) {
        for (k, s) in list.iter().enumerate() {
            let (b, h) = along(s, o, d);
            let sq = lanes(|j| max0(h[j]).sqrt());
            let hit: [bool; LANES] = std::array::from_fn(|j| h[j] > 0.0);
            t_in[k] = select(hit, lanes(|j| -b[j] - sq[j]), [f32::INFINITY; LANES]);
            t_out[k] = lanes(|j| -b[j] + sq[j]);
        }
    }

    #[inline(always)]
    fn covering(
        t_in: &[[f32; LANES]],
        t_out: &[[f32; LANES]],
        s: f32,
    ) -> Option<(f32, usize, usize)> {
        let mut far = [-1.0f32; LANES];
        let mut which = [0.0f32; LANES];
        for (k, (a, b)) in t_in.iter().zip(t_out).enumerate() {
            let ok: [bool; LANES] =
                std::array::from_fn(|j| (a[j] < s) & (b[j] > s) & (b[j] > far[j]));
            far = select(ok, *b, far);
            which = select(ok, [k as f32; LANES], which);
        }
        let m = fold(far, |a, b| if a > b { a } else { b });
        let j = (0..LANES).position(|j| far[j] == m).unwrap_or(0);
        (m > s).then_some((m, which[j] as i32 as usize, j))
    }

    #[inline(always)]
    fn first_min(v: &[f32; LANES]) -> (f32, usize) {
        let m = fold(*v, |a, b| if a < b { a } else { b });
        (m, (0..LANES).position(|j| v[j] == m).unwrap_or(0))
    }
}

/// The lanes reduced by `f`, halves folded onto each other (a tree, not a
/// chain: the steps of one level do not wait for each other).
#[inline(always)]
fn fold(mut v: [f32; LANES], f: impl Fn(f32, f32) -> f32) -> f32 {
    let mut w = LANES / 2;
    while w > 0 {
        for i in 0..w {
            v[i] = f(v[i], v[i + w]);
        }
        w /= 2;
    }
    v[0]
}

/// AVX2 intrinsics: to be inlined only into functions compiled with AVX2.
#[cfg(target_arch = "x86_64")]
pub(super) struct Avx2;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use glam::Vec3;

    use super::super::{Block, LANES};
    use super::{Avx2, Scan};

    // SAFETY (every block below): these run only inside the AVX2 versions
    // of the queries, after `is_x86_feature_detected!("avx2")`; loads are of
    // whole `[f32; LANES]` arrays (LANES = 8).
    const _: () = assert!(LANES == 8);

    #[inline(always)]
    unsafe fn ld(a: &[f32; LANES]) -> __m256 {
        unsafe { _mm256_loadu_ps(a.as_ptr()) }
    }

    #[inline(always)]
    unsafe fn st(a: &mut [f32; LANES], v: __m256) {
        unsafe { _mm256_storeu_ps(a.as_mut_ptr(), v) }
    }

    /// `super::along` (the same order of operations).
    #[inline(always)]
    unsafe fn along(s: &Block, o: [__m256; 3], d: [__m256; 3]) -> (__m256, __m256) {
        unsafe {
            let r2 = ld(&s.r2);
            let ox = _mm256_sub_ps(o[0], ld(&s.x));
            let oy = _mm256_sub_ps(o[1], ld(&s.y));
            let oz = _mm256_sub_ps(o[2], ld(&s.z));
            let b = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(ox, d[0]), _mm256_mul_ps(oy, d[1])),
                _mm256_mul_ps(oz, d[2]),
            );
            let px = _mm256_sub_ps(ox, _mm256_mul_ps(d[0], b));
            let py = _mm256_sub_ps(oy, _mm256_mul_ps(d[1], b));
            let pz = _mm256_sub_ps(oz, _mm256_mul_ps(d[2], b));
            let h = _mm256_sub_ps(
                r2,
                _mm256_add_ps(
                    _mm256_add_ps(_mm256_mul_ps(px, px), _mm256_mul_ps(py, py)),
                    _mm256_mul_ps(pz, pz),
                ),
            );
            (b, h)
        }
    }

    #[inline(always)]
    unsafe fn splat3(v: Vec3) -> [__m256; 3] {
        unsafe {
            [
                _mm256_set1_ps(v.x),
                _mm256_set1_ps(v.y),
                _mm256_set1_ps(v.z),
            ]
        }
    }

    impl Scan for Avx2 {
        #[inline(always)]
        fn entries(
            list: &[Block],
            b0: usize,
            o: Vec3,
            d: Vec3,
            best: &mut [f32; LANES],
            which: &mut [f32; LANES],
        ) {
            unsafe {
                let (ov, dv) = (splat3(o), splat3(d));
                let zero = _mm256_setzero_ps();
                let sign = _mm256_set1_ps(-0.0);
                let (mut vb, mut vw) = (ld(best), ld(which));
                for (i, s) in list.iter().enumerate() {
                    let (b, h) = along(s, ov, dv);
                    let t = _mm256_sub_ps(
                        _mm256_xor_ps(b, sign),
                        _mm256_sqrt_ps(_mm256_max_ps(h, zero)),
                    );
                    let ok = _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_GT_OQ>(h, zero),
                        _mm256_and_ps(
                            _mm256_cmp_ps::<_CMP_GT_OQ>(t, zero),
                            _mm256_cmp_ps::<_CMP_LT_OQ>(t, vb),
                        ),
                    );
                    vb = _mm256_blendv_ps(vb, t, ok);
                    vw = _mm256_blendv_ps(vw, _mm256_set1_ps((b0 + i) as f32), ok);
                }
                st(best, vb);
                st(which, vw);
            }
        }

        #[inline(always)]
        fn intervals(
            list: &[Block],
            o: Vec3,
            d: Vec3,
            t_in: &mut [[f32; LANES]],
            t_out: &mut [[f32; LANES]],
        ) {
            unsafe {
                let (ov, dv) = (splat3(o), splat3(d));
                let zero = _mm256_setzero_ps();
                let sign = _mm256_set1_ps(-0.0);
                let inf = _mm256_set1_ps(f32::INFINITY);
                for ((s, a), e) in list.iter().zip(t_in.iter_mut()).zip(t_out.iter_mut()) {
                    let (b, h) = along(s, ov, dv);
                    let nb = _mm256_xor_ps(b, sign);
                    let sq = _mm256_sqrt_ps(_mm256_max_ps(h, zero));
                    let hit = _mm256_cmp_ps::<_CMP_GT_OQ>(h, zero);
                    st(a, _mm256_blendv_ps(inf, _mm256_sub_ps(nb, sq), hit));
                    st(e, _mm256_add_ps(nb, sq));
                }
            }
        }

        #[inline(always)]
        fn covering(
            t_in: &[[f32; LANES]],
            t_out: &[[f32; LANES]],
            s: f32,
        ) -> Option<(f32, usize, usize)> {
            unsafe {
                let vs = _mm256_set1_ps(s);
                let mut far = _mm256_set1_ps(-1.0);
                let mut which = _mm256_setzero_ps();
                for (k, (a, b)) in t_in.iter().zip(t_out).enumerate() {
                    let (a, b) = (ld(a), ld(b));
                    let ok = _mm256_and_ps(
                        _mm256_and_ps(
                            _mm256_cmp_ps::<_CMP_LT_OQ>(a, vs),
                            _mm256_cmp_ps::<_CMP_GT_OQ>(b, vs),
                        ),
                        _mm256_cmp_ps::<_CMP_GT_OQ>(b, far),
                    );
                    far = _mm256_blendv_ps(far, b, ok);
                    which = _mm256_blendv_ps(which, _mm256_set1_ps(k as f32), ok);
                }
                let (m, j) = first_of(far, _mm256_max_ps);
                // lane j of which, without a trip through memory
                let w = _mm256_permutevar8x32_ps(which, _mm256_set1_epi32(j as i32));
                (m > s).then_some((m, _mm256_cvtss_f32(w) as i32 as usize, j))
            }
        }

        #[inline(always)]
        fn first_min(v: &[f32; LANES]) -> (f32, usize) {
            unsafe { first_of(ld(v), _mm256_min_ps) }
        }
    }

    /// The lanes reduced by `f` (max or min) and the first lane equal to
    /// the result.
    #[inline(always)]
    unsafe fn first_of(v: __m256, f: unsafe fn(__m256, __m256) -> __m256) -> (f32, usize) {
        unsafe {
            let a = f(v, _mm256_permute2f128_ps::<1>(v, v));
            let b = f(a, _mm256_permute_ps::<0b0100_1110>(a));
            let c = f(b, _mm256_permute_ps::<0b1011_0001>(b));
            let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(v, c));
            (
                _mm256_cvtss_f32(c),
                mask.trailing_zeros() as usize & (LANES - 1),
            )
        }
    }
}
