//! The clock-offset estimator on its hard cases: zero and large jitter, ±100 ppm drift, very few
//! samples, a u32 counter wrap and a clock jump. Time is synthetic and passed in.

use rig::sync::{
    ClockEstimator, ClockEvent, DeviceClock, DeviceStamp, DeviceTimebase, EstimatorConfig,
};

/// Deterministic pseudo-random numbers in [0, 1) (xorshift64*), so tests need no RNG crate.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Exponential latency jitter with mean `mean_ns` (a long tail, like a USB/OS stack).
    fn exp(&mut self, mean_ns: f64) -> f64 {
        -mean_ns * (1.0 - self.next()).ln()
    }
}

/// Feed `n` samples of a device clock `x = k·period` seen at host `y = off + rate·x + d`.
fn feed(
    est: &mut ClockEstimator,
    n: u64,
    period_ns: i64,
    off_ns: f64,
    rate: f64,
    mut latency: impl FnMut() -> f64,
) {
    for k in 0..n {
        let x = k as i64 * period_ns;
        let y = off_ns + rate * x as f64 + latency();
        est.observe(x, y.round() as u64);
    }
}

#[test]
fn zero_jitter_recovers_offset_and_drift_exactly() {
    let mut est = ClockEstimator::new(EstimatorConfig::default());
    let rate = 1.0 + 80e-6;
    feed(&mut est, 5000, 1_000_000, 3.0e9, rate, || 0.0);
    let drift = est.drift_ppm().unwrap();
    assert!((drift - 80.0).abs() < 0.01, "drift {drift} ppm");
    // Prediction at a device time 1 s beyond the data: within rounding (1 ns).
    let x = 6_000_000_000i64;
    let want = 3.0e9 + rate * x as f64;
    let got = est.to_host(x).unwrap();
    assert!((got - want).abs() < 2.0, "got {got}, want {want}");
}

#[test]
fn drift_of_plus_and_minus_100_ppm_with_jitter_is_tracked() {
    for ppm in [100.0, -100.0] {
        let mut est = ClockEstimator::new(EstimatorConfig::default());
        let mut rng = Rng(7);
        let rate = 1.0 + ppm * 1e-6;
        // 10 s at 1 kHz with 0.2 ms mean latency jitter.
        feed(&mut est, 10_000, 1_000_000, 1.0e9, rate, || {
            rng.exp(200_000.0)
        });
        let drift = est.drift_ppm().unwrap();
        assert!((drift - ppm).abs() < 5.0, "{ppm} ppm estimated as {drift}");
        // Mapping error across the window: the hull sits on the fastest samples, within the
        // smallest latencies seen (tens of µs here), never the mean latency (200 µs).
        for x in [0i64, 5_000_000_000, 9_999_000_000] {
            let err = est.to_host(x).unwrap() - (1.0e9 + rate * x as f64);
            assert!(err.abs() < 30_000.0, "{ppm} ppm: error {err} ns at {x}");
        }
    }
}

#[test]
fn large_jitter_does_not_bias_the_offset_like_a_mean_would() {
    let mut est = ClockEstimator::new(EstimatorConfig::default());
    let mut rng = Rng(42);
    // Mean latency 5 ms with a long tail, at 100 Hz for 20 s.
    let mut lat_sum = 0.0;
    let mut n = 0.0;
    feed(&mut est, 2000, 10_000_000, 0.0, 1.0, || {
        let d = rng.exp(5_000_000.0);
        lat_sum += d;
        n += 1.0;
        d
    });
    let err = est.to_host(10_000_000_000).unwrap() - 10_000_000_000.0;
    assert!(lat_sum / n > 4e6, "the jitter really is large");
    assert!(
        (0.0..500_000.0).contains(&err),
        "offset error {err} ns should be a small positive residual, far below the 5 ms mean"
    );
    let drift = est.drift_ppm().unwrap();
    assert!(
        drift.abs() < 50.0,
        "no drift was simulated, got {drift} ppm"
    );
}

#[test]
fn very_few_samples_fall_back_to_offset_then_bounded_drift() {
    let mut est = ClockEstimator::new(EstimatorConfig::default());
    assert_eq!(est.to_host(0), None, "no map before any sample");
    let (epoch, ev) = est.observe(1_000, 50_000);
    assert_eq!(ev, Some(ClockEvent::Locked { epoch: 0 }));
    assert_eq!(epoch, 0);
    // One sample: offset only at the nominal rate.
    assert_eq!(est.to_host(2_000).unwrap(), 51_000.0);
    // Two samples 100 ms apart where the second arrived 30 ms late: the raw slope (+30 %) is
    // absurd; it is clamped to the drift bound (500 ppm) and the line still supports both points.
    est.observe(100_001_000, 50_000 + 100_000_000 + 30_000_000);
    let drift = est.drift_ppm().unwrap();
    assert!((drift - 500.0).abs() < 1e-6, "clamped drift, got {drift}");
    let m = est.mapping().unwrap();
    assert!(m.to_host(1_000) <= 50_000.0 + 1e-6);
    assert!(m.to_host(100_001_000) <= 130_050_000.0 + 1e-6);
}

