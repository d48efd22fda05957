//! The simulated Nano17 on its own, for `rig ft` with `force_sensor.kind = "sim"`: a Net F/T
//! twin on loopback UDP with no load on it, read by the lab's Net F/T reader.

use std::sync::Arc;

use hardware_mocks::nano17::SensorModel;
use hardware_mocks::nano17::netft::{NetFtMock, NetFtMockConfig};
use hardware_mocks::truth::{ConstantWrench, SharedWrenchSource};
use rig_core::clock::Clock;
use rig_core::wrench::Wrench;

use crate::force::{FrontEndSettings, FtError, FtStream, netft};

/// Starts the simulated Nano17 with no load and opens it like a lab Net F/T box, with the lab's
/// Net F/T reader. The twin lives as long as the stream.
pub async fn open_ft(settings: FrontEndSettings, clock: Clock) -> Result<FtStream, FtError> {
    let source: SharedWrenchSource = Arc::new(ConstantWrench(Wrench::ZERO));
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
