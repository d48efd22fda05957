//! ATI Net F/T Raw Data Transfer (RDT) over UDP, sans I/O.
//!
//! From the Net F/T manual (section "UDP interface using RDT"): the box listens on UDP port
//! 49152. A request is 8 bytes, big-endian:
//!
//! ```text
//! u16 header = 0x1234 | u16 command | u32 sample_count (0 = stream until told to stop)
//! ```
//!
//! Commands: 0 stop streaming, 2 start real-time streaming, 3 start buffered streaming,
//! 4 start multi-unit streaming, 0x41 reset threshold latch, 0x42 set software bias. A record
//! is 36 bytes, big-endian:
//!
//! ```text
//! u32 rdt_sequence | u32 ft_sequence | u32 status | i32 Fx Fy Fz Tx Ty Tz (counts)
//! ```
//!
//! `rdt_sequence` counts RDT packets sent since streaming started (u32, wraps);
//! `ft_sequence` counts the box's internal samples. Buffered mode packs several records into
//! one datagram. A non-zero status means the box reports a problem (bit 31: error). Newtons are
//! counts / counts-per-force, torques counts / counts-per-torque (from the box's configuration
//! page; the factory default is 1 000 000 counts per N and per N·m).
//!
//! UDP may lose, reorder and duplicate packets. [`SequenceTracker`] (from
//! [`super::sequence`], re-exported here) classifies every arriving `rdt_sequence` and keeps
//! exact counts: a gap adds its size to `lost`; a packet that later fills a gap moves one from
//! `lost` to `reordered`; a sequence seen before is a duplicate.

/// The Net F/T's RDT port.
pub const RDT_PORT: u16 = 49152;
/// Request header.
pub const RDT_HEADER: u16 = 0x1234;
/// Bytes of one request.
pub const REQUEST_LEN: usize = 8;
/// Bytes of one record.
pub const RECORD_LEN: usize = 36;
/// Fastest real-time RDT output of a Net F/T, Hz.
pub const MAX_RDT_RATE_HZ: f64 = 7000.0;
/// Counts per newton of a Net F/T as shipped (its configuration page can change it).
pub const FACTORY_COUNTS_PER_FORCE: f64 = 1e6;
/// Counts per N·mm of a Net F/T as shipped: 1 000 000 per N·m.
pub const FACTORY_COUNTS_PER_TORQUE: f64 = 1e3;
/// Status bit 31: the box reports an error.
pub const STATUS_ERROR: u32 = 1 << 31;

/// RDT commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RdtCommand {
    Stop,
    StartRealtime,
    StartBuffered,
    StartMultiUnit,
    ResetThresholdLatch,
    SetSoftwareBias,
    Other(u16),
}

impl RdtCommand {
    pub fn code(self) -> u16 {
        match self {
            RdtCommand::Stop => 0,
            RdtCommand::StartRealtime => 2,
            RdtCommand::StartBuffered => 3,
            RdtCommand::StartMultiUnit => 4,
            RdtCommand::ResetThresholdLatch => 0x41,
            RdtCommand::SetSoftwareBias => 0x42,
            RdtCommand::Other(c) => c,
        }
    }

    pub fn from_code(c: u16) -> Self {
        match c {
            0 => RdtCommand::Stop,
            2 => RdtCommand::StartRealtime,
            3 => RdtCommand::StartBuffered,
            4 => RdtCommand::StartMultiUnit,
            0x41 => RdtCommand::ResetThresholdLatch,
            0x42 => RdtCommand::SetSoftwareBias,
            c => RdtCommand::Other(c),
        }
    }
}

/// Why bytes are not a valid RDT message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RdtError {
    #[error("RDT request has {0} bytes, expected 8")]
    RequestLength(usize),
    #[error("RDT request header {0:#06x}, expected 0x1234")]
    Header(u16),
    #[error("RDT datagram has {0} bytes, not a positive multiple of 36")]
    RecordLength(usize),
}

/// An RDT request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RdtRequest {
    pub command: RdtCommand,
    /// Records to send; 0 = until stopped.
    pub sample_count: u32,
}

impl RdtRequest {
    pub fn encode(&self) -> [u8; REQUEST_LEN] {
        let mut b = [0u8; REQUEST_LEN];
        b[0..2].copy_from_slice(&RDT_HEADER.to_be_bytes());
        b[2..4].copy_from_slice(&self.command.code().to_be_bytes());
        b[4..8].copy_from_slice(&self.sample_count.to_be_bytes());
        b
    }

    pub fn decode(b: &[u8]) -> Result<Self, RdtError> {
        if b.len() != REQUEST_LEN {
            return Err(RdtError::RequestLength(b.len()));
        }
        let header = u16::from_be_bytes([b[0], b[1]]);
        if header != RDT_HEADER {
            return Err(RdtError::Header(header));
        }
        Ok(Self {
            command: RdtCommand::from_code(u16::from_be_bytes([b[2], b[3]])),
            sample_count: super::be_u32(b, 4),
        })
    }
}

/// One RDT record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RdtRecord {
    pub rdt_sequence: u32,
    pub ft_sequence: u32,
    pub status: u32,
    pub counts: [i32; 6],
}

impl RdtRecord {
    pub fn encode(&self) -> [u8; RECORD_LEN] {
        let mut b = [0u8; RECORD_LEN];
        b[0..4].copy_from_slice(&self.rdt_sequence.to_be_bytes());
        b[4..8].copy_from_slice(&self.ft_sequence.to_be_bytes());
        b[8..12].copy_from_slice(&self.status.to_be_bytes());
        super::put_be_i32x6(&mut b, 12, &self.counts);
        b
    }

    /// Decodes exactly one 36-byte record.
    pub fn decode(b: &[u8]) -> Result<Self, RdtError> {
        if b.len() != RECORD_LEN {
            return Err(RdtError::RecordLength(b.len()));
        }
        let u = |at: usize| super::be_u32(b, at);
        Ok(Self {
            rdt_sequence: u(0),
            ft_sequence: u(4),
            status: u(8),
            counts: super::be_i32x6(b, 12),
        })
    }

    /// Decodes a datagram of one or more records (buffered mode packs several).
    pub fn decode_datagram(b: &[u8]) -> Result<impl Iterator<Item = RdtRecord> + '_, RdtError> {
        if b.is_empty() || !b.len().is_multiple_of(RECORD_LEN) {
            return Err(RdtError::RecordLength(b.len()));
        }
        Ok(b.chunks_exact(RECORD_LEN)
            .filter_map(|c| Self::decode(c).ok()))
    }

    /// N and N·mm from counts.
    pub fn to_wrench(&self, counts_per_force: f64, counts_per_torque: f64) -> [f64; 6] {
        super::counts_to_wrench(
            &self.counts.map(f64::from),
            counts_per_force,
            counts_per_torque,
        )
    }
}

pub use super::sequence::{Arrival, MAX_TRACKED_GAP, SequenceStats, SequenceTracker, TRACK_WINDOW};
