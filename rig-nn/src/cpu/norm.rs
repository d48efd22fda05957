//! Batch norm in training mode on the CPU, forward and backward on our own loops, through a
//! burn backend extension (as [`super::conv`] does for the convolution), with the residual
//! addition and the ReLU that follow it in a ResNet fused in.
//!
//! burn computes a training batch norm from generic tensor operations: the statistics of each
//! channel come from `swap_dims(0, 1)` and a reshape, which on the flex backend is a full
//! transposing copy of the activation, three of them forward and backward per layer. A profile
//! of the ResNet-18 training step after the convolution moved to [`super::conv`] had a sixth of
//! its time in those copies. Here every channel of an NCHW tensor is `N` contiguous runs of
//! `H·W` values, read in place:
//!
//! - **forward:** per channel the mean `μ` and biased variance `σ²` over `N·H·W` values (two
//!   passes, sums in f64), then `z = γ (x − μ) / √(σ² + ε) + β (+ r)` and `y = z` or
//!   `y = max(z, 0)`, in one pass: the ResNet's `relu(bn(x) + shortcut)` without the two
//!   passes and two activations the separate addition and ReLU would cost;
//! - **backward** (Ioffe and Szegedy 2015, §3): through the ReLU `dz = dy` where `y > 0` (and
//!   where `y` is NaN, as burn's `relu_backward` keeps it), else 0; `dr = dz`; with
//!   `x̂ = (x − μ) / √(σ² + ε)` and `m = N·H·W`, `dβ = Σ dz`, `dγ = Σ dz·x̂`,
//!   `dx = γ / √(σ² + ε) · (dz − dβ/m − x̂·dγ/m)`, in two passes: the sums (f32 blocks of 16
//!   terms a lane, carried into f64), then `dx` (and `dr` when the residual wants it), `dz`
//!   computed where it is read rather than written out first.
//!
//! Both run a channel a task, and each reads a channel's planes twice: the statistics (or the
//! sums) in image order, then the output (or `dx`) in reverse image order, so that the planes
//! read last are still in the core's cache when the second pass starts. The loops themselves
//! are [`super::lanes`]'s, compiled for the widest vector unit the CPU has.
//!
//! The mean and biased variance are returned too, untracked, for the running statistics, which
//! [`batch_norm`] updates exactly as `BatchNorm::forward` does in training. Outside training
//! (no autodiff, or the layer frozen) and off the flex device, burn's `BatchNorm::forward`, its
//! addition and its ReLU run.

use std::borrow::Cow;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, NodeGuard, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, Flex, backend_extension,
};
use burn::nn::{BatchNorm, InstanceNorm};
use burn::tensor::Tensor;
use burn::tensor::activation::relu;
use rayon::prelude::*;

use super::conv::on_cpu_kernels;
use super::kernels::{dense, flex, map2, unwritten, written};
use super::lanes::{
    PlaneGrad, PlaneMap, Slot, activation_grad, grad_plane, grad_sums, norm_plane, plane_sq,
    plane_sum,
};

/// A training batch norm's output and the batch statistics it used.
#[derive(ExtensionType)]
pub struct NormOut<B: Backend> {
    pub output: FloatTensor<B>,
    pub mean: FloatTensor<B>,
    pub variance: FloatTensor<B>,
}

/// Batch norm in training mode as a backend operation (NCHW or any `[N, C, ...]`), then a
/// ReLU if `relu`; `train_batch_norm_add` adds `residual` (the input's shape) before the ReLU.
#[backend_extension(Flex, Autodiff)]
pub trait TrainNorm: Backend {
    fn train_batch_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        relu: bool,
        epsilon: f64,
    ) -> NormOut<Self>;

    fn train_batch_norm_add(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        residual: FloatTensor<Self>,
        relu: bool,
        epsilon: f64,
    ) -> NormOut<Self>;
}

impl TrainNorm for Flex {
    fn train_batch_norm(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        relu: bool,
        epsilon: f64,
    ) -> NormOut<Self> {
        flex_norm(x, gamma, beta, None, relu, epsilon)
    }

