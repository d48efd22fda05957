//! The networks of the TransForce trainer, in burn 0.22, and the CPU kernels they run on.
//!
//! The networks (each a burn `Module` built from a shape, on a [`Device`](burn::tensor::Device)):
//!
//! - [`ForceNet`], the force model: a ResNet [`Encoder`] (depth 18, 34 or 50: [`Depth`]) gives
//!   each frame an embedding, an LSTM runs over a sequence of them, an MLP with a sigmoid gives
//!   the force at each frame, in 0..1 of the force range (TransForce); or the MLP straight on
//!   the embedding (the `nolstm` control). Its shape is a [`ForceShape`]; its loss
//!   [`gamma_l1`].
//! - [`FastEncoder`]: the encoder compiled for inference on the CPU (batch norms folded,
//!   channels-last, fused epilogues), the same function as [`Encoder::forward`] in inference.
//! - [`Generator`] and [`Discriminator`], the CycleGAN's (ResNet-block generator, PatchGAN
//!   discriminator), of a [`GanShape`]; their losses [`lsgan`] and [`l1`].
//! - [`Inception`], the Inception-v3 of FID and KID, with the TensorFlow graph's weights.
//!
//! Where they compute and how they start ([`device`](mod@device) module): [`device()`] is the backend the
//! cargo features select (flex on the CPU; CUDA with `gpu`; wgpu with `wgpu`, Vulkan with
//! `vulkan`), [`build_networks`] and [`init_params`] draw a network's initial weights from its
//! seed alone, and [`on_pool`] runs a training loop on rayon's pool.
//!
//! On the flex device the networks' layers go through this crate's kernels ([`cpu`]): the
//! convolution, transposed convolution, norms, padding and leaky ReLU, forward and backward,
//! and Adam as [`FusedAdam`]; on a GPU, burn's own.

pub mod cpu;
pub mod device;
pub mod force_net;
pub mod gan;
pub mod inception;
mod layers;
pub mod loss;
#[cfg(test)]
mod testing;

pub use cpu::FusedAdam;
pub use device::{GPU, build_networks, device, float_params, init_params, on_pool};
pub use force_net::{Depth, Encoder, FastEncoder, ForceNet, ForceShape, ResUnit};
pub use gan::{DiscLayer, Discriminator, DownBlock, GanShape, Generator, ResBlock, UpBlock};
pub use inception::{FEATURE_DIM, Inception};
pub use loss::{gamma_l1, l1, lsgan};
