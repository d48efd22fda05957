//! The discriminator's leaky ReLU on the CPU, forward and backward as one parallel pass each,
//! through a burn backend extension (as [`super::pad`] does for the reflection pad).
//!
//! burn's `leaky_relu` is a comparison, a scaling and a masked select, each a pass and a graph
//! node on the calling thread, and their backward as many again; in the CycleGAN's step they
//! were the largest thing its main thread ran while the workers waited (docs/experiments.md).
//! Here `y = x` where `x ≥ 0` (or NaN) and `α·x` where `x < 0`, burn's choice at each point, and
//! the gradient is `dy` or `α·dy` by the same test on `x`.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::tensor::activation::leaky_relu as burns_leaky_relu;
use burn::tensor::{Tensor, TensorData};

use super::conv::on_cpu_kernels;
use super::kernels::{dense, map2};

/// A leaky ReLU of slope `slope` below zero, as a backend operation.
#[backend_extension(Flex, Autodiff)]
pub trait TrainLeaky: Backend {
    fn leaky_relu(x: FloatTensor<Self>, slope: f64) -> FloatTensor<Self>;
}

fn flex_leaky(x: &FlexTensor, slope: f64) -> FlexTensor {
    let a = slope as f32;
    let xs = dense(x);
    let y = map2(&xs, &xs, |x, _| if x < 0.0 { a * x } else { x });
    FlexTensor::from_data(TensorData::new(y, x.layout().shape().clone()))
}

impl TrainLeaky for Flex {
    fn leaky_relu(x: FlexTensor, slope: f64) -> FlexTensor {
        flex_leaky(&x, slope)
    }
}

/// The backward step; the state is the input (a cheap `Arc` clone) and the slope.
#[derive(Debug)]
struct LeakyBackward;

impl Backward<Flex, 1> for LeakyBackward {
    type State = (FlexTensor, f64);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, slope) = ops.state;
        if let Some(node) = node {
            let a = slope as f32;
            let dx = map2(
                &dense(&x),
                &dense(&dy),
                |x, d| if x < 0.0 { a * d } else { d },
            );
            let shape = x.layout().shape().clone();
            grads.register::<Flex>(node.id, FlexTensor::from_data(TensorData::new(dx, shape)));
        }
    }
}

impl<C: CheckpointStrategy> TrainLeaky for Autodiff<Flex, C> {
    fn leaky_relu(x: FloatTensor<Self>, slope: f64) -> FloatTensor<Self> {
        let y = flex_leaky(x.primitive(), slope);
        match LeakyBackward
            .prepare::<C>([x.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((x.into_primitive(), slope), y),
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

/// `burn::tensor::activation::leaky_relu(x, slope)`: on this module's loop for f32 tensors on
/// the flex device, else burn's.
pub fn leaky_relu<const D: usize>(x: Tensor<D>, slope: f64) -> Tensor<D> {
    if !on_cpu_kernels(&x) {
        return burns_leaky_relu(x, slope);
    }
    Tensor::from_dispatch(<Dispatch as TrainLeaky>::leaky_relu(
        x.into_dispatch(),
        slope,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, Distribution};

    use crate::cpu::kernels::BLOCK;
    use crate::testing::values;

    #[test]
    fn the_leaky_relu_matches_burns_values_and_gradient_exactly() {
        // Enough values for several tasks, exact zeros among them (burn passes zero through
        // with gradient 1), and a tail after the last whole task.
        let dev = Device::flex().autodiff();
        let n = 3 * (BLOCK + 77);
        let x = Tensor::<1>::random([n], Distribution::Normal(0.0, 1.0), &dev);
        let x = x.clone().mask_fill(x.abs().lower_elem(0.05), 0.0);
        let x = x.reshape([1, 3, 1, n / 3]);
        let r = Tensor::<4>::random(x.dims(), Distribution::Normal(0.0, 1.0), &dev);
        let mut got = Vec::new();
        for ours in [true, false] {
            let xi = x.clone().detach().require_grad();
            let y = if ours {
                leaky_relu(xi.clone(), 0.2)
            } else {
                burns_leaky_relu(xi.clone(), 0.2)
            };
            let grads = (y.clone() * r.clone()).sum().backward();
            got.push([values(y), values(xi.grad(&grads).unwrap())]);
        }
        assert!(values(x).iter().filter(|v| **v == 0.0).count() > 100);
        assert_eq!(got[0][0], got[1][0], "y");
        assert_eq!(got[0][1], got[1][1], "dx");
    }
}
