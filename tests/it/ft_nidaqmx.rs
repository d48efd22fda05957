//! The NI-DAQmx front end through its real `dlopen` path, against the stand-in NI library
//! (`nidaqmx-standin`, built as this package's dev-dependency next to the test binary): a
//! minute at 1 kHz with no loss and the calibration applied to exactly the voltages the card
//! read, an overrun counted exactly, a removed card tripping the safety supervisor, NI's
//! message for a wrong device or channel, the index on the sample clock through a late start,
//! a FIFO overflow restarted, and a missing library naming what to install.
//!
//! Each in-process test uses a device of its own (`NiA`, `NiB`, ...) on the one stand-in the
//! process loads, so they run in parallel; the stand-in's clock is the test's (×20 simulated
//! time where a test needs a long stretch of the sample clock).

use std::ffi::{CString, c_char, c_void};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use hardware_mocks::nano17::nidaqmx::hook::{
    HOOK_VERSION, LOG_WIDTH, StandinHook, StandinStats, fault,
};
use rig::force::nidaqmx::{self, Api, TaskSpec, library};
use rig::force::{FrontEndSettings, FtError, FtStream, WrenchSample};
use rig_core::clock::Clock;
use rig_core::config::SaturationPolicy;
use rig_core::ft::SampleFlags;
use rig_core::ft::cal::Calibration;
use rig_core::ft::nidaqmx::{PhysicalChannel, TerminalConfig, parse_channels};
use rig_core::ft::transform::ToolTransform;

use crate::common;

const RATE_HZ: f64 = 1000.0;

fn standin_path() -> PathBuf {
    library::beside_executable("libnidaqmx_standin.so")
        .expect("the stand-in NI library is built with the tests (dev-dependency nidaqmx-standin)")
}

fn cal_path() -> &'static str {
    concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/nano17_useraxis.cal"
    )
}

/// The stand-in as loaded by the rig's own loader, and its extra symbols.
struct Standin {
    api: &'static Api,
}

impl Standin {
    fn load() -> Self {
        Self {
            api: library::load_path(&standin_path(), "the test").unwrap(),
        }
    }

    fn sym<T: Copy>(&self, name: &str) -> T {
        // SAFETY: the stand-in's C signatures (hardware_mocks::nano17::nidaqmx::hook).
        unsafe { *self.api.library().get::<T>(name.as_bytes()).unwrap() }
    }

    fn attach(&self, device: &str, hook: Option<&StandinHook>) {
        let f: unsafe extern "C" fn(*const c_char, *const StandinHook) -> i32 =
            self.sym("standin_attach");
        let d = CString::new(device).unwrap();
        let st = unsafe { f(d.as_ptr(), hook.map_or(std::ptr::null(), |h| h as *const _)) };
        assert_eq!(st, 0);
    }

    fn inject(&self, device: &str, kind: u32, at: u64, arg: u64) {
        let f: unsafe extern "C" fn(*const c_char, u32, u64, u64) -> i32 =
            self.sym("standin_inject");
        let d = CString::new(device).unwrap();
        assert_eq!(unsafe { f(d.as_ptr(), kind, at, arg) }, 0);
    }

    fn log(&self, device: &str, max: u64) {
        let f: unsafe extern "C" fn(*const c_char, u64) -> i32 = self.sym("standin_log");
        let d = CString::new(device).unwrap();
        assert_eq!(unsafe { f(d.as_ptr(), max) }, 0);
    }

    /// The voltages the card read for samples `first..first + n`.
    fn log_read(&self, device: &str, first: u64, n: u64) -> Vec<[f64; LOG_WIDTH]> {
        let f: unsafe extern "C" fn(*const c_char, u64, u64, *mut f64) -> u64 =
            self.sym("standin_log_read");
        let d = CString::new(device).unwrap();
        let mut out = vec![0.0; n as usize * LOG_WIDTH];
        let got = unsafe { f(d.as_ptr(), first, n, out.as_mut_ptr()) } as usize;
        out.chunks_exact(LOG_WIDTH)
            .take(got)
            .map(|c| std::array::from_fn(|i| c[i]))
            .collect()
    }

