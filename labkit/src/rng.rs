//! The lab's seeded random numbers (worlds, datasets, training).

/// SplitMix64: small, seedable, identical on every platform (the simulator's only randomness).
#[derive(Clone, Debug)]
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in (0, 1].
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 1.0) * (1.0 / (1u64 << 53) as f64)
    }
    pub fn gaussian(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

impl Rng {
    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (1.0 - self.uniform())
    }
    /// Uniform integer in [lo, hi] (the whole of u64 for `int(0, u64::MAX)`, whose span does not
    /// fit in a u64).
    pub fn int(&mut self, lo: u64, hi: u64) -> u64 {
        match (hi - lo).checked_add(1) {
            Some(span) => lo + self.next_u64() % span,
            None => self.next_u64(),
        }
    }
    /// True with probability p.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() <= p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_integer_over_the_whole_range_does_not_divide_by_zero() {
        let mut a = Rng(3);
        let mut b = Rng(3);
        assert_eq!(a.int(0, u64::MAX), b.next_u64());
        assert!((5..=9).contains(&a.int(5, 9)));
    }
}
