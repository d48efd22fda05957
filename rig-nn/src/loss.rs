//! The losses of the trainer: TransForce's γ-weighted L1 for the force model, least squares
//! (LSGAN) and L1 for the CycleGAN.

use burn::tensor::Tensor;

/// The γ-weighted L1 loss of TransForce: Σ_i γ^(T−i) · |F^i − F̂^i|_1 over the T frames of a
/// sequence (i = 1..T, so the last frame weighs 1), averaged over the batch.
/// `pred` and `truth` are `[B, T, 3]`.
pub fn gamma_l1(pred: Tensor<3>, truth: Tensor<3>, gamma: f64) -> Tensor<1> {
    let [b, t, _] = pred.dims();
    let weights: Vec<f32> = (1..=t).map(|i| gamma.powi((t - i) as i32) as f32).collect();
    let w = Tensor::<1>::from_floats(weights.as_slice(), &pred.device()).reshape([1, t, 1]);
    let per = (pred - truth).abs() * w;
    per.sum().div_scalar(b.max(1) as f64).reshape([1])
}

/// Least-squares GAN loss: mean (D(x) − target)².
pub fn lsgan(scores: Tensor<4>, target: f32) -> Tensor<1> {
    (scores - target).powi_scalar(2).mean().reshape([1])
}

/// Mean absolute difference.
pub fn l1(a: Tensor<4>, b: Tensor<4>) -> Tensor<1> {
    (a - b).abs().mean().reshape([1])
}

#[cfg(test)]
mod tests {
    use burn::tensor::TensorData;

    use super::*;
    use crate::testing::{close, dev, values};

    #[test]
    fn gamma_weighted_l1_weighs_the_last_frame_most() {
        let pred = Tensor::<3>::zeros([2, 3, 3], &dev());
        let one = [1f32, 0., 0., 0., 2., 0., 0., 0., -3.];
        let truth = Tensor::<3>::from_data(TensorData::new([one, one].concat(), [2, 3, 3]), &dev());
        // γ = 0.8, T = 3: weights 0.64, 0.8, 1 → 0.64·1 + 0.8·2 + 1·3 = 5.24 per sequence; the
        // batch mean of two equal sequences is the same.
        let l = values(gamma_l1(pred.clone(), truth.clone(), 0.8));
        close(&l, &[5.24], 1e-5);
        // γ = 1 is the plain summed L1: 1 + 2 + 3.
        close(&values(gamma_l1(pred, truth, 1.0)), &[6.0], 1e-5);
    }
}