    fn train_batch_norm_add(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        residual: FlexTensor,
        relu: bool,
        epsilon: f64,
    ) -> NormOut<Self> {
        flex_norm(x, gamma, beta, Some(residual), relu, epsilon)
    }
}

fn flex_norm(
    x: FlexTensor,
    gamma: FlexTensor,
    beta: FlexTensor,
    residual: Option<FlexTensor>,
    relu: bool,
    epsilon: f64,
) -> NormOut<Flex> {
    let shape = x.layout().shape().clone();
    let g = Planes::of(&x);
    let xs = dense(&x);
    if let Some(r) = &residual {
        assert_eq!(
            r.layout().shape(),
            &shape,
            "train_batch_norm: the residual's shape is not the input's"
        );
    }
    let r = residual.as_ref().map(dense);
    let (y, mean, var) = normalise(
        &g,
        &xs,
        [&dense(&gamma), &dense(&beta)],
        epsilon,
        r.as_deref(),
        relu,
    );
    NormOut {
        output: FlexTensor::from_data(burn::tensor::TensorData::new(y, shape)),
        mean: flex(mean, [g.c]),
        variance: flex(var, [g.c]),
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

    /// Channel `c`'s plane of image `n` in `v`.
    fn plane<'a>(&self, v: &'a [f32], n: usize, c: usize) -> &'a [f32] {
        &v[(n * self.c + c) * self.len..][..self.len]
    }

    /// The planes of `v` (laid out as the tensor's) grouped by channel: item `c` holds
    /// channel `c`'s plane of every image, in image order.
    fn by_channel<'a, T>(&self, v: &'a mut [T]) -> Vec<Vec<&'a mut [T]>> {
        let mut out: Vec<Vec<&mut [T]>> = (0..self.c).map(|_| Vec::with_capacity(self.n)).collect();
        if self.len > 0 {
            for (i, p) in v.chunks_mut(self.len).enumerate() {
                out[i % self.c].push(p);
            }
        }
        out
    }
}

/// One channel's mean and biased variance, two passes with f64 sums.
fn channel_stats(g: &Planes, x: &[f32], c: usize) -> (f32, f32) {
    let planes = || (0..g.n).map(move |n| g.plane(x, n, c));
    let sum: f64 = planes().map(plane_sum).sum();
    let mean = sum / g.count();
    let sq: f64 = planes().map(|p| plane_sq(p, mean)).sum();
    (mean as f32, (sq / g.count()) as f32)
}

/// `1 / √(σ² + ε)`.
fn inv_std(var: f32, eps: f64) -> f32 {
    1.0 / ((var as f64 + eps).sqrt() as f32)
}

/// The normalised output and the batch's per-channel mean and biased variance.
///
/// Channel by channel (a channel a task): the statistics' two passes, then the output's pass
/// over the same planes in reverse order, so that the planes the statistics read last are
/// still in the core's cache when the output reads them. Where a channel's planes fit in the
/// core's cache (786 KB a channel in the first stage of the ResNet-18 bench), the activation
/// comes from memory once rather than three times; measured, the forward gained about 10 %,
/// so the cache keeps less of it than that.
fn normalise(
    g: &Planes,
    x: &[f32],
    [gamma, beta]: [&[f32]; 2],
    eps: f64,
    residual: Option<&[f32]>,
    relu: bool,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut y = unwritten(x.len());
    let per: Vec<(f32, f32)> = g
        .by_channel(&mut y)
        .into_par_iter()
        .enumerate()
        .map(|(c, ys)| {
            let (mean, var) = channel_stats(g, x, c);
            // `(x − μ)` first: exact for values near μ, where `x·s + (β − μ·s)` would cancel.
            let map = PlaneMap {
                mu: mean,
                scale: gamma[c] * inv_std(var, eps),
                shift: beta[c],
            };
            for (n, yp) in ys.into_iter().enumerate().rev() {
                let rp = residual.map(|r| g.plane(r, n, c));
                norm_plane(yp, g.plane(x, n, c), rp, map, relu);
            }
            (mean, var)
        })
        .collect();
    // SAFETY: the channels' planes cover `y`, each written in full.
    let y = unsafe { written(y) };
    let (mean, var) = per.into_iter().unzip();
    (y, mean, var)
}

