//! The Nano17 on an NI data-acquisition card through NI-DAQmx (ATI's DAQ F/T system):
//! `force_sensor.kind = "nidaqmx"`.
//!
//! - [`library`] loads NI's C library at run time (`dlopen`), finds it as the system's library
//!   search does (or where `force_sensor.library` / `RIG_NIDAQMX_LIBRARY` say), and reports
//!   NI's errors with NI's own message (`DAQmxGetExtendedErrorInfo`) and what to check.
//! - [`reader`] owns one task on its own thread: the six gauge channels (plus the thermistor
//!   when the calibration file has temperature compensation) as voltage channels in the
//!   configured terminal configuration (differential, ATI's wiring, by default), each with the
//!   calibration file's output range, sampled continuously on the card's sample clock at
//!   `force_sensor.rate_hz` (≥ 1 kHz) and read in 5 ms blocks, interleaved by scan.
//!
//! Each sample's `device_seq` is its index on the card's sample clock, so the run's sync
//! estimator maps it onto the rig's clock as it maps the Net F/T's RDT sequence (`t_host_ns` is
//! when its block was read). The card runs in overwrite mode: a host that falls more than the
//! buffer (2 s) behind gets `-200279`; the reader jumps to the oldest samples still held and
//! counts every sample it skipped as lost (`FtStats::lost`, the next sample flagged
//! `AFTER_GAP`), so the count is exact and the indices stay on the clock. An onboard FIFO
//! overflow (`-200010`, `-200361`) stops the card's acquisition: the reader restarts the task
//! and counts the stopped stretch as lost. A removed card (`-200045`, `-200324`) ends the stream
//! with NI's message; the run's safety supervisor sees the stream end and stops the arm.
//!
//! The gauge volts become a wrench through [`FrontEndSettings::gauges_conditioner`], the code
//! path of the serial DAQ route too: temperature compensation, `F = M · (V − bias)`, the tare,
//! the tool transform; a gauge within 0.5 % of its range is flagged `GAUGE_SATURATED`
//! (ATI's rule).
//!
//! The workspace's `nidaqmx-standin` crate builds a stand-in for NI's library (a simulated
//! card with the simulated Nano17 wired to it) that the tests and `rig run --sim-ft nidaqmx`
//! load through this same path.

pub mod library;
pub mod reader;

use rig_core::clock::Clock;
use rig_core::config::ForceSensorConfig;
use rig_core::ft::nidaqmx as ni;

pub use library::{Api, LIBRARY_ENV};
pub use reader::TaskSpec;

use super::conditioning::FrontEndSettings;
use super::error::FtError;
use super::stream::{FtStream, start_reader};

/// The task a `[force_sensor]` section with `kind = "nidaqmx"` describes.
pub fn task_spec(
    cfg: &ForceSensorConfig,
    settings: &FrontEndSettings,
) -> Result<TaskSpec, FtError> {
    let gauges = cfg.channels.as_deref().unwrap_or(ni::DEFAULT_CHANNELS);
    let (gauges, thermistor) =
        ni::check_channels(gauges, cfg.thermistor_channel.as_deref()).map_err(FtError::Config)?;
    let thermistor = match settings.reads_thermistor() {
        true => thermistor.or_else(|| ni::default_thermistor_channel(&gauges)),
        false => None,
    };
    let calibration = settings.calibration.as_ref().ok_or_else(|| {
        FtError::Config(
            "force_sensor.calibration_file is required when force_sensor.kind is \"nidaqmx\""
                .into(),
        )
    })?;
    if !(settings.rate_hz.is_finite() && settings.rate_hz >= ni::MIN_RATE_HZ) {
        return Err(FtError::Config(format!(
            "force_sensor.rate_hz = {} is below the NI route's {} Hz",
            settings.rate_hz,
            ni::MIN_RATE_HZ
        )));
    }
    Ok(TaskSpec {
        gauges,
        thermistor,
        terminal: cfg.terminal_config,
        rate_hz: settings.rate_hz,
        range: calibration.output_range,
    })
}

/// Loads NI-DAQmx, sets the task up and starts streaming.
pub async fn open(
    cfg: &ForceSensorConfig,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    let spec = task_spec(cfg, &settings)?;
    let api = library::load(cfg.library.as_deref())?;
    open_with(api, spec, settings, clock).await
}

/// Starts the task on `api` (NI's library or a stand-in) on a thread of its own; returns once
/// the card is acquiring, or with NI's error.
pub async fn open_with(
    api: &'static Api,
    spec: TaskSpec,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    let cond = settings.gauges_conditioner("nidaqmx")?;
    let description = format!(
        "NI-DAQmx {}{} ({})",
        ni::join_channels(&spec.gauges),
        spec.thermistor
            .as_ref()
            .map(|t| format!(" + thermistor {t}"))
            .unwrap_or_default(),
        api.origin
    );
    let (stream, sink, ctl, done) = FtStream::channel(description);
    start_reader(
        stream,
        done,
        "ft-nidaqmx",
        "NI-DAQmx",
        move || reader::Task::start(api, &spec).map(|task| (task, spec)),
        move |(task, spec)| reader::Reader::new(api, task, spec, cond, sink, clock).run(ctl),
    )
    .await
}
