//! Seeded random numbers: PCG32 (O'Neill 2014) for building the world
//! (volumes, reliefs, rig perturbations) and sensor noise; xoshiro256++ for
//! the photon walks, where the generator is on the hot path.
//!
//! Every block of photons gets its own stream, derived from the render seed
//! and the block index, so a render is identical for any thread count.

/// PCG-XSH-RR 64/32: small state, fast, good statistics for Monte Carlo.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    inc: u64,
}

/// SplitMix64 finaliser: spreads nearby seeds (0, 1, 2, ...) apart.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator for `stream` of `seed`; distinct streams are independent.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut r = Rng {
            state: 0,
            inc: (mix64(stream ^ 0x5851_F42D_4C95_7F2D) << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(mix64(seed));
        r.next_u32();
        r
    }

    #[inline(always)]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }

    /// Uniform in [0, 1), 24 bits.
    #[inline(always)]
    pub fn uniform(&mut self) -> f32 {
        unit_f32(self.next_u32())
    }

    /// Uniform in [0, 1), 53 bits.
    pub fn uniform_f64(&mut self) -> f64 {
        let hi = (self.next_u32() as u64) << 21;
        let lo = (self.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    /// Standard normal (Box-Muller's cosine half).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform_f64();
        let u2 = self.uniform_f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Poisson with mean `lambda`: exact (Knuth) for small means, normal
    /// approximation above 30 where its error is far below read noise.
    pub fn poisson(&mut self, lambda: f64) -> f64 {
        if lambda <= 0.0 {
            return 0.0;
        }
        if lambda > 30.0 {
            return (lambda + lambda.sqrt() * self.normal()).max(0.0).round();
        }
        let l = (-lambda).exp();
        let mut k = 0.0;
        let mut p = 1.0;
        loop {
            p *= self.uniform_f64();
            if p <= l {
                return k;
            }
            k += 1.0;
        }
    }
}

/// So rand_distr's samplers (the sensor's ziggurat normals) draw from a
/// seeded PCG stream.
impl rand_core::RngCore for Rng {
    #[inline(always)]
    fn next_u32(&mut self) -> u32 {
        Rng::next_u32(self)
    }

    #[inline(always)]
    fn next_u64(&mut self) -> u64 {
        ((Rng::next_u32(self) as u64) << 32) | Rng::next_u32(self) as u64
    }

    fn fill_bytes(&mut self, dst: &mut [u8]) {
        rand_core::impls::fill_bytes_via_next(self, dst)
    }
}

/// xoshiro256++ (Blackman & Vigna 2018), the photon walks' generator: 64
/// bits per step from shifts, xors and adds (no multiply on the state's
/// dependency chain), so a walk step draws its numbers in a few cycles.
/// Seeded by SplitMix64 from (seed, stream); streams start at independent
/// random points of the 2^256 - 1 period.
#[derive(Clone, Debug)]
pub struct WalkRng {
    s: [u64; 4],
}

impl WalkRng {
    /// A generator for `stream` of `seed`; distinct streams are independent.
    pub fn new(seed: u64, stream: u64) -> Self {
        let key = mix64(seed) ^ mix64(stream ^ 0x5851_F42D_4C95_7F2D).rotate_left(32);
        // SplitMix64's sequence from `key` (mix64 adds its increment)
        let mut s = [0u64; 4];
        for (i, v) in s.iter_mut().enumerate() {
            *v = mix64(key.wrapping_add((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        }
        if s == [0; 4] {
            s[0] = 1; // the one state xoshiro cannot leave
        }
        WalkRng { s }
    }

    /// The generator with this state (one lane of the wide walk).
    #[inline(always)]
    pub(crate) fn from_state(s: [u64; 4]) -> Self {
        WalkRng { s }
    }

    #[inline(always)]
    pub(crate) fn state(&self) -> [u64; 4] {
        self.s
    }

    #[inline(always)]
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let r = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        r
    }

    /// The high 32 bits of one step.
    #[inline(always)]
    pub fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    /// Uniform in [0, 1), 24 bits (one step).
    #[inline(always)]
    pub fn uniform(&mut self) -> f32 {
        unit_f32((self.next_u64() >> 32) as u32)
    }
}

/// The top 24 bits of `bits` as a uniform number in [0, 1).
#[inline(always)]
pub fn unit_f32(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// A unit-mean exponential variate, -ln(v), from 32 random bits, with
/// v = (bits + 1) / 2^32 in (0, 1]. The logarithm is computed inline in f64,
/// without a division or libm call (the walk's free flights take one per
/// event): bits + 1 = 2^k m with m in [M0, 2 M0), M0 = 0.703; a table holds
/// 1/c and ln c for 64 subintervals of m (c = 1 for the two that touch 1, so
/// values near 1 lose nothing to cancellation), and ln(m / c) = ln(1 + r),
/// with |r| < 1/64, comes from its series to r^4 (truncation < 2e-10).
/// Relative error below 1e-7 after rounding to f32.
#[inline(always)]
pub fn exp1_from_bits(bits: u32) -> f32 {
    let x = (bits as u64 + 1) as f64;
    let b = x.to_bits();
    let t = b.wrapping_sub(LN_OFF);
    let k = (t >> 52) as i64 - 32; // the 2^-32 of v
    let i = ((t >> (52 - LN_BITS)) & ((1 << LN_BITS) - 1)) as usize;
    let m = f64::from_bits(b.wrapping_sub(t & 0xFFF0_0000_0000_0000));
    let (inv_c, ln_c) = LN_TABLE[i];
    let r = m * inv_c - 1.0;
    let r2 = r * r;
    let ln1p = r + r2 * (-0.5 + r * (1.0 / 3.0)) - r2 * r2 * 0.25;
    (-(k as f64 * std::f64::consts::LN_2 + ln_c + ln1p)) as f32
}

/// log2 of the logarithm table's size.
const LN_BITS: u32 = 6;
/// Bits of M0 = 0.703125, where the table's mantissa range starts; 1.0 falls
/// on the boundary of subintervals 37 and 38.
const LN_OFF: u64 = 0x3FE6_8000_0000_0000;
/// (1 / c, ln c) per subinterval, computed at compile time.
static LN_TABLE: [(f64, f64); 1 << LN_BITS] = ln_table();

/// ln c = 2 atanh((c - 1) / (c + 1)) by its series (|s| < 0.18: 30 terms are
/// exact in f64).
const fn ln_series(c: f64) -> f64 {
    let s = (c - 1.0) / (c + 1.0);
    let s2 = s * s;
    let (mut term, mut sum, mut k) = (s, 0.0, 0);
    while k < 30 {
        sum += term / (2 * k + 1) as f64;
        term *= s2;
        k += 1;
    }
    2.0 * sum
}

const fn ln_table() -> [(f64, f64); 1 << LN_BITS] {
    let mut t = [(0.0, 0.0); 1 << LN_BITS];
    let mut i = 0;
    while i < t.len() {
        let lo = f64::from_bits(LN_OFF + ((i as u64) << (52 - LN_BITS)));
        let hi = f64::from_bits(LN_OFF + ((i as u64 + 1) << (52 - LN_BITS)));
        // the centre, except next to 1 (where ln v itself is small)
        let c = if lo == 1.0 || hi == 1.0 {
            1.0
        } else {
            f64::from_bits(LN_OFF + ((2 * i as u64 + 1) << (51 - LN_BITS)))
        };
        t[i] = (1.0 / c, ln_series(c));
        i += 1;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_mean_and_range() {
        let mut r = Rng::new(7, 3);
        let n = 200_000;
        let mut s = 0.0f64;
        for _ in 0..n {
            let u = r.uniform();
            assert!((0.0..1.0).contains(&u));
            s += u as f64;
        }
        // sd of the mean = sqrt(1/12/n) = 6.5e-4
        assert!((s / n as f64 - 0.5).abs() < 3e-3);
    }

    #[test]
    fn exp1_matches_the_logarithm() {
        let mut r = WalkRng::new(3, 4);
        let edge = (0..2000u32).flat_map(|j| [j, u32::MAX - j, 1 << (j % 32)]);
        let random = (0..2_000_000).map(|_| r.next_u32());
        for bits in edge.chain(random) {
            let exact = -((bits as f64 + 1.0) / 4_294_967_296.0).ln();
            let e = exp1_from_bits(bits) as f64;
            assert!(
                (e - exact).abs() <= 1e-7 * exact + 1e-12,
                "{bits}: {e} vs {exact}"
            );
        }
        // mean 1, variance 1
        let n = 400_000;
        let xs: Vec<f64> = (0..n)
            .map(|_| exp1_from_bits(r.next_u32()) as f64)
            .collect();
        let m = xs.iter().sum::<f64>() / n as f64;
        let v = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n as f64;
        assert!((m - 1.0).abs() < 0.008 && (v - 1.0).abs() < 0.03, "{m} {v}");
    }

    #[test]
    fn walk_streams_differ_and_repeat() {
        let take = |seed, stream| {
            let mut r = WalkRng::new(seed, stream);
            (0..8).map(|_| r.next_u64()).collect::<Vec<_>>()
        };
        assert_eq!(take(1, 0), take(1, 0));
        assert_ne!(take(1, 0), take(1, 1));
        assert_ne!(take(1, 0), take(2, 0));
        let mut r = WalkRng::new(7, 3);
        let n = 200_000;
        let s: f64 = (0..n).map(|_| r.uniform() as f64).sum();
        assert!((s / n as f64 - 0.5).abs() < 3e-3);
    }

    #[test]
    fn streams_differ_and_repeat() {
        let a: Vec<u32> = (0..8)
            .map({
                let mut r = Rng::new(1, 0);
                move |_| r.next_u32()
            })
            .collect();
        let b: Vec<u32> = (0..8)
            .map({
                let mut r = Rng::new(1, 1);
                move |_| r.next_u32()
            })
            .collect();
        let a2: Vec<u32> = (0..8)
            .map({
                let mut r = Rng::new(1, 0);
                move |_| r.next_u32()
            })
            .collect();
        assert_ne!(a, b);
        assert_eq!(a, a2);
    }

    #[test]
    fn poisson_mean_and_variance() {
        let mut r = Rng::new(11, 0);
        for lambda in [0.5, 4.0, 80.0] {
            let n = 40_000;
            let xs: Vec<f64> = (0..n).map(|_| r.poisson(lambda)).collect();
            let m = xs.iter().sum::<f64>() / n as f64;
            let v = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n as f64;
            assert!(
                (m - lambda).abs() < 4.0 * (lambda / n as f64).sqrt() + 0.01,
                "{lambda} {m}"
            );
            assert!((v / lambda - 1.0).abs() < 0.08, "{lambda} {v}");
        }
    }
}