    fn stats(&self, device: &str) -> StandinStats {
        let f: unsafe extern "C" fn(*const c_char, *mut StandinStats) -> i32 =
            self.sym("standin_stats");
        let d = CString::new(device).unwrap();
        let mut s = StandinStats::default();
        assert_eq!(unsafe { f(d.as_ptr(), &mut s) }, 0);
        s
    }
}

/// What the test's hook hands the card: the test's clock and a load that starts at `from_ns`.
/// With a pacer (as the simulated rig's hook has), the reader's polls pace the fast clock, so a
/// host that stalls the reader thread holds the clock rather than overrunning the card.
struct Scene {
    clock: Clock,
    pacer: Option<rig_core::clock::Pacer>,
    load_from_ns: AtomicU64,
}

/// The true sensor-frame wrench: none before `from_ns`, then slow sines on every axis.
fn load(t_ns: u64, from_ns: u64) -> [f64; 6] {
    if t_ns < from_ns {
        return [0.0; 6];
    }
    let s = (t_ns - from_ns) as f64 * 1e-9;
    let w = |a: f64, f: f64| a * (2.0 * std::f64::consts::PI * f * s).sin();
    [
        w(2.0, 0.3),
        w(-1.5, 0.2),
        -4.0 + w(3.0, 0.1),
        w(20.0, 0.25),
        w(-15.0, 0.15),
        w(5.0, 0.4),
    ]
}

unsafe extern "C" fn scene_now(ctx: *mut c_void) -> u64 {
    let s = unsafe { &*ctx.cast::<Scene>() };
    let now = s.clock.now_ns();
    if let Some(p) = &s.pacer {
        p.reached(now);
    }
    now
}

unsafe extern "C" fn scene_wrench(ctx: *mut c_void, t_ns: u64, out: *mut f64) {
    let s = unsafe { &*ctx.cast::<Scene>() };
    let w = load(t_ns, s.load_from_ns.load(Ordering::Acquire));
    unsafe { std::ptr::copy_nonoverlapping(w.as_ptr(), out, 6) };
}

/// Attaches a scene to `device` (the scene must outlive the device's use; tests leak it).
fn attach_scene(ni: &Standin, device: &str, clock: &Clock, paced: bool) -> &'static Scene {
    let scene: &'static Scene = Box::leak(Box::new(Scene {
        clock: clock.clone(),
        pacer: paced.then(|| clock.pacer("test NI reader", rig_core::clock::SIM_PACER_LEAD)),
        load_from_ns: AtomicU64::new(u64::MAX),
    }));
    let hook = StandinHook {
        version: HOOK_VERSION,
        ctx: scene as *const Scene as *mut c_void,
        now_ns: Some(scene_now),
        wrench_at: Some(scene_wrench),
        faults: None,
        acquiring: None,
    };
    ni.attach(device, Some(&hook));
    scene
}

/// The tip 12 mm below the sensor, turned 30° about z.
fn tool() -> ToolTransform {
    ToolTransform::from_angles([0.0, 0.0, -12.0], [0.0, 0.0, 30f64.to_radians()]).unwrap()
}

fn settings(cal: &Calibration) -> FrontEndSettings {
    FrontEndSettings {
        tool: tool(),
        max_loads: cal.max_loads,
        saturation: SaturationPolicy::Flag,
        calibration: Some(cal.clone()),
        temperature_compensation: true,
        counts_per_force: 1.0,
        counts_per_torque: 1.0,
        rate_hz: RATE_HZ,
    }
}

fn spec(device: &str, cal: &Calibration) -> TaskSpec {
    TaskSpec {
        gauges: parse_channels(&format!("{device}/ai0:5")).unwrap(),
        thermistor: Some(PhysicalChannel {
            device: device.to_owned(),
            index: 6,
        }),
        terminal: TerminalConfig::Differential,
        rate_hz: RATE_HZ,
        range: cal.output_range,
    }
}

/// What the rig must report for card sample `v` (six gauges, thermistor): the calibration's
/// temperature compensation, `M · (V − bias)`, the tool transform.
fn expected(cal: &Calibration, v: &[f64; LOG_WIDTH], bias: &[f64; 6]) -> [f64; 6] {
    let g: [f64; 6] = std::array::from_fn(|i| v[i]);
    let (comp, ok) = cal.compensate(&g, Some(v[6]));
    assert!(ok);
    tool().apply(&cal.wrench(&comp, bias))
}

