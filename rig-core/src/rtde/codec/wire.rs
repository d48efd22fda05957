//! The RTDE wire: the 3-byte header, package types, decode and encode errors, the incremental
//! framer, and the cursor the package decoders read payloads with.

use bytes::{Buf, BufMut, Bytes, BytesMut};

/// The controller's RTDE TCP port.
pub const RTDE_PORT: u16 = 30004;
/// Protocol version 1 (CB3 software before 3.5).
pub const PROTOCOL_V1: u16 = 1;
/// Protocol version 2: recipe ids in data packages, a frequency in the output setup, and
/// text messages with a source and a level.
pub const PROTOCOL_V2: u16 = 2;
/// Header length: u16 size + u8 type.
pub const HEADER_LEN: usize = 3;
/// Largest package the u16 size field can describe.
pub const MAX_PACKAGE_LEN: usize = u16::MAX as usize;

/// The package type byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum PackageType {
    /// 'V' (86): protocol version request / reply.
    RequestProtocolVersion = b'V',
    /// 'v' (118): controller ("URControl") version request / reply.
    GetUrControlVersion = b'v',
    /// 'M' (77): text message.
    TextMessage = b'M',
    /// 'U' (85): data package.
    DataPackage = b'U',
    /// 'O' (79): set up an output recipe.
    SetupOutputs = b'O',
    /// 'I' (73): set up an input recipe.
    SetupInputs = b'I',
    /// 'S' (83): start streaming.
    Start = b'S',
    /// 'P' (80): pause streaming.
    Pause = b'P',
}

impl PackageType {
    /// The type for a wire byte, or `None` for a byte no RTDE version defines.
    pub fn from_u8(b: u8) -> Option<Self> {
        Some(match b {
            b'V' => Self::RequestProtocolVersion,
            b'v' => Self::GetUrControlVersion,
            b'M' => Self::TextMessage,
            b'U' => Self::DataPackage,
            b'O' => Self::SetupOutputs,
            b'I' => Self::SetupInputs,
            b'S' => Self::Start,
            b'P' => Self::Pause,
            _ => return None,
        })
    }
}

/// Why bytes could not be read as RTDE.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    /// The size field is below the header length: the stream cannot be re-framed after this,
    /// so the connection must be dropped.
    #[error("package size {0} is below the 3-byte header: stream is out of sync")]
    SizeTooSmall(u16),
    /// A type byte no RTDE version defines. The frame itself is intact and can be skipped.
    #[error("unknown package type 0x{0:02x}")]
    UnknownType(u8),
    /// The payload ended before a field of the package.
    #[error("{package}: payload truncated: needs {need} bytes, has {have}")]
    Truncated {
        package: &'static str,
        need: usize,
        have: usize,
    },
    /// The payload is longer than the package's fields.
    #[error("{package}: {extra} unexpected trailing bytes")]
    TrailingBytes { package: &'static str, extra: usize },
    /// A string that should be ASCII/UTF-8 is not.
    #[error("{0}: text is not valid UTF-8")]
    BadText(&'static str),
    /// A type name in a setup reply that is neither a data type nor NOT_FOUND / IN_USE.
    #[error("unknown RTDE data type name {0:?}")]
    BadTypeName(String),
    /// A package type that only ever travels the other way.
    #[error("package type '{0}' is not sent in this direction")]
    WrongDirection(char),
}

/// Why a package could not be written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EncodeError {
    #[error("package of {0} bytes exceeds the 65535-byte RTDE limit")]
    TooLong(usize),
    #[error("{0} is longer than 255 bytes and cannot be sent in a text message field")]
    FieldTooLong(&'static str),
    #[error("{0} is not supported by protocol version 1")]
    NotInV1(&'static str),
}

/// One whole frame cut from the byte stream.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The raw type byte (may be a type this codec does not know).
    pub type_byte: u8,
    /// The payload after the header.
    pub payload: Bytes,
}

impl Frame {
    /// The frame's package type; [`DecodeError::UnknownType`] for a byte no RTDE version
    /// defines.
    pub fn package_type(&self) -> Result<PackageType, DecodeError> {
        PackageType::from_u8(self.type_byte).ok_or(DecodeError::UnknownType(self.type_byte))
    }
}

/// Incremental framer: push bytes as they arrive, pop whole frames.
///
/// TCP may split one package across reads or coalesce several into one; the framer does not
/// care. A size field below 3 is unrecoverable ([`DecodeError::SizeTooSmall`]); the caller
/// should drop the connection. Frames with an unknown type byte are returned as they are, so
/// the caller decides to skip them.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    buf: BytesMut,
}

