//! The convolution the networks train with on the CPU: forward, input gradient and weight
//! gradient on our own kernels, reached through a burn backend extension.
//!
//! burn's flex backend has a convolution forward, but its autodiff takes the two gradients
//! from burn's generic formulas: the input gradient as a transposed convolution and the weight
//! gradient as a convolution with the batch as channels, each with its own layout copies. A
//! profile of the ResNet-18 training step had more time in those copies than in the matrix
//! products (docs/experiments.md). Here each image is one product on the classic unrolled
//! layout (Chellapilla, Puri and Simard 2006, "High performance convolutional neural networks
//! for document processing"), all NCHW, no copies beside the unrolling itself:
//!
//! - **forward:** `col = im2col(x_n)`, `[k·k·c_in, pixels]`; `y_n = W · col + b`, with `W` the
//!   weights as `[c_out, c_in·k·k]` (their own layout);
//! - **weight gradient:** `dW += dy_n · colᵀ`, summed over the images of a worker and then over
//!   workers; the bias gradient is the sum of `dy` over images and pixels;
//! - **input gradient:** `dcol = Wᵀ · dy_n`, folded back onto the image (`col2im`, the adjoint
//!   of the unrolling: every tap adds into the pixel it read).
//!
//! A 1 × 1 convolution of stride 1 without padding uses the image itself as `col`. A 3 × 3
//! convolution of stride 1 and padding 1, most of a ResNet's, is not unrolled at all: each
//! image (and `dy`) is copied once channels-last with a zero border, and every product reads
//! that copy with overlapping rows ([`three_rows`], as the encoder's inference form
//! [`crate::FastEncoder`] does): the forward and the input gradient (the convolution of `dy` with the kernel turned
//! by 180° and its channels swapped) are three products each, one per kernel row; the weight
//! gradient of kernel row `ky` is the transpose of that row's left side times `dy`, read from
//! the bordered copy the forward made (kept in the backward state while training). Where both
//! channel counts are at least [`wino::MIN_CHANNELS`] (or [`wino::MIN_CHANNELS_DIRECT`] where the
//! direct kernels below take the layer) and the image sizes even (a ResNet's
//! deeper stages), the forward and the input gradient go through Winograd's F(2 × 2, 3 × 3)
//! instead ([`wino`]: 2.25× fewer multiplications, a group of images per product). Images are
//! shared out over the rayon pool (one product per image on one thread); a batch smaller than
//! the pool runs its products multi-threaded instead. Transposes are strides handed to `gemm`.
//! The 3 × 3 path's products whose output channels come in sixteens run instead on the direct
//! AVX-512 kernels of [`super::simd`] where the CPU has them. With those kernels the 3 × 3
//! layers of stride 2 and padding 1 skip im2col too: their forward and weight gradient are the
//! same products on pixels two apart of the bordered image (kept for the weight gradient as
//! for stride 1; one image per thread, whatever the batch). Where their input channels come in
//! sixteens too, the input gradient goes by phases ([`simd::stride2_input_grad`]: each parity
//! of input row and column is reached by 1, 2, 2 or 4 of the 9 taps, a direct product each on
//! `dy` bordered channels-last); otherwise it stays on the unrolled path.
//!
//! A stride-1 convolution with few output channels (the generator's 7 × 7 head, 32 → 3) takes
//! the relation of the transposed convolution ([`super::deconv`]) the other way: its input
//! gradient is the forward of the "full" convolution of `dy` by the turned kernel
//! ([`turned_input_grad`]), and its weight gradient one sum per tap over the input put
//! channels-last ([`few_outputs_weight_grad`]), instead of the unrolled path's products with
//! three rows against a large unrolling.
//!
//! [`conv2d`] takes this path for f32 tensors on the flex device, with or without autodiff, for
//! any convolution with a bias, square kernel and stride, symmetric zero padding, no dilation
//! and one group; anything else (and every GPU device) goes to burn's own `Conv2d::forward`.
//! The tests check values and all three gradients against burn's on shapes that include padding
//! wider than the input and strides that skip pixels.

use std::mem::MaybeUninit;
use std::sync::Arc;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, DispatchDevice, Flex, backend_extension};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::tensor::{DType, Tensor};
use gemm::Parallelism;
use rayon::prelude::*;

use super::kernels::{
    Mat, add_into, as_slots, border, border_into, bordered_len, dense, flex, product, taps_major,
    three_rows, three_rows_grad, to_pixels, to_planes, unborder_into, unwritten, written, zeroed,
};
use super::unroll::Geom;
use super::unroll::{col2im, unrolled};
use super::{lanes, simd, wino};

/// The autodiff backend's float tensor over flex (its primitive and graph node).
type AdTensor = FloatTensor<Autodiff<Flex>>;

/// The convolution as a backend operation (NCHW, bias, square kernel `k` from the weight's
/// shape, `stride` and zero padding `pad` on both axes).
#[backend_extension(Flex, Autodiff)]
pub trait TrainConv: Backend {
    fn train_conv2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: usize,
        pad: usize,
    ) -> FloatTensor<Self>;
}

impl TrainConv for Flex {
    fn train_conv2d(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        stride: usize,
        pad: usize,
    ) -> FlexTensor {
        flex_conv(&x, &weight, &bias, stride, pad, false).0
    }
}