/// Float rounding of the same arithmetic done twice.
fn assert_same(got: &[f64; 6], want: &[f64; 6], what: &str) {
    for i in 0..6 {
        assert!(
            (got[i] - want[i]).abs() <= 1e-9 * (1.0 + want[i].abs()),
            "{what}: axis {i}: {} vs {}",
            got[i],
            want[i]
        );
    }
}

/// Reads samples until `pred` says stop, up to 30 s of the test's clock.
async fn collect(
    clock: &Clock,
    stream: &mut FtStream,
    mut until: impl FnMut(&WrenchSample) -> bool,
) -> Vec<WrenchSample> {
    let mut out = Vec::new();
    loop {
        let s = common::next_sample(clock, stream).await;
        let stop = until(&s);
        out.push(s);
        if stop {
            return out;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_nidaqmx_streams_a_minute_at_1khz_with_no_loss_and_the_calibration_applied() {
    const DEV: &str = "NiA";
    let clock = Clock::scaled(20.0);
    let ni = Standin::load();
    let scene = attach_scene(&ni, DEV, &clock, true);
    ni.log(DEV, 80_000);
    let cal = Calibration::load(cal_path()).unwrap();
    let mut stream = nidaqmx::open_with(ni.api, spec(DEV, &cal), settings(&cal), clock.clone())
        .await
        .unwrap();
    assert!(
        stream.description.contains("NiA/ai0"),
        "{}",
        stream.description
    );
    let tare = stream.tare(500).await.unwrap();
    // The bias is in gauge volts: the simulated sensor's offsets (plus noise), compensated.
    assert!((tare.raw.mean[2] - 0.2044).abs() < 0.01, "{tare:?}");
    scene.load_from_ns.store(clock.now_ns(), Ordering::Release);
    while stream.try_next().is_some() {}
    let first = common::next_sample(&clock, &mut stream).await;
    // A minute of the card's sample clock at 1 kHz.
    let last_seq = first.device_seq + 60_000;
    let mut samples = vec![first];
    samples.extend(collect(&clock, &mut stream, |s| s.device_seq >= last_seq).await);
    let stats = stream.finish().await.unwrap();
    assert_eq!(stats.lost, 0, "{stats}");
    assert!(samples.len() > 60_000);
    for w in samples.windows(2) {
        assert_eq!(
            w[1].device_seq,
            w[0].device_seq + 1,
            "a gap in the card's indices"
        );
    }
    let card = ni.stats(DEV);
    assert_eq!(card.skipped, 0);
    let log = ni.log_read(DEV, 0, last_seq + 1);
    let from_ns = scene.load_from_ns.load(Ordering::Acquire);
    let mut loaded = 0;
    for s in &samples {
        assert!(s.flags.is_clean(), "{s:?}");
        let v = &log[s.device_seq as usize];
        assert_same(
            &s.wrench.to_array(),
            &expected(&cal, v, &tare.raw.mean),
            "sample",
        );
        // Independently of the calibration code: the true load at the sample's instant on the
        // card's clock, within the simulated sensor's noise (σ 1/160 N; the tared offset).
        let t_k = card.first_sample_ns + (s.device_seq as f64 * 1e9 / RATE_HZ).round() as u64;
        let truth = tool().apply(&load(t_k, from_ns));
        let f = s.wrench.force_n;
        for i in 0..3 {
            assert!((f[i] - truth[i]).abs() < 0.06, "{s:?} vs {truth:?}");
        }
        loaded += usize::from(t_k > from_ns);
    }
    assert!(loaded > 59_000, "{loaded}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_nidaqmx_counts_an_injected_overrun_exactly_and_keeps_the_indices() {
    const DEV: &str = "NiB";
    let clock = Clock::scaled(20.0);
    let ni = Standin::load();
    attach_scene(&ni, DEV, &clock, false);
    ni.log(DEV, 40_000);
    // The host stalls when its reads reach sample 3000, past the card's 2 s buffer.
    ni.inject(DEV, fault::OVERRUN, 3000, 0);
    let cal = Calibration::load(cal_path()).unwrap();
    let mut stream = nidaqmx::open_with(ni.api, spec(DEV, &cal), settings(&cal), clock.clone())
        .await
        .unwrap();
    let samples = collect(&clock, &mut stream, |s| s.device_seq >= 12_000).await;
    let stats = stream.finish().await.unwrap();
    let gaps: Vec<(u64, u64)> = samples
        .windows(2)
        .filter(|w| w[1].device_seq != w[0].device_seq + 1)
        .map(|w| (w[0].device_seq, w[1].device_seq))
        .collect();
    assert_eq!(gaps.len(), 1, "{gaps:?}");
    let (before, after) = gaps[0];
    let missing = after - before - 1;
    // The reads stalled when they reached 3000: the gap starts at the last read block there.
    assert!((2990..3000).contains(&before), "{gaps:?}");
    // The stall lasts 1.5 buffers (3000 samples): at least half a buffer was overwritten, and
    // the reader resumes an eighth of a buffer past the oldest sample the card still held.
    assert!(missing >= 1000 + 250, "{missing}");
    assert_eq!(stats.lost, missing, "{stats}");
    assert_eq!(ni.stats(DEV).skipped, missing);
    assert_eq!(samples[0].device_seq, 0);
    let next = samples.iter().find(|s| s.device_seq == after).unwrap();
    assert!(next.flags.contains(SampleFlags::AFTER_GAP), "{next:?}");
    // The values after the gap are the card's samples of those indices.
    let log = ni.log_read(DEV, 0, 12_001);
    for s in samples.iter().filter(|s| s.device_seq > before - 5) {
        let v = &log[s.device_seq as usize];
        assert!(
            v.iter().all(|x| x.is_finite()),
            "{} was never read",
            s.device_seq
        );
        assert_same(
            &s.wrench.to_array(),
            &expected(&cal, v, &[0.0; 6]),
            "after the gap",
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_nidaqmx_device_removal_trips_the_supervisor_within_one_stall_period() {
    use rig::run::events::{StreamSettings, Trip};
    use rig::run::streams::Streams;
    const DEV: &str = "NiC";
    let clock = Clock::scaled(10.0);
    let ni = Standin::load();
    attach_scene(&ni, DEV, &clock, false);
    ni.inject(DEV, fault::REMOVE, 1500, 0);
    let cal = Calibration::load(cal_path()).unwrap();
    let stream = nidaqmx::open_with(ni.api, spec(DEV, &cal), settings(&cal), clock.clone())
        .await
        .unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(1 << 16);
    let drain = tokio::spawn(async move { while rx.recv().await.is_some() {} });
    let stall = Duration::from_millis(500);
    let streams = Streams::start(
        Some(stream),
        None,
        clock.clone(),
        StreamSettings {
            max_force_n: 20.0,
            ft_stall: stall,
            camera_stall: Duration::from_secs(1),
            envelope: None,
            flange: None,
        },
        tx,
        None,
        None,
    );
    let mut trips = streams.trips();
    clock
        .timeout(Duration::from_secs(20), trips.wait_for(|t| t.is_some()))
        .await
        .expect("the supervisor tripped")
        .unwrap();
    let stops = streams.safety_stops();
    let trip = &stops[0];
    match &trip.trip {
        Trip::FtLost(why) => {
            assert!(why.contains("-200045"), "{why}");
            assert!(why.to_lowercase().contains("removed"), "{why}");
        }
        other => panic!("{other:?}"),
    }
    let removed_ns = ni.stats(DEV).first_sample_ns + 1_500_000_000;
    assert!(
        trip.detected_ns <= removed_ns + stall.as_nanos() as u64,
        "tripped {} ms after the removal",
        (trip.detected_ns as f64 - removed_ns as f64) * 1e-6
    );
    streams.shutdown().await;
    drain.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_nidaqmx_wrong_device_names_ni_s_error_and_the_fix() {
    const DEV: &str = "NiD";
    let ni = Standin::load();
    ni.attach(DEV, None);
    let cal = Calibration::load(cal_path()).unwrap();
    let mut bad = spec(DEV, &cal);
    bad.gauges = parse_channels("Dev9/ai0:5").unwrap();
    bad.thermistor = None;
    let e = nidaqmx::open_with(ni.api, bad, settings(&cal), Clock::system())
        .await
        .err()
        .expect("no such device");
    let text = e.to_string();
    match &e {
        FtError::Ni { code, .. } => assert_eq!(*code, -200220),
        other => panic!("{other:?}"),
    }
    assert!(text.contains("Device identifier is invalid"), "{text}");
    assert!(text.contains("nilsdev"), "{text}");
    // The card is free again: a right name works.
    let mut ok = spec(DEV, &cal);
    ok.thermistor = None;
    let s = nidaqmx::open_with(ni.api, ok, settings(&cal), Clock::system())
        .await
        .unwrap();
    s.finish().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_nidaqmx_indices_on_the_sample_clock_survive_a_late_start() {
    use rig::sync::{DeviceClock, DeviceStamp, DeviceTimebase, EstimatorConfig};
    const DEV: &str = "NiE";
    let clock = Clock::scaled(10.0);
    let ni = Standin::load();
    attach_scene(&ni, DEV, &clock, false);
    // The sample clock starts 300 ms after the task.
    ni.inject(DEV, fault::LATE_START, 0, 300_000_000);
    let cal = Calibration::load(cal_path()).unwrap();
    let t_start = clock.now_ns();
    let mut stream = nidaqmx::open_with(ni.api, spec(DEV, &cal), settings(&cal), clock.clone())
        .await
        .unwrap();
    let samples = collect(&clock, &mut stream, |s| s.device_seq >= 4000).await;
    stream.finish().await.unwrap();
    let first_ns = ni.stats(DEV).first_sample_ns;
    assert!(first_ns >= t_start + 300_000_000);
    assert_eq!(samples[0].device_seq, 0);
    // The run's estimator, fed as the collector feeds it, maps each index onto the sample's
    // instant on the card's clock.
    // As the run configures it: no clock jumps on a fast simulated clock.
    let mut dc = DeviceClock::new(
        DeviceTimebase::Counter {
            bits: 63,
            nominal_hz: RATE_HZ,
        },
        EstimatorConfig {
            jump_tolerance_ns: 1e9 * clock.rate(),
            ..EstimatorConfig::default()
        },
    );
    let mut worst: f64 = 0.0;
    for s in &samples {
        let (dev, _) = dc.device_ns(DeviceStamp::Counter(s.device_seq)).unwrap();
        dc.estimator.observe(dev, s.t_host_ns);
        if s.device_seq < 1000 {
            continue;
        }
        let mapped = dc.estimator.to_host(dev).unwrap();
        let truth = first_ns as f64 + s.device_seq as f64 * 1e9 / RATE_HZ;
        worst = worst.max((mapped - truth).abs());
    }
    // Reads return a 5 ms block at a time; the estimator's lower hull finds the block ends.
    assert!(worst < 1e6, "sync error {worst} ns");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ft_nidaqmx_fifo_overflow_restarts_the_card_and_counts_the_stopped_stretch() {
    const DEV: &str = "NiF";
    let clock = Clock::scaled(10.0);
    let ni = Standin::load();
    attach_scene(&ni, DEV, &clock, false);
    ni.inject(DEV, fault::FIFO_OVERFLOW, 2000, 0);
    let cal = Calibration::load(cal_path()).unwrap();
    let mut stream = nidaqmx::open_with(ni.api, spec(DEV, &cal), settings(&cal), clock.clone())
        .await
        .unwrap();
    let first_run_ns = ni.stats(DEV).first_sample_ns;
    let samples = collect(&clock, &mut stream, |s| s.device_seq >= 5000).await;
    let stats = stream.finish().await.unwrap();
    let card = ni.stats(DEV);
    assert_eq!(card.starts, 2, "the reader restarted the task");
    assert_eq!(samples.iter().filter(|s| s.device_seq < 2000).count(), 2000);
    let gaps: Vec<(u64, u64)> = samples
        .windows(2)
        .filter(|w| w[1].device_seq != w[0].device_seq + 1)
        .map(|w| (w[0].device_seq, w[1].device_seq))
        .collect();
    let missing: u64 = gaps.iter().map(|(a, b)| b - a - 1).sum();
    assert_eq!(missing, stats.lost, "{gaps:?} {stats}");
    // The count continues on the clock: the restarted card's sample 0 gets the index of its
    // instant on the first run's sample clock, within the read latency (a few blocks).
    let resumed = samples
        .iter()
        .find(|s| s.device_seq >= 2000)
        .unwrap()
        .device_seq;
    let on_clock = (card.first_sample_ns - first_run_ns) as f64 * RATE_HZ * 1e-9;
    assert!(
        (resumed as f64 - on_clock).abs() < 30.0,
        "restarted at index {resumed}, the clock says {on_clock:.0}"
    );
}

/// A lab-style config for `rig ft` with the NI route, edited by `edits`.
fn ni_config(dir: &Path, extra: &str) -> PathBuf {
    let lab = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/rig-configs/lab-example.toml"
    ))
    .unwrap();
    let start = lab.find("[force_sensor]").unwrap();
    let end = start + lab[start..].find("\n[camera]").unwrap();
    let section = format!(
        "[force_sensor]\nkind = \"nidaqmx\"\ncalibration_file = {:?}\nrate_hz = 1000.0\n\
         tare_samples = 200\n{extra}\n",
        cal_path()
    );
    let text = format!("{}{}{}", &lab[..start], section, &lab[end..]);
    let path = dir.join("ni.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn rig_ft(args: &[&str], cfg: &Path, env: Option<&Path>) -> std::process::Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_rig"));
    c.arg("ft").args(args).arg("--config").arg(cfg);
    c.env_remove(library::LIBRARY_ENV);
    if let Some(p) = env {
        c.env(library::LIBRARY_ENV, p);
    }
    c.output().unwrap()
}

#[test]
fn ft_nidaqmx_cli_streams_and_checks_against_the_standin() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = ni_config(tmp.path(), "");
    let out = rig_ft(
        &["stream", "--seconds", "1.5", "--json"],
        &cfg,
        Some(&standin_path()),
    );
    let text = common::output_text(&out);
    assert!(out.status.success(), "{text}");
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(lines[0].get("tare").is_some(), "{text}");
    let windows: Vec<_> = lines
        .iter()
        .filter(|l| l.get("rate_hz").is_some())
        .collect();
    assert!(!windows.is_empty(), "{text}");
    for w in windows {
        assert_eq!(w["stats"]["lost"], 0, "{text}");
        // Unloaded and tared: every axis within the noise of zero.
        for i in 0..3 {
            assert!(w["mean"][i].as_f64().unwrap().abs() < 0.01, "{text}");
        }
    }
    let check = rig_ft(&["check", "--seconds", "1"], &cfg, Some(&standin_path()));
    let text = common::output_text(&check);
    assert!(check.status.success(), "{text}");
    assert!(text.contains("F/T check passed"), "{text}");
    assert!(text.contains("NI-DAQmx Dev1/ai0"), "{text}");
}

#[test]
fn ft_nidaqmx_cli_wrong_channel_gives_ni_s_message_without_a_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = ni_config(tmp.path(), "channels = \"Dev1/ai20:25\"");
    let out = rig_ft(&["tare"], &cfg, Some(&standin_path()));
    let text = common::output_text(&out);
    assert!(!out.status.success(), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    assert!(text.contains("-200170"), "{text}");
    assert!(
        text.contains("Physical channel specified does not exist"),
        "{text}"
    );
    assert!(text.contains("force_sensor.channels"), "{text}");
}

#[test]
fn ft_nidaqmx_without_the_library_fails_at_start_naming_what_to_install() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = ni_config(tmp.path(), "");
    // A library path that is not there.
    let missing = tmp.path().join("libnidaqmx.so.1");
    let out = rig_ft(&["tare"], &cfg, Some(&missing));
    let text = common::output_text(&out);
    assert!(!out.status.success(), "{text}");
    assert!(text.contains(&missing.display().to_string()), "{text}");
    assert!(text.contains("ni-daqmx"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    // The system's search, where this machine has no NI driver.
    // SAFETY: probing whether the system has NI's library, as the rig would.
    if unsafe { libloading::Library::new("libnidaqmx.so.1") }.is_ok() {
        eprintln!("this machine has NI-DAQmx installed: the system-search case is not tested");
        return;
    }
    let out = rig_ft(&["tare"], &cfg, None);
    let text = common::output_text(&out);
    assert!(!out.status.success(), "{text}");
    assert!(text.contains("libnidaqmx.so.1"), "{text}");
    assert!(text.contains("install NI-DAQmx for Linux"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
}

#[test]
fn ft_nidaqmx_config_is_validated_before_anything_opens() {
    let tmp = tempfile::tempdir().unwrap();
    for (extra, key, why) in [
        (
            "channels = \"Dev1/ai0:4\"",
            "force_sensor.channels",
            "six gauges",
        ),
        (
            "channels = \"ai0:5\"",
            "force_sensor.channels",
            "device name",
        ),
        (
            "thermistor_channel = \"Dev1/ai2\"",
            "force_sensor.thermistor_channel",
            "also a gauge",
        ),
        (
            "terminal_config = \"pseudo\"",
            "terminal_config",
            "unknown variant",
        ),
    ] {
        let cfg = ni_config(tmp.path(), extra);
        let out = rig_ft(&["tare"], &cfg, Some(&standin_path()));
        let text = common::output_text(&out);
        assert!(!out.status.success(), "{extra}: {text}");
        assert!(text.contains(key) && text.contains(why), "{extra}: {text}");
    }
    let slow = ni_config(tmp.path(), "").to_string_lossy().into_owned();
    let text = std::fs::read_to_string(&slow)
        .unwrap()
        .replace("rate_hz = 1000.0", "rate_hz = 500.0");
    std::fs::write(&slow, text).unwrap();
    let out = rig_ft(&["tare"], Path::new(&slow), Some(&standin_path()));
    let text = common::output_text(&out);
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains("force_sensor.rate_hz") && text.contains("1000 Hz"),
        "{text}"
    );
}

#[test]
fn ft_nidaqmx_simulated_run_records_a_dataset_that_checks_with_sync_under_1ms() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let _rig = common::one_rig_at_a_time();
    let run = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cone", "--config"])
        .arg(common::sim_config())
        .arg("--out")
        .arg(&out)
        .args([
            "--limit",
            "24",
            "--speed-factor",
            "20",
            "--sim-ft",
            "nidaqmx",
        ])
        .env(library::LIBRARY_ENV, standin_path())
        .output()
        .unwrap();
    let text = common::output_text(&run);
    assert!(run.status.success(), "{text}");
    assert!(text.contains("NI card"), "{text}");
    assert!(
        text.contains("24 trajectories recorded, 0 failed"),
        "{text}"
    );
    let check = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check", "--json"])
        .arg(&out)
        .output()
        .unwrap();
    let text = common::output_text(&check);
    assert!(check.status.success(), "{text}");
    let j: serde_json::Value = serde_json::from_slice(&check.stdout).unwrap();
    assert_eq!(j["complete"], 24, "{j:#}");
    let p99 = j["sync_error"]["p99_ns"].as_f64().unwrap();
    assert!(p99 < 1e6, "sync p99 {p99} ns");
    for t in j["trajectories"].as_array().unwrap() {
        assert_eq!(t["wrench_seq_gaps"].as_array().unwrap().len(), 0, "{t:#}");
    }
}

#[test]
fn ft_nidaqmx_a_card_removed_mid_press_stops_the_run_and_resume_completes() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let _rig = common::one_rig_at_a_time();
    let run = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_rig"))
            .args(["run", "--indenter", "cone", "--config"])
            .arg(common::sim_config())
            .arg("--out")
            .arg(&out)
            .args([
                "--limit",
                "3",
                "--speed-factor",
                "20",
                "--sim-ft",
                "nidaqmx",
            ])
            .args(extra)
            .env(library::LIBRARY_ENV, standin_path())
            .output()
            .unwrap()
    };
    let first = run(&["--sim-fault", "ft-unplug@p0-d0.2-a030/down+500"]);
    let text = common::output_text(&first);
    assert!(!first.status.success(), "{text}");
    assert!(text.contains("status -200045"), "{text}");
    assert!(text.contains("nothing more can be recorded"), "{text}");
    let m = rig::record::Manifest::load(&out).unwrap();
    assert_eq!(
        m.entry("p0-d0.2-a000").unwrap().status,
        rig::record::Status::Complete
    );
    assert_eq!(
        m.entry("p0-d0.2-a030").unwrap().status,
        rig::record::Status::Failed
    );
    let again = run(&["--resume"]);
    let text = common::output_text(&again);
    assert!(again.status.success(), "{text}");
    assert!(text.contains("dataset check: OK, 3 complete"), "{text}");
}
