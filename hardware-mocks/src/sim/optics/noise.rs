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

/// Approximately standard normal numbers, from a seed: the Irwin–Hall sum of four uniforms
/// (16 bits each, from one 64-bit draw), centred and scaled to unit variance. Bounded at ±3.46σ,
/// which is fine for camera noise and several times cheaper than Box–Muller per pixel.
pub(crate) struct Gaussian {
    state: u64,
}

impl Gaussian {
    pub fn new(seed: u64) -> Self {
        Self {
            state: seed ^ 0x5DEE_CE66_D1CE_4E5B,
        }
    }

    pub fn next(&mut self) -> f64 {
        let r = splitmix64(&mut self.state);
        let sum: u64 = (0..4).map(|k| (r >> (16 * k)) & 0xFFFF).sum();
        // Each 16-bit part is uniform on [0, 65535]: mean 4 · 32767.5, variance 4 · (2¹⁶² − 1)/12.
        const MEAN: f64 = 4.0 * 32767.5;
        const SD: f64 = 37837.22; // √(4 · (65536² − 1) / 12)
        (sum as f64 - MEAN) / SD
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_has_unit_variance_and_is_reproducible() {
        let mut g = Gaussian::new(3);
        let xs: Vec<f64> = (0..20_000).map(|_| g.next()).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(mean.abs() < 0.03, "{mean}");
        assert!((var - 1.0).abs() < 0.05, "{var}");
        assert_eq!(Gaussian::new(3).next(), xs[0]);
        assert_ne!(Gaussian::new(4).next(), xs[0]);
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