/// The forward on the flex backend; with `keep`, also the bordered input of the 3 × 3 path
/// for the weight gradient ([`forward`]).
fn flex_conv(
    x: &FlexTensor,
    weight: &FlexTensor,
    bias: &FlexTensor,
    stride: usize,
    pad: usize,
    keep: bool,
) -> (FlexTensor, Option<Arc<Vec<f32>>>) {
    let g = Geom::of(x, weight, stride, pad);
    let (y, kept) = forward(&g, &dense(x), &dense(weight), Some(&dense(bias)), keep);
    (flex(y, [g.n, g.o, g.ho, g.wo]), kept.map(Arc::new))
}

/// The backward step: the state is the forward's input (the autodiff tensor, for its node) and
/// weight (cheap `Arc` clones) and, for a 3 × 3 layer, the input as the forward bordered it
/// (one copy of the activation held until the backward pass, instead of a second bordering
/// there).
///
/// Where another consumer of the input registered its gradient first (a residual block's skip
/// path, or the shortcut's convolution), that gradient is taken out and added into each image's
/// input gradient by the worker that writes it. Left to `Gradients::register`, the sum is one
/// single-threaded pass over the whole activation with the workers idle: about 2 % of a
/// ResNet-34 step's wall time (docs/experiments.md).
#[derive(Debug)]
struct ConvBackward;

impl Backward<Flex, 3> for ConvBackward {
    type State = (AdTensor, FlexTensor, usize, usize, Option<Arc<Vec<f32>>>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_w, node_b] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x_ad, weight, stride, pad, kept) = ops.state;
        let x = x_ad.primitive();
        let g = Geom::of(x, &weight, stride, pad);
        let want = Want {
            dx: node_x.is_some(),
            dw: node_w.is_some(),
            db: node_b.is_some(),
        };
        let earlier = want.dx.then(|| grads.remove::<Flex>(&x_ad)).flatten();
        let shape = [g.n, g.c, g.h, g.w];
        let (acc, earlier) = match earlier {
            Some(e) if e.layout().shape().dims::<4>() == shape => (Some(e), None),
            other => (None, other),
        };
        let acc_d = acc.as_ref().map(dense);
        let kept = kept.as_deref().map(Vec::as_slice);
        let (x_d, w_d, dy_d) = (dense(x), dense(&weight), dense(&dy));
        // Few output channels: the gradients on the loops of [`turns`] and [`few_outputs`]
        // where they take them.
        let acc = acc_d.as_deref();
        let turned = want.dx && turns(&g);
        let few = want.dw && few_outputs(&g);
        let here = Want {
            dx: want.dx && !turned,
            dw: want.dw && !few,
            db: want.db,
        };
        let mut d = backward(&g, &x_d, kept, &w_d, &dy_d, acc, here);
        if turned {
            d.dx = Some(turned_input_grad(&g, &w_d, &dy_d, acc));
        }
        if few {
            d.dw = Some(few_outputs_weight_grad(&g, &x_d, &dy_d));
        }
        if let (Some(node), Some(e)) = (&node_x, earlier) {
            // Not of the input's shape (not expected): back as it was, for `register` to add.
            grads.register::<Flex>(node.id, e);
        }
        if let (Some(node), Some(dx)) = (node_x, d.dx) {
            grads.register::<Flex>(node.id, flex(dx, shape));
        }
        if let (Some(node), Some(dw)) = (node_w, d.dw) {
            grads.register::<Flex>(node.id, flex(dw, [g.o, g.c, g.k, g.k]));
        }
        if let (Some(node), Some(db)) = (node_b, d.db) {
            grads.register::<Flex>(node.id, flex(db, [g.o]));
        }
    }
}

impl<C: CheckpointStrategy> TrainConv for Autodiff<Flex, C> {
    fn train_conv2d(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        stride: usize,
        pad: usize,
    ) -> FloatTensor<Self> {
        let (xp, wp, bp) = (x.primitive(), weight.primitive(), bias.primitive());
        match ConvBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (y, kept) = flex_conv(xp, wp, bp, stride, pad, true);
                prep.finish((x, weight.into_primitive(), stride, pad, kept), y)
            }
            OpsKind::UnTracked(prep) => prep.finish(flex_conv(xp, wp, bp, stride, pad, false).0),
        }
    }
}

/// `conv.forward(x)`: on this module's kernels when they cover the layer and the device (module
/// docs), else burn's.
pub fn conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let Some((stride, pad, bias)) = covered(conv, &x) else {
        return conv.forward(x);
    };
    let y = <Dispatch as TrainConv>::train_conv2d(
        x.into_dispatch(),
        conv.weight.val().into_dispatch(),
        bias.into_dispatch(),
        stride,
        pad,
    );
    Tensor::from_dispatch(y)
}

/// The symmetric padding of a conv or pool, when it has one.
pub(crate) fn symmetric(p: &PaddingConfig2d) -> Option<usize> {
    match *p {
        PaddingConfig2d::Valid => Some(0),
        PaddingConfig2d::Explicit(t, l, b, r) if t == l && l == b && b == r => Some(t),
        _ => None,
    }
}

