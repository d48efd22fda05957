//! The DAQ gauge stream: raw gauge voltages over a serial link, in this project's framing.
//!
//! ATI's DAQ route gives the host six raw gauge voltages (plus a thermistor on sensors with
//! temperature compensation); the host applies the calibration, `F = M · (V − bias)`. A small
//! microcontroller front end (or the simulated one in `hardware-mocks`) samples the gauges and
//! sends one frame per sample over a serial port. The framing is ours; here is its spec. It is
//! the route for a home-built front end (a microcontroller and an ADC on the amplifier outputs),
//! for a lab without an NI card; ATI's own DAQ F/T system puts the voltages on an NI card, read
//! through NI-DAQmx ([`super::nidaqmx`]).
//!
//! # Frame (41 bytes, multi-byte fields big-endian)
//!
//! | Offset | Size | Field |
//! | --- | --- | --- |
//! | 0 | 2 | sync `0xA5 0x5A` |
//! | 2 | 4 | `u32` sequence, +1 per sample, wraps |
//! | 6 | 4 | `u32` device time, µs since the front end started, wraps (~71.6 min) |
//! | 10 | 24 | six `i32` gauge voltages G0..G5, µV |
//! | 34 | 4 | `i32` thermistor voltage, µV ([`NO_THERMISTOR`] when not fitted) |
//! | 38 | 1 | `u8` status: bits 0-5 gauge i beyond the ADC range, bit 6 thermistor fault, bit 7 ADC fault |
//! | 39 | 2 | CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor) over bytes 2..39 |
//!
//! At 1 kHz that is 41 kB/s: a UART at 460 800 baud or more (USB serial adapters do 1-3 Mbaud).
//! µV in an `i32` spans ±2147 V with 1 µV steps, finer than any 16-24 bit ADC over ±10 V.
//!
//! # Parsing and resynchronisation
//!
//! [`DaqParser`] looks for the sync pair, waits for a whole frame and checks the CRC. A frame
//! whose CRC fails is counted: as `truncated` when another sync pair starts inside it (the
//! frame was cut short and the next one began; parsing resumes at that sync), else as
//! `crc_errors` (parsing resumes one byte after the bad sync, and the rest of the bad frame is
//! not counted as garbage). A corrupted frame that happens to hold the sync pair in its data
//! counts as truncated; either way no bad frame is delivered. Bytes skipped while hunting for
//! sync are counted in `garbage_bytes`. The sequence number counts lost frames exactly.

/// Frame length, bytes.
pub const FRAME_LEN: usize = 41;
/// Sync bytes.
pub const SYNC: [u8; 2] = [0xA5, 0x5A];
/// Thermistor value meaning "not fitted".
pub const NO_THERMISTOR: i32 = i32::MIN;
/// Status bit 6: thermistor fault.
pub const STATUS_THERMISTOR_FAULT: u8 = 1 << 6;
/// Status bit 7: ADC fault.
pub const STATUS_ADC_FAULT: u8 = 1 << 7;

/// CRC-16/CCITT-FALSE. `crc16_ccitt(b"123456789") == 0x29B1`.
pub fn crc16_ccitt(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// One DAQ sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DaqFrame {
    pub sequence: u32,
    pub device_time_us: u32,
    pub gauges_uv: [i32; 6],
    pub thermistor_uv: i32,
    pub status: u8,
}

impl DaqFrame {
    /// Gauge voltages in volts.
    pub fn gauges_v(&self) -> [f64; 6] {
        self.gauges_uv.map(|g| f64::from(g) * 1e-6)
    }

    /// Thermistor in volts, `None` when not fitted or faulty.
    pub fn thermistor_v(&self) -> Option<f64> {
        (self.thermistor_uv != NO_THERMISTOR && self.status & STATUS_THERMISTOR_FAULT == 0)
            .then(|| f64::from(self.thermistor_uv) * 1e-6)
    }

    /// Bits 0-5 of the status: gauges beyond the ADC range.
    pub fn saturated_gauges(&self) -> u8 {
        self.status & 0x3f
    }