/// What the backward step keeps: the input, the output if a ReLU was applied (its mask), γ,
/// the batch statistics and ε.
#[derive(Debug, Clone)]
struct NormState {
    x: FlexTensor,
    relu_out: Option<FlexTensor>,
    gamma: FlexTensor,
    mean: FlexTensor,
    var: FlexTensor,
    eps: f64,
}

/// The backward step; `N` is 3 (input, γ, β) or 4 (and the residual).
#[derive(Debug)]
struct NormBackward<const N: usize>;

impl<const N: usize> Backward<Flex, N> for NormBackward<N> {
    type State = NormState;

    fn backward(self, ops: Ops<Self::State, N>, grads: &mut Gradients, _: &mut Checkpointer) {
        let mut parents = ops.parents.into_iter();
        let mut next = || parents.next().flatten();
        let (node_x, node_gamma, node_beta, node_r) = (next(), next(), next(), next());
        let dy_t = grads.consume::<Flex>(&ops.node);
        let s = ops.state;
        let g = Planes::of(&s.x);
        let shape = s.x.layout().shape().clone();
        let dy = dense(&dy_t);
        // The gradient through the ReLU, `dz = dy` where the output was positive (or NaN), else
        // 0, is computed where it is read instead of written out first (one pass over memory
        // fewer); only the residual's gradient needs it whole, and the input gradient's pass
        // writes it then.
        let y = s.relu_out.as_ref().map(dense);
        let y_or_dy: &[f32] = y.as_deref().unwrap_or(&dy);
        let relu = y.is_some();
        let (x, gamma) = (dense(&s.x), dense(&s.gamma));
        let (mean, var) = (dense(&s.mean), dense(&s.var));
        let inv: Vec<f32> = var.iter().map(|&v| inv_std(v, s.eps)).collect();
        let channel_sums = |c: usize| {
            (0..g.n)
                .map(|n| {
                    let [d, y, v] = [&dy[..], y_or_dy, &x[..]].map(|t| g.plane(t, n, c));
                    grad_sums(d, y, v, mean[c], inv[c], relu)
                })
                .fold((0.0, 0.0), |t, p| (t.0 + p.0, t.1 + p.1))
        };
        // `dz` for the residual, when the ReLU made it differ from `dy`.
        let want_dz = relu && node_r.is_some();
        let mut dz_out = (want_dz && node_x.is_some()).then(|| unwritten(x.len()));
        let sums: Vec<(f64, f64)> = match node_x {
            None => (0..g.c).into_par_iter().map(channel_sums).collect(),
            Some(node) => {
                let m = g.count();
                let mut dx = unwritten(x.len());
                let dz_planes: Vec<Option<Vec<&mut [Slot]>>> = match dz_out.as_mut() {
                    Some(dz) => g.by_channel(dz).into_iter().map(Some).collect(),
                    None => (0..g.c).map(|_| None).collect(),
                };
                // Channel by channel: the sums, then the input gradient (and `dz`) over the
                // same planes in reverse order, reading what the sums read last from cache.
                let sums = g
                    .by_channel(&mut dx)
                    .into_par_iter()
                    .zip(dz_planes)
                    .enumerate()
                    .map(|(c, (dxs, dzs))| {
                        let s = channel_sums(c);
                        let coef = PlaneGrad {
                            k: gamma[c] * inv[c],
                            mu: mean[c],
                            inv: inv[c],
                            mdb: (s.0 / m) as f32,
                            mdg: (s.1 / m) as f32,
                        };
                        let mut dzs = dzs.map(|v| v.into_iter().rev());
                        for (n, dxp) in dxs.into_iter().enumerate().rev() {
                            let dzp = dzs.as_mut().and_then(Iterator::next);
                            let [dyp, yp, xp] =
                                [&dy[..], y_or_dy, &x[..]].map(|t| g.plane(t, n, c));
                            grad_plane(dxp, dzp, dyp, yp, xp, relu, coef);
                        }
                        s
                    })
                    .collect();
                // SAFETY: the channels' planes cover `dx`, each written in full.
                let dx = unsafe { written(dx) };
                grads.register::<Flex>(
                    node.id,
                    FlexTensor::from_data(burn::tensor::TensorData::new(dx, shape.clone())),
                );
                sums
            }
        };
        let dz: Cow<'_, [f32]> = match (dz_out, want_dz) {
            // SAFETY: the input gradient's pass wrote every plane of `dz_out` (`g.len` > 0, or
            // `dz_out` is empty).
            (Some(dz), _) => Cow::Owned(unsafe { written(dz) }),
            (None, true) => Cow::Owned(map2(&dy, y_or_dy, |d, y| activation_grad(d, y, true))),
            (None, false) => dy,
        };
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
        if let Some(node) = node_r {
            let dr = match dz {
                Cow::Owned(dz) => FlexTensor::from_data(burn::tensor::TensorData::new(dz, shape)),
                // No ReLU: the residual's gradient is the output's, shared.
                Cow::Borrowed(_) => dy_t.clone(),
            };
            grads.register::<Flex>(node.id, dr);
        }
    }
}

