//! Nano17 force/torque sensing: three front ends, one stream of [`WrenchSample`]s.
//!
//! The protocol cores are sans-IO and live in `rig_core::ft`; this module owns the ports and
//! sockets, the timestamps and the per-sample conditioning:
//!
//! - [`serial`]: an ATI F/T controller on a serial port (`serialport`, no libudev): set the
//!   record format (`CD A` / `CD B`) and resolved output (`CD R`), optionally bias (`SB`),
//!   stream with `QS`, stop with a CR.
//! - [`netft`]: a Net F/T over UDP (RDT): start/stop streaming, optional software bias, exact
//!   loss / reorder counts from the RDT sequence.
//! - [`daq`]: raw gauge voltages in the project's DAQ framing, turned into a wrench with the
//!   sensor's calibration file (temperature-compensated when the file allows).
//!
//! Every reader timestamps a sample with the shared [`Clock`] when its bytes arrive
//! (`t_host_ns`) and keeps the device's own sequence (`device_seq`), so the sync stage can map
//! device time to host time with its estimator. Each sample then goes through a [`Conditioner`]:
//! tare (bias) subtraction, the tool transform to the indenter tip, and checks. Saturation
//! (any gauge at its ADC range, any axis at its max load) and a non-zero device status are set
//! in [`WrenchSample::flags`], never passed silently; the `saturation` policy of the config can
//! also drop such samples or end the stream.
//!
//! Bad input never panics: garbage, truncated records, checksum failures, lost and reordered
//! packets are counted in [`FtStats`]; an unplugged port ends the stream with
//! [`FtError::PortClosed`], reported by [`FtStream::finish`].
//!
//! Files: [`stream`] (the stream, its samples, counters and controls), [`conditioning`] (raw
//! readings to a wrench, tare, checks, the front-end settings), [`error`]; the readers in
//! [`serial`], [`netft`] and [`daq`]; the `rig ft` command in [`cli`]. Their items are
//! re-exported here.

pub mod cli;
pub mod conditioning;
pub mod daq;
pub mod error;
pub mod netft;
pub mod serial;
pub mod stream;

use std::sync::Arc;

use rig_core::clock::Clock;
use rig_core::config::{ForceSensorConfig, ForceSensorKind};
use rig_core::wrench::Wrench;

pub use conditioning::{Conditioned, Conditioner, FrontEndSettings, RawMap, TareReport};
pub use error::FtError;
pub use rig_core::ft::SampleFlags as Flags;
pub use stream::{
    CHANNEL_CAPACITY, Control, FtStats, FtStatsSnapshot, FtStream, Sink, TareHandle, WrenchSample,
};

/// Opens the front end a `[force_sensor]` section describes and starts streaming. `kind =
/// "sim"` starts the simulated Nano17 (a Net F/T on loopback) in-process, with no load.
pub async fn open(cfg: &ForceSensorConfig, clock: Clock) -> Result<FtStream, FtError> {
    let settings = FrontEndSettings::from_config(cfg)?;
    match cfg.kind {
        ForceSensorKind::Serial => {
            let port = cfg
                .port
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.port is required".into()))?;
            serial::open(
                serial::SerialOptions {
                    port,
                    baud: cfg.baud.unwrap_or(115_200),
                    output: cfg.output,
                    device_bias: false,
                },
                settings,
                clock,
            )
            .await
        }
        ForceSensorKind::Daq => {
            let port = cfg
                .port
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.port is required".into()))?;
            daq::open(&port, cfg.baud.unwrap_or(921_600), settings, clock).await
        }
        ForceSensorKind::Netft => {
            let addr = cfg
                .address
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.address is required".into()))?;
            netft::open(&addr, false, settings, clock).await
        }
        ForceSensorKind::Sim => {
            let source: hardware_mocks::truth::SharedWrenchSource =
                Arc::new(hardware_mocks::truth::ConstantWrench(Wrench::ZERO));
            open_sim(source, settings, clock).await
        }
    }
}

/// The simulated Nano17 (a Net F/T mock on loopback) driven by `source`, read by the real
/// Net F/T reader.
pub async fn open_sim(
    source: hardware_mocks::truth::SharedWrenchSource,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    use hardware_mocks::nano17::{SensorModel, netft::NetFtMock, netft::NetFtMockConfig};
    let mut model = SensorModel::nano17(0x5eed);
    model.tool = settings.tool.clone();
    let mock = NetFtMock::start(
        NetFtMockConfig {
            rate_hz: settings.rate_hz,
            counts_per_force: settings.counts_per_force,
            counts_per_torque: settings.counts_per_torque,
            ..NetFtMockConfig::default()
        },
        model,
        source,
        clock.clone(),
    )
    .await
    .map_err(|e| FtError::Io {
        device: "simulated Net F/T".into(),
        reason: e.to_string(),
    })?;
    let mut stream = netft::open(&mock.addr().to_string(), false, settings, clock).await?;
    stream.description = format!("simulated Nano17 (Net F/T on {})", mock.addr());
    stream.keep_alive(Box::new(mock));
    Ok(stream)
}
