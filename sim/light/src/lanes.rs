//! The homogeneous walk, eight photons at once: the walk every render and
//! trace takes in a homogeneous volume. Each lane is one photon with its own
//! xoshiro256++ stream; a step draws a free flight and a new direction for
//! all lanes in branch-free arithmetic (structure of arrays, so the compiler
//! vectorises it: AVX-512 or AVX2 when the CPU has them, SSE2 otherwise,
//! the same IEEE operations and so the same numbers either way; AVX-512's
//! eight 64-bit lanes in one register double AVX2's rate). A lane whose step
//! does anything but scatter in the volume (reach the top, leave through a
//! wall or the bottom, take its last event, or make a next-event estimate)
//! finishes that step in scalar code with the scalar walk's own functions,
//! and a lane whose photon ended takes the block's next photon.
//!
//! The physics is the scalar walk's (free flights against s_t, isotropic
//! scattering, the absorbing event drawn once from its geometric
//! distribution); only the numbers' source differs: -ln v and the azimuth
//! come from polynomials instead of tables, so that they vectorise.

use glam::Vec3;

use crate::medium::Volume;
use crate::microfacet::Dielectric;
use crate::rng::{WalkRng, mix64, unit_f32};
use crate::walk::{Crossing, End, MAX_EVENTS, NEE_RATE, Pass, Source, Tally, geometric_events};

/// Photons walked side by side.
pub const LANES: usize = 8;

/// Below this many mean free paths under the surface a vertex's next-event
/// roulette can pass only for u = 0: q = NEE_RATE e^(1 - 18) < 2^-24.
const NEE_DEPTH_MFP: f32 = 18.0;

/// The lanes' state, one array per quantity; aligned so that no vector
/// load of an array splits a cache line (which cost the step 30 % when the
/// stack happened to place it so).
#[derive(Clone, Default)]
#[repr(align(64))]
struct State {
    px: [f32; LANES],
    py: [f32; LANES],
    pz: [f32; LANES],
    dx: [f32; LANES],
    dy: [f32; LANES],
    dz: [f32; LANES],
    /// xoshiro256++ state words.
    s0: [u64; LANES],
    s1: [u64; LANES],
    s2: [u64; LANES],
    s3: [u64; LANES],
    /// Real collisions so far; the photon ends at event `limit` (0: idle lane).
    events: [u32; LANES],
    limit: [u32; LANES],
    /// 1 when the photon's last event was a scattering vertex (whose
    /// next-event estimate covers the segment leaving it), 0 after a
    /// boundary reflection or at the start.
    from_vertex: [u32; LANES],
}

/// What a step leaves for the scalar part: the draws, and which lanes need
/// it (aligned as `State`).
#[derive(Default)]
#[repr(align(64))]
struct Step {
    dist: [f32; LANES],
    /// The flight's draw (its low half decides the next-event roulette).
    flight_bits: [u64; LANES],
    dir_bits: [u64; LANES],
    special: [u32; LANES],
}

/// Per-run constants of the step.
#[derive(Clone, Copy)]
struct Medium {
    inv_st: f32,
    st: f32,
    hx: f32,
    hy: f32,
    depth: f32,
    /// A flight that ends above this height may have crossed the top: the
    /// flat surface's height, or a relief's lowest point.
    h_low: f32,
    nee: bool,
}

/// Per lane, what the scalar walk keeps outside the arrays.
#[derive(Clone, Copy, Default)]
struct Photon {
    absorb_at: u64,
    active: bool,
}

