//! Adam (Kingma and Ba 2015, "Adam: A method for stochastic optimization", Algorithm 1, with
//! burn's placement of ε) as one fused pass per parameter on the CPU.
//!
//! burn's `Adam` updates a parameter with about a dozen tensor operations (two scaled sums for
//! the moments, a square, a square root, a division, the step), each a pass over the parameter
//! that allocates its result. On the flex backend each is single-threaded and runs on the
//! calling thread while the pool's workers wait: about 1 % of the wall time of a ResNet-34
//! training step (`rig bench train --speed --size 64x48 --width 16 --batch 8`, an Intel VM,
//! main-thread samples of `perf record`). Here the same arithmetic, element by
//! element and in burn's order, is one pass shared out over the pool. The state is burn's
//! [`AdamState`], so files that hold it read the same. Off the flex device (a GPU), and for the
//! options this pass does not cover, the step is burn's own.

use burn::optim::{
    Adam, AdamConfig, AdamState, AdaptiveMomentumState, LearningRate, ModuleOptimizer, Optimizer,
};
use burn::tensor::{Device, Tensor, TensorData};
use rayon::prelude::*;

use super::conv::on_cpu_kernels;

/// Parameters shared out over the pool in blocks of this many floats.
const BLOCK: usize = 1 << 14;

/// burn's `AdamConfig` default ε (the test checks ours against burn's default `Adam`).
const EPSILON: f32 = 1e-5;

/// burn's Adam with `beta_1`, `beta_2` and its default ε, no weight decay, no AMSGrad.
#[derive(Clone)]
pub struct FusedAdam {
    beta_1: f32,
    beta_2: f32,
    burn: Adam,
}

impl FusedAdam {
    /// The optimiser `AdamConfig::new().with_beta_1(beta_1).with_beta_2(beta_2).init()` gives,
    /// stepping through [`FusedAdam`].
    pub fn init(beta_1: f32, beta_2: f32) -> ModuleOptimizer {
        ModuleOptimizer::from(Self::new(beta_1, beta_2))
    }

    fn new(beta_1: f32, beta_2: f32) -> Self {
        let config = AdamConfig::new().with_beta_1(beta_1).with_beta_2(beta_2);
        Self {
            beta_1,
            beta_2,
            burn: config.build(),
        }
    }

    /// One parameter's step on floats: `p`, and the moments `m`, `v` (zero before the first
    /// step), updated in place for step `time` (from 1).
    fn step_floats(&self, lr: f32, time: i32, [p, m, v]: [&mut [f32]; 3], g: &[f32]) {
        let (b1, b2) = (self.beta_1, self.beta_2);
        let (f1, f2) = (1.0 - b1, 1.0 - b2);
        // burn: m̂ / (√v̂ + ε) as m·c / (√v + ε·√(1 − β₂ᵗ)), c = √(1 − β₂ᵗ) / (1 − β₁ᵗ).
        let bc2 = (1.0 - b2.powi(time)).sqrt();
        let c = bc2 / (1.0 - b1.powi(time));
        let eps = EPSILON * bc2;
        p.par_chunks_mut(BLOCK)
            .zip(m.par_chunks_mut(BLOCK))
            .zip(v.par_chunks_mut(BLOCK))
            .zip(g.par_chunks(BLOCK))
            .for_each(|(((p, m), v), g)| {
                for (((p, m), v), &g) in p.iter_mut().zip(m).zip(v).zip(g) {
                    *m = *m * b1 + g * f1;
                    *v = *v * b2 + (g * g) * f2;
                    *p -= (*m * c) / (v.sqrt() + eps) * lr;
                }
            });
    }
}

/// The floats of a tensor on the flex device.
fn floats<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .try_into_vec::<f32>()
        .expect("adam: an f32 tensor on the flex device")
}

