//! The CPU kernels the networks train and infer with on burn's flex backend, each reached
//! through a burn backend extension, so that burn's autodiff records them as one operation with
//! its own backward:
//!
//! - [`conv2d`]: the convolution, forward and both gradients on unrolled products, the 3 × 3
//!   layers on bordered channels-last copies, Winograd for the deep ones, direct AVX-512
//!   kernels where the CPU has them;
//! - [`conv_transpose2d`]: the generator's upsampling, as the adjoint of that convolution;
//! - [`batch_norm`], [`batch_norm_relu`] (with the ResNet's residual and ReLU fused in) and
//!   [`instance_norm`]: the norms in training mode;
//! - [`reflect_pad`] and [`leaky_relu`]: the generator's padding and the discriminator's
//!   activation;
//! - [`FusedAdam`]: Adam as one pass per parameter.
//!
//! Each falls back to burn's own operation for what it does not cover: other layouts, other
//! element types, and every GPU device. The tests check values and gradients against burn's.

mod act;
mod adam;
mod conv;
mod deconv;
mod kernels;
mod lanes;
mod norm;
mod pad;
mod simd;
mod unroll;
mod wino;

pub use act::leaky_relu;
pub use adam::FusedAdam;
pub use conv::conv2d;
pub(crate) use conv::symmetric;
pub use deconv::conv_transpose2d;
pub(crate) use kernels::{matmul, taps_major, three_rows};
pub use norm::{batch_norm, batch_norm_relu, instance_norm};
pub use pad::reflect_pad;
