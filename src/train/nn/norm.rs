//! Batch norm in training mode on the CPU, forward and backward on our own loops, through a
//! burn backend extension (as [`super::conv`] does for the convolution).
//!
//! burn computes a training batch norm from generic tensor operations: the statistics of each
//! channel come from `swap_dims(0, 1)` and a reshape, which on the flex backend is a full
//! transposing copy of the activation, three of them forward and backward per layer. A profile
//! of the ResNet-18 training step after the convolution moved to [`super::conv`] had a sixth of
//! its time in those copies. Here every channel of an NCHW tensor is `N` contiguous runs of
//! `H·W` values, read in place:
//!
//! - **forward:** per channel the mean `μ` and biased variance `σ²` over `N·H·W` values (two
//!   passes, sums in f64), then `y = γ (x − μ) / √(σ² + ε) + β`;
//! - **backward** (Ioffe and Szegedy 2015, §3): with `x̂ = (x − μ) / √(σ² + ε)` and `m = N·H·W`,
//!   `dβ = Σ dy`, `dγ = Σ dy·x̂`, `dx = γ / √(σ² + ε) · (dy − dβ/m − x̂·dγ/m)`.
//!
//! The mean and biased variance are returned too, untracked, for the running statistics, which
//! [`batch_norm`] updates exactly as `BatchNorm::forward` does in training. Outside training
//! (no autodiff, or the layer frozen) and off the flex device, `BatchNorm::forward` runs.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, Flex, backend_extension,
};
use burn::nn::BatchNorm;
use burn::tensor::Tensor;
use rayon::prelude::*;

use super::conv::{dense, flex, on_cpu_kernels};

/// A training batch norm's output and the batch statistics it used.
#[derive(ExtensionType)]
pub struct NormOut<B: Backend> {
    pub output: FloatTensor<B>,
    pub mean: FloatTensor<B>,
    pub variance: FloatTensor<B>,
}

/// Batch norm in training mode as a backend operation (NCHW or any `[N, C, ...]`).
#[backend_extension(Flex, Autodiff)]
pub trait TrainNorm: Backend {
    fn train_batch_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> NormOut<Self>;
}

impl TrainNorm for Flex {
    fn train_batch_norm(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        epsilon: f64,
    ) -> NormOut<Self> {
        let shape = x.layout().shape().clone();
        let g = Planes::of(&x);
        let xs = dense(&x);
        let (mean, var) = stats(&g, &xs);
        let y = normalise(&g, &xs, &dense(&gamma), &dense(&beta), &mean, &var, epsilon);
        NormOut {
            output: FlexTensor::from_data(burn::tensor::TensorData::new(y, shape)),
            mean: flex(mean, [g.c]),
            variance: flex(var, [g.c]),
        }
    }
}

/// `[N, C, rest…]` as `N·C` planes of `len` values.
#[derive(Debug, Clone, Copy)]
struct Planes {
    n: usize,
    c: usize,
    len: usize,
}

impl Planes {
    fn of(x: &FlexTensor) -> Self {
        let dims = x.layout().shape().as_slice().to_vec();
        assert!(
            dims.len() >= 2,
            "train_batch_norm: input {dims:?} has no channel axis"
        );
        Self {
            n: dims[0],
            c: dims[1],
            len: dims[2..].iter().product(),
        }
    }

    fn count(&self) -> f64 {
        (self.n * self.len).max(1) as f64
    }
}

/// Per channel: mean and biased variance, two passes with f64 sums.
fn stats(g: &Planes, x: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let per: Vec<(f32, f32)> = (0..g.c)
        .into_par_iter()
        .map(|c| {
            let planes = || (0..g.n).map(move |n| &x[(n * g.c + c) * g.len..][..g.len]);
            let sum: f64 = planes()
                .map(|p| p.iter().map(|&v| v as f64).sum::<f64>())
                .sum();
            let mean = sum / g.count();
            let sq: f64 = planes()
                .map(|p| p.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>())
                .sum();
            (mean as f32, (sq / g.count()) as f32)
        })
        .collect();
    per.into_iter().unzip()
}

fn normalise(
    g: &Planes,
    x: &[f32],
    gamma: &[f32],
    beta: &[f32],
    mean: &[f32],
    var: &[f32],
    eps: f64,
) -> Vec<f32> {
    let mut y = vec![0.0f32; x.len()];
    if g.len == 0 {
        return y;
    }
    y.par_chunks_mut(g.len)
        .zip(x.par_chunks(g.len))
        .enumerate()
        .for_each(|(i, (yp, xp))| {
            let c = i % g.c;
            // `(x − μ)` first: exact for values near μ, where `x·s + (β − μ·s)` would cancel.
            let (mu, scale) = (mean[c], gamma[c] / ((var[c] as f64 + eps).sqrt() as f32));
            for (o, &v) in yp.iter_mut().zip(xp) {
                *o = (v - mu) * scale + beta[c];
            }
        });
    y
}

