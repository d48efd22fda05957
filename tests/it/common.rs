//! Helpers shared by the tests that drive the `rig` binary on the simulated rig.

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::{Mutex, MutexGuard};

/// The built-in simulated rig's config, as shipped.
pub fn sim_config() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/rig-configs/sim-source.toml"
    ))
}

/// The shipped simulated config with each `(from, to)` line replaced, written as `dir/name`.
/// Panics when the shipped config lacks a `from` (the test would silently test nothing).
pub fn edited_sim_config(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = std::fs::read_to_string(sim_config()).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "the shipped config has no {from:?}");
        text = text.replace(from, to);
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Exit status, stdout and stderr of a finished command, for assertion messages.
pub fn output_text(out: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// One simulated-rig run (`rig run` on the built-in rig) at a time in this test binary: the test
/// harness runs tests in parallel, and two rigs rendering their cameras on a two-core machine
/// (beside the demo's training) only slow each other down. The guard is held for the test.
pub fn one_rig_at_a_time() -> MutexGuard<'static, ()> {
    static RIG: Mutex<()> = Mutex::new(());
    RIG.lock().unwrap_or_else(|e| e.into_inner())
}

/// `rig run --indenter INDENTER --config CONFIG --out OUT --limit N --speed-factor 20`, one
/// rig at a time; panics with the run's output when it fails.
pub fn record_sim_run(config: &Path, indenter: &str, out: &Path, trajectories: usize) {
    let _rig = one_rig_at_a_time();
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", indenter, "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .args(["--limit", &trajectories.to_string(), "--speed-factor", "20"])
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", output_text(&run));
}

/// Drains `stream` into `each` once its device has gone quiet (muted): until the reader has
/// delivered every sample the device sent (`sent`, read at two polls 50 ms apart that agree, so
/// a batch the device built just before the mute is counted too). Waits in clock time, up to
/// 10 s: a loaded host has starved the reader for well over the 150 ms a fixed wait allowed.
pub async fn drain_until_quiet(
    clock: &rig_core::clock::Clock,
    stream: &mut rig::force::FtStream,
    sent: impl Fn() -> u64,
    mut each: impl FnMut(&rig::force::WrenchSample),
) {
    let deadline = clock.now_ns() + 10_000_000_000;
    let mut last_sent = None;
    loop {
        while let Some(s) = stream.try_next() {
            each(&s);
        }
        let now_sent = sent();
        if (last_sent == Some(now_sent) && stream.stats().samples >= now_sent)
            || clock.now_ns() > deadline
        {
            return;
        }
        last_sent = Some(now_sent);
        clock.sleep(std::time::Duration::from_millis(50)).await;
    }
}

/// The stream's next sample; panics (with the stream's counters and error) when none comes
/// within 10 s of clock time. The limit catches a dead stream, not a slow host: a loaded CI
/// machine has starved a reader for over a second of real time.
pub async fn next_sample(
    clock: &rig_core::clock::Clock,
    stream: &mut rig::force::FtStream,
) -> rig::force::WrenchSample {
    match clock
        .timeout(std::time::Duration::from_secs(10), stream.next())
        .await
    {
        Ok(Some(s)) => s,
        _ => panic!("stream stalled: {:?} {:?}", stream.stats(), stream.error()),
    }
}

/// Fails the test unless this machine lets it mount a tmpfs in a user and mount namespace
/// (`unshare -rm`), what the small-disk drills record into.
pub fn needs_unshare() {
    let probe = std::process::Command::new("unshare")
        .args(["-rm", "sh", "-c", "mount -t tmpfs -o size=1m tmpfs /mnt"])
        .status();
    assert!(
        probe.is_ok_and(|s| s.success()),
        "this test needs `unshare -rm` and tmpfs mounts (util-linux, user namespaces)"
    );
}

/// A safety stop's stopping distance, from the run's summary: the arm comes to rest (where the
/// first retract began) within one more 2 ms controller step at the pressing speed `v_m_s`
/// plus v²/2a at the stop deceleration, counted from the pose when the stop request reached
/// the controller; and from the pose the rig held at the crossing, within that plus the
/// request's latency at `v_m_s` and 6 ms (on a loaded host the rig's newest state at the
/// crossing can be a few periods old: the rig's latency, not the arm's stopping distance).
/// Measured from the controller's own pose, not the rig's view of it. Returns the travel
/// after the request and after the crossing, and the allowance, in metres.
pub fn assert_stop_travel(
    stop: &rig::run::safety::SafetyStop,
    summary: &rig::run::RunSummary,
    v_m_s: f64,
) -> (f64, f64, f64) {
    use rig_core::pose::translation_distance;
    let reached = stop
        .reached_controller_ns
        .expect("the controller never saw the stop request");
    let latency_s = reached.saturating_sub(stop.detected_ns) as f64 * 1e-9;
    let rest = summary
        .retracts
        .first()
        .expect("no retract after the stop")
        .from;
    let decel = rig::robot::RobotOptions::default().stop_accel_m_s2;
    let allowed = v_m_s * 2e-3 + v_m_s * v_m_s / (2.0 * decel) + 1e-6;
    let at_request = stop
        .tcp_at_controller
        .expect("no controller pose for the stop request");
    let travel = translation_distance(&at_request, &rest);
    assert!(
        travel <= allowed,
        "the arm travelled {:.4} mm after the stop request reached the controller; at most \
         {:.4} mm allowed",
        travel * 1e3,
        allowed * 1e3
    );
    let at_crossing = stop
        .tcp_at_detection
        .expect("no robot state at the crossing");
    let from_crossing = translation_distance(&at_crossing, &rest);
    assert!(
        from_crossing <= allowed + v_m_s * (latency_s + 6e-3),
        "the arm travelled {:.4} mm after the crossing (request latency {:.2} ms)",
        from_crossing * 1e3,
        latency_s * 1e3
    );
    (travel, from_crossing, allowed)
}
