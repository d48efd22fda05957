//! The pairer: any interleaving of frames and wrench gives the same pairs; drops are counted;
//! exposure latency shifts the frame time; refusals are explicit.

use rig::plan::StageName;
use rig::sync::{
    DeviceStamp, FrameIn, InterpMethod, PairedFrame, Pairer, PairerConfig, SyncStatus, WrenchIn,
};
use rig_core::pose::Pose;
use rig_core::wrench::Wrench;

/// The true force: Fz = t (s) · 10 N, linear, so linear and cubic interpolation are exact.
fn wrench_at(t_ns: f64) -> Wrench {
    Wrench::from_array([0.0, 0.0, t_ns * 1e-8, 0.0, 0.0, 0.0])
}

enum Ev {
    F(FrameIn),
    W(WrenchIn),
}

/// 1 kHz wrench (counter from 0, host receives 100 µs later), frames every 33 ms stamped with
/// host ns (received 4 ms later), over `ms` milliseconds, skipping frame seqs in `drop`.
fn events(ms: u64, drop: &[u64]) -> Vec<(u64, Ev)> {
    let mut ev = Vec::new();
    for k in 0..=ms {
        let t = k * 1_000_000;
        ev.push((
            t + 100_000,
            Ev::W(WrenchIn {
                stamp: DeviceStamp::Counter(k),
                host_rx_ns: t + 100_000,
                wrench: wrench_at(t as f64),
            }),
        ));
    }
    let mut seq = 0;
    let mut t = 5_000_000;
    while t <= ms * 1_000_000 {
        if !drop.contains(&seq) {
            ev.push((
                t + 4_000_000,
                Ev::F(FrameIn {
                    seq,
                    stamp: DeviceStamp::Nanos(t),
                    host_rx_ns: t + 4_000_000,
                }),
            ));
        }
        seq += 1;
        t += 33_000_000;
    }
    ev
}

fn cfg(method: InterpMethod) -> PairerConfig {
    let mut c = PairerConfig {
        method,
        ..Default::default()
    };
    // Both links have a known minimum latency; subtract it so host times are capture times.
    c.wrench_clock.min_latency_ns = 100_000.0;
    c.frame_clock.min_latency_ns = 4_000_000.0;
    c
}

fn run(p: &mut Pairer, evs: Vec<(u64, Ev)>) -> Vec<PairedFrame> {
    let mut out = Vec::new();
    for (_, e) in evs {
        match e {
            Ev::F(f) => p.push_frame(f),
            Ev::W(w) => p.push_wrench(w),
        }
        out.extend(p.poll());
    }
    out.extend(p.finish());
    out
}

#[test]
fn pairs_are_exact_on_a_linear_signal_and_independent_of_interleaving() {
    let mut sorted = events(1000, &[]);
    sorted.sort_by_key(|(t, _)| *t);
    let mut a = Pairer::new(cfg(InterpMethod::Linear));
    let pa = run(&mut a, sorted);
    // Worst interleaving: every frame first, then the whole wrench stream.
    let mut frames_first = events(1000, &[]);
    frames_first.sort_by_key(|(t, e)| (matches!(e, Ev::W(_)), *t));
    let mut b = Pairer::new(cfg(InterpMethod::Linear));
    let pb = run(&mut b, frames_first);
    assert_eq!(pa.len(), 31);
    assert_eq!(pa, pb);
    for p in &pa {
        assert_eq!(p.status, SyncStatus::Ok, "{p:?}");
        let want = 5e6 + 33e6 * p.frame_seq as f64;
        assert!(
            (p.t_frame_ns - want).abs() < 1.0,
            "{} vs {want}",
            p.t_frame_ns
        );
        let fz = p.wrench.unwrap().force_n[2];
        assert!((fz - want * 1e-8).abs() < 1e-6, "fz {fz}");
        assert!(
            p.sync_error_ns.unwrap() < 1.0,
            "frames fall on wrench samples here"
        );
    }
    assert_eq!(a.stats().frames_dropped, 0);
}