/// Records the backward step of one batch norm on the graph.
fn tracked<C: CheckpointStrategy, const N: usize>(
    nodes: [NodeGuard; N],
    state: impl FnOnce() -> NormState,
    output: FlexTensor,
) -> FloatTensor<Autodiff<Flex, C>> {
    match NormBackward::<N>
        .prepare::<C>(nodes)
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => prep.finish(state(), output),
        OpsKind::UnTracked(prep) => prep.finish(output),
    }
}

impl<C: CheckpointStrategy> TrainNorm for Autodiff<Flex, C> {
    fn train_batch_norm(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        relu: bool,
        epsilon: f64,
    ) -> NormOut<Self> {
        autodiff_norm::<C>(x, gamma, beta, None, relu, epsilon)
    }

    fn train_batch_norm_add(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        residual: FloatTensor<Self>,
        relu: bool,
        epsilon: f64,
    ) -> NormOut<Self> {
        autodiff_norm::<C>(x, gamma, beta, Some(residual), relu, epsilon)
    }
}

fn autodiff_norm<C: CheckpointStrategy>(
    x: FloatTensor<Autodiff<Flex, C>>,
    gamma: FloatTensor<Autodiff<Flex, C>>,
    beta: FloatTensor<Autodiff<Flex, C>>,
    residual: Option<FloatTensor<Autodiff<Flex, C>>>,
    relu: bool,
    epsilon: f64,
) -> NormOut<Autodiff<Flex, C>> {
    let out = flex_norm(
        x.primitive().clone(),
        gamma.primitive().clone(),
        beta.primitive().clone(),
        residual.as_ref().map(|r| r.primitive().clone()),
        relu,
        epsilon,
    );
    let (mean, variance) = (out.mean, out.variance);
    let nodes = [x.node(), gamma.node(), beta.node()];
    let state = || NormState {
        x: x.into_primitive(),
        relu_out: relu.then(|| out.output.clone()),
        gamma: gamma.into_primitive(),
        mean: mean.clone(),
        var: variance.clone(),
        eps: epsilon,
    };
    let output = match &residual {
        Some(r) => {
            let [a, b, c] = nodes;
            tracked::<C, 4>([a, b, c, r.node()], state, out.output.clone())
        }
        None => tracked::<C, 3>(nodes, state, out.output.clone()),
    };
    NormOut {
        output,
        mean: Autodiff::<Flex, C>::from_inner(mean),
        variance: Autodiff::<Flex, C>::from_inner(variance),
    }
}

/// `bn.forward(x)`: in training on the flex device through this module's loops (and the running
/// statistics updated as burn does: `r ← (1 − momentum) r + momentum · batch`), else burn's.
pub fn batch_norm<const D: usize>(bn: &BatchNorm, x: Tensor<D>) -> Tensor<D> {
    fused(bn, x, None, false)
}

/// `relu(bn.forward(x) + residual)` (without the addition when `residual` is `None`), as one
/// pass where [`batch_norm`] runs on this module's loops.
pub fn batch_norm_relu<const D: usize>(
    bn: &BatchNorm,
    x: Tensor<D>,
    residual: Option<Tensor<D>>,
) -> Tensor<D> {
    fused(bn, x, residual, true)
}

