//! Reflection padding of an NCHW tensor's two spatial axes on the CPU, forward and backward on
//! our own loops through a burn backend extension (as [`super::conv`] does for the
//! convolution).
//!
//! The CycleGAN's generator pads this way before its 7 × 7 layers and each 3 × 3 layer of its
//! residual blocks (six times a pass, six passes a step). burn's `Tensor::pad` with
//! `PadMode::Reflect` builds the result from slices, flips and concatenations, each a pass and
//! a graph node on the calling thread, and its backward takes them apart again: with the
//! instance norms on burn's generic operations, these were most of what the main thread ran
//! alone while the workers waited in a CycleGAN step (docs/experiments.md).
//!
//! Here, with `p` the padding and `r(q)` the input index that padded index `q` copies
//! (`q − p`, mirrored about the first and the last pixel without repeating them, as
//! `numpy.pad(mode="reflect")`, PyTorch's `ReflectionPad2d` and burn's reflect mode do; `p`
//! must be below the side):
//!
//! - **forward:** `y[q_y, q_x] = x[r(q_y), r(q_x)]`, one row copy and `2p` single pixels a row;
//! - **backward:** the adjoint, `dx[i, j] = Σ dy[q_y, q_x]` over the padded pixels with
//!   `r(q_y) = i` and `r(q_x) = j`: each padded row's gradient added back into the row it
//!   copied, its `2p` border pixels into the pixels they mirrored.
//!
//! Both run planes in parallel. Off the flex device, or for other dtypes, burn's pad runs.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::tensor::Tensor;
use burn::tensor::ops::PadMode;
use rayon::prelude::*;

use super::conv::on_cpu_kernels;
use super::kernels::{dense, flex};

/// Reflection padding by `p` on both spatial axes of an NCHW tensor, as a backend operation.
#[backend_extension(Flex, Autodiff)]
pub trait TrainPad: Backend {
    fn reflect_pad2d(x: FloatTensor<Self>, p: usize) -> FloatTensor<Self>;
}

/// Planes of fewer floats than this are handed out to the workers together.
const MIN_FLOATS_A_TASK: usize = 4096;

/// The input index that padded index `q` copies, on a side of `n` padded by `p` (`p < n`).
fn source(q: usize, p: usize, n: usize) -> usize {
    if q < p {
        p - q
    } else if q - p < n {
        q - p
    } else {
        2 * (n - 1) + p - q
    }
}

fn planes_a_task(plane: usize) -> usize {
    MIN_FLOATS_A_TASK.div_ceil(plane.max(1))
}

fn check(dims: [usize; 4], p: usize) {
    let [_, _, h, w] = dims;
    assert!(
        p < h && p < w,
        "reflect_pad2d: padding {p} needs a side above it, got {h} × {w}"
    );
}

fn forward(x: &[f32], [n, c, h, w]: [usize; 4], p: usize) -> Vec<f32> {
    let (hp, wp) = (h + 2 * p, w + 2 * p);
    let mut y = vec![0.0f32; n * c * hp * wp];
    let per = planes_a_task(hp * wp);
    y.par_chunks_mut(hp * wp * per)
        .zip(x.par_chunks(h * w * per))
        .for_each(|(ys, xs)| {
            for (out, plane) in ys.chunks_mut(hp * wp).zip(xs.chunks(h * w)) {
                for (qy, row) in out.chunks_mut(wp).enumerate() {
                    let src = &plane[source(qy, p, h) * w..][..w];
                    row[p..p + w].copy_from_slice(src);
                    for j in 0..p {
                        row[j] = src[p - j];
                        row[p + w + j] = src[w - 2 - j];
                    }
                }
            }
        });
    y
}

fn backward(dy: &[f32], [n, c, h, w]: [usize; 4], p: usize) -> Vec<f32> {
    let (hp, wp) = (h + 2 * p, w + 2 * p);
    let mut dx = vec![0.0f32; n * c * h * w];
    let per = planes_a_task(hp * wp);
    dx.par_chunks_mut(h * w * per)
        .zip(dy.par_chunks(hp * wp * per))
        .for_each(|(dxs, dys)| {
            for (plane, grad) in dxs.chunks_mut(h * w).zip(dys.chunks(hp * wp)) {
                for (qy, row) in grad.chunks(wp).enumerate() {
                    let dst = &mut plane[source(qy, p, h) * w..][..w];
                    for (d, &g) in dst.iter_mut().zip(&row[p..p + w]) {
                        *d += g;
                    }
                    for j in 0..p {
                        dst[p - j] += row[j];
                        dst[w - 2 - j] += row[p + w + j];
                    }
                }
            }
        });
    dx
}

