//! Sequences and batches for training: which frames of which trajectories make a sequence,
//! and images in and out of burn tensors. Deterministic from a seed.

use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

use super::data::ImageSpec;

/// A small deterministic PRNG (SplitMix64), so that runs are reproducible from a seed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            v.swap(i, self.below(i + 1));
        }
    }
}

/// A sequence: T frame indices of one trajectory, in time order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sequence {
    pub traj: usize,
    pub frames: Vec<usize>,
}

/// At each trajectory, draw `k` sequences of `t` distinct frames in time order (the paper:
/// T = 8, K = 4). Trajectories with fewer than `t` frames give none.
pub fn sample_sequences(lengths: &[usize], t: usize, k: usize, rng: &mut Rng) -> Vec<Sequence> {
    let mut out = Vec::new();
    for (traj, &n) in lengths.iter().enumerate() {
        if t == 0 || n < t {
            continue;
        }
        for _ in 0..k {
            // Partial Fisher-Yates: the first t of a shuffled 0..n, then sorted.
            let mut idx: Vec<usize> = (0..n).collect();
            for i in 0..t {
                let j = i + rng.below(n - i);
                idx.swap(i, j);
            }
            let mut frames = idx[..t].to_vec();
            frames.sort_unstable();
            out.push(Sequence { traj, frames });
        }
    }
    out
}

/// RGB u8 frames (HWC) to an NCHW tensor in [-1, 1].
pub fn images_to_tensor(frames: &[&[u8]], spec: &ImageSpec, dev: &Device) -> Tensor<4> {
    let (w, h) = (spec.width as usize, spec.height as usize);
    let mut v = vec![0f32; frames.len() * 3 * w * h];
    for (n, f) in frames.iter().enumerate() {
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    v[((n * 3 + c) * h + y) * w + x] = f[(y * w + x) * 3 + c] as f32 / 127.5 - 1.0;
                }
            }
        }
    }
    Tensor::from_data(TensorData::new(v, [frames.len(), 3, h, w]), dev)
}

/// An NCHW tensor in [-1, 1] back to RGB u8 frames (HWC), clamped.
pub fn tensor_to_images(t: Tensor<4>) -> Vec<Vec<u8>> {
    let [n, c, h, w] = t.dims();
    let v: Vec<f32> = t
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32 tensor");
    (0..n)
        .map(|i| {
            let mut out = vec![0u8; h * w * 3];
            for y in 0..h {
                for x in 0..w {
                    for ch in 0..c.min(3) {
                        let val = v[((i * c + ch) * h + y) * w + x];
                        out[(y * w + x) * 3 + ch] =
                            ((val + 1.0) * 127.5).round().clamp(0.0, 255.0) as u8;
                    }
                }
            }
            out
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::modality::Modality;

    #[test]
    fn sequences_are_sorted_distinct_and_deterministic() {
        let lens = [20, 5, 8, 3];
        let a = sample_sequences(&lens, 8, 4, &mut Rng(7));
        let b = sample_sequences(&lens, 8, 4, &mut Rng(7));
        assert_eq!(a, b);
        // 20 and 8 frames give 4 each; 5 and 3 are too short.
        assert_eq!(a.len(), 8);
        for s in &a {
            assert_eq!(s.frames.len(), 8);
            assert!(s.frames.windows(2).all(|w| w[0] < w[1]));
            assert!(*s.frames.last().unwrap() < lens[s.traj]);
        }
        // Exactly 8 of 8 frames: the whole trajectory.
        assert!(
            a.iter()
                .filter(|s| s.traj == 2)
                .all(|s| s.frames == (0..8).collect::<Vec<_>>())
        );
        assert_ne!(a, sample_sequences(&lens, 8, 4, &mut Rng(8)));
    }

    #[test]
    fn image_tensor_round_trip_is_exact() {
        let spec = ImageSpec {
            width: 4,
            height: 3,
            modality: Modality::RgbMarker,
        };
        let a: Vec<u8> = (0..36).map(|i| (i * 7) as u8).collect();
        let b: Vec<u8> = (0..36).map(|i| 255 - i as u8).collect();
        let t = images_to_tensor(&[&a, &b], &spec, &Device::flex());
        assert_eq!(t.dims(), [2, 3, 3, 4]);
        assert_eq!(tensor_to_images(t), vec![a, b]);
    }
}