/// `relu(norm.forward(x) + residual)` for an instance norm (the ReLU only if `with_relu`, the
/// addition only with a residual): on this module's loops wherever `x` is f32 on the flex
/// device, in training or not, since an instance norm keeps no running statistics. Each image's
/// channel is its own group, so `[N, C, H, W]` is normalised as the batch norm above normalises
/// `[1, N·C, H, W]` (the same reshape, no copy), with the affine parameters, if any, repeated
/// per image (their gradients summed back by the repeat). burn's `InstanceNorm::forward` takes
/// the same statistics (biased variance, `ε` inside the root) from generic tensor operations:
/// about ten passes and graph nodes a layer, all on the calling thread, where the CycleGAN
/// spent a good part of its step (docs/experiments.md).
pub fn instance_norm(
    norm: &InstanceNorm,
    x: Tensor<4>,
    residual: Option<Tensor<4>>,
    with_relu: bool,
) -> Tensor<4> {
    if !on_cpu_kernels(&x) || residual.as_ref().is_some_and(|r| !on_cpu_kernels(r)) {
        let mut y = norm.forward(x);
        if let Some(r) = residual {
            y = y + r;
        }
        return if with_relu { relu(y) } else { y };
    }
    let [n, c, h, w] = x.dims();
    let dev = x.device();
    let (gamma, beta) = match (&norm.gamma, &norm.beta) {
        (Some(g), Some(b)) if norm.affine => (g.val().repeat_dim(0, n), b.val().repeat_dim(0, n)),
        _ => (
            Tensor::<1>::ones([n * c], &dev),
            Tensor::<1>::zeros([n * c], &dev),
        ),
    };
    let planes = |t: Tensor<4>| t.reshape([1, n * c, h, w]).into_dispatch();
    let (x, gamma, beta) = (planes(x), gamma.into_dispatch(), beta.into_dispatch());
    let out = match residual {
        Some(r) => <Dispatch as TrainNorm>::train_batch_norm_add(
            x,
            gamma,
            beta,
            planes(r),
            with_relu,
            norm.epsilon,
        ),
        None => <Dispatch as TrainNorm>::train_batch_norm(x, gamma, beta, with_relu, norm.epsilon),
    };
    Tensor::<4>::from_dispatch(out.output).reshape([n, c, h, w])
}

