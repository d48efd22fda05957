//! The ATI F/T controller's serial protocol, sans I/O.
//!
//! From the ATI F/T controller manual (serial interface chapter): commands are ASCII, ended by a
//! carriage return; the controller echoes what it receives and answers with a `>` prompt when
//! ready for the next command.
//!
//! | Command | Meaning |
//! | --- | --- |
//! | `CD A` / `CD B` | ASCII / binary output records |
//! | `CD R` | resolved force/torque output (rather than raw gauges) |
//! | `QR` | query one record |
//! | `QS` | query stream: records until any byte (we send CR) arrives |
//! | `SB` | sensor bias: the present reading becomes zero |
//! | `SA n` | average `n` samples per record (n a power of two) |
//!
//! Records, resolved output:
//!
//! - ASCII: the error (status) word, then the six counts Fx, Fy, Fz, Tx, Ty, Tz, comma
//!   separated (padded with spaces), ended by CR LF.
//! - Binary: 13 bytes: one status byte, then six big-endian two's-complement `i16` counts.
//!
//! Newtons are counts / CPF and N·mm counts / CPT (the counts-per-force and counts-per-torque
//! the controller reports for its calibration).
//!
//! [`SerialParser`] is fed bytes as they arrive and yields [`SerialEvent`]s. It never panics and
//! resynchronises after bad input:
//!
//! - ASCII: a record is one line, so a bad line (garbage, a truncated record) costs only that
//!   line; it is counted as `garbage_lines` or `truncated_records`. Echoed commands and other
//!   text from the controller come out as [`SerialEvent::Text`], the prompt as
//!   [`SerialEvent::Prompt`].
//! - Binary: records have no sync marker, so the parser checks plausibility: all six counts within
//!   `max_counts` (per axis: the max loads × CPF/CPT with a margin). A record that fails is counted as bad,
//!   one byte is skipped and the parser is unlocked until it finds [`BINARY_LOCK_RECORDS`]
//!   consecutive plausible records. Binary mode starts after the `QS` echo line.

use std::fmt;

/// Bytes in one binary record: status + 6 × i16.
pub const BINARY_RECORD_LEN: usize = 13;
/// Consecutive plausible binary records required to (re)lock onto the stream.
pub const BINARY_LOCK_RECORDS: usize = 3;
/// An ASCII line longer than this without a line end is garbage.
pub const MAX_LINE_LEN: usize = 160;
/// Counts per newton taken for an F/T controller when the config gives none
/// (`force_sensor.counts_per_force`), and sent by the simulated controller.
pub const DEFAULT_COUNTS_PER_FORCE: f64 = 320.0;
/// Counts per N·mm likewise (`force_sensor.counts_per_torque`).
pub const DEFAULT_COUNTS_PER_TORQUE: f64 = 64.0;

/// Record format the controller is set to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum OutputMode {
    /// `CD A`: text records.
    Ascii,
    /// `CD B`: 13-byte binary records (a third of the bytes: needed for ≥1 kHz on RS-232).
    #[default]
    Binary,
}

/// A command to the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `CD A`
    OutputAscii,
    /// `CD B`
    OutputBinary,
    /// `CD R`
    OutputResolved,
    /// `QR`
    QueryRecord,
    /// `QS`
    QueryStream,
    /// A lone CR: stops a `QS` stream.
    StopStream,
    /// `SB`
    Bias,
    /// `SA n`
    Averaging(u16),
}

impl Command {
    /// The bytes to send, CR included.
    pub fn encode(&self) -> Vec<u8> {
        let s = match self {
            Command::OutputAscii => "CD A".to_owned(),
            Command::OutputBinary => "CD B".to_owned(),
            Command::OutputResolved => "CD R".to_owned(),
            Command::QueryRecord => "QR".to_owned(),
            Command::QueryStream => "QS".to_owned(),
            Command::StopStream => String::new(),
            Command::Bias => "SB".to_owned(),
            Command::Averaging(n) => format!("SA {n}"),
        };
        let mut b = s.into_bytes();
        b.push(b'\r');
        b
    }

    /// Parses a command line as the controller does (case-insensitive, spaces optional).
    pub fn parse(line: &str) -> Option<Command> {
        let t: String = line
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_uppercase();
        Some(match t.as_str() {
            "" => Command::StopStream,
            "CDA" => Command::OutputAscii,
            "CDB" => Command::OutputBinary,
            "CDR" => Command::OutputResolved,
            "QR" => Command::QueryRecord,
            "QS" => Command::QueryStream,
            "SB" => Command::Bias,
            _ => {
                let n = t.strip_prefix("SA")?.parse::<u16>().ok()?;
                Command::Averaging(n)
            }
        })
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let b = self.encode();
        f.write_str(String::from_utf8_lossy(&b[..b.len() - 1]).as_ref())
    }
}

/// One resolved record: status word and counts Fx..Tz.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CountsRecord {
    pub status: u32,
    pub counts: [i32; 6],
}

