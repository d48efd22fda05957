//! The DAQ gauge stream (framing: `rig_core::ft::daq`) on a serial port: the route for a
//! home-built front end (a microcontroller with a multi-channel ADC wired to the Nano17's
//! amplifier outputs), for a lab without an NI card. A lab with ATI's DAQ F/T system (an NI
//! card) uses [`super::nidaqmx`]; both turn gauge volts into a wrench through the same
//! [`FrontEndSettings::gauges_conditioner`].
//!
//! One OS thread owns the port (blocking `serialport`), feeds [`DaqParser`], tracks the frame
//! sequence for exact loss counts, and conditions each frame with the calibration file:
//! temperature compensation (when the file has it and the frame carries a thermistor
//! reading), `F = M · (V − bias)`, the tool transform. Status bits 0-5 (gauge at the ADC range)
//! flag [`SampleFlags::GAUGE_SATURATED`]. The DAQ streams without commands; stopping just
//! closes the port.

use std::io::Read;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::ft::SampleFlags;
use rig_core::ft::daq::{DaqParser, STATUS_ADC_FAULT};
use rig_core::ft::sequence::SequenceTracker;

use super::conditioning::FrontEndSettings;
use super::error::FtError;
use super::stream::{Control, FtStats, FtStream};

/// Read timeout of the port (how often the reader looks at its controls).
pub const READ_TIMEOUT: Duration = Duration::from_millis(50);

/// Opens the port and starts reading. The settings must carry the calibration.
pub async fn open(
    port_name: &str,
    baud: u32,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    let mut cond = settings.gauges_conditioner("daq")?;
    let mut port = serialport::new(port_name, baud)
        .timeout(READ_TIMEOUT)
        .open_native()
        .map_err(|e| FtError::PortOpen {
            port: port_name.to_owned(),
            reason: e.to_string(),
        })?;
    let (stream, sink, mut ctl, done) = FtStream::channel(format!("DAQ {port_name}"));
    let port_name = port_name.to_owned();
    std::thread::Builder::new()
        .name("ft-daq".into())
        .spawn(move || {
            let mut parser = DaqParser::new();
            let mut tracker = SequenceTracker::new();
            let mut buf = vec![0u8; 8192];
            'outer: loop {
                loop {
                    match ctl.try_recv() {
                        Ok(Control::Tare { samples, reply }) => cond.start_tare(samples, reply),
                        Ok(Control::Stop)
                        | Err(tokio::sync::mpsc::error::TryRecvError::Disconnected) => {
                            break 'outer;
                        }
                        Err(tokio::sync::mpsc::error::TryRecvError::Empty) => break,
                    }
                }
                let n = match port.read(&mut buf) {
                    Ok(0) => {
                        sink.fail(FtError::PortClosed {
                            port: port_name.clone(),
                            reason: "end of file".into(),
                        });
                        break;
                    }
                    Ok(n) => n,
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
                        ) =>
                    {
                        continue;
                    }
                    Err(e) => {
                        sink.fail(FtError::PortClosed {
                            port: port_name.clone(),
                            reason: e.to_string(),
                        });
                        break;
                    }
                };
                let t_host_ns = clock.now_ns();
                parser.push(&buf[..n]);
                while let Some(f) = parser.next_frame() {
                    let (arrival, seq) = tracker.observe_unwrapped(f.sequence);
                    let Some(mut flags) = arrival.sample_flags() else {
                        continue;
                    };
                    if f.saturated_gauges() != 0 {
                        flags |= SampleFlags::GAUGE_SATURATED;
                    }
                    let status = u32::from(f.status & (0x3f | STATUS_ADC_FAULT));
                    if !sink.condition_and_deliver(
                        &mut cond,
                        &f.gauges_v(),
                        f.thermistor_v(),
                        status,
                        flags,
                        t_host_ns,
                        seq,
                    ) {
                        break 'outer;
                    }
                }
                let ps = parser.stats();
                let ts = tracker.stats();
                FtStats::set(&sink.stats.garbage, ps.garbage_bytes);
                FtStats::set(&sink.stats.checksum_errors, ps.crc_errors);
                FtStats::set(&sink.stats.truncated, ps.truncated);
                FtStats::set(&sink.stats.lost, ts.lost);
                FtStats::set(&sink.stats.reordered, ts.reordered);
            }
            let _ = done.send(());
        })
        .map_err(|e| FtError::Io {
            device: "DAQ".into(),
            reason: e.to_string(),
        })?;
    Ok(stream)
}