fn flex_pad(x: &FlexTensor, p: usize) -> FlexTensor {
    let dims: [usize; 4] = x.layout().shape().dims();
    check(dims, p);
    let [n, c, h, w] = dims;
    flex(forward(&dense(x), dims, p), [n, c, h + 2 * p, w + 2 * p])
}

impl TrainPad for Flex {
    fn reflect_pad2d(x: FlexTensor, p: usize) -> FlexTensor {
        flex_pad(&x, p)
    }
}

/// The backward step; the state is the input's shape and the padding.
#[derive(Debug)]
struct PadBackward;

impl Backward<Flex, 1> for PadBackward {
    type State = ([usize; 4], usize);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (dims, p) = ops.state;
        if let Some(node) = node {
            grads.register::<Flex>(node.id, flex(backward(&dense(&dy), dims, p), dims));
        }
    }
}

impl<C: CheckpointStrategy> TrainPad for Autodiff<Flex, C> {
    fn reflect_pad2d(x: FloatTensor<Self>, p: usize) -> FloatTensor<Self> {
        let y = flex_pad(x.primitive(), p);
        match PadBackward
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let dims: [usize; 4] = x.primitive().layout().shape().dims();
                prep.finish((dims, p), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

/// Reflection padding of the two spatial axes of an NCHW tensor by `p` (the CycleGAN generator
/// pads this way so that borders carry image content, not zeros): on this module's loops for
/// f32 tensors on the flex device, else burn's `Tensor::pad`.
pub fn reflect_pad(x: Tensor<4>, p: usize) -> Tensor<4> {
    if p == 0 {
        return x;
    }
    if !on_cpu_kernels(&x) {
        return x.pad([(p, p), (p, p)], PadMode::Reflect);
    }
    Tensor::from_dispatch(<Dispatch as TrainPad>::reflect_pad2d(x.into_dispatch(), p))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, Distribution};

    use crate::testing::{close_to_largest as close, values};

    /// Ours against burn's reflect pad: values, and the gradient of `Σ y ⊙ r`.
    fn check_against_burn(dims: [usize; 4], p: usize) {
        let dev = Device::flex().autodiff();
        let x = Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &dev);
        let [n, c, h, w] = dims;
        let r = Tensor::<4>::random(
            [n, c, h + 2 * p, w + 2 * p],
            Distribution::Normal(0.0, 1.0),
            &dev,
        );
        let mut got = Vec::new();
        for ours in [true, false] {
            let xi = x.clone().detach().require_grad();
            let y = if ours {
                reflect_pad(xi.clone(), p)
            } else {
                xi.clone().pad([(p, p), (p, p)], PadMode::Reflect)
            };
            let grads = (y.clone() * r.clone()).sum().backward();
            got.push([values(y), values(xi.grad(&grads).unwrap())]);
        }
        for (i, part) in ["y", "dx"].iter().enumerate() {
            close(&format!("{dims:?} p {p}: {part}"), &got[0][i], &got[1][i]);
        }
    }

    #[test]
    fn reflection_padding_matches_burns_values_and_gradient() {
        // The generator's pads (1 before a residual block's 3 × 3 layers, 3 before its 7 × 7
        // ones), padding one short of the side (the mirror reaches the far edge), a
        // non-square plane, and enough planes that the workers take several each.
        check_against_burn([2, 3, 4, 5], 1);
        check_against_burn([2, 2, 8, 6], 3);
        check_against_burn([1, 2, 3, 4], 2);
        check_against_burn([4, 64, 6, 8], 1);
    }

    #[test]
    fn a_row_is_mirrored_about_its_end_pixels() {
        // [1 2 3 4] padded by 2 reads [3 2 | 1 2 3 4 | 3 2]: the end pixels are not repeated.
        let dev = Device::flex();
        let x = Tensor::<4>::from_floats(
            [[[
                [1.0, 2.0, 3.0, 4.0],
                [5.0, 6.0, 7.0, 8.0],
                [9.0, 10.0, 11.0, 12.0],
            ]]],
            &dev,
        );
        let y = values(reflect_pad(x, 2));
        assert_eq!(&y[2 * 8..3 * 8], &[3.0, 2.0, 1.0, 2.0, 3.0, 4.0, 3.0, 2.0]);
        // The first padded row mirrors the input's third row (index 2 for q = 0).
        assert_eq!(&y[..8], &[11.0, 10.0, 9.0, 10.0, 11.0, 12.0, 11.0, 10.0]);
    }

    #[test]
    #[should_panic(expected = "needs a side above it")]
    fn padding_as_wide_as_the_side_is_refused() {
        let dev = Device::flex();
        let _ = reflect_pad(Tensor::<4>::zeros([1, 1, 2, 5], &dev), 2);
    }
}
