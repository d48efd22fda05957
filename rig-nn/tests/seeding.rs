//! A network's initial weights come from its seed alone ([`rig_nn::build_networks`],
//! [`rig_nn::init_params`]). In a binary of its own: burn draws every parameter from one
//! generator per device for the whole process, so another test drawing at the same time
//! (outside the lock, as the unit tests' networks do at their first forward pass) would move
//! the draws under test.

use burn::tensor::{Device, Distribution, Tensor};
use rig_nn::{GanShape, Generator, build_networks, float_params as weights, init_params};

/// A small generator built as the trainer builds its networks: under the lock, from `seed`,
/// every parameter drawn before the lock is released.
fn generator(seed: u64) -> Generator {
    let dev = Device::flex();
    let shape = GanShape {
        ngf: 4,
        ndf: 4,
        res_blocks: 1,
        disc_layers: 2,
        down: 1,
    };
    build_networks(&dev, Some(seed), || {
        let g = Generator::new(&shape, &dev);
        init_params(&g);
        g
    })
}

#[test]
fn a_networks_initial_weights_are_those_of_its_seed_whatever_is_drawn_after_the_build() {
    let first = generator(5);
    // Draws from the device's generator after the build and before the weights are read: they
    // must not reach weights already drawn.
    let _ = Tensor::<2>::random([64, 64], Distribution::Default, &Device::flex());
    let other = weights(&generator(6));
    let first = weights(&first);
    assert_eq!(first.len(), other.len());
    assert!(!first.is_empty());
    assert!(
        first == weights(&generator(5)),
        "seed 5 gave other weights the second time"
    );
    assert!(first != other, "seeds 5 and 6 gave the same weights");
}
