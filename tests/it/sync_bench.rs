//! The sync bench's simulation: with a slow device crystal, drift estimation is what keeps the
//! paired force accurate, and interpolation beats the nearest sample. (Errors only; the timings
//! are for `rig bench sync` to report, not for a test to assert.)

use rig::cli::bench::sync::{Scenario, run_variant};
use rig::sync::InterpMethod;

#[test]
fn drift_estimation_and_interpolation_each_reduce_the_force_error() {
    let s = Scenario {
        duration_s: 8.0,
        drift_ppm: -80.0,
        ..Default::default()
    };
    let off_lin = run_variant(&s, InterpMethod::Linear, false);
    let fit_lin = run_variant(&s, InterpMethod::Linear, true);
    let fit_near = run_variant(&s, InterpMethod::Nearest, true);
    let fit_cub = run_variant(&s, InterpMethod::Cubic, true);
    assert_eq!(fit_lin.frames, 239, "every frame but the first paired");
    assert!(
        fit_lin.rms_n < 0.5 * off_lin.rms_n,
        "drift fit {} N vs offset-only {} N",
        fit_lin.rms_n,
        off_lin.rms_n
    );
    assert!(fit_lin.rms_n < 0.5 * fit_near.rms_n);
    assert!(fit_cub.rms_n <= fit_lin.rms_n * 1.05);
    // Paired within 2 % of an assumed 12 N range (the acceptance bound), by far.
    assert!(fit_cub.max_n < 0.02 * 12.0);
}
