//! The transposed convolution the CycleGAN's generator upsamples with, forward and backward on
//! [`super::conv`]'s kernels through a burn backend extension.
//!
//! A transposed convolution of `x` (`n × c_in × h × w`) by a weight `W` of `[c_in, c_out, k, k]`
//! with stride `s`, padding `p` and output padding `q < s` is the adjoint of the convolution
//! from `c_out × H × W` to `c_in × h × w` by the same `W` read as that convolution's
//! `[c_out', c_in', k, k] = [c_in, c_out, k, k]` (Dumoulin and Visin 2016, "A guide to
//! convolution arithmetic for deep learning", §4), with `H = (h − 1)·s − 2p + k + q`; the
//! output padding only lengthens the sides to `H`, which that convolution maps back to `h`.
//! So, with `conv` that convolution:
//!
//! - **forward:** `y = conv`'s input gradient for output gradient `x`, then `+ b`;
//! - **input gradient:** `dx = conv(dy)`, its forward without bias;
//! - **weight gradient:** `conv`'s weight gradient for input `dy` and output gradient `x`;
//! - **bias gradient:** `Σ dy` over images and pixels, per output channel.
//!
//! The generator's layers (3 × 3, stride 2, padding 1, output padding 1) then run on the
//! stride-2 kernels: forward by phases, input gradient and weight gradient on the direct
//! products. burn's own, on the flex backend, ran its forward as a scatter loop and its
//! backward as generic convolutions with layout copies, on the calling thread
//! (docs/experiments.md, *The trainer beside PyTorch*). Anything other than one group, no
//! dilation, a square kernel, equal strides and paddings, a bias and f32 on the flex device goes
//! to burn's `ConvTranspose2d::forward`.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::nn::conv::ConvTranspose2d;
use burn::tensor::Tensor;
use rayon::prelude::*;

use super::conv::{Want, backward, forward, on_cpu_kernels};
use super::kernels::{dense, flex};
use super::lanes;
use super::unroll::Geom;

/// A transposed convolution (square kernel, equal strides and paddings) as a backend
/// operation.
#[backend_extension(Flex, Autodiff)]
pub trait TrainDeconv: Backend {
    fn train_conv_transpose2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: usize,
        pad: usize,
        pad_out: usize,
    ) -> FloatTensor<Self>;
}

/// The layer's sizes: its output's `[n, c_out, H, W]`, and the convolution it is the adjoint
/// of (module docs).
fn sizes(x: &FlexTensor, weight: &FlexTensor, s: usize, p: usize, q: usize) -> ([usize; 4], Geom) {
    let [n, ci, h, w]: [usize; 4] = x.layout().shape().dims();
    let [wi, co, k, kw]: [usize; 4] = weight.layout().shape().dims();
    let side = |len: usize| ((len.max(1) - 1) * s + k + q).checked_sub(2 * p);
    let (Some(ho), Some(wo)) = (side(h), side(w)) else {
        panic!("train_conv_transpose2d: padding {p} leaves no output of {h} × {w}");
    };
    assert!(
        wi == ci && kw == k && q < s && h > 0 && w > 0,
        "train_conv_transpose2d: input {:?}, weight {:?}, stride {s}, output padding {q}",
        [n, ci, h, w],
        [wi, co, k, kw]
    );
    ([n, co, ho, wo], Geom::new([n, co, ho, wo], ci, k, s, p))
}

fn flex_deconv(
    x: &FlexTensor,
    weight: &FlexTensor,
    bias: &FlexTensor,
    [s, p, q]: [usize; 3],
) -> FlexTensor {
    let (dims, g) = sizes(x, weight, s, p, q);
    let want = Want {
        dx: true,
        dw: false,
        db: false,
    };
    let d = backward(&g, &[], None, &dense(weight), &dense(x), None, want);
    let mut y = d.dx.expect("the input gradient was asked for");
    let [_, co, ho, wo] = dims;
    let b = dense(bias);
    y.par_chunks_mut(ho * wo)
        .enumerate()
        .for_each(|(i, plane)| {
            let b = b[i % co];
            plane.iter_mut().for_each(|v| *v += b);
        });
    flex(y, dims)
}

impl TrainDeconv for Flex {
    fn train_conv_transpose2d(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        stride: usize,
        pad: usize,
        pad_out: usize,
    ) -> FlexTensor {
        flex_deconv(&x, &weight, &bias, [stride, pad, pad_out])
    }
}

/// The backward step; the state is the forward's input and weight (cheap `Arc` clones) and
/// its stride, padding and output padding.
#[derive(Debug)]
struct DeconvBackward;

