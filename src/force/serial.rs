//! The ATI F/T controller over a serial port.
//!
//! `serialport` is blocking, so one OS thread owns the port: it configures the controller
//! (`CD R`, then `CD A` or `CD B`, each answered by the `>` prompt; optionally `SB`), starts
//! `QS`, and then reads, feeds [`SerialParser`] and hands each record to the
//! [`Conditioner`]. Between reads (50 ms timeout) it looks at its control channel: a tare, or
//! stop (a CR stops `QS`; the prompt is awaited briefly, then the port closes).
//!
//! A serial controller has no sequence number, so `device_seq` is the record count; a lost
//! record shows as a garbage or truncated line in the counters instead.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use rig_core::clock::Clock;
use rig_core::ft::SampleFlags;
use rig_core::ft::serial::{
    BINARY_RECORD_LEN, Command, OutputMode, SerialEvent, SerialParser, plausible_counts,
};
use tokio::sync::mpsc::UnboundedReceiver;

use super::conditioning::{Conditioner, FrontEndSettings};
use super::error::FtError;
use super::stream::{Control, FtStats, FtStream, Sink, start_reader};

/// How long the controller may take to answer a command.
pub const COMMAND_TIMEOUT: Duration = Duration::from_secs(1);
/// Read timeout of the port (how often the reader looks at its controls).
pub const READ_TIMEOUT: Duration = Duration::from_millis(50);

/// Where and how to talk to the controller.
#[derive(Debug, Clone)]
pub struct SerialOptions {
    pub port: String,
    pub baud: u32,
    pub output: OutputMode,
    /// Send `SB` (controller-side bias) before streaming.
    pub device_bias: bool,
}

/// Bytes per record of a mode (ASCII: the typical padded line).
pub fn record_bytes(mode: OutputMode) -> usize {
    match mode {
        OutputMode::Ascii => 46,
        OutputMode::Binary => BINARY_RECORD_LEN,
    }
}

/// Highest record rate a UART at `baud` (8N1: 10 bits per byte) carries in `mode`.
pub fn max_rate_hz(baud: u32, mode: OutputMode) -> f64 {
    f64::from(baud) / 10.0 / record_bytes(mode) as f64
}

/// Opens the port, configures the controller and starts streaming.
pub async fn open(
    opts: SerialOptions,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    let port = serialport::new(&opts.port, opts.baud)
        .timeout(READ_TIMEOUT)
        .open_native()
        .map_err(|e| FtError::PortOpen {
            port: opts.port.clone(),
            reason: e.to_string(),
        })?;
    let (stream, sink, ctl, done) = FtStream::channel(format!("serial {}", opts.port));
    let setup = move || {
        let mut reader = Reader {
            port,
            opts,
            parser: SerialParser::new(
                OutputMode::Ascii,
                plausible_counts(
                    &settings.max_loads,
                    settings.counts_per_force,
                    settings.counts_per_torque,
                    1.5,
                ),
            ),
            cond: settings.counts_conditioner(),
            sink,
            clock,
            buf: vec![0u8; 8192],
            seq: 0,
        };
        reader.configure().map(|()| reader)
    };
    start_reader(
        stream,
        done,
        "ft-serial",
        "serial",
        setup,
        move |mut r: Reader| r.stream(ctl),
    )
    .await
}

struct Reader {
    port: serialport::TTYPort,
    opts: SerialOptions,
    parser: SerialParser,
    cond: Conditioner,
    sink: Sink,
    clock: Clock,
    buf: Vec<u8>,
    seq: u64,
}

impl Reader {
    fn closed(&self, reason: impl ToString) -> FtError {
        FtError::PortClosed {
            port: self.opts.port.clone(),
            reason: reason.to_string(),
        }
    }

