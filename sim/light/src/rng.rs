//! Seeded random numbers for the photon walks: PCG32 (O'Neill 2014).
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
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// Uniform in [0, 1), 53 bits.
    pub fn uniform_f64(&mut self) -> f64 {
        let hi = (self.next_u32() as u64) << 21;
        let lo = (self.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }

    /// Standard normal (Box-Muller).
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
