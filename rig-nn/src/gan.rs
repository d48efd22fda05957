//! The CycleGAN's networks (Zhu et al., "Unpaired Image-to-Image Translation using
//! Cycle-Consistent Adversarial Networks", 2017):
//!
//! - [`Generator`]: ResNet blocks with instance norm and reflection padding (c7s1-k, d2k, d4k,
//!   R4k × n, u2k, uk, c7s1-3);
//! - [`Discriminator`]: the PatchGAN of the same paper (its 70×70 design: C64-C128-C256-C512,
//!   4×4 kernels, LeakyReLU 0.2, no norm on the first layer).

use burn::module::Module;
use burn::nn::InstanceNorm;
use burn::nn::conv::{Conv2d, ConvTranspose2d, ConvTranspose2dConfig};
use burn::tensor::activation::tanh;
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

use crate::cpu::{conv_transpose2d, conv2d, instance_norm, leaky_relu, reflect_pad};
use crate::layers::{conv, inorm};

/// Size of a CycleGAN. The paper's defaults are `ngf = ndf = 64`, 9 residual blocks at 256 px
/// and 3 discriminator layers; small images on a CPU want far less.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GanShape {
    pub ngf: usize,
    pub ndf: usize,
    pub res_blocks: usize,
    pub disc_layers: usize,
    /// The generator's stride-2 downsamplings before its residual blocks (and as many
    /// upsamplings after them). The reference has 2, made for 256 px images, whose residual
    /// blocks then work on 64 × 64 maps. On a 32 × 24 image two leave an 8 × 6 map, coarser than
    /// the markers' 3 px pitch, so the generator has to redraw every marker from a summary; one
    /// keeps a 16 × 12 map. Image sides must be multiples of 2^down. Translators saved before
    /// the field existed had 2.
    #[serde(default = "reference_downsamplings")]
    pub down: usize,
}

fn reference_downsamplings() -> usize {
    2
}

#[derive(Module, Debug)]
pub struct ResBlock {
    conv1: Conv2d,
    norm1: InstanceNorm,
    conv2: Conv2d,
    norm2: InstanceNorm,
}

impl ResBlock {
    fn new(c: usize, dev: &Device) -> Self {
        Self {
            conv1: conv(c, c, 3, 1, 0, dev),
            norm1: inorm(c, dev),
            conv2: conv(c, c, 3, 1, 0, dev),
            norm2: inorm(c, dev),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let y = conv2d(&self.conv1, reflect_pad(x.clone(), 1));
        let y = instance_norm(&self.norm1, y, None, true);
        let y = conv2d(&self.conv2, reflect_pad(y, 1));
        instance_norm(&self.norm2, y, Some(x), false)
    }
}

#[derive(Module, Debug)]
pub struct DownBlock {
    conv: Conv2d,
    norm: InstanceNorm,
}

#[derive(Module, Debug)]
pub struct UpBlock {
    conv: ConvTranspose2d,
    norm: InstanceNorm,
}

/// ResNet-block generator: RGB in [-1, 1] to RGB in [-1, 1], same size (height and width must be
/// multiples of 2^[`GanShape::down`]).
#[derive(Module, Debug)]
pub struct Generator {
    stem: Conv2d,
    stem_norm: InstanceNorm,
    down: Vec<DownBlock>,
    blocks: Vec<ResBlock>,
    up: Vec<UpBlock>,
    head: Conv2d,
}

impl Generator {
    pub fn new(shape: &GanShape, dev: &Device) -> Self {
        let k = shape.ngf.max(1);
        // Channels double at each downsampling and halve again on the way up.
        let widths: Vec<usize> = (0..=shape.down).map(|i| k << i).collect();
        let down = widths
            .windows(2)
            .map(|w| DownBlock {
                conv: conv(w[0], w[1], 3, 2, 1, dev),
                norm: inorm(w[1], dev),
            })
            .collect();
        let up = widths
            .windows(2)
            .rev()
            .map(|w| (w[1], w[0]))
            .map(|(a, b)| UpBlock {
                conv: ConvTranspose2dConfig::new([a, b], [3, 3])
                    .with_stride([2, 2])
                    .with_padding([1, 1])
                    .with_padding_out([1, 1])
                    .init(dev),
                norm: inorm(b, dev),
            })
            .collect();
        Self {
            stem: conv(3, k, 7, 1, 0, dev),
            stem_norm: inorm(k, dev),
            down,
            blocks: (0..shape.res_blocks)
                .map(|_| ResBlock::new(widths[shape.down], dev))
                .collect(),
            up,
            head: conv(k, 3, 7, 1, 0, dev),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut x = instance_norm(
            &self.stem_norm,
            conv2d(&self.stem, reflect_pad(x, 3)),
            None,
            true,
        );
        for d in &self.down {
            x = instance_norm(&d.norm, conv2d(&d.conv, x), None, true);
        }
        for b in &self.blocks {
            x = b.forward(x);
        }
        for u in &self.up {
            x = instance_norm(&u.norm, conv_transpose2d(&u.conv, x), None, true);
        }
        tanh(conv2d(&self.head, reflect_pad(x, 3)))
    }
}

#[derive(Module, Debug)]
pub struct DiscLayer {
    conv: Conv2d,
    norm: Option<InstanceNorm>,
}

/// PatchGAN discriminator: one real/fake score per overlapping patch (no sigmoid: LSGAN).
#[derive(Module, Debug)]
pub struct Discriminator {
    layers: Vec<DiscLayer>,
    head: Conv2d,
}

impl Discriminator {
    pub fn new(shape: &GanShape, dev: &Device) -> Self {
        let ndf = shape.ndf.max(1);
        let n = shape.disc_layers.max(1);
        let mut layers = vec![DiscLayer {
            conv: conv(3, ndf, 4, 2, 1, dev),
            norm: None,
        }];
        let mut c = ndf;
        for i in 1..=n {
            let next = ndf * (1 << i.min(3));
            let stride = if i == n { 1 } else { 2 };
            layers.push(DiscLayer {
                conv: conv(c, next, 4, stride, 1, dev),
                norm: Some(inorm(next, dev)),
            });
            c = next;
        }
        Self {
            layers,
            head: conv(c, 1, 4, 1, 1, dev),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut x = x;
        for l in &self.layers {
            x = conv2d(&l.conv, x);
            if let Some(n) = &l.norm {
                x = instance_norm(n, x, None, false);
            }
            x = leaky_relu(x, 0.2);
        }
        conv2d(&self.head, x)
    }
}

#[cfg(test)]
mod tests {
    use burn::tensor::TensorData;

