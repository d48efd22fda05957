//! Small seeded random numbers for the renderer (marker jitter, sensor noise), so images are
//! reproducible from a seed without a random-number dependency.

/// SplitMix64 step (Steele, Lea & Flood 2014): a fast, well-mixed 64-bit generator.
pub(crate) fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform number in `[0, 1)` that depends only on `(seed, key, stream)`.
pub(crate) fn hash_unit(seed: u64, key: u64, stream: u64) -> f64 {
    let mut s = seed ^ key.wrapping_mul(0xD6E8_FEB8_6659_FD93) ^ stream.rotate_left(17);
    splitmix64(&mut s);
    to_unit(splitmix64(&mut s))
}

fn to_unit(x: u64) -> f64 {
    (x >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Approximately standard normal numbers, from a seed: Irwin–Hall sums of uniforms, centred and
/// scaled to unit variance. Bounded at ±3.46σ, which is fine for camera noise and several times
/// cheaper than Box–Muller per pixel.
pub(crate) struct Gaussian {
    state: u64,
}

impl Gaussian {
    pub fn new(seed: u64) -> Self {
        Self {
            state: seed ^ 0x5DEE_CE66_D1CE_4E5B,
        }
    }

    /// Two approximately standard normal numbers from one draw: each the Irwin–Hall sum of four
    /// 8-bit uniforms, centred and scaled (bounded at ±3.46σ, 1021 levels: plenty for camera
    /// noise of a few 8-bit levels, from one 64-bit draw).
    pub fn next_pair(&mut self) -> [f32; 2] {
        let r = splitmix64(&mut self.state);
        // Each byte is uniform on [0, 255]: a sum of four has mean 510 and variance
        // 4 · (256² − 1)/12.
        const MEAN: f32 = 510.0;
        const SD: f32 = 147.796_48; // √(4 · 65535 / 12)
        let sum = |x: u64| {
            ((x & 0xFF) + ((x >> 8) & 0xFF) + ((x >> 16) & 0xFF) + ((x >> 24) & 0xFF)) as f32
        };
        [(sum(r) - MEAN) / SD, (sum(r >> 32) - MEAN) / SD]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_pairs_have_unit_variance_and_no_correlation() {
        let mut g = Gaussian::new(5);
        let pairs: Vec<[f32; 2]> = (0..20_000).map(|_| g.next_pair()).collect();
        for k in 0..2 {
            let xs: Vec<f64> = pairs.iter().map(|p| f64::from(p[k])).collect();
            let mean = xs.iter().sum::<f64>() / xs.len() as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
            assert!(mean.abs() < 0.03, "{mean}");
            assert!((var - 1.0).abs() < 0.05, "{var}");
        }
        let cov = pairs.iter().map(|p| f64::from(p[0] * p[1])).sum::<f64>() / 20_000.0;
        assert!(cov.abs() < 0.03, "{cov}");
        // The same seed gives the same numbers; another seed others.
        assert_eq!(Gaussian::new(5).next_pair(), pairs[0]);
        assert_ne!(Gaussian::new(6).next_pair(), pairs[0]);
    }

    #[test]
    fn hash_unit_is_in_range_and_depends_on_every_input() {
        let a = hash_unit(1, 2, 0);
        assert!((0.0..1.0).contains(&a));
        assert_ne!(a, hash_unit(2, 2, 0));
        assert_ne!(a, hash_unit(1, 3, 0));
        assert_ne!(a, hash_unit(1, 2, 1));
    }
}