impl FrameDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Append received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Mutable access to the internal buffer, so an async reader can read straight into it.
    pub fn buffer_mut(&mut self) -> &mut BytesMut {
        &mut self.buf
    }

    /// Bytes buffered but not yet framed.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// The next whole frame, `Ok(None)` if more bytes are needed.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, DecodeError> {
        if self.buf.len() < HEADER_LEN {
            return Ok(None);
        }
        let size = u16::from_be_bytes([self.buf[0], self.buf[1]]);
        if (size as usize) < HEADER_LEN {
            return Err(DecodeError::SizeTooSmall(size));
        }
        if self.buf.len() < size as usize {
            self.buf.reserve(size as usize - self.buf.len());
            return Ok(None);
        }
        let mut whole = self.buf.split_to(size as usize);
        let type_byte = whole[2];
        whole.advance(HEADER_LEN);
        Ok(Some(Frame {
            type_byte,
            payload: whole.freeze(),
        }))
    }
}

/// Write a header + payload into `out`.
pub(super) fn put_package(
    out: &mut BytesMut,
    ty: PackageType,
    payload: impl FnOnce(&mut BytesMut) -> Result<(), EncodeError>,
) -> Result<(), EncodeError> {
    let start = out.len();
    out.put_u16(0); // patched below
    out.put_u8(ty as u8);
    payload(out)?;
    let len = out.len() - start;
    if len > MAX_PACKAGE_LEN {
        out.truncate(start);
        return Err(EncodeError::TooLong(len));
    }
    out[start..start + 2].copy_from_slice(&(len as u16).to_be_bytes());
    Ok(())
}

/// A little cursor over a payload that reports truncation with the package's name.
pub(super) struct Reader<'a> {
    package: &'static str,
    buf: &'a [u8],
}

impl<'a> Reader<'a> {
    pub(super) fn new(package: &'static str, buf: &'a [u8]) -> Self {
        Self { package, buf }
    }
    pub(super) fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if self.buf.len() < n {
            return Err(DecodeError::Truncated {
                package: self.package,
                need: n,
                have: self.buf.len(),
            });
        }
        let (head, tail) = self.buf.split_at(n);
        self.buf = tail;
        Ok(head)
    }
    pub(super) fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }
    pub(super) fn u16(&mut self) -> Result<u16, DecodeError> {
        let b = self.take(2)?;
        Ok(u16::from_be_bytes([b[0], b[1]]))
    }
    pub(super) fn u32(&mut self) -> Result<u32, DecodeError> {
        let b = self.take(4)?;
        Ok(u32::from_be_bytes(b.try_into().expect("4 bytes")))
    }
    pub(super) fn f64(&mut self) -> Result<f64, DecodeError> {
        let b = self.take(8)?;
        Ok(f64::from_be_bytes(b.try_into().expect("8 bytes")))
    }
    pub(super) fn rest_str(&mut self) -> Result<String, DecodeError> {
        let b = self.take(self.buf.len())?;
        std::str::from_utf8(b)
            .map(str::to_owned)
            .map_err(|_| DecodeError::BadText(self.package))
    }
    pub(super) fn short_str(&mut self) -> Result<String, DecodeError> {
        let n = self.u8()? as usize;
        let b = self.take(n)?;
        std::str::from_utf8(b)
            .map(str::to_owned)
            .map_err(|_| DecodeError::BadText(self.package))
    }
    pub(super) fn finish(self) -> Result<(), DecodeError> {
        if self.buf.is_empty() {
            Ok(())
        } else {
            Err(DecodeError::TrailingBytes {
                package: self.package,
                extra: self.buf.len(),
            })
        }
    }
}