impl CountsRecord {
    /// N and N·mm from counts.
    pub fn to_wrench(&self, counts_per_force: f64, counts_per_torque: f64) -> [f64; 6] {
        super::counts_to_wrench(
            &self.counts.map(f64::from),
            counts_per_force,
            counts_per_torque,
        )
    }

    /// The ASCII line (CR LF included), as the controller prints it.
    pub fn encode_ascii(&self) -> Vec<u8> {
        let c = self.counts;
        format!(
            "{:>5},{:>6},{:>6},{:>6},{:>6},{:>6},{:>6}\r\n",
            self.status, c[0], c[1], c[2], c[3], c[4], c[5]
        )
        .into_bytes()
    }

    /// The 13-byte binary record. Counts are clamped to `i16` and the status to a byte.
    pub fn encode_binary(&self) -> [u8; BINARY_RECORD_LEN] {
        let mut b = [0u8; BINARY_RECORD_LEN];
        b[0] = self.status.min(255) as u8;
        for i in 0..6 {
            let v = self.counts[i].clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16;
            b[1 + 2 * i..3 + 2 * i].copy_from_slice(&v.to_be_bytes());
        }
        b
    }
}

/// Per-axis plausibility limits for binary records: `margin` × max load × counts per unit,
/// clamped to the `i16` range.
pub fn plausible_counts(
    max_loads: &[f64; 6],
    counts_per_force: f64,
    counts_per_torque: f64,
    margin: f64,
) -> [i32; 6] {
    let mut out = [i32::from(i16::MAX); 6];
    for i in 0..6 {
        let k = super::counts_per_unit(i, counts_per_force, counts_per_torque);
        let m = (max_loads[i] * k * margin).ceil();
        if m.is_finite() && m > 0.0 {
            out[i] = m.min(f64::from(i16::MAX)) as i32;
        }
    }
    out
}

/// Something the controller sent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SerialEvent {
    Record(CountsRecord),
    /// A line of text that is not a record (an echoed command, a message).
    Text(String),
    /// The `>` prompt: the controller is ready for a command.
    Prompt,
}

/// Counters of what the parser saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SerialStats {
    pub records: u64,
    pub text_lines: u64,
    pub garbage_lines: u64,
    pub truncated_records: u64,
    /// Binary records that failed the plausibility check.
    pub bad_binary_records: u64,
    /// Bytes skipped while (re)locking onto a binary stream.
    pub skipped_bytes: u64,
}

impl SerialStats {
    /// Everything that was bad input.
    pub fn errors(&self) -> u64 {
        self.garbage_lines + self.truncated_records + self.bad_binary_records
    }
}

/// The byte-stream parser. See the module docs.
#[derive(Debug, Clone)]
pub struct SerialParser {
    mode: OutputMode,
    buf: Vec<u8>,
    pos: usize,
    binary_streaming: bool,
    locked: bool,
    max_counts: [i32; 6],
    stats: SerialStats,
}

impl SerialParser {
    /// `max_counts`: per axis, the largest plausible |count| in binary mode (e.g. 1.5 × max
    /// load × CPF); see [`plausible_counts`].
    pub fn new(mode: OutputMode, max_counts: [i32; 6]) -> Self {
        Self {
            mode,
            buf: Vec::with_capacity(4096),
            pos: 0,
            binary_streaming: false,
            locked: false,
            max_counts: max_counts.map(|m| m.clamp(1, i32::from(i16::MAX))),
            stats: SerialStats::default(),
        }
    }

    pub fn mode(&self) -> OutputMode {
        self.mode
    }

    /// Switches the record format (after `CD A` / `CD B` was acknowledged).
    pub fn set_mode(&mut self, mode: OutputMode) {
        self.mode = mode;
        self.binary_streaming = false;
        self.locked = false;
    }

    /// In binary mode: the bytes from now on are binary records (used when the `QS` echo is
    /// not seen, e.g. a controller with echo disabled).
    pub fn begin_binary_stream(&mut self) {
        self.binary_streaming = true;
        self.locked = false;
    }

    /// Back to text (after a stream was stopped); drops what is buffered.
    pub fn end_stream(&mut self) {
        self.binary_streaming = false;
        self.locked = false;
        self.buf.clear();
        self.pos = 0;
    }

    pub fn stats(&self) -> SerialStats {
        self.stats
    }

