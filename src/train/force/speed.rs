//! How fast the force model trains and infers on this machine, on random data: for `rig bench
//! train --speed` and its side-by-side with PyTorch (`scripts/bench-torch`).

use burn::optim::GradientsParams;
use burn::tensor::{Tensor, TensorData};
use serde::Serialize;

use rig_nn::{device, gamma_l1, on_pool};

use super::{ForceConfig, ForceModel, initial_network, new_optimizer, shape_for};
use crate::train::batch::{Rng, images_to_tensor};
use crate::train::data::ImageSpec;

/// What the force model's training step and inference cost on this machine: for
/// `rig bench train --speed` and its side-by-side with PyTorch (`scripts/bench-torch`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StepSpeed {
    /// Training: sequences (of `seq_len` frames) a second through forward, backward and the
    /// optimiser step, as [`super::train`] runs them (the loss read back each step).
    pub sequences_per_s: f64,
    pub images_per_s: f64,
    /// Inference as `rig eval` runs it ([`ForceModel::sequence_forces`] on a batch of
    /// `batch` sequences), per frame.
    pub infer_ms_per_frame: f64,
}

/// Times `steps` training steps of `cfg`'s model on `spec`-sized random frames (after two
/// untimed warm-up steps), then `steps` inference batches of the same shape. The values of the
/// data do not change the work, so no dataset is needed.
pub fn step_speed(cfg: &ForceConfig, spec: ImageSpec, steps: usize) -> StepSpeed {
    let dev = device();
    let shape = shape_for(cfg, &spec);
    let (adev, mut net) = initial_network(&shape, &dev, cfg.seed);
    let mut optim = new_optimizer(cfg.optimizer);
    let (b, t) = (cfg.batch.max(1), cfg.seq_len.max(1));
    let (w, h) = (spec.width as usize, spec.height as usize);
    let mut rng = Rng(cfg.seed);
    let frames: Vec<Vec<u8>> = (0..b * t)
        .map(|_| (0..w * h * 3).map(|_| rng.below(256) as u8).collect())
        .collect();
    let refs: Vec<&[u8]> = frames.iter().map(|f| f.as_slice()).collect();
    let labels: Vec<f32> = (0..b * t * 3).map(|_| rng.unit() as f32).collect();
    let steps = steps.max(1);
    let mut timed = 0.0;
    for i in 0..steps + 2 {
        let t0 = std::time::Instant::now();
        // On the pool, as `train` runs its steps.
        net = on_pool(|| {
            let x = images_to_tensor(&refs, &spec, &adev).reshape([b, t, 3, h, w]);
            let y = Tensor::<3>::from_data(TensorData::new(labels.clone(), [b, t, 3]), &adev);
            let loss = gamma_l1(net.forward(x), y, cfg.gamma);
            let _ = loss.clone().into_scalar::<f32>();
            let grads = GradientsParams::from_grads(loss.backward(), &net);
            optim.step(cfg.lr, net, grads)
        });
        if i >= 2 {
            timed += t0.elapsed().as_secs_f64();
        }
    }
    let seqs = (steps * b) as f64 / timed.max(1e-9);

    let model = ForceModel::untrained(cfg, spec, 40);
    let _ = model.sequence_forces(&refs, b, t);
    let t0 = std::time::Instant::now();
    for _ in 0..steps {
        let _ = model.sequence_forces(&refs, b, t);
    }
    let infer = t0.elapsed().as_secs_f64() * 1e3 / (steps * b * t) as f64;
    StepSpeed {
        sequences_per_s: seqs,
        images_per_s: seqs * t as f64,
        infer_ms_per_frame: infer,
    }
}