#[test]
fn offset_only_mode_ignores_drift() {
    let cfg = EstimatorConfig {
        estimate_drift: false,
        ..Default::default()
    };
    let mut est = ClockEstimator::new(cfg);
    feed(&mut est, 1000, 1_000_000, 0.0, 1.0 + 100e-6, || 0.0);
    assert_eq!(est.drift_ppm().unwrap(), 0.0);
}

#[test]
fn u32_sequence_counter_wrap_is_continuous() {
    let mut clock = DeviceClock::new(
        DeviceTimebase::Counter {
            bits: 32,
            nominal_hz: 1000.0,
        },
        EstimatorConfig::default(),
    );
    let start = u32::MAX as u64 - 499;
    let mut host = 7_000_000_000u64;
    let mut last_dev = None;
    for k in 0..1000u64 {
        let raw = (start + k) % (1u64 << 32);
        let (dev, delta) = clock.device_ns(DeviceStamp::Counter(raw)).unwrap();
        if let Some(prev) = last_dev {
            assert_eq!(
                dev - prev,
                1_000_000,
                "one count is 1 ms, across the wrap too"
            );
            assert_eq!(delta, 1);
        }
        last_dev = Some(dev);
        clock.estimator.observe(dev, host);
        host += 1_000_000;
    }
    let (_, _, jumps) = clock.estimator.counts();
    assert_eq!(jumps, 0, "a wrap is not a jump");
    // The sample just after the wrap (counter 0) maps to its host time.
    let (dev0, _) = clock.device_ns(DeviceStamp::Counter(0)).unwrap();
    assert_eq!(dev0, last_dev.unwrap() - 499 * 1_000_000);
    let t = clock.estimator.to_host(dev0).unwrap();
    assert!((t - (7_000_000_000.0 + 500.0 * 1e6)).abs() < 1.0, "{t}");
}

#[test]
fn clock_jump_is_detected_relocked_and_old_samples_keep_their_map() {
    let mut est = ClockEstimator::new(EstimatorConfig::default());
    feed(&mut est, 2000, 1_000_000, 0.0, 1.0, || 0.0);
    let before = est.mapping().unwrap();
    // The device clock steps back by 1 s (a device reboot / resync) while host time goes on.
    let mut events = Vec::new();
    for k in 2000..2010i64 {
        let x = k * 1_000_000 - 1_000_000_000;
        let y = (k * 1_000_000) as u64;
        let (_, ev) = est.observe(x, y);
        events.extend(ev);
    }
    let jump = events
        .iter()
        .find_map(|e| match e {
            ClockEvent::Jump {
                step_ns,
                new_epoch,
                old_epoch,
            } => Some((*step_ns, *old_epoch, *new_epoch)),
            _ => None,
        })
        .expect("jump reported");
    assert_eq!((jump.1, jump.2), (0, 1));
    assert!((jump.0 - 1e9).abs() < 1.0, "step {} ns", jump.0);
    assert_eq!(est.epoch(), 1);
    // New samples map correctly in the new epoch …
    let t = est.to_host(2009 * 1_000_000 - 1_000_000_000).unwrap();
    assert!((t - 2009e6).abs() < 1.0, "{t}");
    // … and old ones with the frozen map of epoch 0.
    assert_eq!(
        est.to_host_in(0, 1_000_000).unwrap(),
        before.to_host(1_000_000)
    );
}

#[test]
fn a_single_late_packet_is_an_outlier_not_a_jump() {
    let mut est = ClockEstimator::new(EstimatorConfig::default());
    feed(&mut est, 100, 1_000_000, 0.0, 1.0, || 0.0);
    est.observe(100_000_000, 100_000_000 + 200_000_000); // 200 ms late
    let (_, ev) = est.observe(101_000_000, 101_000_000);
    assert!(matches!(ev, Some(ClockEvent::Outlier { .. })), "{ev:?}");
    assert_eq!(est.epoch(), 0);
    assert!((est.to_host(101_000_000).unwrap() - 101e6).abs() < 1.0);
}
