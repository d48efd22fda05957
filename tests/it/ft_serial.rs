//! The serial F/T controller front end against the simulated controller on a real pty.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use hardware_mocks::nano17::serial::{SerialControllerMock, SerialMockConfig};
use hardware_mocks::nano17::{MockStats, SensorModel};
use rig::force::serial::{SerialOptions, open};
use rig::force::{FrontEndSettings, FtError};
use rig_core::clock::Clock;
use rig_core::config::SaturationPolicy;
use rig_core::ft::serial::OutputMode;
use rig_core::ft::transform::ToolTransform;
use rig_core::ft::{NANO17_SI_25_MAX, NANO17_SI_25_RESOLUTION, SampleFlags};
use rig_core::wrench::Wrench;

/// Unloaded until `from_ns` (set once the tare is done), then a different load every second.
fn truth(t_ns: u64, from_ns: u64) -> [f64; 6] {
    if t_ns < from_ns {
        return [0.0; 6];
    }
    let k = (t_ns / 1_000_000_000) as f64;
    [
        1.5 * (k * 0.7).sin(),
        -2.0 * (k * 0.3).cos(),
        -3.0 - 1.2 * k,
        20.0 * (k * 0.5).sin(),
        -15.0 + 2.0 * k,
        5.0 * (k * 1.1).cos(),
    ]
}

/// Whether a sample measured at `t_ns` is within 2 ms of a load change. Samples are compared
/// at the instant the simulated controller measured them (from the record count), so only the
/// rounding of that mapping needs a guard, not the host's reading delay.
fn near_step(t_ns: u64, from_ns: u64) -> bool {
    let ms = (t_ns / 1_000_000) % 1000;
    !(2..=998).contains(&ms) || t_ns.abs_diff(from_ns) < 2_000_000
}

fn settings(rate_hz: f64) -> FrontEndSettings {
    FrontEndSettings {
        tool: ToolTransform::identity(),
        max_loads: NANO17_SI_25_MAX,
        saturation: SaturationPolicy::Flag,
        calibration: None,
        temperature_compensation: false,
        counts_per_force: 320.0,
        counts_per_torque: 64.0,
        rate_hz,
    }
}