/// Stride, padding and bias of a layer this module computes, on a device it runs on.
fn covered(conv: &Conv2d, x: &Tensor<4>) -> Option<(usize, usize, Tensor<1>)> {
    let [_, _, kh, kw] = conv.weight.val().dims();
    let pad = symmetric(&conv.padding)?;
    let [_, _, h, w] = x.dims();
    let plain = conv.groups == 1
        && conv.dilation == [1, 1]
        && kh == kw
        && conv.stride[0] == conv.stride[1]
        && conv.stride[0] > 0
        && h + 2 * pad >= kh
        && w + 2 * pad >= kw;
    if !plain || !on_cpu_kernels(x) {
        return None;
    }
    let bias = conv.bias.as_ref()?.val();
    Some((conv.stride[0], pad, bias))
}

/// Whether `x` is an f32 tensor on the flex device (with or without autodiff): what the
/// extensions of this module and [`super::norm`] are implemented for.
pub(super) fn on_cpu_kernels<const D: usize>(x: &Tensor<D>) -> bool {
    matches!(x.device().inner().as_dispatch(), DispatchDevice::Flex(_)) && x.dtype() == DType::F32
}

/// Image `i` of `x` bordered, for the weight gradient of the 3 × 3 and stride-2 paths: as the
/// forward kept it (`kept`, `n` × [`bordered_len`] floats) or, without it, bordered again into
/// `col`.
fn bordered_input<'a>(
    g: &Geom,
    x: &[f32],
    kept: Option<&'a [f32]>,
    i: usize,
    col: &'a mut Vec<f32>,
) -> &'a [f32] {
    let per_pad = bordered_len([g.c, g.h, g.w]);
    match kept {
        Some(k) => &k[i * per_pad..][..per_pad],
        None => {
            border(&x[i * g.image()..][..g.image()], [g.c, g.h, g.w], col);
            col
        }
    }
}

/// Work shared out by image when the batch fills the pool, else each product multi-threaded.
fn split(n: usize) -> (usize, Parallelism) {
    let threads = rayon::current_num_threads().max(1);
    if n >= threads {
        (n.div_ceil(threads), Parallelism::None)
    } else {
        (n.max(1), Parallelism::Rayon(threads))
    }
}