/// The backward step's state: input, γ, and the batch statistics.
#[derive(Debug)]
struct NormBackward;

impl Backward<Flex, 3> for NormBackward {
    type State = (FlexTensor, FlexTensor, FlexTensor, FlexTensor, f64);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_gamma, node_beta] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, gamma, mean, var, eps) = ops.state;
        let g = Planes::of(&x);
        let shape = x.layout().shape().clone();
        let (x, dy, gamma) = (dense(&x), dense(&dy), dense(&gamma));
        let (mean, var) = (dense(&mean), dense(&var));
        let inv: Vec<f32> = var
            .iter()
            .map(|&v| 1.0 / ((v as f64 + eps).sqrt() as f32))
            .collect();
        // Per channel Σ dy and Σ dy·x̂.
        let sums: Vec<(f64, f64)> = (0..g.c)
            .into_par_iter()
            .map(|c| {
                let (mut db, mut dg) = (0.0f64, 0.0f64);
                for n in 0..g.n {
                    let at = (n * g.c + c) * g.len;
                    for (&d, &v) in dy[at..at + g.len].iter().zip(&x[at..at + g.len]) {
                        db += d as f64;
                        dg += d as f64 * ((v - mean[c]) * inv[c]) as f64;
                    }
                }
                (db, dg)
            })
            .collect();
        if let Some(node) = node_x {
            let m = g.count();
            let mut dx = vec![0.0f32; x.len()];
            if g.len > 0 {
                dx.par_chunks_mut(g.len).enumerate().for_each(|(i, dxp)| {
                    let c = i % g.c;
                    let at = i * g.len;
                    let k = gamma[c] * inv[c];
                    let mdb = (sums[c].0 / m) as f32;
                    let mdg = (sums[c].1 / m) as f32;
                    for ((o, &d), &v) in dxp.iter_mut().zip(&dy[at..]).zip(&x[at..]) {
                        *o = k * (d - mdb - (v - mean[c]) * inv[c] * mdg);
                    }
                });
            }
            grads.register::<Flex>(
                node.id,
                FlexTensor::from_data(burn::tensor::TensorData::new(dx, shape)),
            );
        }
        if let Some(node) = node_gamma {
            grads.register::<Flex>(
                node.id,
                flex(sums.iter().map(|s| s.1 as f32).collect(), [g.c]),
            );
        }
        if let Some(node) = node_beta {
            grads.register::<Flex>(
                node.id,
                flex(sums.iter().map(|s| s.0 as f32).collect(), [g.c]),
            );
        }
    }
}

