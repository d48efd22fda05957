//! Text messages ('M'): a level and a message (v1), plus a source (v2). Both directions use
//! the same layout.

use bytes::{BufMut, BytesMut};

use super::wire::{DecodeError, EncodeError, PROTOCOL_V2, Reader};

/// Text message severity (v2 `warning_level`; v1 `message type`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageLevel {
    Exception,
    Error,
    Warning,
    Info,
    /// A level byte beyond the documented ones, kept rather than rejected.
    Other(u8),
}

impl MessageLevel {
    pub fn from_u8(b: u8) -> Self {
        match b {
            0 => Self::Exception,
            1 => Self::Error,
            2 => Self::Warning,
            3 => Self::Info,
            other => Self::Other(other),
        }
    }
    pub fn to_u8(self) -> u8 {
        match self {
            Self::Exception => 0,
            Self::Error => 1,
            Self::Warning => 2,
            Self::Info => 3,
            Self::Other(b) => b,
        }
    }
}

/// A text message ('M'). In protocol v1 it carries only a level and the message; `source` is
/// then empty.
#[derive(Debug, Clone, PartialEq)]
pub struct TextMessage {
    pub message: String,
    pub source: String,
    pub level: MessageLevel,
}

impl TextMessage {
    pub(super) fn encode(&self, version: u16, out: &mut BytesMut) -> Result<(), EncodeError> {
        if version >= PROTOCOL_V2 {
            put_short_str(out, &self.message, "text message")?;
            put_short_str(out, &self.source, "text message source")?;
            out.put_u8(self.level.to_u8());
        } else {
            out.put_u8(self.level.to_u8());
            out.put_slice(self.message.as_bytes());
        }
        Ok(())
    }

    pub(super) fn decode(version: u16, payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("text message", payload);
        let msg = if version >= PROTOCOL_V2 {
            let message = r.short_str()?;
            let source = r.short_str()?;
            let level = MessageLevel::from_u8(r.u8()?);
            Self {
                message,
                source,
                level,
            }
        } else {
            let level = MessageLevel::from_u8(r.u8()?);
            Self {
                message: r.rest_str()?,
                source: String::new(),
                level,
            }
        };
        r.finish()?;
        Ok(msg)
    }
}

fn put_short_str(out: &mut BytesMut, s: &str, what: &'static str) -> Result<(), EncodeError> {
    let n = u8::try_from(s.len()).map_err(|_| EncodeError::FieldTooLong(what))?;
    out.put_u8(n);
    out.put_slice(s.as_bytes());
    Ok(())
}