impl Pass<'_> {
    /// Whether this pass's volume takes the wide walk.
    pub(crate) fn wide_walk_applies(&self) -> bool {
        self.dielectric().is_some()
            && self.scene.volume.as_ref().is_some_and(|v| {
                v.grid.is_none() && v.cells.is_none() && v.majorant[self.channel] > 0.0
            })
    }

    /// `count` photons of one block through the wide walk; lane k draws from
    /// stream (block, k) of `seed`.
    pub(crate) fn run_block_wide(
        &self,
        source: &Source,
        count: u64,
        seed: u64,
        block: u64,
        table: &[(f32, f32)],
    ) -> Tally {
        let vol = self
            .scene
            .volume
            .as_ref()
            .expect("wide walk needs a volume");
        let bsdf = self.dielectric().expect("wide walk needs a dielectric top");
        if self.vertex_nee && self.accum.is_some() {
            self.lanes::<true>(vol, &bsdf, source, count, seed, block, table)
        } else {
            self.lanes::<false>(vol, &bsdf, source, count, seed, block, table)
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn lanes<const NEE: bool>(
        &self,
        vol: &Volume,
        bsdf: &Dielectric,
        source: &Source,
        count: u64,
        seed: u64,
        block: u64,
        table: &[(f32, f32)],
    ) -> Tally {
        let hf = &self.scene.surface;
        let (st, alb) = table[0];
        let medium = Medium {
            inv_st: 1.0 / st,
            st,
            hx: vol.half[0],
            hy: vol.half[1],
            depth: vol.half[2],
            h_low: if hf.is_flat() {
                hf.flat_height
            } else {
                hf.h_min
            },
            nee: NEE,
        };
        let mut t = Tally {
            launched: count,
            ..Tally::default()
        };
        let mut s = State::default();
        let mut photons = [Photon::default(); LANES];
        let mut step = Step::default();
        let mut next = 0u64;
        let key = mix64(seed ^ block.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        for k in 0..LANES {
            let r = WalkRng::new(key, k as u64).state();
            (s.s0[k], s.s1[k], s.s2[k], s.s3[k]) = (r[0], r[1], r[2], r[3]);
            self.refill(
                &mut s,
                &mut photons,
                k,
                source,
                &mut next,
                count,
                alb,
                &mut t,
            );
        }
        let step_fn = step_impl();
        while photons.iter().any(|p| p.active) {
            step_fn(&mut s, &medium, &mut step);
            for k in 0..LANES {
                if step.special[k] == 0 || !photons[k].active {
                    continue;
                }
                let mut rng = WalkRng::from_state([s.s0[k], s.s1[k], s.s2[k], s.s3[k]]);
                let end =
                    self.finish_step::<NEE>(&mut s, &photons[k], k, &step, bsdf, table, &mut rng);
                [s.s0[k], s.s1[k], s.s2[k], s.s3[k]] = rng.state();
                if let Some(end) = end {
                    t.events += s.events[k] as u64;
                    match end {
                        End::Absorbed => t.absorbed += 1,
                        End::Escaped => t.escaped += 1,
                        End::Truncated => t.truncated += 1,
                        End::Exited => t.exited += 1,
                        End::SurfaceLoss => t.surface_loss += 1,
                    }
                    self.refill(
                        &mut s,
                        &mut photons,
                        k,
                        source,
                        &mut next,
                        count,
                        alb,
                        &mut t,
                    );
                }
            }
        }
        t
    }

    /// Lane k takes the block's next photons until one enters the volume
    /// (those that do not are counted here), or goes idle when none are left.
    #[allow(clippy::too_many_arguments)]
    fn refill(
        &self,
        s: &mut State,
        photons: &mut [Photon; LANES],
        k: usize,
        source: &Source,
        next: &mut u64,
        count: u64,
        alb: f32,
        t: &mut Tally,
    ) {
        let mut rng = WalkRng::from_state([s.s0[k], s.s1[k], s.s2[k], s.s3[k]]);
        photons[k] = Photon::default();
        s.limit[k] = 0;
        s.events[k] = 0;
        while *next < count {
            *next += 1;
            let (o, d) = self.emit(source, &mut rng);
            let Some((p, d)) = self.enter(o, d, &mut rng, t) else {
                continue;
            };
            let absorb_at = geometric_events(alb, rng.next_u64());
            photons[k] = Photon {
                absorb_at,
                active: true,
            };
            s.from_vertex[k] = 0;
            s.limit[k] = absorb_at.min(MAX_EVENTS as u64) as u32;
            (s.px[k], s.py[k], s.pz[k]) = (p.x, p.y, p.z);
            (s.dx[k], s.dy[k], s.dz[k]) = (d.x, d.y, d.z);
            break;
        }
        [s.s0[k], s.s1[k], s.s2[k], s.s3[k]] = rng.state();
    }

    /// Lane k's step in the scalar walk's terms, from the step's draws:
    /// the ending, if its photon ended.
    #[allow(clippy::too_many_arguments)]
    fn finish_step<const NEE: bool>(
        &self,
        s: &mut State,
        photon: &Photon,
        k: usize,
        step: &Step,
        bsdf: &Dielectric,
        table: &[(f32, f32)],
        rng: &mut WalkRng,
    ) -> Option<End> {
        let hf = &self.scene.surface;
        let vol = self.scene.volume.as_ref()?;
        let [hx, hy, depth] = vol.half;
        let mut p = Vec3::new(s.px[k], s.py[k], s.pz[k]);
        let d = Vec3::new(s.dx[k], s.dy[k], s.dz[k]);
        let dist = step.dist[k];
        let store = |s: &mut State, p: Vec3, d: Vec3| {
            (s.px[k], s.py[k], s.pz[k]) = (p.x, p.y, p.z);
            (s.dx[k], s.dy[k], s.dz[k]) = (d.x, d.y, d.z);
        };
        if let Some((_, x)) = hf.crossing_from_below(p, d, dist) {
            // a segment from a scattering vertex was splatted by its estimate
            let splat = !(NEE && s.from_vertex[k] == 1);
            return match self.cross_boundary(x, d, bsdf, splat, rng) {
                Crossing::Inside(d2) => {
                    store(s, x + d2 * 1e-4, d2);
                    s.from_vertex[k] = 0;
                    None
                }
                Crossing::Ended(e) => Some(e),
            };
        }
        p += d * dist;
        if p.x.abs() > hx || p.y.abs() > hy || p.z < -depth {
            return Some(End::Escaped);
        }
        s.events[k] += 1;
        if s.events[k] >= s.limit[k] {
            return Some(if s.events[k] as u64 == photon.absorb_at {
                End::Absorbed
            } else {
                End::Truncated
            });
        }
        if NEE {
            let u = unit_f32(step.flight_bits[k] as u32);
            self.vertex_splat(p, table[0].0, table, bsdf, u, rng);
        }
        s.from_vertex[k] = 1;
        let (x, y, z) = sphere_from_bits(step.dir_bits[k]);
        store(s, p, Vec3::new(x, y, z));
        None
    }
}

type StepFn = fn(&mut State, &Medium, &mut Step);

/// The step compiled for this CPU: with AVX2 where there is one.
fn step_impl() -> StepFn {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx512bw")
        {
            return |s, m, o| {
                // SAFETY: the CPU has these AVX-512 subsets (checked just above).
                unsafe { step_avx512(s, m, o) }
            };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            return |s, m, o| {
                // SAFETY: the CPU has AVX2 (checked just above).
                unsafe { step_avx2(s, m, o) }
            };
        }
    }
    step_portable
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn step_avx2(s: &mut State, m: &Medium, o: &mut Step) {
    step_body(s, m, o)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw")]
unsafe fn step_avx512(s: &mut State, m: &Medium, o: &mut Step) {
    step_body(s, m, o)
}

fn step_portable(s: &mut State, m: &Medium, o: &mut Step) {
    step_body(s, m, o)
}

/// One step of every lane: two draws, the free flight, and, where the lane
/// only scatters, its new position and direction. Lanes marked special keep
/// their position and direction for the scalar part.
#[inline(always)]
fn step_body(s: &mut State, m: &Medium, o: &mut Step) {
    for k in 0..LANES {
        let flight = xoshiro(&mut s.s0[k], &mut s.s1[k], &mut s.s2[k], &mut s.s3[k]);
        let dir = xoshiro(&mut s.s0[k], &mut s.s1[k], &mut s.s2[k], &mut s.s3[k]);
        let dist = exp1_poly((flight >> 32) as u32) * m.inv_st;
        let (px, py, pz) = (s.px[k], s.py[k], s.pz[k]);
        let (dx, dy, dz) = (s.dx[k], s.dy[k], s.dz[k]);
        let (nx, ny, nz) = (px + dx * dist, py + dy * dist, pz + dz * dist);
        let top = (dz > 0.0) & (nz > m.h_low);
        let out = (nx.abs() > m.hx) | (ny.abs() > m.hy) | (nz < -m.depth);
        let events = s.events[k] + 1;
        let last = events >= s.limit[k];
        let u = unit_f32(flight as u32);
        let near = (m.st * (m.h_low - nz).max(0.0) < NEE_DEPTH_MFP) | (u == 0.0);
        let nee = m.nee & (u < NEE_RATE) & near;
        let special = top | out | last | nee;
        let (cx, cy, cz) = sphere_from_bits(dir);
        s.px[k] = if special { px } else { nx };
        s.py[k] = if special { py } else { ny };
        s.pz[k] = if special { pz } else { nz };
        s.dx[k] = if special { dx } else { cx };
        s.dy[k] = if special { dy } else { cy };
        s.dz[k] = if special { dz } else { cz };
        s.events[k] = if special { s.events[k] } else { events };
        s.from_vertex[k] = if special { s.from_vertex[k] } else { 1 };
        o.dist[k] = dist;
        o.flight_bits[k] = flight;
        o.dir_bits[k] = dir;
        o.special[k] = special as u32;
    }
}

/// xoshiro256++ on one lane's state words (the same sequence as WalkRng).
#[inline(always)]
fn xoshiro(s0: &mut u64, s1: &mut u64, s2: &mut u64, s3: &mut u64) -> u64 {
    let r = s0.wrapping_add(*s3).rotate_left(23).wrapping_add(*s0);
    let t = *s1 << 17;
    *s2 ^= *s0;
    *s3 ^= *s1;
    *s1 ^= *s2;
    *s0 ^= *s3;
    *s2 ^= t;
    *s3 = s3.rotate_left(45);
    r
}

/// A unit-mean exponential variate, -ln v with v = (bits + 1) / 2^32 in
/// (0, 1], in f32 arithmetic alone (no table, no division, so eight lanes
/// go in one vector): ln v = ln m + e ln 2 with v = 2^e m, m in
/// [sqrt 1/2, sqrt 2), and ln m = ln(1 + x) by Cephes' logf polynomial
/// (about 1 ulp). For v >= sqrt 1/2 (e = 0), x = -(1 - v) comes straight
/// from the integer !bits = 2^32 (1 - v), so v near 1 (short flights) keeps
/// full relative precision; below that v is rounded to 24 bits, where
/// |ln v| > 0.34 and the rounding costs under 2e-7 relative.
#[inline(always)]
pub fn exp1_poly(bits: u32) -> f32 {
    const TWO_M32: f32 = 1.0 / 4_294_967_296.0;
    let near_one = bits >= 0xB504_F334; // v >= sqrt(1/2)
    // !bits < 2^31 where it is used, so an i32 conversion (one rounding)
    let w = (!bits) as i32 as f32 * TWO_M32; // 1 - v
    // v from its two exact 16-bit halves, with one rounding
    let v = (bits >> 16) as i32 as f32 * (1.0 / 65_536.0)
        + ((bits & 0xFFFF) + 1) as i32 as f32 * TWO_M32;
    // v = 2^e m1, m1 in [1, 2); then m in [sqrt 1/2, sqrt 2)
    let vb = v.to_bits() as i32;
    let e1 = (vb >> 23) - 127;
    let m1 = f32::from_bits(((vb & 0x007F_FFFF) | 0x3F80_0000) as u32);
    let big = m1 > std::f32::consts::SQRT_2;
    let m = if big { m1 * 0.5 } else { m1 };
    let e = if big { e1 + 1 } else { e1 };
    let x = if near_one { -w } else { m - 1.0 };
    let e = if near_one { 0.0 } else { e as f32 };
    let z = x * x;
    let p = 7.037_683_6e-2_f32;
    let p = p * x - 1.151_461_1e-1;
    let p = p * x + 1.167_699_9e-1;
    let p = p * x - 1.242_014_1e-1;
    let p = p * x + 1.424_932_3e-1;
    let p = p * x - 1.666_805_8e-1;
    let p = p * x + 2.000_071_5e-1;
    let p = p * x - 2.499_999_4e-1;
    let p = p * x + 3.333_333_1e-1;
    let ln_1px = x + (x * z * p - 0.5 * z);
    // e ln 2 in two parts (Cody-Waite) so the sum rounds once
    let ln_v = ln_1px + e * -2.121_944_4e-4 + e * 0.693_359_4;
    -ln_v
}

/// Uniform direction on the sphere from 64 random bits, from arithmetic
/// alone: z uniform in (-1, 1] from the high 24 bits; the azimuth's quadrant
/// from bits 30-31 and its offset a in [-pi/4, pi/4) from bits 6-29, with
/// cos a and sin a from their Taylor series (truncation below 2e-9 at
/// |a| = pi/4) and the quadrant's turn applied exactly (swaps and signs).
#[inline(always)]
pub fn sphere_from_bits(bits: u64) -> (f32, f32, f32) {
    let z = 1.0 - 2.0 * unit_f32((bits >> 32) as u32);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let low = bits as u32;
    let f = ((low >> 6) & 0x00FF_FFFF) as f32 * (1.0 / 16_777_216.0) - 0.5;
    let a = f * std::f32::consts::FRAC_PI_2;
    let a2 = a * a;
    let sin_a = a
        * (1.0
            + a2 * (-1.0 / 6.0
                + a2 * (1.0 / 120.0 + a2 * (-1.0 / 5040.0 + a2 * (1.0 / 362_880.0)))));
    let cos_a = 1.0
        + a2 * (-0.5
            + a2 * (1.0 / 24.0
                + a2 * (-1.0 / 720.0 + a2 * (1.0 / 40_320.0 + a2 * (-1.0 / 3_628_800.0)))));
    // turn by q quarter turns: q = 1: (-s, c), 2: (-c, -s), 3: (s, -c)
    let q = low >> 30;
    let (c, s) = if q & 1 == 1 {
        (sin_a, cos_a)
    } else {
        (cos_a, sin_a)
    };
    let c_sign = ((q ^ (q >> 1)) & 1) << 31;
    let s_sign = (q >> 1) << 31;
    let c = f32::from_bits(c.to_bits() ^ c_sign);
    let s = f32::from_bits(s.to_bits() ^ s_sign);
    (r * c, r * s, z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::{WalkRng, exp1_from_bits};

    #[test]
    fn exp1_poly_matches_the_logarithm() {
        let mut worst = 0.0f64;
        let mut check = |bits: u32| {
            let want = -((bits as f64 + 1.0) / 4_294_967_296.0).ln();
            let got = exp1_poly(bits) as f64;
            let err = if want > 0.0 {
                (got - want).abs() / want
            } else {
                got.abs()
            };
            worst = worst.max(err);
        };
        let mut rng = WalkRng::new(3, 3);
        for _ in 0..200_000 {
            check(rng.next_u32());
        }
        for bits in [
            0,
            1,
            2,
            1000,
            u32::MAX,
            u32::MAX - 1,
            u32::MAX - 1000,
            1 << 31,
            (1 << 31) - 1,
        ] {
            check(bits);
        }
        // measured 1.8e-7 (f32 rounding alone is 6e-8)
        assert!(worst < 2e-7, "worst relative error {worst:e}");
        assert_eq!(exp1_poly(u32::MAX), 0.0);
        // and agrees with the scalar walk's table version
        for bits in [0u32, 77, 1 << 20, 3_000_000_000, u32::MAX - 5] {
            let (a, b) = (exp1_poly(bits), exp1_from_bits(bits));
            assert!((a - b).abs() <= 3e-7 * b.max(1e-9), "{bits}: {a} {b}");
        }
    }

    #[test]
    fn sphere_from_bits_is_uniform_and_unit() {
        let mut rng = WalkRng::new(4, 1);
        let n = 400_000;
        let (mut mean, mut zz, mut xy) = ([0.0f64; 3], 0.0f64, 0.0f64);
        let mut octants = [0usize; 8];
        for _ in 0..n {
            let (x, y, z) = sphere_from_bits(rng.next_u64());
            let len = ((x * x + y * y + z * z) as f64).sqrt();
            assert!((len - 1.0).abs() < 1e-6, "{x} {y} {z}");
            mean[0] += x as f64;
            mean[1] += y as f64;
            mean[2] += z as f64;
            zz += (z * z) as f64;
            xy += (x * y) as f64;
            let o = (x > 0.0) as usize | ((y > 0.0) as usize) << 1 | ((z > 0.0) as usize) << 2;
            octants[o] += 1;
        }
        for m in mean {
            assert!((m / n as f64).abs() < 0.004, "{mean:?}");
        }
        assert!((zz / n as f64 - 1.0 / 3.0).abs() < 0.003);
        assert!((xy / n as f64).abs() < 0.002);
        for c in octants {
            assert!((c as f64 / n as f64 - 0.125).abs() < 0.003, "{octants:?}");
        }
        // the azimuth against libm over the whole circle
        for k in 0..(1u32 << 14) {
            let low = k << 18 | (k * 7919) & 0x3_FFFF;
            let (c, s, _) = sphere_from_bits(low as u64); // z = 1 - 0: r = 0
            assert_eq!((c, s), (0.0, 0.0));
            let bits = (1u64 << 63) | low as u64; // z = 0, r = 1
            let (c, s, z) = sphere_from_bits(bits);
            assert_eq!(z, 0.0);
            let f = ((low >> 6) & 0xFF_FFFF) as f64 / 16_777_216.0 - 0.5;
            let phi =
                (low >> 30) as f64 * std::f64::consts::FRAC_PI_2 + f * std::f64::consts::FRAC_PI_2;
            assert!(
                (c as f64 - phi.cos()).abs() < 2e-7,
                "{k}: {c} {}",
                phi.cos()
            );
            assert!(
                (s as f64 - phi.sin()).abs() < 2e-7,
                "{k}: {s} {}",
                phi.sin()
            );
        }
    }

    /// Every compiled step gives the same numbers: the same IEEE
    /// operations, whatever the vector width.
    #[test]
    fn steps_agree_bit_for_bit() {
        let m = Medium {
            inv_st: 1.0 / 3.2,
            st: 3.2,
            hx: 5.0,
            hy: 5.0,
            depth: 3.0,
            h_low: 0.0,
            nee: true,
        };
        let mut s = State::default();
        let mut rng = WalkRng::new(11, 0);
        for k in 0..LANES {
            let r = WalkRng::new(5, k as u64).state();
            (s.s0[k], s.s1[k], s.s2[k], s.s3[k]) = (r[0], r[1], r[2], r[3]);
            (s.px[k], s.py[k], s.pz[k]) =
                (rng.uniform() - 0.5, rng.uniform() - 0.5, -rng.uniform());
            (s.dx[k], s.dy[k], s.dz[k]) = sphere_from_bits(rng.next_u64());
            s.limit[k] = 1 + k as u32 * 40;
        }
        let run = |f: StepFn| {
            let (mut s, mut o) = (s.clone(), Step::default());
            let mut trace = Vec::new();
            for _ in 0..300 {
                f(&mut s, &m, &mut o);
                trace.push((s.px, s.pz, s.dy, s.events, s.from_vertex, o.dist, o.special));
            }
            trace
        };
        let portable = run(step_portable);
        assert_eq!(portable, run(step_impl()));
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            assert_eq!(portable, run(|s, m, o| unsafe { step_avx2(s, m, o) }));
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx512bw")
        {
            assert_eq!(portable, run(|s, m, o| unsafe { step_avx512(s, m, o) }));
        }
        assert!(portable.iter().any(|t| t.6.iter().any(|&x| x == 1)));
        assert!(portable.iter().any(|t| t.6.iter().any(|&x| x == 0)));
    }

    /// The wide walk and the scalar walk sample the same distribution: the
    /// shares of exits and absorptions and the mean events per photon agree
    /// within their statistical errors; a medium with 10 % more scattering,
    /// through the same comparison, does not.
    #[test]
    fn wide_walk_matches_the_scalar_walk() {
        let world = crate::bench::medium_world("whole-milk").unwrap();
        let n = 60_000;
        let src = crate::bench::pencil();
        let wide = world.trace_with(&src, 1, n, 1, None, true);
        let scalar = world.trace_with(&src, 1, n, 2, None, false);
        assert!(wide.balanced() && scalar.balanced());
        assert_ne!(wide, scalar);
        let agree = |a: &Tally, b: &Tally| {
            let share = |x: u64, t: &Tally| x as f64 / t.launched as f64;
            let close = |pa: f64, pb: f64| {
                let sd = (pa * (1.0 - pa) / n as f64 * 2.0).sqrt();
                (pa - pb).abs() < 4.0 * sd + 1e-9
            };
            let mean = |t: &Tally| t.events as f64 / t.entered as f64;
            close(share(a.exited, a), share(b.exited, b))
                && close(share(a.absorbed, a), share(b.absorbed, b))
                && (mean(a) / mean(b) - 1.0).abs() < 0.03
        };
        assert!(agree(&wide, &scalar), "{wide:?}\n{scalar:?}");
        let mut desc = crate::sample::SceneDesc::preset("whole-milk").unwrap();
        if let crate::sample::SceneDesc::Sample(s) = &mut desc {
            s.size_mm = [200.0, 200.0, 100.0];
            s.volume.material =
                crate::sample::MaterialDesc::Coefficients(crate::sample::Coefficients {
                    sigma_s: [2.55, 3.21 * 1.1, 3.77],
                    sigma_a: [0.0011, 0.0024, 0.014],
                });
        }
        let wrong =
            crate::World::new(desc, crate::RigTruth::nominal(), crate::SimQuality::ci()).unwrap();
        let other = wrong.trace_with(&src, 1, n, 2, None, false);
        assert!(!agree(&wide, &other), "{wide:?}\n{other:?}");
    }

    #[test]
    fn lane_generator_is_walk_rng() {
        let mut a = WalkRng::new(7, 2);
        let st = a.state();
        let (mut s0, mut s1, mut s2, mut s3) = (st[0], st[1], st[2], st[3]);
        for _ in 0..100 {
            assert_eq!(xoshiro(&mut s0, &mut s1, &mut s2, &mut s3), a.next_u64());
        }
    }
}