    use super::*;
    use crate::testing::{close, dev, values};

    #[test]
    fn reflection_padding_mirrors_without_repeating_the_edge() {
        let x = Tensor::<4>::from_data(
            TensorData::new(vec![1f32, 2., 3., 4., 5., 6.], [1, 1, 2, 3]),
            &dev(),
        );
        let y = reflect_pad(x, 1);
        assert_eq!(y.dims(), [1, 1, 4, 5]);
        // Row −1 mirrors row 1, row 2 mirrors row 0; column −1 mirrors column 1, column 3
        // mirrors column 1.
        #[rustfmt::skip]
        let want = [
            5., 4., 5., 6., 5.,
            2., 1., 2., 3., 2.,
            5., 4., 5., 6., 5.,
            2., 1., 2., 3., 2.,
        ];
        close(&values(y), &want, 0.0);
    }

    #[test]
    fn instance_norm_normalises_each_channel_of_each_image() {
        let norm = inorm(2, &dev());
        // Channel 0: 1, 2, 3, 4 (mean 2.5, biased variance 1.25); channel 1: constant 7.
        let x = Tensor::<4>::from_data(
            TensorData::new(vec![1f32, 2., 3., 4., 7., 7., 7., 7.], [1, 2, 2, 2]),
            &dev(),
        );
        let y = values(norm.forward(x));
        // (x − 2.5) / sqrt(1.25 + 1e-5)
        close(
            &y[..4],
            &[-1.341_635_4, -0.447_211_8, 0.447_211_8, 1.341_635_4],
            1e-5,
        );
        // A constant channel normalises to 0 (variance 0, kept finite by ε).
        close(&y[4..], &[0.0; 4], 1e-6);
    }

    #[test]
    fn a_gan_shape_saved_before_down_existed_reads_as_the_reference_two() {
        let old = r#"{"ngf":8,"ndf":8,"res_blocks":2,"disc_layers":2}"#;
        let shape: GanShape = serde_json::from_str(old).unwrap();
        assert_eq!(shape.down, 2);
        let new: GanShape =
            serde_json::from_str(&serde_json::to_string(&GanShape { down: 1, ..shape }).unwrap())
                .unwrap();
        assert_eq!(new.down, 1);
    }

    #[test]
    fn generators_and_discriminators_keep_their_shapes() {
        let d = dev();
        let gan = GanShape {
            ngf: 4,
            ndf: 4,
            res_blocks: 1,
            disc_layers: 2,
            down: 2,
        };
        let x = Tensor::<4>::zeros([2, 3, 24, 32], &d);
        for down in 0..=3 {
            let g = Generator::new(&GanShape { down, ..gan }, &d);
            assert_eq!(g.forward(x.clone()).dims(), [2, 3, 24, 32], "down {down}");
            // The residual blocks work at 1/2^down of the image, on ngf · 2^down channels.
            let c = 4 << down;
            assert_eq!(g.blocks[0].conv1.weight.dims(), [c, c, 3, 3], "down {down}");
            assert_eq!((g.down.len(), g.up.len()), (down, down));
        }
        let score = Discriminator::new(&gan, &d).forward(x).dims();
        assert_eq!(score[..2], [2, 1]);
    }
}