    /// Reads once; `Ok(0)` on a timeout.
    fn read_some(&mut self) -> Result<usize, FtError> {
        match self.port.read(&mut self.buf) {
            Ok(0) => Err(self.closed("end of file")),
            Ok(n) => {
                let (buf, parser) = (&self.buf, &mut self.parser);
                parser.push(&buf[..n]);
                Ok(n)
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(self.closed(e)),
        }
    }

    fn send(&mut self, cmd: Command) -> Result<(), FtError> {
        self.port
            .write_all(&cmd.encode())
            .and_then(|()| self.port.flush())
            .map_err(|e| self.closed(e))
    }

    /// Sends a command and waits for the prompt.
    fn command(&mut self, cmd: Command) -> Result<(), FtError> {
        self.send(cmd)?;
        let deadline = Instant::now() + COMMAND_TIMEOUT;
        loop {
            while let Some(ev) = self.parser.next_event() {
                match ev {
                    SerialEvent::Prompt => return Ok(()),
                    SerialEvent::Text(t) if t.eq_ignore_ascii_case("error") => {
                        return Err(FtError::Io {
                            device: self.opts.port.clone(),
                            reason: format!("the controller refused `{cmd}`"),
                        });
                    }
                    _ => {}
                }
            }
            if Instant::now() > deadline {
                return Err(FtError::NoAnswer {
                    device: self.opts.port.clone(),
                    what: format!("reply to `{cmd}`"),
                    timeout_ms: COMMAND_TIMEOUT.as_millis() as u64,
                });
            }
            self.read_some()?;
        }
    }

    fn configure(&mut self) -> Result<(), FtError> {
        // A CR first: stops a stream left running by a previous session, and gets a prompt.
        self.send(Command::StopStream)?;
        std::thread::sleep(Duration::from_millis(20));
        let _ = self.read_some();
        self.parser.end_stream();
        self.command(Command::OutputResolved)?;
        self.command(match self.opts.output {
            OutputMode::Ascii => Command::OutputAscii,
            OutputMode::Binary => Command::OutputBinary,
        })?;
        self.parser.set_mode(self.opts.output);
        if self.opts.device_bias {
            self.command(Command::Bias)?;
        }
        self.send(Command::QueryStream)
    }

    fn publish_counters(&self) {
        let s = self.parser.stats();
        let st = &self.sink.stats;
        match self.opts.output {
            OutputMode::Ascii => FtStats::set(&st.garbage, s.garbage_lines),
            OutputMode::Binary => FtStats::set(&st.garbage, s.skipped_bytes),
        }
        FtStats::set(&st.truncated, s.truncated_records);
        FtStats::set(&st.checksum_errors, s.bad_binary_records);
    }

    fn stream(&mut self, mut ctl: UnboundedReceiver<Control>) {
        loop {
            loop {
                match ctl.try_recv() {
                    Ok(Control::Tare { samples, reply }) => self.cond.start_tare(samples, reply),
                    Ok(Control::Stop)
                    | Err(tokio::sync::mpsc::error::TryRecvError::Disconnected) => {
                        self.stop();
                        return;
                    }
                    Err(tokio::sync::mpsc::error::TryRecvError::Empty) => break,
                }
            }
            if let Err(e) = self.read_some() {
                self.publish_counters();
                self.sink.fail(e);
                return;
            }
            let t_host_ns = self.clock.now_ns();
            while let Some(ev) = self.parser.next_event() {
                if let SerialEvent::Record(r) = ev {
                    let raw = r.counts.map(f64::from);
                    let seq = self.seq;
                    self.seq += 1;
                    if !self.sink.condition_and_deliver(
                        &mut self.cond,
                        &raw,
                        None,
                        r.status,
                        SampleFlags::NONE,
                        t_host_ns,
                        seq,
                    ) {
                        self.publish_counters();
                        self.stop();
                        return;
                    }
                }
            }
            self.publish_counters();
        }
    }

    fn stop(&mut self) {
        if self.send(Command::StopStream).is_err() {
            return;
        }
        let deadline = Instant::now() + Duration::from_millis(200);
        while Instant::now() < deadline {
            if self.read_some().is_err() {
                return;
            }
            // Records still in flight are parsed and discarded; stop at the prompt (ASCII) or
            // when the line goes quiet (binary: the prompt is not framed).
            let mut prompt = false;
            while let Some(ev) = self.parser.next_event() {
                if ev == SerialEvent::Prompt {
                    prompt = true;
                }
            }
            if prompt {
                return;
            }
        }
    }
}
