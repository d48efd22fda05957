//! Helpers of the tests: the flex device, tensors read back, and comparisons.

use burn::tensor::{Device, Tensor};

pub(crate) fn dev() -> Device {
    Device::flex()
}

pub(crate) fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

/// `|a − b| ≤ 1e-4 · max|b|` elementwise, for our kernels (`a`) against burn's (`b`): both
/// compute the same sums of at most a few hundred O(1) terms in another order (ours partly
/// in f64), so they differ by f32 rounding of terms of the size of the largest entry; an
/// error in indexing (a misplaced convolution tap, a wrong channel) moves whole entries.
pub(crate) fn close_to_largest(what: &str, a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(
            (x - y).abs() <= 1e-4 * scale,
            "{what}[{i}]: {x} against burn's {y} (largest {scale})"
        );
    }
}

pub(crate) fn close(a: &[f32], b: &[f32], tol: f32) {
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(b) {
        assert!((x - y).abs() <= tol, "{a:?} vs {b:?}");
    }
}
