//! Where the networks compute and how their parameters start, in one place: the device (the
//! backend the cargo features select), the process-wide lock under which a network's initial
//! weights are drawn from its seed, and the pool a training loop runs on.

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::{Bool, Device, Int, Tensor};

/// The device the trainer computes on: CUDA with the `gpu` feature; with `wgpu`, the GPU
/// wgpu's heuristics pick (a high-power one first; `CUBECL_WGPU_DEFAULT_DEVICE`, e.g.
/// `DiscreteGpu(1)`, overrides it), on Vulkan with SPIR-V kernels when the `vulkan` feature
/// is on; else the flex CPU backend.
pub fn device() -> Device {
    #[cfg(feature = "gpu")]
    {
        Device::cuda(0)
    }
    #[cfg(all(feature = "vulkan", not(feature = "gpu")))]
    {
        Device::vulkan(burn::tensor::DeviceKind::DefaultDevice)
    }
    #[cfg(all(feature = "wgpu", not(any(feature = "gpu", feature = "vulkan"))))]
    {
        Device::wgpu(burn::tensor::DeviceKind::DefaultDevice)
    }
    #[cfg(not(any(feature = "gpu", feature = "wgpu")))]
    {
        Device::flex()
    }
}

/// Whether [`device`] is a GPU (the `gpu` or `wgpu` feature). There burn's own kernels run,
/// not this crate's CPU ones ([`crate::cpu`]), and the encoder has no CPU inference form
/// ([`crate::FastEncoder`]).
pub const GPU: bool = cfg!(any(feature = "gpu", feature = "wgpu"));

/// Builds networks under one process-wide lock, seeding the device's generator first when a
/// seed is given. burn keeps one random generator per device for the whole process and draws
/// from it when a parameter is initialised (training itself draws nothing from it). burn
/// initialises parameters lazily, at their first use, so `build` must call [`init_params`] on
/// every network it makes: then a network's initial weights depend on its seed alone even while
/// other trainings run in other threads (`rig demo` trains two side by side). Without it they
/// were drawn at the first forward pass, outside the lock, interleaved with the other
/// training's draws, and the same data and seed gave different models run to run.
pub fn build_networks<T>(dev: &Device, seed: Option<u64>, build: impl FnOnce() -> T) -> T {
    static BUILD: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _g = BUILD.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(seed) = seed {
        dev.seed(seed);
    }
    build()
}

/// Draws every parameter of `net` now (burn defers that to its first use): see
/// [`build_networks`].
pub fn init_params<M: Module>(net: &M) {
    struct Touch;
    impl ModuleVisitor for Touch {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            let _ = p.val();
        }
        fn visit_int<const D: usize>(&mut self, p: &Param<Tensor<D, Int>>) {
            let _ = p.val();
        }
        fn visit_bool<const D: usize>(&mut self, p: &Param<Tensor<D, Bool>>) {
            let _ = p.val();
        }
    }
    net.visit(&mut Touch);
}

/// Every float parameter of `net`, flattened in the order the module visits them: two
/// networks of one shape are the same network when these are equal (the seeding tests).
pub fn float_params<M: Module>(net: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            let v = p.val().into_data().try_to_vec::<f32>();
            self.0
                .extend(v.expect("float parameters are stored as f32"));
        }
    }
    let mut c = Collect(Vec::new());
    net.visit(&mut c);
    c.0
}

/// Runs `work` on a worker thread of rayon's pool, the calling thread waiting for it: for
/// training loops. A training step is a chain of operations, most shared out over the pool and
/// joined. Run from outside the pool, each one wakes the sleeping workers and waits for them,
/// and between them the calling thread is one more runnable thread than there are cores (the
/// workers yield a while before they sleep). Run on a worker, the step starts each operation
/// where it already is and shares it with one fewer wake-up. On 2 cores (an AMD EPYC VM)
/// a CycleGAN step of the protocol's shape ran 20 % faster so, and at 1 thread the protocol's
/// force models 6-24 % faster (docs/experiments.md).
pub fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_pool_runs_the_work_on_a_worker_of_the_pool_and_returns_its_result() {
        assert_eq!(rayon::current_thread_index(), None);
        let (on_worker, sum) = on_pool(|| (rayon::current_thread_index().is_some(), 2 + 3));
        assert!(on_worker);
        assert_eq!(sum, 5);
    }
}
