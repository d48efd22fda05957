//! The kernels beside burn's own, at shapes of the trainer's networks on 64 × 48 images:
//!
//! - a training step of one 3 × 3 convolution (forward and both gradients) of the ResNet's first
//!   stage, on [`rig_nn::cpu::conv2d`] and on burn's `Conv2d::forward`;
//! - the same for the batch norm with its ReLU ([`rig_nn::cpu::batch_norm_relu`] against burn's
//!   `BatchNorm::forward` then `relu`);
//! - the force model's encoder in inference on a batch of frames, compiled
//!   ([`rig_nn::FastEncoder`]) and as burn runs it ([`rig_nn::ForceNet::encode`]);
//! - FID's Inception-v3 on a batch of 32 × 24 frames ([`rig_nn::Inception::features`], the CPU
//!   inference form, against [`rig_nn::Inception::burn_features`]), when its weights are where
//!   `scripts/fetch-inception` puts them (`$RIG_INCEPTION_WEIGHTS`, else
//!   `${XDG_CACHE_HOME:-~/.cache}/rig/inception-fid.safetensors`); skipped, with a note, if not.
//!
//! `cargo bench -p rig-nn` times them; `cargo test --benches` runs each once.

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Distribution, Tensor};
use criterion::{Criterion, criterion_group, criterion_main};
use rig_nn::cpu::{batch_norm_relu, conv2d};
use rig_nn::{Depth, ForceNet, ForceShape};

/// Batch, channels and image of the first stage of the ResNet-18 the quick demo trains
/// (width 16 on 64 × 48 frames, 8 sequences of 8 frames).
const N: usize = 64;
const C: usize = 16;
const HW: [usize; 2] = [48, 64];

fn input(dev: &Device) -> Tensor<4> {
    Tensor::random([N, C, HW[0], HW[1]], Distribution::Normal(0.0, 1.0), dev)
}

/// One forward and backward of `layer` on `x`, the loss the sum of the output.
fn step(x: &Tensor<4>, layer: impl Fn(Tensor<4>) -> Tensor<4>) {
    let x = x.clone().detach().require_grad();
    let grads = layer(x.clone()).sum().backward();
    assert!(x.grad(&grads).is_some());
}

fn convolution(c: &mut Criterion) {
    let dev = Device::flex().autodiff();
    let conv: Conv2d = Conv2dConfig::new([C, C], [3, 3])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .init(&dev);
    let x = input(&dev);
    let mut g = c.benchmark_group("conv 3x3 16->16, 64 x 16 x 48 x 64, forward + backward");
    g.sample_size(10);
    g.bench_function("rig-nn", |b| b.iter(|| step(&x, |x| conv2d(&conv, x))));
    g.bench_function("burn", |b| b.iter(|| step(&x, |x| conv.forward(x))));
    g.finish();
}

fn batch_norm(c: &mut Criterion) {
    let dev = Device::flex().autodiff();
    let bn: BatchNorm = BatchNormConfig::new(C).init(&dev);
    let x = input(&dev);
    let mut g = c.benchmark_group("batch norm + relu, 64 x 16 x 48 x 64, forward + backward");
    g.sample_size(10);
    g.bench_function("rig-nn", |b| {
        b.iter(|| step(&x, |x| batch_norm_relu(&bn, x, None)))
    });
    g.bench_function("burn", |b| b.iter(|| step(&x, |x| relu(bn.forward(x)))));
    g.finish();
}

fn encoder(c: &mut Criterion) {
    let dev = Device::flex();
    let shape = ForceShape {
        depth: Depth::R18,
        width: C,
        embed: 64,
        lstm: true,
        residual: true,
        imagenet_stem: false,
        spatial: Some(ForceShape::final_map(false, HW[0], HW[1])),
    };
    let net = ForceNet::new(&shape, &dev);
    let fast = net
        .fast_encoder()
        .expect("the ResNet-18 encoder has a CPU inference form");
    let frames: Vec<Vec<u8>> = (0..8)
        .map(|i| {
            (0..HW[0] * HW[1] * 3)
                .map(|p| ((p * 7 + i * 13) % 256) as u8)
                .collect()
        })
        .collect();
    let refs: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
    let x = Tensor::<4>::random([8, 3, HW[0], HW[1]], Distribution::Uniform(-1.0, 1.0), &dev);
    let mut g = c.benchmark_group("ResNet-18 encoder, 8 frames of 64 x 48, inference");
    g.sample_size(10);
    g.bench_function("FastEncoder", |b| {
        b.iter(|| fast.encode(&refs, HW[1], HW[0]))
    });
    g.bench_function("burn", |b| b.iter(|| net.encode(x.clone()).into_data()));
    g.finish();
}

/// The Inception weights file, as `rig::train::inception` finds it by default.
fn inception_weights() -> std::path::PathBuf {
    if let Some(p) = std::env::var_os("RIG_INCEPTION_WEIGHTS") {
        return p.into();
    }
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .map(std::path::PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| std::path::Path::new(&h).join(".cache")))
        .unwrap_or_default();
    cache.join("rig").join("inception-fid.safetensors")
}

fn inception(c: &mut Criterion) {
    let path = inception_weights();
    let Ok(bytes) = std::fs::read(&path) else {
        eprintln!(
            "Inception bench skipped: no weights at {} (python3 scripts/fetch-inception)",
            path.display()
        );
        return;
    };
    let net = rig_nn::Inception::parse(&bytes, &Device::flex()).expect("the Inception weights");
    let (w, h) = (32, 24);
    let frames: Vec<Vec<u8>> = (0..8)
        .map(|i| {
            (0..w * h * 3)
                .map(|p| ((p * 7 + i * 13) % 256) as u8)
                .collect()
        })
        .collect();
    let refs: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
    let mut g = c.benchmark_group("Inception-v3 features, 8 frames of 32 x 24");
    g.sample_size(10);
    g.bench_function("inference form", |b| {
        b.iter(|| net.features(&refs, w, h, |_| {}).unwrap())
    });
    g.bench_function("burn", |b| {
        b.iter(|| net.burn_features(&refs, w, h, |_| {}).unwrap())
    });
    g.finish();
}

criterion_group!(benches, convolution, batch_norm, encoder, inception);
criterion_main!(benches);