#[test]
fn frames_wait_until_the_wrench_stream_has_passed_them() {
    let mut p = Pairer::new(cfg(InterpMethod::Cubic));
    p.push_frame(FrameIn {
        seq: 0,
        stamp: DeviceStamp::Nanos(10_500_000),
        host_rx_ns: 14_500_000,
    });
    for k in 0..=10u64 {
        p.push_wrench(WrenchIn {
            stamp: DeviceStamp::Counter(k),
            host_rx_ns: k * 1_000_000 + 100_000,
            wrench: wrench_at((k * 1_000_000) as f64),
        });
        assert!(
            p.poll().is_empty(),
            "released before the stream passed 10.5 ms"
        );
    }
    p.push_wrench(WrenchIn {
        stamp: DeviceStamp::Counter(11),
        host_rx_ns: 11_100_000,
        wrench: wrench_at(11e6),
    });
    assert!(
        p.poll().is_empty(),
        "cubic needs two samples after the frame"
    );
    p.push_wrench(WrenchIn {
        stamp: DeviceStamp::Counter(12),
        host_rx_ns: 12_100_000,
        wrench: wrench_at(12e6),
    });
    let out = p.poll();
    assert_eq!(out.len(), 1);
    assert!((out[0].wrench.unwrap().force_n[2] - 0.105).abs() < 1e-9);
    assert!((out[0].sync_error_ns.unwrap() - 500_000.0).abs() < 1.0);
}

#[test]
fn dropped_frames_are_counted_and_reported() {
    let mut evs = events(1000, &[3, 7, 8]);
    evs.sort_by_key(|(t, _)| *t);
    let mut p = Pairer::new(cfg(InterpMethod::Nearest));
    let out = run(&mut p, evs);
    assert_eq!(out.len(), 28);
    let s = p.stats();
    assert_eq!(s.frames_dropped, 3);
    let gaps: Vec<(i64, u64)> = s
        .frame_gaps
        .iter()
        .map(|g| (g.after_seq, g.missing))
        .collect();
    assert_eq!(gaps, vec![(2, 1), (6, 2)]);
}

#[test]
fn exposure_latency_moves_the_frame_time_back() {
    let mut c = cfg(InterpMethod::Linear);
    c.exposure_latency_ns = 2_500_000.0;
    let mut evs = events(300, &[]);
    evs.sort_by_key(|(t, _)| *t);
    let mut p = Pairer::new(c);
    let out = run(&mut p, evs);
    let f = &out[1];
    assert!((f.t_frame_ns - (38e6 - 2.5e6)).abs() < 1.0);
    assert!((f.wrench.unwrap().force_n[2] - 0.355).abs() < 1e-9);
    assert!((f.sync_error_ns.unwrap() - 500_000.0).abs() < 1.0);
}

#[test]
fn wrench_gap_and_frames_beyond_the_stream_are_refused_not_invented() {
    let mut p = Pairer::new(cfg(InterpMethod::Linear));
    for k in (0..=20u64).chain(40..=60) {
        p.push_wrench(WrenchIn {
            stamp: DeviceStamp::Counter(k),
            host_rx_ns: k * 1_000_000 + 100_000,
            wrench: wrench_at((k * 1_000_000) as f64),
        });
    }
    assert_eq!(p.stats().wrench_lost, 19);
    for (seq, t) in [(0u64, 10_000_000u64), (1, 30_000_000), (2, 90_000_000)] {
        p.push_frame(FrameIn {
            seq,
            stamp: DeviceStamp::Nanos(t),
            host_rx_ns: t + 4_000_000,
        });
    }
    let mut out = p.poll();
    out.extend(p.finish());
    let st: Vec<SyncStatus> = out.iter().map(|f| f.status).collect();
    assert_eq!(
        st,
        vec![SyncStatus::Ok, SyncStatus::Gap, SyncStatus::OutOfRange]
    );
    assert!(out[1].wrench.is_none() && out[2].wrench.is_none());
    assert!((out[2].sync_error_ns.unwrap() - 30e6).abs() < 1.0);
}

#[test]
fn stage_and_pose_are_attached_at_the_frame_time() {
    let mut p = Pairer::new(cfg(InterpMethod::Linear));
    p.set_stage(0.0, StageName::Down);
    p.set_stage(20e6, StageName::Shear);
    for k in 0..=40u64 {
        let t = k * 1_000_000;
        p.push_wrench(WrenchIn {
            stamp: DeviceStamp::Counter(k),
            host_rx_ns: t + 100_000,
            wrench: wrench_at(t as f64),
        });
        p.push_pose(
            t as f64,
            Pose::new(0.0, 0.0, 0.2 - t as f64 * 1e-12, 0.0, 0.0, 0.0),
        );
    }
    for (seq, t) in [(0u64, 10_500_000u64), (1, 25_000_000)] {
        p.push_frame(FrameIn {
            seq,
            stamp: DeviceStamp::Nanos(t),
            host_rx_ns: t + 4_000_000,
        });
    }
    let out = p.poll();
    assert_eq!(out.len(), 2);
    assert_eq!(out[0].stage, Some(StageName::Down));
    assert_eq!(out[1].stage, Some(StageName::Shear));
    let z = out[0].tcp_pose.unwrap().z;
    assert!((z - (0.2 - 10.5e6 * 1e-12)).abs() < 1e-12, "{z}");
}