impl Backward<Flex, 3> for DeconvBackward {
    type State = (FlexTensor, FlexTensor, [usize; 3]);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_w, node_b] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, weight, [s, p, q]) = ops.state;
        let (dims, g) = sizes(&x, &weight, s, p, q);
        let [n, co, ho, wo] = dims;
        let (dy_d, w_d) = (dense(&dy), dense(&weight));
        if let Some(node) = node_x {
            let (dx, _) = forward(&g, &dy_d, &w_d, None, false);
            grads.register::<Flex>(node.id, flex(dx, x.layout().shape().dims::<4>()));
        }
        if let Some(node) = node_w {
            let want = Want {
                dx: false,
                dw: true,
                db: false,
            };
            let d = backward(&g, &dy_d, None, &w_d, &dense(&x), None, want);
            let dw = d.dw.expect("the weight gradient was asked for");
            grads.register::<Flex>(node.id, flex(dw, weight.layout().shape().dims::<4>()));
        }
        if let Some(node) = node_b {
            let plane = ho * wo;
            let db: Vec<f32> = (0..co)
                .into_par_iter()
                .map(|o| {
                    (0..n)
                        .map(|i| lanes::plane_sum(&dy_d[(i * co + o) * plane..][..plane]))
                        .sum::<f64>() as f32
                })
                .collect();
            grads.register::<Flex>(node.id, flex(db, [co]));
        }
    }
}

impl<C: CheckpointStrategy> TrainDeconv for Autodiff<Flex, C> {
    fn train_conv_transpose2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: usize,
        pad: usize,
        pad_out: usize,
    ) -> FloatTensor<Self> {
        let spq = [stride, pad, pad_out];
        let y = flex_deconv(x.primitive(), weight.primitive(), bias.primitive(), spq);
        match DeconvBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                prep.finish((x.into_primitive(), weight.into_primitive(), spq), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

/// `layer.forward(x)`: on the convolution's kernels ([`super::conv2d`]) where the layer and the device are covered
/// (module docs), else burn's.
pub fn conv_transpose2d(layer: &ConvTranspose2d, x: Tensor<4>) -> Tensor<4> {
    let [k, kw] = layer.kernel_size;
    let [s, sw] = layer.stride;
    let [p, pw] = layer.padding;
    let [q, qw] = layer.padding_out;
    let plain = layer.groups == 1
        && layer.dilation == [1, 1]
        && k == kw
        && s == sw
        && p == pw
        && q == qw
        && q < s;
    let bias = layer.bias.as_ref().map(|b| b.val());
    let (true, Some(bias), true) = (plain, bias, on_cpu_kernels(&x)) else {
        return layer.forward(x);
    };
    let y = <Dispatch as TrainDeconv>::train_conv_transpose2d(
        x.into_dispatch(),
        layer.weight.val().into_dispatch(),
        bias.into_dispatch(),
        s,
        p,
        q,
    );
    Tensor::from_dispatch(y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::conv::ConvTranspose2dConfig;
    use burn::tensor::{Device, Distribution};

    use crate::testing::{close_to_largest as close, values};

    /// Ours against burn's `ConvTranspose2d::forward`: values, and the gradients of `Σ y ⊙ r`
    /// with respect to the input, weight and bias.
    fn check(n: usize, [ci, co]: [usize; 2], [h, w]: [usize; 2], k: usize, [s, p, q]: [usize; 3]) {
        let dev = Device::flex().autodiff();
        let layer: ConvTranspose2d = ConvTranspose2dConfig::new([ci, co], [k, k])
            .with_stride([s, s])
            .with_padding([p, p])
            .with_padding_out([q, q])
            .init(&dev);
        let x = Tensor::<4>::random([n, ci, h, w], Distribution::Normal(0.0, 1.0), &dev);
        let what = format!("n {n} {ci}->{co} {h}x{w} k {k} s {s} p {p} q {q}");
        let mut got = Vec::new();
        let mut r = None;
        for ours in [true, false] {
            let xi = x.clone().detach().require_grad();
            let y = if ours {
                conv_transpose2d(&layer, xi.clone())
            } else {
                layer.forward(xi.clone())
            };
            let r = r
                .get_or_insert_with(|| {
                    Tensor::random(y.dims(), Distribution::Normal(0.0, 1.0), &dev)
                })
                .clone();
            let grads = (y.clone() * r).sum().backward();
            let gx = xi.grad(&grads).unwrap();
            let gw = layer.weight.val().grad(&grads).unwrap();
            let gb = layer.bias.as_ref().unwrap().val().grad(&grads).unwrap();
            got.push([values(y), values(gx), values(gw), values(gb)]);
        }
        for (i, part) in ["y", "dx", "dw", "db"].iter().enumerate() {
            close(&format!("{what}: {part}"), &got[0][i], &got[1][i]);
        }
    }

    #[test]
    fn the_transposed_convolution_matches_burns_values_and_gradients() {
        // The generator's upsampling (3 × 3, stride 2, padding 1, output padding 1) at widths
        // the stride-2 kernels take (sixteens) and at widths they do not; one image; then
        // other geometries on the unrolled path: stride 1, a 4 × 4 kernel of stride 2 without
        // output padding, stride 3 with output padding 2, padding wider than the kernel's
        // reach into a one-pixel input.
        check(3, [32, 16], [4, 3], 3, [2, 1, 1]);
        check(2, [128, 64], [3, 4], 3, [2, 1, 1]);
        check(2, [5, 3], [4, 5], 3, [2, 1, 1]);
        check(1, [16, 32], [2, 2], 3, [2, 1, 1]);
        check(2, [4, 6], [5, 4], 3, [1, 1, 0]);
        check(2, [3, 4], [4, 4], 4, [2, 1, 0]);
        check(2, [3, 2], [3, 2], 3, [3, 0, 2]);
        check(2, [2, 3], [1, 1], 3, [1, 1, 0]);
    }
}