impl<C: CheckpointStrategy> TrainNorm for Autodiff<Flex, C> {
    fn train_batch_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> NormOut<Self> {
        let out = Flex::train_batch_norm(
            x.primitive().clone(),
            gamma.primitive().clone(),
            beta.primitive().clone(),
            epsilon,
        );
        let output = match NormBackward
            .prepare::<C>([x.node(), gamma.node(), beta.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(
                (
                    x.into_primitive(),
                    gamma.into_primitive(),
                    out.mean.clone(),
                    out.variance.clone(),
                    epsilon,
                ),
                out.output,
            ),
            OpsKind::UnTracked(prep) => prep.finish(out.output),
        };
        NormOut {
            output,
            mean: Self::from_inner(out.mean),
            variance: Self::from_inner(out.variance),
        }
    }
}

/// `bn.forward(x)`: in training on the flex device through this module's loops (and the running
/// statistics updated as burn does: `r ← (1 − momentum) r + momentum · batch`), else burn's.
pub fn batch_norm<const D: usize>(bn: &BatchNorm, x: Tensor<D>) -> Tensor<D> {
    let dev = x.device();
    let training = dev.is_autodiff() && bn.training.is_enabled();
    if !training || !on_cpu_kernels(&x) {
        return bn.forward(x);
    }
    let out = <Dispatch as TrainNorm>::train_batch_norm(
        x.into_dispatch(),
        bn.gamma.val().into_dispatch(),
        bn.beta.val().into_dispatch(),
        bn.epsilon,
    );
    let m = bn.momentum;
    for (running, batch) in [
        (&bn.running_mean, out.mean),
        (&bn.running_var, out.variance),
    ] {
        let batch = Tensor::<1>::from_dispatch(batch).detach();
        let r = running.value_sync().to_device(&dev);
        running.update(r.mul_scalar(1.0 - m).add(batch.mul_scalar(m)).detach());
    }
    Tensor::from_dispatch(out.output)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::BatchNormConfig;
    use burn::tensor::{Device, Distribution};

    use crate::train::nn::tests::{close_to_largest as close, values};

    /// Ours against burn's `BatchNorm::forward` in training: output, the three gradients of
    /// `Σ y ⊙ r`, and the running statistics after two steps.
    fn check(dims: [usize; 4], offset: f32, spread: f32) {
        let dev = Device::flex().autodiff();
        let what = format!("{dims:?} offset {offset} spread {spread}");
        let x = Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &dev)
            .mul_scalar(spread)
            .add_scalar(offset);
        let r = Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &dev);
        let mut got = Vec::new();
        for ours in [true, false] {
            let mut bn: BatchNorm = BatchNormConfig::new(dims[1]).init(&dev);
            // Non-trivial affine parameters, the same for both.
            bn.gamma = bn
                .gamma
                .map(|g| g.mul_scalar(1.5).add_scalar(-0.25).detach().require_grad());
            bn.beta = bn.beta.map(|b| b.add_scalar(0.3).detach().require_grad());
            let mut out = Vec::new();
            for _ in 0..2 {
                let xi = x.clone().detach().require_grad();
                let y = if ours {
                    batch_norm(&bn, xi.clone())
                } else {
                    bn.forward(xi.clone())
                };
                let grads = (y.clone() * r.clone()).sum().backward();
                out = vec![
                    values(y),
                    values(xi.grad(&grads).unwrap()),
                    values(bn.gamma.val().grad(&grads).unwrap()),
                    values(bn.beta.val().grad(&grads).unwrap()),
                ];
            }
            out.push(values(bn.running_mean.value()));
            out.push(values(bn.running_var.value()));
            got.push(out);
        }
        for (i, part) in ["y", "dx", "dgamma", "dbeta", "running mean", "running var"]
            .iter()
            .enumerate()
        {
            close(&format!("{what}: {part}"), &got[0][i], &got[1][i]);
        }
    }

    #[test]
    fn the_training_batch_norm_matches_burns_values_gradients_and_running_statistics() {
        check([4, 3, 5, 6], 0.0, 1.0);
        // One pixel, three images: three values a channel. (With two, x̂ = ±1 whatever x is
        // and dx is rounding noise around zero in both implementations.)
        check([3, 5, 1, 1], 0.0, 1.0);
        check([1, 2, 7, 3], 0.0, 1.0);
    }

    #[test]
    fn a_large_offset_with_a_small_spread_keeps_the_variance() {
        // Values 1000 ± 0.01: one-pass f32 statistics (E[x²] − E[x]²) lose the variance
        // entirely here (x² ≈ 1e6, its f32 spacing 0.06 against a variance of 1e-4). The
        // normalised output must still have zero mean and the variance ε leaves it.
        let dev = Device::flex().autodiff();
        let x = Tensor::<4>::random([8, 2, 6, 6], Distribution::Normal(0.0, 1.0), &dev)
            .mul_scalar(0.01)
            .add_scalar(1000.0);
        let bn: BatchNorm = BatchNormConfig::new(2).init(&dev);
        let xs = values(x.clone());
        let y = values(batch_norm(&bn, x.require_grad()));
        let channel = |v: &[f32], c: usize| -> Vec<f64> {
            (0..8)
                .flat_map(|n| v[(n * 2 + c) * 36..][..36].to_vec())
                .map(|v| v as f64)
                .collect()
        };
        let moments = |v: &[f64]| {
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / v.len() as f64;
            (mean, var)
        };
        for c in 0..2 {
            let (mean, var) = moments(&channel(&y, c));
            let (_, s2) = moments(&channel(&xs, c));
            // The output's variance is s² / (s² + ε) for the sample variance s² of the input
            // (about 1e-4; ε = 1e-5), up to f32 rounding of the output (1e-7 relative).
            // The mean is exact but for μ rounded to f32: half the f32 spacing at 1000
            // (3.05e-5) over the scale √(s² + ε) ≈ 0.0105 leaves at most 0.0029 of offset.
            assert!(mean.abs() < 3e-3, "channel {c}: mean {mean}");
            let want = s2 / (s2 + 1e-5);
            assert!(
                (var - want).abs() < 1e-4,
                "channel {c}: variance {var}, want {want}"
            );
        }
    }
}