fn fused<const D: usize>(
    bn: &BatchNorm,
    x: Tensor<D>,
    residual: Option<Tensor<D>>,
    with_relu: bool,
) -> Tensor<D> {
    let dev = x.device();
    let training = dev.is_autodiff() && bn.training.is_enabled();
    if !training || !on_cpu_kernels(&x) || residual.as_ref().is_some_and(|r| !on_cpu_kernels(r)) {
        let mut y = bn.forward(x);
        if let Some(r) = residual {
            y = y + r;
        }
        return if with_relu { relu(y) } else { y };
    }
    let (x, gamma, beta) = (
        x.into_dispatch(),
        bn.gamma.val().into_dispatch(),
        bn.beta.val().into_dispatch(),
    );
    let out = match residual {
        Some(r) => <Dispatch as TrainNorm>::train_batch_norm_add(
            x,
            gamma,
            beta,
            r.into_dispatch(),
            with_relu,
            bn.epsilon,
        ),
        None => <Dispatch as TrainNorm>::train_batch_norm(x, gamma, beta, with_relu, bn.epsilon),
    };
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
    use burn::module::Module;
    use burn::nn::{BatchNormConfig, InstanceNormConfig};
    use burn::tensor::{Device, Distribution};

    use crate::testing::{close_to_largest as close, values};

    /// Ours against burn's `BatchNorm::forward` in training (then `+ r0` if `residual`, then
    /// burn's ReLU if `with_relu`): output, the gradients of `Σ y ⊙ r` with respect to the
    /// input, γ, β (and the residual), and the running statistics after two steps.
    fn check(dims: [usize; 4], offset: f32, spread: f32, residual: bool, with_relu: bool) {
        let dev = Device::flex().autodiff();
        let what = format!(
            "{dims:?} offset {offset} spread {spread} residual {residual} relu {with_relu}"
        );
        let x = Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &dev)
            .mul_scalar(spread)
            .add_scalar(offset);
        let r0 = Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &dev);
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
                let ri = r0.clone().detach().require_grad();
                let res = residual.then(|| ri.clone());
                let y = if ours {
                    fused(&bn, xi.clone(), res, with_relu)
                } else {
                    let mut y = bn.forward(xi.clone());
                    if let Some(res) = res {
                        y = y + res;
                    }
                    if with_relu { relu(y) } else { y }
                };
                let grads = (y.clone() * r.clone()).sum().backward();
                out = vec![
                    values(y),
                    values(xi.grad(&grads).unwrap()),
                    values(bn.gamma.val().grad(&grads).unwrap()),
                    values(bn.beta.val().grad(&grads).unwrap()),
                ];
                if residual {
                    out.push(values(ri.grad(&grads).unwrap()));
                }
            }
            out.push(values(bn.running_mean.value()));
            out.push(values(bn.running_var.value()));
            got.push(out);
        }
        let mut parts = vec!["y", "dx", "dgamma", "dbeta"];
        if residual {
            parts.push("dresidual");
        }
        parts.extend(["running mean", "running var"]);
        assert_eq!(parts.len(), got[0].len());
        for (i, part) in parts.iter().enumerate() {
            close(&format!("{what}: {part}"), &got[0][i], &got[1][i]);
        }
    }

    #[test]
    fn the_training_batch_norm_matches_burns_values_gradients_and_running_statistics() {
        check([4, 3, 5, 6], 0.0, 1.0, false, false);
        // One pixel, three images: three values a channel. (With two, x̂ = ±1 whatever x is
        // and dx is rounding noise around zero in both implementations.)
        check([3, 5, 1, 1], 0.0, 1.0, false, false);
        // Planes of 21 values: the eight-lane sums have a tail.
        check([1, 2, 7, 3], 0.0, 1.0, false, false);
    }

    #[test]
    fn the_fused_residual_and_relu_match_burns_addition_and_relu() {
        // About half the outputs are cut by the ReLU, so the masked gradient is exercised.
        for (residual, with_relu) in [(false, true), (true, true), (true, false)] {
            check([4, 3, 5, 6], 0.0, 1.0, residual, with_relu);
            check([2, 4, 3, 11], 0.5, 2.0, residual, with_relu);
        }
    }

    /// Our instance norm against burn's `InstanceNorm::forward` (then `+ r0`, then burn's ReLU,
    /// as asked): output and the gradients of `Σ y ⊙ r` with respect to the input, the residual
    /// and, when affine, γ and β; and the output without autodiff.
    fn check_instance(dims: [usize; 4], affine: bool, residual: bool, with_relu: bool) {
        let what =
            format!("instance {dims:?} affine {affine} residual {residual} relu {with_relu}");
        let dev = Device::flex().autodiff();
        let normal = || Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &dev);
        // Each plane its own offset and spread, so that one set of statistics for the whole
        // batch or channel would be visibly wrong.
        let x = normal() * normal().exp() + normal().mul_scalar(3.0);
        let (r0, r) = (normal(), normal());
        let mut norm = InstanceNormConfig::new(dims[1])
            .with_affine(affine)
            .init(&dev);
        norm.gamma = norm
            .gamma
            .map(|p| p.map(|g| g.mul_scalar(1.5).add_scalar(-0.25).detach().require_grad()));
        norm.beta = norm
            .beta
            .map(|p| p.map(|b| b.add_scalar(0.3).detach().require_grad()));
        let mut got = Vec::new();
        for ours in [true, false] {
            let xi = x.clone().detach().require_grad();
            let ri = r0.clone().detach().require_grad();
            let res = residual.then(|| ri.clone());
            let y = if ours {
                instance_norm(&norm, xi.clone(), res, with_relu)
            } else {
                let mut y = norm.forward(xi.clone());
                if let Some(res) = res {
                    y = y + res;
                }
                if with_relu { relu(y) } else { y }
            };
            let grads = (y.clone() * r.clone()).sum().backward();
            let mut out = vec![values(y), values(xi.grad(&grads).unwrap())];
            if residual {
                out.push(values(ri.grad(&grads).unwrap()));
            }
            if affine {
                for p in [&norm.gamma, &norm.beta] {
                    out.push(values(p.as_ref().unwrap().val().grad(&grads).unwrap()));
                }
            }
            got.push(out);
        }
        for (i, (a, b)) in got[0].iter().zip(&got[1]).enumerate() {
            close(&format!("{what}: part {i} (y, dx, [dr], [dγ, dβ])"), a, b);
        }
        let plain = Device::flex();
        let norm = norm.valid();
        let xv = Tensor::<4>::from_data(x.to_data(), &plain);
        let ours = instance_norm(&norm, xv.clone(), None, with_relu);
        let burns = if with_relu {
            relu(norm.forward(xv))
        } else {
            norm.forward(xv)
        };
        close(
            &format!("{what}: without autodiff"),
            &values(ours),
            &values(burns),
        );
    }

    #[test]
    fn the_instance_norm_matches_burns_values_and_gradients() {
        for affine in [false, true] {
            for (residual, with_relu) in [(false, false), (false, true), (true, false)] {
                check_instance([3, 4, 5, 6], affine, residual, with_relu);
            }
        }
        // Planes of 21 values (a tail after the sixteen-lane blocks), one image.
        check_instance([1, 2, 7, 3], false, true, true);
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
            // (2⁻¹⁵ ≈ 3.05e-5) over this sample's scale √(s² + ε) (about 0.0105, but s² of
            // 288 draws varies by about 8 %: a bound from the nominal scale failed 2 runs in
            // 200), with 5 % for the output's own rounding.
            let bound = 1.05 * 2f64.powi(-15) / (s2 + 1e-5).sqrt();
            assert!(
                mean.abs() < bound,
                "channel {c}: mean {mean}, bound {bound}"
            );
            let want = s2 / (s2 + 1e-5);
            assert!(
                (var - want).abs() < 1e-4,
                "channel {c}: variance {var}, want {want}"
            );
        }
    }

    #[test]
    fn the_gradient_sums_of_a_large_plane_keep_f64_precision_within_each_f32_block() {
        // 200 003 values (blocks of 256 and a ragged tail) of one sign with a large offset in
        // x: a single f32 running sum would drift by about n·2⁻²⁴ ≈ 1e-2 of the total; sixteen
        // lanes of 16 terms a block, carried into f64, stay within 16·2⁻²⁴ ≈ 1e-6 of it.
        let n = 200_003;
        let dy: Vec<f32> = (0..n).map(|i| 0.1 + (i % 7) as f32 * 0.013).collect();
        let y: Vec<f32> = (0..n)
            .map(|i| if i % 5 == 0 { -1.0 } else { 1.0 })
            .collect();
        let x: Vec<f32> = (0..n).map(|i| 1000.0 + (i % 11) as f32 * 0.25).collect();
        let (mean, inv) = (1001.25f32, 0.8f32);
        for relu in [false, true] {
            let (mut want_b, mut want_g, mut scale_b, mut scale_g) = (0.0f64, 0.0, 0.0, 0.0);
            for ((&d, &yv), &v) in dy.iter().zip(&y).zip(&x) {
                let dz = if relu && yv <= 0.0 { 0.0 } else { f64::from(d) };
                let xh = f64::from((v - mean) * inv);
                want_b += dz;
                want_g += dz * xh;
                scale_b += dz.abs();
                scale_g += (dz * xh).abs();
            }
            let (got_b, got_g) = grad_sums(&dy, &y, &x, mean, inv, relu);
            assert!(
                (got_b - want_b).abs() < 2e-6 * scale_b,
                "relu {relu}: Σdz {got_b} {want_b}"
            );
            assert!(
                (got_g - want_g).abs() < 2e-6 * scale_g,
                "relu {relu}: Σdz·x̂ {got_g} {want_g}"
            );
        }
    }
}
