//! The DAQ gauge-stream front end against the simulated DAQ on a real pty: the calibration
//! path (temperature compensation, F = M·(V − bias), tool transform) end to end.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use hardware_mocks::nano17::daq::{DaqMock, DaqMockConfig};
use hardware_mocks::nano17::{MockStats, SensorModel};
use rig::force::{FrontEndSettings, FtError, daq};
use rig_core::clock::Clock;
use rig_core::config::SaturationPolicy;
use rig_core::ft::cal::Calibration;
use rig_core::ft::transform::ToolTransform;
use rig_core::ft::{NANO17_SI_25_RESOLUTION, SampleFlags};
use rig_core::wrench::Wrench;

/// No load until `from_ns` (set once the tare is done), then a different load every 500 ms.
fn truth(t_ns: u64, from_ns: u64) -> [f64; 6] {
    if t_ns < from_ns {
        return [0.0; 6];
    }
    let k = (t_ns / 500_000_000) as f64;
    [0.5 * k, -0.3 * k, -2.0 - k, 3.0 * k, -2.0 * k, 1.0]
}

/// Whether a sample measured at `t_ns` is within 2 ms of a load change. Samples are compared
/// at the instant the simulated sensor measured them (from their sequence number), so only
/// the rounding of that mapping needs a guard, not the host's reading delay.
fn near_step(t_ns: u64, from_ns: u64) -> bool {
    let ms = (t_ns / 1_000_000) % 500;
    !(2..=498).contains(&ms) || t_ns.abs_diff(from_ns) < 2_000_000
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_daq_gauge_stream_converts_with_the_cal_file_and_counts_faults() {
    let clock = Clock::system();
    let cal = Calibration::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/nano17_useraxis.cal"
    ))
    .unwrap();
    // The indenter tip 12 mm below the sensor, turned 30° about z.
    let tool =
        ToolTransform::from_angles([0.0, 0.0, -12.0], [0.0, 0.0, 30f64.to_radians()]).unwrap();
    let mut model = SensorModel::nano17(4);
    model.tool = tool.clone();
    // The load starts only after the tare, however long a busy host takes to get there.
    let load_from = Arc::new(AtomicU64::new(u64::MAX));
    let from = load_from.clone();
    let mock = DaqMock::start(
        DaqMockConfig::default(),
        model,
        Arc::new(move |t| Wrench::from_array(truth(t, from.load(Ordering::Acquire)))),
        clock.clone(),
    )
    .unwrap();
    let settings = FrontEndSettings {
        tool,
        max_loads: cal.max_loads,
        saturation: SaturationPolicy::Flag,
        calibration: Some(cal),
        temperature_compensation: true,
        counts_per_force: 1.0,
        counts_per_torque: 1.0,
        rate_hz: 1000.0,
    };
    let mut stream = daq::open(
        &mock.path().display().to_string(),
        921_600,
        settings,
        clock.clone(),
    )
    .await
    .unwrap();
    let tare = stream.tare(400).await.unwrap();
    // The bias is in gauge volts: the simulated offsets (plus noise).
    assert!((tare.raw.mean[2] - 0.2044).abs() < 0.01, "{tare:?}");
    let from_ns = (clock.now_ns() / 500_000_000 + 1) * 500_000_000;
    load_from.store(from_ns, Ordering::Release);
    let mut max_err = [0.0f64; 6];
    let mut compared = 0;
    while clock.now_ns() < from_ns + 2_000_000_000 {
        let s = crate::common::next_sample(&clock, &mut stream).await;
        let t_ns = mock.stats().sample_time_ns(s.device_seq, 1000.0);
        if t_ns < from_ns || near_step(t_ns, from_ns) {
            continue;
        }
        assert!(s.flags.is_clean(), "{}", s.flags);
        let t = truth(t_ns, from_ns);
        for (i, v) in s.wrench.to_array().iter().enumerate() {
            max_err[i] = max_err[i].max((v - t[i]).abs());
        }
        compared += 1;
    }
    println!("daq: compared {compared} samples, max |error| {max_err:?}");
    assert!(compared > 1000);
    // Noise σ is one resolution step per sensor axis; the 12 mm lever adds F × d to torques.
    for i in 0..6 {
        let tol = if i < 3 {
            6.0 * NANO17_SI_25_RESOLUTION[i]
        } else {
            6.0 * (NANO17_SI_25_RESOLUTION[i] + 12.0 / 160.0)
        };
        assert!(max_err[i] < tol, "axis {i}: {} > {tol}", max_err[i]);
    }

    // Faults: garbage, checksum failures, truncated frames, saturation; all counted exactly.
    let f = mock.faults();
    f.inject_garbage(b"hello, DAQ");
    f.corrupt_records(3);
    clock.sleep(Duration::from_millis(50)).await;
    f.truncate_records(2);
    clock.sleep(Duration::from_millis(100)).await;
    f.set_saturated(true);
    clock.sleep(Duration::from_millis(30)).await;
    f.set_saturated(false);
    clock.sleep(Duration::from_millis(100)).await;
    f.set_muted(true);
    let ms = mock.stats();
    let mut gauge_sat = 0u64;
    crate::common::drain_until_quiet(
        &clock,
        &mut stream,
        || MockStats::get(&ms.sent),
        |s| {
            if s.flags.contains(SampleFlags::GAUGE_SATURATED) {
                gauge_sat += 1;
            }
        },
    )
    .await;
    let st = stream.stats();
    println!("daq faults: {st:?}");
    assert_eq!(st.samples, MockStats::get(&ms.sent));
    assert_eq!(st.garbage, 10);
    assert_eq!(st.checksum_errors, 3);
    assert_eq!(st.truncated, 2);
    assert_eq!(
        st.lost, 5,
        "corrupted and truncated frames show as sequence gaps"
    );
    assert!(
        gauge_sat >= 10 && gauge_sat == st.saturated,
        "{gauge_sat} {st:?}"
    );

    f.set_muted(false);
    f.unplug();
    let _ = clock
        .timeout(Duration::from_secs(3), async {
            while stream.next().await.is_some() {}
        })
        .await;
    assert!(matches!(
        stream.finish().await,
        Err(FtError::PortClosed { .. })
    ));
}