    /// Volts to µV, rounded and clamped to the `i32` range.
    pub fn volts_to_uv(v: f64) -> i32 {
        if !v.is_finite() {
            return if v > 0.0 { i32::MAX } else { i32::MIN + 1 };
        }
        (v * 1e6)
            .round()
            .clamp(f64::from(i32::MIN + 1), f64::from(i32::MAX)) as i32
    }

    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let mut b = [0u8; FRAME_LEN];
        b[0..2].copy_from_slice(&SYNC);
        b[2..6].copy_from_slice(&self.sequence.to_be_bytes());
        b[6..10].copy_from_slice(&self.device_time_us.to_be_bytes());
        super::put_be_i32x6(&mut b, 10, &self.gauges_uv);
        b[34..38].copy_from_slice(&self.thermistor_uv.to_be_bytes());
        b[38] = self.status;
        let crc = crc16_ccitt(&b[2..39]);
        b[39..41].copy_from_slice(&crc.to_be_bytes());
        b
    }

    /// Decodes one frame, checking sync and CRC.
    pub fn decode(b: &[u8]) -> Option<Self> {
        if b.len() != FRAME_LEN || b[0..2] != SYNC {
            return None;
        }
        let crc = u16::from_be_bytes([b[39], b[40]]);
        if crc16_ccitt(&b[2..39]) != crc {
            return None;
        }
        let u = |at: usize| super::be_u32(b, at);
        Some(Self {
            sequence: u(2),
            device_time_us: u(6),
            gauges_uv: super::be_i32x6(b, 10),
            thermistor_uv: u(34) as i32,
            status: b[38],
        })
    }
}

/// Counters of what the parser saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct DaqStats {
    pub frames: u64,
    pub garbage_bytes: u64,
    pub crc_errors: u64,
    pub truncated: u64,
}

impl DaqStats {
    pub fn errors(&self) -> u64 {
        self.crc_errors + self.truncated
    }
}

/// The byte-stream parser. See the module docs.
#[derive(Debug, Clone, Default)]
pub struct DaqParser {
    buf: Vec<u8>,
    pos: usize,
    // Bytes before this index belong to a frame already counted as bad: not garbage.
    bad_until: usize,
    stats: DaqStats,
}

impl DaqParser {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> DaqStats {
        self.stats
    }

    pub fn push(&mut self, bytes: &[u8]) {
        if self.pos > 0 && self.pos >= self.buf.len() / 2 {
            self.buf.drain(..self.pos);
            self.bad_until = self.bad_until.saturating_sub(self.pos);
            self.pos = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Counts `from..to` as garbage, except bytes of a frame already counted as bad.
    fn skip(&mut self, from: usize, to: usize) {
        let counted = to.saturating_sub(from.max(self.bad_until));
        self.stats.garbage_bytes += counted as u64;
    }

    fn find_sync(&self, from: usize) -> Option<usize> {
        self.buf[from..]
            .windows(2)
            .position(|w| w == SYNC)
            .map(|p| from + p)
    }

    /// The next valid frame, if a whole one is buffered.
    pub fn next_frame(&mut self) -> Option<DaqFrame> {
        loop {
            let Some(start) = self.find_sync(self.pos) else {
                // Keep a trailing 0xA5: it may be the first half of a sync pair.
                let keep =
                    usize::from(self.buf.last() == Some(&SYNC[0]) && self.buf.len() > self.pos);
                let end = self.buf.len() - keep;
                self.skip(self.pos, end);
                self.pos = end;
                return None;
            };
            self.skip(self.pos, start);
            self.pos = start;
            if self.buf.len() - start < FRAME_LEN {
                return None;
            }
            if let Some(f) = DaqFrame::decode(&self.buf[start..start + FRAME_LEN]) {
                self.pos = start + FRAME_LEN;
                self.stats.frames += 1;
                return Some(f);
            }
            // Bad frame: a sync pair inside it means it was cut short.
            match self.buf[start + 2..start + FRAME_LEN]
                .windows(2)
                .position(|w| w == SYNC)
            {
                Some(p) => {
                    self.stats.truncated += 1;
                    self.pos = start + 2 + p;
                }
                _ => {
                    self.stats.crc_errors += 1;
                    self.bad_until = start + FRAME_LEN;
                    self.pos = start + 1;
                }
            }
        }
    }
}
