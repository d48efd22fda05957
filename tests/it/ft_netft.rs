//! The Net F/T front end against the simulated Net F/T over UDP loopback.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use hardware_mocks::nano17::netft::{NetFtMock, NetFtMockConfig};
use hardware_mocks::nano17::{MockStats, SensorModel};
use rig::force::{FrontEndSettings, netft};
use rig_core::clock::Clock;
use rig_core::config::SaturationPolicy;
use rig_core::ft::transform::ToolTransform;
use rig_core::ft::{NANO17_SI_25_MAX, SampleFlags};
use rig_core::wrench::Wrench;

const DROP_EVERY: u32 = 97;
const REORDER_EVERY: u32 = 41;
const DUPLICATE_EVERY: u32 = 113;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_netft_rdt_7khz_for_5s_counts_injected_loss_and_reordering_exactly() {
    let clock = Clock::system();
    let load = [0.8, -0.4, -6.0, 12.0, 4.0, -2.0];
    let mock = NetFtMock::start(
        NetFtMockConfig {
            rate_hz: 7000.0,
            ..NetFtMockConfig::default()
        },
        SensorModel::nano17(3),
        Arc::new(move |_t| Wrench::from_array(load)),
        clock.clone(),
    )
    .await
    .unwrap();
    let f = mock.faults();
    f.drop_every.store(DROP_EVERY, Ordering::Release);
    f.reorder_every.store(REORDER_EVERY, Ordering::Release);
    f.duplicate_every.store(DUPLICATE_EVERY, Ordering::Release);
    let settings = FrontEndSettings {
        tool: ToolTransform::identity(),
        max_loads: NANO17_SI_25_MAX,
        saturation: SaturationPolicy::Flag,
        calibration: None,
        temperature_compensation: false,
        counts_per_force: 1e6,
        counts_per_torque: 1e3,
        rate_hz: 7000.0,
    };
    // Software bias on the box (0x42) at start: the load present then reads as zero.
    let mut stream = netft::open(&mock.addr().to_string(), true, settings, clock.clone())
        .await
        .unwrap();
    let t0 = clock.now_ns();
    let mut max_seq = 0u64;
    let mut n = 0u64;
    let mut late = 0u64;
    let mut gaps = 0u64;
    let mut max_abs = [0.0f64; 6];
    while clock.now_ns() - t0 < 5_000_000_000 {
        let s = crate::common::next_sample(&clock, &mut stream).await;
        n += 1;
        max_seq = max_seq.max(s.device_seq);
        if s.flags.contains(SampleFlags::REORDERED) {
            late += 1;
        }
        if s.flags.contains(SampleFlags::AFTER_GAP) {
            gaps += 1;
        }
        for (m, v) in max_abs.iter_mut().zip(s.wrench.to_array()) {
            *m = m.max(v.abs());
        }
    }
    mock.faults().set_muted(true);
    let ms = mock.stats();
    crate::common::drain_until_quiet(
        &clock,
        &mut stream,
        || MockStats::get(&ms.sent),
        |s| {
            n += 1;
            max_seq = max_seq.max(s.device_seq);
            if s.flags.contains(SampleFlags::REORDERED) {
                late += 1;
            }
        },
    )
    .await;
    let st = stream.stats();
    let sent = MockStats::get(&ms.sent);
    println!(
        "netft: max rdt_sequence {max_seq} in 5 s ({:.0} Hz), sent {sent}, received {n}, stats {st:?}, mock dropped {} reordered {} duplicated {}",
        max_seq as f64 / 5.0,
        MockStats::get(&ms.dropped),
        MockStats::get(&ms.reordered),
        MockStats::get(&ms.duplicated)
    );
    assert!(
        max_seq >= 34_000,
        "RDT rate too low: {max_seq} records in 5 s"
    );
    // Every sequence number 1..=max_seq that the box dropped is counted lost, and nothing else.
    let expected_lost = max_seq / u64::from(DROP_EVERY);
    assert_eq!(st.lost, expected_lost);
    assert_eq!(st.reordered, MockStats::get(&ms.reordered));
    assert_eq!(st.reordered, late);
    assert!(st.reordered > 700, "{st:?}");
    assert_eq!(st.duplicates, MockStats::get(&ms.duplicated));
    assert_eq!(n, sent, "every packet sent was delivered once");
    assert_eq!(n + st.lost, max_seq, "delivered + lost = sequence span");
    assert!(gaps >= st.lost.saturating_sub(st.reordered) / 2);
    assert_eq!(st.consumer_overflow, 0);
    // Bias at start: a constant load reads as zero within noise (σ = 1/160 N).
    assert!(max_abs[2] < 0.05, "{max_abs:?}");
    stream.finish().await.unwrap();
    mock.shutdown().await;
}
