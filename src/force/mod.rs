//! Nano17 force/torque sensing: four front ends, one stream of [`WrenchSample`]s.
//!
//! The protocol cores are sans-IO and live in `rig_core::ft`; this module owns the ports and
//! sockets, the timestamps and the per-sample conditioning:
//!
//! - [`serial`]: an ATI F/T controller on a serial port (`serialport`, no libudev): set the
//!   record format (`CD A` / `CD B`) and resolved output (`CD R`), optionally bias (`SB`),
//!   stream with `QS`, stop with a CR.
//! - [`netft`]: a Net F/T over UDP (RDT): start/stop streaming, optional software bias, exact
//!   loss / reorder counts from the RDT sequence.
//! - [`nidaqmx`]: ATI's DAQ F/T system, the gauge voltages on an NI card read through
//!   NI-DAQmx (loaded at run time), turned into a wrench with the sensor's calibration file.
//! - [`daq`]: raw gauge voltages from a home-built front end in the project's serial framing,
//!   turned into a wrench the same way (temperature-compensated when the file allows).
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
//! [`serial`], [`netft`], [`nidaqmx`] and [`daq`]. Their items are re-exported here; the `rig ft` command is
//! `crate::cli::ft`.

pub mod conditioning;
pub mod daq;
pub mod error;
pub mod netft;
pub mod nidaqmx;
pub mod serial;
pub mod stream;

use rig_core::clock::Clock;
use rig_core::config::{ForceSensorConfig, ForceSensorKind};

pub use conditioning::{Conditioned, Conditioner, FrontEndSettings, RawMap, TareReport};
pub use error::FtError;
pub use rig_core::ft::SampleFlags as Flags;
pub use stream::{
    CHANNEL_CAPACITY, Control, FtStats, FtStatsSnapshot, FtStream, Sink, TareHandle, WrenchSample,
};

/// Opens the lab front end a `[force_sensor]` section describes and starts streaming. `kind =
/// "sim"` is refused: the simulated Nano17 is started by `crate::simrig::open_ft`.
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
        ForceSensorKind::Nidaqmx => nidaqmx::open(cfg, settings, clock).await,
        ForceSensorKind::Netft => {
            let addr = cfg
                .address
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.address is required".into()))?;
            netft::open(&addr, false, settings, clock).await
        }
        ForceSensorKind::Sim => Err(FtError::Config(
            "force_sensor.kind = \"sim\" is the simulated rig's sensor, not a lab front end: \
             open it through crate::simrig::open_ft (as `rig ft` does)"
                .into(),
        )),
    }
}
