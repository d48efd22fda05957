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
/// scaled to unit variance. Bounded at ±3.25σ, which is fine for camera noise and several times
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

    /// Four approximately standard normal numbers from one 64-bit draw: each the Irwin–Hall sum
    /// of four 4-bit uniforms, centred and scaled. That is 61 values 0.11σ apart, bounded at
    /// ±3.25σ: plenty for camera noise of a few 8-bit levels, where one level is well over
    /// 0.11σ. The sixteen nibbles are summed in parallel within the word (pairs into bytes, then
    /// pairs of bytes into 16-bit lanes), a handful of operations for all four.
    pub fn next_quad(&mut self) -> [f32; 4] {
        let r = splitmix64(&mut self.state);
        // Each nibble is uniform on [0, 15]: a sum of four has mean 30 and variance
        // 4 · (16² − 1)/12 = 85.
        const MEAN: f32 = 30.0;
        const INV_SD: f32 = 0.108_465_24; // 1/√85
        let pairs = (r & 0x0F0F_0F0F_0F0F_0F0F) + ((r >> 4) & 0x0F0F_0F0F_0F0F_0F0F);
        let quads = (pairs & 0x00FF_00FF_00FF_00FF) + ((pairs >> 8) & 0x00FF_00FF_00FF_00FF);
        let lane = |k: u32| (((quads >> (16 * k)) & 0xFFFF) as f32 - MEAN) * INV_SD;
        [lane(0), lane(1), lane(2), lane(3)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_quads_have_unit_variance_and_no_correlation() {
        let mut g = Gaussian::new(5);
        let quads: Vec<[f32; 4]> = (0..20_000).map(|_| g.next_quad()).collect();
        for k in 0..4 {
            let xs: Vec<f64> = quads.iter().map(|q| f64::from(q[k])).collect();
            let mean = xs.iter().sum::<f64>() / xs.len() as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
            assert!(mean.abs() < 0.03, "lane {k}: mean {mean}");
            assert!((var - 1.0).abs() < 0.05, "lane {k}: variance {var}");
            // Bounded at (60 − 30)/√85 = 3.254σ, and the bound is reached only rarely.
            assert!(xs.iter().all(|x| x.abs() <= 3.2540001), "lane {k}");
            let beyond_2 = xs.iter().filter(|x| x.abs() > 2.0).count() as f64 / xs.len() as f64;
            assert!(
                (beyond_2 - 0.0455).abs() < 0.01,
                "lane {k}: {beyond_2} beyond 2σ"
            );
        }
        // The lanes of one draw, and successive draws, are uncorrelated.
        for (a, b) in [(0, 1), (1, 2), (2, 3), (0, 3)] {
            let cov = quads.iter().map(|q| f64::from(q[a] * q[b])).sum::<f64>() / 20_000.0;
            assert!(cov.abs() < 0.03, "lanes {a}, {b}: {cov}");
        }
        let lag = quads
            .windows(2)
            .map(|w| f64::from(w[0][0] * w[1][0]))
            .sum::<f64>()
            / 19_999.0;
        assert!(lag.abs() < 0.03, "{lag}");
        // The same seed gives the same numbers; another seed others.
        assert_eq!(Gaussian::new(5).next_quad(), quads[0]);
        assert_ne!(Gaussian::new(6).next_quad(), quads[0]);
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
