//! Layer constructors the networks share: a convolution with explicit padding, instance norm
//! without affine parameters, batch norm.

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, InstanceNorm, InstanceNormConfig, PaddingConfig2d};
use burn::tensor::Device;

pub(crate) fn conv(
    c_in: usize,
    c_out: usize,
    k: usize,
    stride: usize,
    pad: usize,
    dev: &Device,
) -> Conv2d {
    Conv2dConfig::new([c_in, c_out], [k, k])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
        .init(dev)
}

/// Instance norm without affine parameters, as in the reference CycleGAN.
pub(crate) fn inorm(c: usize, dev: &Device) -> InstanceNorm {
    InstanceNormConfig::new(c).with_affine(false).init(dev)
}

pub(crate) fn bn(c: usize, dev: &Device) -> BatchNorm {
    BatchNormConfig::new(c).init(dev)
}