    /// Bytes buffered but not yet consumed.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 && self.pos >= self.buf.len() / 2 {
            self.buf.drain(..self.pos);
            self.pos = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete event, if any.
    pub fn next_event(&mut self) -> Option<SerialEvent> {
        loop {
            if self.mode == OutputMode::Binary && self.binary_streaming {
                return self.next_binary();
            }
            let rest = &self.buf[self.pos..];
            if rest.is_empty() {
                return None;
            }
            if rest[0] == b'>' {
                self.pos += 1;
                return Some(SerialEvent::Prompt);
            }
            if rest[0] == b'\r' || rest[0] == b'\n' {
                self.pos += 1;
                continue;
            }
            let Some(end) = rest.iter().position(|&b| b == b'\n' || b == b'\r') else {
                if rest.len() > MAX_LINE_LEN {
                    self.stats.garbage_lines += 1;
                    self.pos = self.buf.len();
                }
                return None;
            };
            let consumed = end + 1;
            let event = classify_line(self.mode, &mut self.stats, &rest[..end]);
            self.pos += consumed;
            if let Some(e) = event {
                if let SerialEvent::Text(t) = &e
                    && self.mode == OutputMode::Binary
                    && Command::parse(t) == Some(Command::QueryStream)
                {
                    // The echo of `QS`: binary records follow right after the line end.
                    // Skip an LF that completes a CR LF pair.
                    if self.buf.get(self.pos) == Some(&b'\n') {
                        self.pos += 1;
                    }
                    self.binary_streaming = true;
                    self.locked = false;
                }
                return Some(e);
            }
        }
    }
}

fn classify_line(mode: OutputMode, stats: &mut SerialStats, line: &[u8]) -> Option<SerialEvent> {
    {
        let Ok(text) = std::str::from_utf8(line) else {
            stats.garbage_lines += 1;
            return None;
        };
        let text = text.trim_matches(|c: char| c == '>' || c.is_whitespace());
        if text.is_empty() {
            return None;
        }
        let mut fields: Vec<&str> = text.split(',').map(str::trim).collect();
        // A record cut right after a comma leaves an empty last field: still a (truncated) record.
        let cut_after_comma = fields.len() > 1 && fields.last().is_some_and(|f| f.is_empty());
        if cut_after_comma {
            fields.pop();
        }
        let numeric = fields.iter().all(|f| {
            let digits = f.strip_prefix('-').unwrap_or(f);
            !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
        });
        if numeric {
            if fields.len() == 7 && !cut_after_comma && mode == OutputMode::Ascii {
                let mut vals = [0i64; 7];
                for (v, f) in vals.iter_mut().zip(&fields) {
                    match f.parse::<i64>() {
                        Ok(x) => *v = x,
                        Err(_) => {
                            stats.garbage_lines += 1;
                            return None;
                        }
                    }
                }
                let Ok(status) = u32::try_from(vals[0]) else {
                    stats.garbage_lines += 1;
                    return None;
                };
                let mut counts = [0i32; 6];
                for i in 0..6 {
                    match i32::try_from(vals[i + 1]) {
                        Ok(c) => counts[i] = c,
                        Err(_) => {
                            stats.garbage_lines += 1;
                            return None;
                        }
                    }
                }
                stats.records += 1;
                return Some(SerialEvent::Record(CountsRecord { status, counts }));
            }
            if fields.len() < 7 || cut_after_comma {
                stats.truncated_records += 1;
            } else {
                stats.garbage_lines += 1;
            }
            return None;
        }
        let printable = text.bytes().all(|b| (0x20..0x7f).contains(&b));
        let starts_alpha = text.as_bytes()[0].is_ascii_alphabetic();
        if printable && starts_alpha {
            stats.text_lines += 1;
            Some(SerialEvent::Text(text.to_owned()))
        } else {
            stats.garbage_lines += 1;
            None
        }
    }
}

impl SerialParser {
    fn plausible_at(&self, at: usize) -> Option<CountsRecord> {
        let b = self.buf.get(at..at + BINARY_RECORD_LEN)?;
        let mut counts = [0i32; 6];
        for i in 0..6 {
            let v = i32::from(i16::from_be_bytes([b[1 + 2 * i], b[2 + 2 * i]]));
            if v.abs() > self.max_counts[i] {
                return None;
            }
            counts[i] = v;
        }
        Some(CountsRecord {
            status: u32::from(b[0]),
            counts,
        })
    }

    fn next_binary(&mut self) -> Option<SerialEvent> {
        loop {
            let avail = self.buf.len() - self.pos;
            if self.locked {
                if avail < BINARY_RECORD_LEN {
                    return None;
                }
                if let Some(r) = self.plausible_at(self.pos) {
                    self.pos += BINARY_RECORD_LEN;
                    self.stats.records += 1;
                    return Some(SerialEvent::Record(r));
                }
                self.stats.bad_binary_records += 1;
                self.locked = false;
                self.pos += 1;
                self.stats.skipped_bytes += 1;
                continue;
            }
            // Unlocked: look for BINARY_LOCK_RECORDS plausible records in a row.
            if avail < BINARY_RECORD_LEN * BINARY_LOCK_RECORDS {
                return None;
            }
            let ok = (0..BINARY_LOCK_RECORDS).all(|k| {
                self.plausible_at(self.pos + k * BINARY_RECORD_LEN)
                    .is_some()
            });
            if ok {
                self.locked = true;
                continue;
            }
            self.pos += 1;
            self.stats.skipped_bytes += 1;
        }
    }
}