/// The convolution's output; with `keep`, also every image as the 3 × 3 and stride-2 paths
/// [`border`]ed it (`n` × [`bordered_len`] floats), which the weight gradient reads again
/// (`None` for the other paths).
pub(super) fn forward(
    g: &Geom,
    x: &[f32],
    w: &[f32],
    b: Option<&[f32]>,
    keep: bool,
) -> (Vec<f32>, Option<Vec<f32>>) {
    let (pix, taps) = (g.pixels(), g.taps());
    let mut y = unwritten(g.n * g.o * pix);
    let (chunk, par) = split(g.n);
    let bias = |o: usize| b.map_or(0.0, |b| b[o]);
    let wk = g.bordered().then(|| taps_major(w, [g.o, g.c, 3], false));
    let per_pad = bordered_len([g.c, g.h, g.w]);
    let mut kept = (keep && g.bordered()).then(|| unwritten(g.n * per_pad));
    // The deep layers' kernels for Winograd, when the layer takes that path.
    let wino = wk
        .as_ref()
        .filter(|_| g.three() && wino::fits(g.c, g.o, g.h, g.w))
        .map(|wk| wino::kernels(wk, g.c, g.o));
    // `col` is the unrolled image, or the bordered one (unless it goes to `slot`, kept) and the
    // product on the padded width.
    let per_image = |col: &mut Vec<f32>,
                     wide: &mut Vec<f32>,
                     i: usize,
                     y_n: &mut [MaybeUninit<f32>],
                     slot: Option<&mut [MaybeUninit<f32>]>| {
        let x_n = &x[i * g.image()..][..g.image()];
        if let Some(wk) = &wk {
            let wp = g.w + 2;
            let pad: &[f32] = match slot {
                Some(slot) => border_into(x_n, [g.c, g.h, g.w], slot),
                None => {
                    border(x_n, [g.c, g.h, g.w], col);
                    col
                }
            };
            if g.stride2() {
                wide.resize(pix * g.o, 0.0);
                simd::stride2_rows(pad, [wp, g.c], [g.ho, g.wo], wk, g.o, wide);
                to_planes(wide, [g.o, pix], b, pix, y_n);
                return;
            }
            wide.resize(g.h * wp * g.o, 0.0);
            three_rows(pad, [wp, g.c, g.h * wp], wk, g.o, wide, par);
            unborder_into(wide, [g.o, g.h, g.w], b, y_n);
            return;
        }
        // The bias first; the product adds onto it.
        for (o, row) in y_n.chunks_mut(pix).enumerate() {
            row.fill(MaybeUninit::new(bias(o)));
        }
        // SAFETY: every element of `y_n` was written just above.
        let y_n = unsafe { &mut *(y_n as *mut [MaybeUninit<f32>] as *mut [f32]) };
        let rhs = unrolled(g, x_n, col);
        product(
            y_n,
            [g.o, pix, taps],
            true,
            Mat::rows(w, taps),
            Mat::rows(rhs, pix),
            par,
        );
    };
    // A group of images through Winograd: bordered (into their kept slots, else `own`), then
    // convolved together.
    let winograd = |u: &[f32],
                    first: usize,
                    ys: &mut [MaybeUninit<f32>],
                    mut pads: Option<&mut [MaybeUninit<f32>]>| {
        let count = ys.len() / (g.o * pix);
        let group = wino::group(g.h, g.w);
        let (mut own, mut scratch) = (Vec::new(), wino::Scratch::kept());
        for start in (0..count).step_by(group) {
            let len = group.min(count - start);
            let slots = match pads.as_deref_mut() {
                Some(p) => &mut p[start * per_pad..][..len * per_pad],
                None => {
                    own.resize(len * per_pad, 0.0);
                    as_slots(&mut own[..len * per_pad])
                }
            };
            let imgs: Vec<&[f32]> = slots
                .chunks_mut(per_pad)
                .enumerate()
                .map(|(j, slot)| {
                    let i = first + start + j;
                    &*border_into(&x[i * g.image()..][..g.image()], [g.c, g.h, g.w], slot)
                })
                .collect();
            let out = &mut ys[start * g.o * pix..][..len * g.o * pix];
            wino::convolve(&imgs, [g.c, g.h, g.w], u, g.o, b, par, &mut scratch, out);
        }
    };
    let worker =
        |c: usize, ys: &mut [MaybeUninit<f32>], mut pads: Option<&mut [MaybeUninit<f32>]>| {
            if let Some(u) = &wino {
                return winograd(u, c * chunk, ys, pads);
            }
            let (mut col, mut wide) = (Vec::new(), Vec::new());
            for (j, y_n) in ys.chunks_mut(g.o * pix).enumerate() {
                let slot = pads
                    .as_deref_mut()
                    .map(|p| &mut p[j * per_pad..][..per_pad]);
                per_image(&mut col, &mut wide, c * chunk + j, y_n, slot);
            }
        };
    let ys = y.par_chunks_mut(chunk * g.o * pix).enumerate();
    match kept.as_mut() {
        Some(k) => ys
            .zip(k.par_chunks_mut(chunk * per_pad))
            .for_each(|((c, ys), pads)| worker(c, ys, Some(pads))),
        None => ys.for_each(|(c, ys)| worker(c, ys, None)),
    }
    // SAFETY: the chunks cover `y` and `per_image` writes every element of its image (the
    // 3 × 3 path through `unborder_into`, which writes every index of `o × h × w`, and here
    // `ho × wo = h × w`; the stride-2 path through `to_planes`, every index of `o × ho × wo`),
    // as `winograd` does for each image of its groups (`wino::convolve` writes every index of
    // each image's `o × h × w`); the chunks of `kept` match those of `y` image for image, and
    // `border_into` writes every element of its slot.
    unsafe { (written(y), kept.map(|k| written(k))) }
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Want {
    pub(super) dx: bool,
    pub(super) dw: bool,
    pub(super) db: bool,
}

pub(super) struct Grads {
    pub(super) dx: Option<Vec<f32>>,
    pub(super) dw: Option<Vec<f32>>,
    pub(super) db: Option<Vec<f32>>,
}

/// The gradients; `kept` is the forward's bordered input of the 3 × 3 path (see [`forward`]),
/// or `None` to border `x` again; `acc`, of `x`'s shape, is added into the input gradient.
pub(super) fn backward(
    g: &Geom,
    x: &[f32],
    kept: Option<&[f32]>,
    w: &[f32],
    dy: &[f32],
    acc: Option<&[f32]>,
    want: Want,
) -> Grads {
    let (pix, taps) = (g.pixels(), g.taps());
    let (chunk, par) = split(g.n);
    let dw_len = if want.dw { g.o * taps } else { 0 };
    let db_len = if want.db { g.o } else { 0 };
    // The 3 × 3 path's input-gradient weights (its weight gradient comes out as `[9c, o]`).
    let wd = (g.three() && want.dx).then(|| taps_major(w, [g.o, g.c, 3], true));
    // The same through Winograd for the deep layers (`o` channels in, `c` out).
    let wino_d = wd
        .as_ref()
        .filter(|_| wino::fits(g.o, g.c, g.h, g.w))
        .map(|wd| wino::kernels(wd, g.o, g.c));
    let (per_dy, group) = (bordered_len([g.o, g.h, g.w]), wino::group(g.h, g.w));
    // The stride-2 path's input gradient by phases, when its `c` channels come in sixteens.
    let phases = (g.stride2() && want.dx && simd::covers(g.c))
        .then(|| simd::stride2_phase_weights(w, g.o, g.c));
    // `acc`'s images `i..i + count` into `dx`, which holds them written.
    let add_acc = |dx: &mut [MaybeUninit<f32>], i: usize, count: usize| {
        if let Some(acc) = acc {
            let acc = &acc[i * g.image()..][..count * g.image()];
            for (d, &a) in dx[..acc.len()].iter_mut().zip(acc) {
                // SAFETY: every caller passes images that `work` has written in full.
                d.write(unsafe { d.assume_init() } + a);
            }
        }
    };
    // One worker's images: `first..first + count`, its input-gradient slice if wanted; returns
    // its partial weight and bias gradients.
    let work = |first: usize, count: usize, mut dx: Option<&mut [MaybeUninit<f32>]>| {
        let mut dw = vec![0.0f32; dw_len];
        let mut db = vec![0.0f32; db_len];
        let (mut col, mut dcol, mut wide) = (Vec::new(), Vec::new(), Vec::new());
        let (mut dgroup, mut pending, mut scratch) = (Vec::new(), 0, wino::Scratch::kept());
        for j in 0..count {
            let i = first + j;
            let dy_n = &dy[i * g.o * pix..][..g.o * pix];
            if want.db {
                for (acc, row) in db.iter_mut().zip(dy_n.chunks(pix)) {
                    // `sum_of`'s sums, compiled for the widest vectors the CPU has: on the
                    // baseline's SSE2 its f64 conversions were half of this closure's time.
                    *acc += lanes::plane_sum(row) as f32;
                }
            }
            if g.three() {
                // `dyb` holds `dy` bordered: the input gradient is the convolution of `dy`
                // with the turned kernel (`wd`), and the weight gradient for kernel row `ky` is
                // `L_kyᵀ · dy` on the padded width (whose discarded columns are the border's
                // zeros in `dyb`).
                let wp = g.w + 2;
                let m = g.h * wp;
                // Through Winograd, `dy` is bordered into the next slot of `dgroup`, and the
                // input gradients of the group are computed together once it is full.
                let dyb: &[f32] = match &wino_d {
                    Some(_) => {
                        dgroup.resize((pending + 1) * per_dy, 0.0);
                        let slot = &mut dgroup[pending * per_dy..][..per_dy];
                        border_into(dy_n, [g.o, g.h, g.w], as_slots(slot));
                        &dgroup[pending * per_dy..][..per_dy]
                    }
                    None => {
                        border(dy_n, [g.o, g.h, g.w], &mut dcol);
                        &dcol
                    }
                };
                if want.dw {
                    let pad = bordered_input(g, x, kept, i, &mut col);
                    let dy_wide = &dyb[(wp + 1) * g.o..][..m * g.o];
                    three_rows_grad(pad, [wp, g.c, m], dy_wide, g.o, &mut dw, par);
                }
                if let (Some(dx), Some(ud)) = (dx.as_deref_mut(), &wino_d) {
                    pending += 1;
                    if pending == group || j + 1 == count {
                        let first_j = j + 1 - pending;
                        let dys: Vec<&[f32]> = dgroup.chunks(per_dy).take(pending).collect();
                        let out = &mut dx[first_j * g.image()..][..pending * g.image()];
                        wino::convolve(
                            &dys,
                            [g.o, g.h, g.w],
                            ud,
                            g.c,
                            None,
                            par,
                            &mut scratch,
                            out,
                        );
                        add_acc(out, first + first_j, pending);
                        pending = 0;
                    }
                } else if let (Some(dx), Some(wd)) = (dx.as_deref_mut(), &wd) {
                    let dx_n = &mut dx[j * g.image()..][..g.image()];
                    wide.resize(m * g.c, 0.0);
                    three_rows(dyb, [wp, g.o, m], wd, g.c, &mut wide, par);
                    unborder_into(&wide, [g.c, g.h, g.w], None, dx_n);
                    add_acc(dx_n, i, 1);
                }
                continue;
            }
            // The stride-2 path's `dy` bordered channels-last, once for both its weight gradient
            // (the interior rows) and its input gradient by phases.
            let dyb: Option<&[f32]> = if g.stride2() && (want.dw || phases.is_some()) {
                dcol.resize(bordered_len([g.o, g.ho, g.wo]), 0.0);
                Some(border_into(dy_n, [g.o, g.ho, g.wo], as_slots(&mut dcol)))
            } else {
                None
            };
            if let (true, Some(dyb)) = (want.dw, dyb) {
                let pad = bordered_input(g, x, kept, i, &mut col);
                let (dims, row) = ([g.ho, g.wo], (g.wo + 2) * g.o);
                let interior = &dyb[row + g.o..];
                simd::stride2_rows_grad(pad, [g.w + 2, g.c], dims, interior, row, g.o, &mut dw);
            } else if want.dw {
                let cols = unrolled(g, &x[i * g.image()..][..g.image()], &mut col);
                product(
                    &mut dw,
                    [g.o, taps, pix],
                    j > 0,
                    Mat::rows(dy_n, pix),
                    Mat::transposed(cols, pix),
                    par,
                );
            }
            if let (Some(dx), Some(phases), Some(dyb)) = (dx.as_deref_mut(), &phases, dyb) {
                // The gradient channels-last, then to planes.
                let (dims, pin) = ([g.h, g.w, g.c], g.h * g.w);
                wide.resize(pin * g.c, 0.0);
                simd::stride2_input_grad(dyb, [g.ho, g.wo, g.o], phases, dims, &mut wide);
                let dx_n = &mut dx[j * g.image()..][..g.image()];
                to_planes(&wide, [g.c, pin], None, pin, dx_n);
            } else if let Some(dx) = dx.as_deref_mut() {
                let dx_n = zeroed(&mut dx[j * g.image()..][..g.image()]);
                let wt = Mat::transposed(w, taps);
                if g.direct() {
                    product(dx_n, [g.c, pix, g.o], false, wt, Mat::rows(dy_n, pix), par);
                } else {
                    dcol.resize(taps * pix, 0.0);
                    product(
                        &mut dcol,
                        [taps, pix, g.o],
                        false,
                        wt,
                        Mat::rows(dy_n, pix),
                        par,
                    );
                    col2im(g, &dcol, dx_n);
                }
            }
            if let Some(dx) = dx.as_deref_mut() {
                // Both branches above wrote image `j` in full.
                add_acc(&mut dx[j * g.image()..][..g.image()], i, 1);
            }
        }
        (dw, db)
    };
    // Not zeroed here, on the calling thread: each worker writes its images in full.
    let mut dx = want.dx.then(|| unwritten(g.n * g.image()));
    let parts: Vec<(Vec<f32>, Vec<f32>)> = match dx.as_mut() {
        Some(dx) => dx
            .par_chunks_mut(chunk * g.image())
            .enumerate()
            .map(|(c, dxs)| work(c * chunk, dxs.len() / g.image(), Some(dxs)))
            .collect(),
        None => (0..g.n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| work(c * chunk, chunk.min(g.n - c * chunk), None))
            .collect(),
    };
    // The workers' partial sums added in order (the first as the start: `0 + a` is `a`), the
    // weight gradient's in parallel blocks: a 256-channel 4 × 4 layer's is 2 MB.
    let mut parts = parts.into_iter();
    let (mut dw, mut db) = parts
        .next()
        .unwrap_or_else(|| (vec![0.0f32; dw_len], vec![0.0f32; db_len]));
    for (pw, pb) in parts {
        add_into(&mut dw, &pw);
        for (a, v) in db.iter_mut().zip(&pb) {
            *a += v;
        }
    }
    if g.bordered() && want.dw {
        // `[9c, o]` in (ky, kx, ci) order back to the weight's `[o, c, 3, 3]`.
        let mut out = unwritten(dw.len());
        out.par_chunks_mut((g.c * 9).max(1))
            .enumerate()
            .for_each(|(oo, kernel)| {
                for (ci, taps) in kernel.chunks_exact_mut(9).enumerate() {
                    for (t, v) in taps.iter_mut().enumerate() {
                        v.write(dw[(t * g.c + ci) * g.o + oo]);
                    }
                }
            });
        // SAFETY: the `o` kernels of `9c` floats cover `out`, each written in full.
        dw = unsafe { written(out) };
    }
    Grads {
        // SAFETY: the chunks cover `dx`, and `work` writes every element of each image it is
        // given: the 3 × 3 path through `unborder_into` (every index of `c × h × w`) or, for its
        // groups, `wino::convolve` (every index of each image's `c × h × w`, the last group
        // flushed at the worker's last image), the others zero the image first (`zeroed`).
        dx: dx.map(|v| unsafe { written(v) }),
        dw: want.dw.then_some(dw),
        db: want.db.then_some(db),
    }
}

/// Whether a convolution's input gradient goes through [`turned_input_grad`]: stride 1, at
/// most four output channels (the generator's 7 × 7 head, 32 → 3), padding below the kernel.
/// The unrolled path would multiply `Wᵀ · dy` into a `c·k·k × pixels` unrolling with only `o`
/// terms a sum and fold it back (`col2im`): for the head 1568 × 768 floats an image, written
/// and read again for 3 terms each, which made its backward the costliest layer of a CycleGAN
/// step.
pub(super) fn turns(g: &Geom) -> bool {
    g.s == 1 && g.o <= 4 && g.p < g.k
}

/// The input gradient of a stride-1 convolution `g` (`[n, c, h, w]` in, `o` channels out, a
/// `k × k` kernel `w` of `[o, c, k, k]`, padding `p`) as a forward convolution of `dy` into `c`
/// channels by the kernel turned by 180° with its channel axes swapped, padding `k − 1 − p`
/// (the "full" convolution; Dumoulin and Visin 2016, §4.1): an unrolling of `o·k·k` rows and
/// `c` outputs a pixel. `acc` (of the input's shape) is added in.
pub(super) fn turned_input_grad(
    g: &Geom,
    weight: &[f32],
    dy: &[f32],
    acc: Option<&[f32]>,
) -> Vec<f32> {
    let (n, c, o, k) = (g.n, g.c, g.o, g.k);
    let mut turned = vec![0.0f32; weight.len()];
    for (ci, kernels) in turned.chunks_mut(o * k * k).enumerate() {
        for (oi, taps) in kernels.chunks_mut(k * k).enumerate() {
            let from = &weight[(oi * c + ci) * k * k..][..k * k];
            for (t, v) in taps.iter_mut().enumerate() {
                *v = from[k * k - 1 - t];
            }
        }
    }
    let full = Geom::new([n, o, g.ho, g.wo], c, k, 1, k - 1 - g.p);
    let (mut dx, _) = forward(&full, dy, &turned, None, false);
    if let Some(acc) = acc {
        add_into(&mut dx, acc);
    }
    dx
}

/// Whether the weight gradient goes through [`few_outputs_weight_grad`]: besides [`turns`],
/// no padding and input channels in sixteens (the head's 32).
pub(super) fn few_outputs(g: &Geom) -> bool {
    turns(g) && g.p == 0 && g.c.is_multiple_of(16)
}

/// The weight gradient of a stride-1, unpadded convolution with few output channels (see
/// [`few_outputs`]): `dw[o, c, ky, kx] = Σ_images Σ_(y, x) dy[o, y, x] · x[c, y + ky, x + kx]`,
/// the images put channels-last once, then a task per tap ([`lanes::tap_grad`]). The unrolled
/// path's product `dy · colᵀ` has `o` rows: for the head, three rows against a 1568 × 768
/// unrolling written for them alone. With the input gradient already turned, the head's
/// backward at batch 4 took 1.4 ms on that product and 0.6 ms with this sum (docs/experiments.md).
pub(super) fn few_outputs_weight_grad(g: &Geom, x: &[f32], dy: &[f32]) -> Vec<f32> {
    let (n, c, w, o, k, ho, wo) = (g.n, g.c, g.w, g.o, g.k, g.ho, g.wo);
    let plane = g.h * w;
    let mut xcl = unwritten(n * c * plane);
    xcl.par_chunks_mut(c * plane)
        .zip(x.par_chunks(c * plane))
        .for_each(|(dst, src)| to_pixels(src, [c, plane], plane, dst));
    // SAFETY: `to_pixels` wrote each image's `plane` pixels of `c` floats: every element.
    let xcl = unsafe { written(xcl) };
    let zeros = vec![0.0f32; ho * wo];
    let images: Vec<(&[f32], [&[f32]; 4])> = (0..n)
        .map(|i| {
            let planes = std::array::from_fn(|oi| {
                if oi < o {
                    &dy[(i * o + oi) * ho * wo..][..ho * wo]
                } else {
                    &zeros[..]
                }
            });
            (&xcl[i * c * plane..][..c * plane], planes)
        })
        .collect();
    let by_tap: Vec<Vec<f32>> = (0..k * k)
        .into_par_iter()
        .map(|t| {
            let mut out = vec![0.0f32; o * c];
            lanes::tap_grad(&images, [c, w, ho, wo], [t / k, t % k], &mut out);
            out
        })
        .collect();
    let mut dw = vec![0.0f32; o * c * k * k];
    for (t, tap) in by_tap.iter().enumerate() {
        for (oc, &v) in tap.iter().enumerate() {
            dw[oc * k * k + t] = v;
        }
    }
    dw
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::PaddingConfig2d;
    use burn::nn::conv::Conv2dConfig;
    use burn::tensor::{Device, Distribution};

    use crate::testing::{close_to_largest as close, values};

    /// Our convolution against burn's `Conv2d::forward`: values, and the gradients of
    /// `Σ y ⊙ r` for a random `r` with respect to the input, weight and bias; then again with
    /// `Σ x ⊙ q` added, a second use of the input after the convolution (a residual block's
    /// skip path), whose gradient the convolution's backward finds registered and adds in.
    fn check(n: usize, c: usize, o: usize, hw: [usize; 2], k: usize, s: usize, p: usize) {
        check_with(n, c, o, hw, k, s, p, false);
        check_with(n, c, o, hw, k, s, p, true);
    }

    #[allow(clippy::too_many_arguments)]
    fn check_with(
        n: usize,
        c: usize,
        o: usize,
        [h, w]: [usize; 2],
        k: usize,
        s: usize,
        p: usize,
        skip: bool,
    ) {
        let dev = Device::flex().autodiff();
        let conv: Conv2d = Conv2dConfig::new([c, o], [k, k])
            .with_stride([s, s])
            .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
            .init(&dev);
        let x = Tensor::<4>::random([n, c, h, w], Distribution::Normal(0.0, 1.0), &dev);
        let q = Tensor::<4>::random([n, c, h, w], Distribution::Normal(0.0, 1.0), &dev);
        let what = format!("n {n} c {c} o {o} {h}x{w} k {k} s {s} p {p} skip {skip}");
        assert!(covered(&conv, &x).is_some(), "{what}: not covered");
        let mut got = Vec::new();
        let mut r = None;
        for ours in [true, false] {
            let xi = x.clone().detach().require_grad();
            let y = if ours {
                conv2d(&conv, xi.clone())
            } else {
                conv.forward(xi.clone())
            };
            let r = r
                .get_or_insert_with(|| {
                    Tensor::random(y.dims(), Distribution::Normal(0.0, 1.0), &dev)
                })
                .clone();
            let mut loss = (y.clone() * r).sum();
            if skip {
                loss = loss + (xi.clone() * q.clone()).sum();
            }
            let grads = loss.backward();
            let gx = xi.grad(&grads).unwrap();
            let gw = conv.weight.val().grad(&grads).unwrap();
            let gb = conv.bias.as_ref().unwrap().val().grad(&grads).unwrap();
            got.push([values(y), values(gx), values(gw), values(gb)]);
        }
        for (i, part) in ["y", "dx", "dw", "db"].iter().enumerate() {
            close(&format!("{what}: {part}"), &got[0][i], &got[1][i]);
        }
    }

    #[test]
    fn the_training_convolution_matches_burns_values_and_gradients() {
        // The encoder's and the generator's layer kinds: 3 × 3 same, strided, 1 × 1 and its
        // strided shortcut, the 7 × 7 stem, and the discriminator's 4 × 4 stride 2.
        check(3, 4, 5, [9, 7], 3, 1, 1);
        check(3, 4, 6, [9, 7], 3, 2, 1);
        check(3, 8, 6, [6, 5], 1, 1, 0);
        check(3, 8, 6, [6, 5], 1, 2, 0);
        check(2, 3, 4, [13, 11], 7, 2, 3);
        check(2, 3, 4, [12, 10], 4, 2, 1);
        // One image, fewer than the pool's threads: the products run multi-threaded instead.
        check(1, 4, 5, [9, 7], 3, 1, 1);
    }

    #[test]
    fn padding_wider_than_the_image_and_strides_that_skip_taps_stay_exact() {
        // A 2 × 3 image under a 5 × 5 kernel with padding 3: some taps see only padding, some
        // rows of the unrolling are all zero, and stride 3 skips input columns entirely.
        check(2, 2, 3, [2, 3], 5, 1, 3);
        check(2, 2, 3, [2, 3], 5, 3, 3);
        check(2, 2, 3, [1, 1], 3, 1, 1);
        // The 3 × 3, stride-1, padding-1 path (bordered, no im2col): one row, a width that is
        // a multiple of the vector width, more channels out than in and the reverse.
        check(2, 5, 16, [1, 9], 3, 1, 1);
        check(4, 16, 8, [6, 16], 3, 1, 1);
        // Winograd's channel counts: more out than in, the reverse, one 2 × 2 block, and an
        // odd size (direct); the batch of 5 splits unevenly over the workers.
        check(5, 32, 40, [6, 8], 3, 1, 1);
        check(2, 48, 32, [2, 2], 3, 1, 1);
        check(2, 32, 32, [5, 6], 3, 1, 1);
        // ... and where the direct AVX-512 kernels keep 32 channels direct (`MIN_CHANNELS_DIRECT`):
        // 64 each way, more out than in and the reverse.
        check(3, 64, 64, [6, 8], 3, 1, 1);
        check(2, 64, 96, [4, 4], 3, 1, 1);
        check(2, 96, 64, [2, 6], 3, 1, 1);
        // Larger images: Winograd's groups hold one image each.
        check(3, 32, 32, [32, 34], 3, 1, 1);
        // Stride 2 with outputs in sixteens (the direct kernels on AVX-512): even and odd
        // sizes, one input channel to many, and a width past one tile of 24 outputs.
        check(3, 16, 32, [8, 12], 3, 2, 1);
        check(2, 5, 16, [9, 7], 3, 2, 1);
        check(2, 1, 48, [3, 3], 3, 2, 1);
        check(2, 16, 64, [4, 58], 3, 2, 1);
        // ... whose input gradients go by phases where the inputs come in sixteens too: odd
        // sizes (the last row and column of a phase read the zero border), 32 input channels
        // (two column blocks), a single pixel (three of the four phases empty).
        check(2, 16, 32, [7, 9], 3, 2, 1);
        check(3, 32, 16, [5, 3], 3, 2, 1);
        check(2, 32, 16, [1, 1], 3, 2, 1);
        // Input exactly the kernel's size, no padding: one output pixel.
        check(2, 3, 2, [3, 3], 3, 1, 0);
    }

    #[test]
    fn layers_with_few_outputs_take_the_turned_input_gradient_and_the_per_tap_weights() {
        // At most four outputs, stride 1 (`turns`): the generator's 7 × 7 head of 32
        // channels into 3, unpadded (both gradients on the few-output loops), with 4 outputs and
        // 16 inputs, and a padded layer (the discriminator's last, 4 × 4 padding 1, into one
        // score; its weight gradient on the unrolled path) and padding 2 of a 5 × 5 kernel on
        // channels not in sixteens. The second run of each (`check`'s `skip`) adds a gradient
        // registered earlier into the turned input gradient.
        check(2, 32, 3, [12, 14], 7, 1, 0);
        check(3, 16, 4, [9, 8], 3, 1, 0);
        check(2, 64, 1, [3, 4], 4, 1, 1);
        check(1, 5, 2, [7, 6], 5, 1, 2);
    }

    #[test]
    fn layers_the_kernels_do_not_cover_fall_back_to_burn() {
        let dev = Device::flex();
        let x = Tensor::<4>::zeros([1, 2, 6, 6], &dev);
        let dilated: Conv2d = Conv2dConfig::new([2, 2], [3, 3])
            .with_dilation([2, 2])
            .init(&dev);
        assert!(covered(&dilated, &x).is_none());
        let no_bias: Conv2d = Conv2dConfig::new([2, 2], [3, 3])
            .with_bias(false)
            .init(&dev);
        assert!(covered(&no_bias, &x).is_none());
        let lopsided: Conv2d = Conv2dConfig::new([2, 2], [3, 3])
            .with_padding(PaddingConfig2d::Explicit(1, 0, 1, 0))
            .init(&dev);
        assert!(covered(&lopsided, &x).is_none());
        // Still the same function through burn's path.
        assert_eq!(conv2d(&no_bias, x.clone()).dims(), [1, 2, 4, 4]);
    }
}
