//! RTDE pause and resume against the simulated UR5e over real TCP: no data while paused (and
//! no stall alarm), the same recipe streaming again after resume.

use std::time::Duration;

use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use rig::robot::rtde::{RtdeClient, RtdeConfig};
use rig_core::clock::Clock;

#[tokio::test]
async fn pause_stops_the_stream_and_resume_restarts_it() {
    let clock = Clock::scaled(4.0);
    let mock = Ur5e::start(Ur5eConfig::default(), clock.clone())
        .await
        .unwrap();
    let mut cfg = RtdeConfig::new(mock.rtde_addr());
    // Shorter than the pause below: a paused link must not count as stalled.
    cfg.stall_timeout = Duration::from_millis(300);
    let client = RtdeClient::connect(cfg, clock.clone()).await.unwrap();
    clock.sleep(Duration::from_millis(100)).await;
    assert!(client.stats().data_packages > 0);

    client.pause().await.unwrap();
    // Let packages already in flight arrive, then count.
    clock.sleep(Duration::from_millis(50)).await;
    let before = client.stats().data_packages;
    let t_paused = client.latest().unwrap().timestamp_s;
    clock.sleep(Duration::from_secs(1)).await;
    let stats = client.stats();
    assert_eq!(stats.data_packages, before, "data arrived while paused");
    assert_eq!(
        stats.link_failures, 0,
        "a paused link was taken for a stalled one"
    );
    // Pausing a paused link is a no-op.
    client.pause().await.unwrap();

    client.resume().await.unwrap();
    // Both requests are idempotent: resuming a streaming link is a no-op.
    client.resume().await.unwrap();
    clock.sleep(Duration::from_millis(200)).await;
    let s = client.stats();
    assert!(s.data_packages > before + 20, "{s:?}");
    assert_eq!(s.connections, 1, "resume must not reconnect");
    // The stream resumed on the controller's own timeline, a second or more later.
    assert!(client.latest().unwrap().timestamp_s > t_paused + 1.0);
}