impl Optimizer for FusedAdam {
    type State<const D: usize> = AdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        // The moments as this pass reads them: f32 on the flex device, no AMSGrad maximum.
        let moments_fit = state.as_ref().is_none_or(|s| {
            let s = &s.momentum;
            s.max_moment_2.is_none() && on_cpu_kernels(&s.moment_1) && on_cpu_kernels(&s.moment_2)
        });
        if !moments_fit || !on_cpu_kernels(&tensor) || !on_cpu_kernels(&grad) {
            return self.burn.step(lr, tensor, grad, state);
        }
        let (dev, dims) = (tensor.device(), tensor.dims());
        let mut p = floats(tensor);
        let g = floats(grad);
        let (time, mut m, mut v) = match state {
            Some(s) => {
                let s = s.momentum;
                (s.time + 1, floats(s.moment_1), floats(s.moment_2))
            }
            // burn's first step is m = (1 − β₁)·g, v = (1 − β₂)·g²: the same as from zeros.
            None => (1, vec![0.0; p.len()], vec![0.0; p.len()]),
        };
        let t = i32::try_from(time).unwrap_or(i32::MAX);
        // burn scales by the learning rate as an f32 scalar (`mul_scalar` in the element type).
        self.step_floats(lr as f32, t, [&mut p, &mut m, &mut v], &g);
        let tensor =
            |v: Vec<f32>, dev: &Device| Tensor::<D>::from_data(TensorData::new(v, dims), dev);
        let moments = AdaptiveMomentumState::new(time, tensor(m, &dev), tensor(v, &dev));
        (tensor(p, &dev), Some(AdamState::new(moments)))
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        Adam::to_device(state, device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// Five steps of ours against burn's `Adam` on the same parameter and gradients, for the
    /// trainer's two β₁ and a learning rate that changes between steps. The arithmetic is the
    /// same operation by operation, so the two agree to the last bits, up to the sign of a
    /// zero; asserted to 1e-6 of the largest value.
    #[test]
    fn the_fused_step_matches_burns_adam() {
        let dev = Device::flex();
        for beta_1 in [0.9, 0.5] {
            let fused = FusedAdam::new(beta_1, 0.999);
            let theirs = AdamConfig::new().with_beta_1(beta_1).build();
            // More floats than one block, and not a multiple of it; gradients with zeros.
            let dims = [3, 7001];
            // Parameters of the steps' own size, so an error in a step is not lost in the
            // parameter's rounding.
            let p0 = Tensor::<2>::random(dims, Distribution::Normal(0.0, 1e-3), &dev);
            let (mut pa, mut pb) = (p0.clone(), p0);
            let (mut sa, mut sb) = (None, None);
            for step in 0..5 {
                let g = Tensor::<2>::random(dims, Distribution::Normal(0.0, 0.1), &dev);
                let g = g.clone().mask_fill(g.abs().lower_elem(0.01), 0.0);
                let lr = 1e-3 * (1.0 + step as f64);
                (pa, sa) = fused.step(lr, pa, g.clone(), sa);
                (pb, sb) = theirs.step(lr, pb, g, sb);
                let (a, b) = (
                    pa.to_data().try_to_vec::<f32>().unwrap(),
                    pb.to_data().try_to_vec::<f32>().unwrap(),
                );
                let largest = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                for (i, (x, y)) in a.iter().zip(&b).enumerate() {
                    assert!(
                        (x - y).abs() <= 1e-6 * largest,
                        "β₁ {beta_1}, step {step}, [{i}]: {x} against burn's {y}"
                    );
                }
                let (ma, mb) = (
                    &sa.as_ref().unwrap().momentum,
                    &sb.as_ref().unwrap().momentum,
                );
                assert_eq!(ma.time, mb.time);
                for (which, x, y) in [
                    ("first", &ma.moment_1, &mb.moment_1),
                    ("second", &ma.moment_2, &mb.moment_2),
                ] {
                    assert_eq!(
                        x.to_data().try_to_vec::<f32>().unwrap(),
                        y.to_data().try_to_vec::<f32>().unwrap(),
                        "β₁ {beta_1}, step {step}: {which} moments"
                    );
                }
            }
        }
    }
}