fn get(a: &std::sync::atomic::AtomicU64) -> u64 {
    MockStats::get(a)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_serial_binary_streams_10s_at_1khz_over_a_pty_with_zero_loss() {
    let clock = Clock::system();
    // The load starts only after the tare, however long a busy host takes to get there.
    let load_from = Arc::new(AtomicU64::new(u64::MAX));
    let from = load_from.clone();
    let mock = SerialControllerMock::start(
        SerialMockConfig {
            rate_hz: 1000.0,
            ..SerialMockConfig::default()
        },
        SensorModel::nano17(1),
        Arc::new(move |t| Wrench::from_array(truth(t, from.load(Ordering::Acquire)))),
        clock.clone(),
    )
    .unwrap();
    let port = mock.path().display().to_string();
    let mut stream = open(
        SerialOptions {
            port,
            baud: 921_600,
            output: OutputMode::Binary,
            device_bias: false,
        },
        settings(1000.0),
        clock.clone(),
    )
    .await
    .unwrap();
    let tare = stream.tare(600).await.unwrap();
    // The simulated sensor's offset is real: about 1.4 N on Fz before the tare.
    assert!(tare.wrench.mean[2].abs() > 0.5, "{tare:?}");
    let from_ns = (clock.now_ns() / 1_000_000_000 + 1) * 1_000_000_000;
    load_from.store(from_ns, Ordering::Release);
    let t_start = clock.now_ns();
    let mut n = 0u64;
    let mut max_err = [0.0f64; 6];
    let mut compared = 0u64;
    let mut last_seq = None;
    while clock.now_ns() < t_start + 10_000_000_000 {
        let s = crate::common::next_sample(&clock, &mut stream).await;
        n += 1;
        if let Some(p) = last_seq {
            assert_eq!(s.device_seq, p + 1);
        }
        last_seq = Some(s.device_seq);
        let t_ns = mock.stats().sample_time_ns(s.device_seq, 1000.0);
        if t_ns < from_ns || near_step(t_ns, from_ns) {
            continue;
        }
        assert!(s.flags.is_clean(), "{:?}", s.flags);
        compared += 1;
        let w = s.wrench.to_array();
        let t = truth(t_ns, from_ns);
        for i in 0..6 {
            max_err[i] = max_err[i].max((w[i] - t[i]).abs());
        }
    }
    mock.faults().set_muted(true);
    crate::common::drain_until_quiet(
        &clock,
        &mut stream,
        || get(&mock.stats().sent),
        |_| {
            n += 1;
        },
    )
    .await;
    let st = stream.stats();
    let sent = get(&mock.stats().sent);
    println!(
        "serial binary: {sent} records sent, {} received in ~10.8 s; {compared} compared, max |error| {max_err:?}",
        st.samples
    );
    assert!(
        compared > 9000,
        "{compared} samples compared in 10 s at 1 kHz"
    );
    assert_eq!(st.samples, sent, "lost records: {st:?}");
    assert!(sent >= 10_500, "rate below 1 kHz: {sent} records in 10.8 s");
    assert_eq!(
        st.garbage + st.truncated + st.checksum_errors + st.consumer_overflow,
        0,
        "{st:?}"
    );
    // Within the count resolution plus noise (σ = resolution) and the tare's standard error.
    for i in 0..6 {
        let res = if i < 3 { 1.0 / 320.0 } else { 1.0 / 64.0 };
        let tol = res + 6.0 * NANO17_SI_25_RESOLUTION[i] + 4.0 * tare.wrench.std_error[i];
        assert!(max_err[i] < tol, "axis {i}: {} > {tol}", max_err[i]);
    }
    let _ = n;
    stream.finish().await.unwrap();
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_serial_ascii_counts_garbage_truncation_saturation_and_reports_unplug() {
    let clock = Clock::system();
    let mock = SerialControllerMock::start(
        SerialMockConfig {
            rate_hz: 1000.0,
            mode: OutputMode::Binary,
            ..SerialMockConfig::default()
        },
        SensorModel::nano17(2),
        Arc::new(|_t| Wrench::from_array([0.5, 0.0, -4.0, 0.0, 3.0, 0.0])),
        clock.clone(),
    )
    .unwrap();
    let mut stream = open(
        SerialOptions {
            port: mock.path().display().to_string(),
            baud: 115_200,
            output: OutputMode::Ascii,
            device_bias: true,
        },
        settings(1000.0),
        clock.clone(),
    )
    .await
    .unwrap();
    let mut flags = Vec::new();
    clock.sleep(Duration::from_millis(200)).await;
    mock.faults().inject_garbage(b"\x01\x02#garbage~\r\n");
    mock.faults().truncate_records(3);
    clock.sleep(Duration::from_millis(200)).await;
    mock.faults().set_saturated(true);
    clock.sleep(Duration::from_millis(50)).await;
    mock.faults().set_saturated(false);
    clock.sleep(Duration::from_millis(200)).await;
    mock.faults().set_muted(true);
    crate::common::drain_until_quiet(
        &clock,
        &mut stream,
        || get(&mock.stats().sent),
        |s| flags.push(s.flags),
    )
    .await;
    let st = stream.stats();
    let sent = get(&mock.stats().sent);
    println!("serial ascii faults: sent {sent}, stats {st:?}");
    assert_eq!(st.samples, sent, "every intact record arrives: {st:?}");
    assert_eq!(st.truncated, 3);
    assert_eq!(st.garbage, 1);
    assert!(st.saturated >= 20 && st.saturated <= 80, "{st:?}");
    assert_eq!(st.status_errors, st.saturated);
    let sat = flags
        .iter()
        .filter(|f| f.contains(SampleFlags::DEVICE_STATUS) && f.contains(SampleFlags::SATURATED))
        .count() as u64;
    assert_eq!(sat, st.saturated);
    // SB on start: the controller-side bias leaves only noise (|F| well below the offset).
    // Unplug: the stream ends with a clear error, no panic.
    mock.faults().set_muted(false);
    mock.faults().unplug();
    let ended = clock
        .timeout(Duration::from_secs(3), async {
            while stream.next().await.is_some() {}
        })
        .await;
    assert!(ended.is_ok(), "stream did not end after unplug");
    match stream.finish().await {
        Err(FtError::PortClosed { port, .. }) => assert!(port.starts_with("/dev/")),
        other => panic!("{other:?}"),
    }
}
