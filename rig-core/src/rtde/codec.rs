//! Sans-IO RTDE codec: framing, packages in both directions, and typed field values.
//!
//! Wire format (UR "Real-Time Data Exchange (RTDE) Guide", protocol v1 and v2):
//! every package starts with a 3-byte header, `u16 size` (big-endian, counting the header
//! itself) and `u8 type`, followed by `size − 3` payload bytes. All integers and doubles are
//! big-endian. The payload of a type depends on the direction (client → controller or
//! controller → client) and on the negotiated protocol version, so the decoders take both.
//!
//! Nothing here touches a socket or a clock: [`FrameDecoder`] is fed bytes as they arrive
//! (split or coalesced anyhow) and yields whole frames; [`ClientPackage`] and
//! [`ServerPackage`] turn frames into typed packages and back.

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
fn put_package(
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
struct Reader<'a> {
    package: &'static str,
    buf: &'a [u8],
}

impl<'a> Reader<'a> {
    fn new(package: &'static str, buf: &'a [u8]) -> Self {
        Self { package, buf }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
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
    fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, DecodeError> {
        let b = self.take(2)?;
        Ok(u16::from_be_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, DecodeError> {
        let b = self.take(4)?;
        Ok(u32::from_be_bytes(b.try_into().expect("4 bytes")))
    }
    fn f64(&mut self) -> Result<f64, DecodeError> {
        let b = self.take(8)?;
        Ok(f64::from_be_bytes(b.try_into().expect("8 bytes")))
    }
    fn rest_str(&mut self) -> Result<String, DecodeError> {
        let b = self.take(self.buf.len())?;
        std::str::from_utf8(b)
            .map(str::to_owned)
            .map_err(|_| DecodeError::BadText(self.package))
    }
    fn short_str(&mut self) -> Result<String, DecodeError> {
        let n = self.u8()? as usize;
        let b = self.take(n)?;
        std::str::from_utf8(b)
            .map(str::to_owned)
            .map_err(|_| DecodeError::BadText(self.package))
    }
    fn finish(self) -> Result<(), DecodeError> {
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
    fn encode(&self, version: u16, out: &mut BytesMut) -> Result<(), EncodeError> {
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

    fn decode(version: u16, payload: &[u8]) -> Result<Self, DecodeError> {
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

/// RTDE data types, with their wire sizes (RTDE guide, "Data types").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataType {
    Bool,
    Uint8,
    Uint32,
    Uint64,
    Int32,
    Double,
    Vector3d,
    Vector6d,
    Vector6Int32,
    Vector6Uint32,
}

impl DataType {
    pub const ALL: [DataType; 10] = [
        Self::Bool,
        Self::Uint8,
        Self::Uint32,
        Self::Uint64,
        Self::Int32,
        Self::Double,
        Self::Vector3d,
        Self::Vector6d,
        Self::Vector6Int32,
        Self::Vector6Uint32,
    ];

    /// Bytes on the wire.
    pub const fn size(self) -> usize {
        match self {
            Self::Bool | Self::Uint8 => 1,
            Self::Uint32 | Self::Int32 => 4,
            Self::Uint64 | Self::Double => 8,
            Self::Vector3d => 24,
            Self::Vector6d => 48,
            Self::Vector6Int32 | Self::Vector6Uint32 => 24,
        }
    }

    /// The name used in setup replies.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Bool => "BOOL",
            Self::Uint8 => "UINT8",
            Self::Uint32 => "UINT32",
            Self::Uint64 => "UINT64",
            Self::Int32 => "INT32",
            Self::Double => "DOUBLE",
            Self::Vector3d => "VECTOR3D",
            Self::Vector6d => "VECTOR6D",
            Self::Vector6Int32 => "VECTOR6INT32",
            Self::Vector6Uint32 => "VECTOR6UINT32",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == s)
    }
}

/// The type the controller assigned to one requested variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldType {
    Known(DataType),
    /// The controller has no variable of that name: the whole recipe is invalid.
    NotFound,
    /// Another client already writes this input variable: the whole recipe is invalid.
    InUse,
}

impl FieldType {
    pub fn name(self) -> &'static str {
        match self {
            Self::Known(t) => t.name(),
            Self::NotFound => "NOT_FOUND",
            Self::InUse => "IN_USE",
        }
    }
    fn from_name(s: &str) -> Result<Self, DecodeError> {
        match s {
            "NOT_FOUND" => Ok(Self::NotFound),
            "IN_USE" => Ok(Self::InUse),
            other => DataType::from_name(other)
                .map(Self::Known)
                .ok_or_else(|| DecodeError::BadTypeName(other.to_owned())),
        }
    }
}

/// A typed field value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    Bool(bool),
    Uint8(u8),
    Uint32(u32),
    Uint64(u64),
    Int32(i32),
    Double(f64),
    Vector3d([f64; 3]),
    Vector6d([f64; 6]),
    Vector6Int32([i32; 6]),
    Vector6Uint32([u32; 6]),
}

impl Value {
    pub fn data_type(&self) -> DataType {
        match self {
            Self::Bool(_) => DataType::Bool,
            Self::Uint8(_) => DataType::Uint8,
            Self::Uint32(_) => DataType::Uint32,
            Self::Uint64(_) => DataType::Uint64,
            Self::Int32(_) => DataType::Int32,
            Self::Double(_) => DataType::Double,
            Self::Vector3d(_) => DataType::Vector3d,
            Self::Vector6d(_) => DataType::Vector6d,
            Self::Vector6Int32(_) => DataType::Vector6Int32,
            Self::Vector6Uint32(_) => DataType::Vector6Uint32,
        }
    }

    /// The zero of a type (the value of a variable nobody has written yet).
    pub fn zero(t: DataType) -> Self {
        match t {
            DataType::Bool => Self::Bool(false),
            DataType::Uint8 => Self::Uint8(0),
            DataType::Uint32 => Self::Uint32(0),
            DataType::Uint64 => Self::Uint64(0),
            DataType::Int32 => Self::Int32(0),
            DataType::Double => Self::Double(0.0),
            DataType::Vector3d => Self::Vector3d([0.0; 3]),
            DataType::Vector6d => Self::Vector6d([0.0; 6]),
            DataType::Vector6Int32 => Self::Vector6Int32([0; 6]),
            DataType::Vector6Uint32 => Self::Vector6Uint32([0; 6]),
        }
    }

    /// Numeric views used by typed state readers; `None` when the type does not fit.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Self::Double(v) => Some(v),
            Self::Int32(v) => Some(v as f64),
            Self::Uint32(v) => Some(v as f64),
            Self::Uint8(v) => Some(v as f64),
            Self::Uint64(v) => Some(v as f64),
            Self::Bool(v) => Some(v as u8 as f64),
            _ => None,
        }
    }
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            Self::Int32(v) => Some(v as i64),
            Self::Uint32(v) => Some(v as i64),
            Self::Uint8(v) => Some(v as i64),
            Self::Uint64(v) => i64::try_from(v).ok(),
            Self::Bool(v) => Some(v as i64),
            _ => None,
        }
    }
    pub fn as_vector6d(&self) -> Option<[f64; 6]> {
        match *self {
            Self::Vector6d(v) => Some(v),
            _ => None,
        }
    }

    fn put(&self, out: &mut BytesMut) {
        match *self {
            Self::Bool(v) => out.put_u8(v as u8),
            Self::Uint8(v) => out.put_u8(v),
            Self::Uint32(v) => out.put_u32(v),
            Self::Uint64(v) => out.put_u64(v),
            Self::Int32(v) => out.put_i32(v),
            Self::Double(v) => out.put_f64(v),
            Self::Vector3d(v) => v.iter().for_each(|x| out.put_f64(*x)),
            Self::Vector6d(v) => v.iter().for_each(|x| out.put_f64(*x)),
            Self::Vector6Int32(v) => v.iter().for_each(|x| out.put_i32(*x)),
            Self::Vector6Uint32(v) => v.iter().for_each(|x| out.put_u32(*x)),
        }
    }

    fn read(t: DataType, r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let b = r.take(t.size())?;
        let mut b = b;
        Ok(match t {
            // The controller sends 0 or 1; any non-zero byte reads as true.
            DataType::Bool => Self::Bool(b.get_u8() != 0),
            DataType::Uint8 => Self::Uint8(b.get_u8()),
            DataType::Uint32 => Self::Uint32(b.get_u32()),
            DataType::Uint64 => Self::Uint64(b.get_u64()),
            DataType::Int32 => Self::Int32(b.get_i32()),
            DataType::Double => Self::Double(b.get_f64()),
            DataType::Vector3d => Self::Vector3d(std::array::from_fn(|_| b.get_f64())),
            DataType::Vector6d => Self::Vector6d(std::array::from_fn(|_| b.get_f64())),
            DataType::Vector6Int32 => Self::Vector6Int32(std::array::from_fn(|_| b.get_i32())),
            DataType::Vector6Uint32 => Self::Vector6Uint32(std::array::from_fn(|_| b.get_u32())),
        })
    }
}

/// Decode the values of a data package's payload (after the recipe id) against its recipe's
/// types. The payload must hold exactly the recipe's fields.
pub fn decode_values(types: &[DataType], payload: &[u8]) -> Result<Vec<Value>, DecodeError> {
    let mut r = Reader::new("data package", payload);
    let values = types
        .iter()
        .map(|t| Value::read(*t, &mut r))
        .collect::<Result<Vec<_>, _>>()?;
    r.finish()?;
    Ok(values)
}

/// Encode values in recipe order (no recipe id).
pub fn encode_values(values: &[Value], out: &mut BytesMut) {
    for v in values {
        v.put(out);
    }
}

/// Packages a client sends to the controller.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientPackage {
    /// 'V': ask for a protocol version.
    RequestProtocolVersion(u16),
    /// 'v': ask for the controller version.
    GetUrControlVersion,
    /// 'O': output recipe. `frequency_hz` is sent in v2 only (v1 streams at 125 Hz).
    SetupOutputs {
        frequency_hz: f64,
        names: Vec<String>,
    },
    /// 'I': input recipe.
    SetupInputs { names: Vec<String> },
    /// 'S'
    Start,
    /// 'P'
    Pause,
    /// 'U': input values for a recipe; the payload is encoded by [`encode_values`].
    Data { recipe_id: u8, payload: Bytes },
    /// 'M': a client may send messages to the controller log.
    TextMessage(TextMessage),
}

/// Packages the controller sends to a client.
#[derive(Debug, Clone, PartialEq)]
pub enum ServerPackage {
    ProtocolVersion {
        accepted: bool,
    },
    UrControlVersion {
        major: u32,
        minor: u32,
        bugfix: u32,
        build: u32,
    },
    /// Reply to 'O'. v1 replies carry no recipe id.
    OutputSetup {
        recipe_id: Option<u8>,
        types: Vec<FieldType>,
    },
    /// Reply to 'I'.
    InputSetup {
        recipe_id: u8,
        types: Vec<FieldType>,
    },
    StartReply {
        accepted: bool,
    },
    PauseReply {
        accepted: bool,
    },
    /// Output values. v1 data packages carry no recipe id (a v1 client has one output recipe).
    Data {
        recipe_id: Option<u8>,
        payload: Bytes,
    },
    TextMessage(TextMessage),
}

fn join_names(names: &[String]) -> String {
    names.join(",")
}

fn split_names(s: &str) -> Vec<String> {
    if s.is_empty() {
        Vec::new()
    } else {
        s.split(',').map(|n| n.trim().to_owned()).collect()
    }
}

fn put_types(out: &mut BytesMut, types: &[FieldType]) {
    let joined = types.iter().map(|t| t.name()).collect::<Vec<_>>().join(",");
    out.put_slice(joined.as_bytes());
}

fn read_types(r: &mut Reader<'_>) -> Result<Vec<FieldType>, DecodeError> {
    let s = r.rest_str()?;
    split_names(&s)
        .iter()
        .map(|n| FieldType::from_name(n))
        .collect()
}

impl ClientPackage {
    pub fn package_type(&self) -> PackageType {
        match self {
            Self::RequestProtocolVersion(_) => PackageType::RequestProtocolVersion,
            Self::GetUrControlVersion => PackageType::GetUrControlVersion,
            Self::SetupOutputs { .. } => PackageType::SetupOutputs,
            Self::SetupInputs { .. } => PackageType::SetupInputs,
            Self::Start => PackageType::Start,
            Self::Pause => PackageType::Pause,
            Self::Data { .. } => PackageType::DataPackage,
            Self::TextMessage(_) => PackageType::TextMessage,
        }
    }

    /// Append this package, header included, to `out`.
    pub fn encode(&self, version: u16, out: &mut BytesMut) -> Result<(), EncodeError> {
        put_package(out, self.package_type(), |o| {
            match self {
                Self::RequestProtocolVersion(v) => o.put_u16(*v),
                Self::GetUrControlVersion | Self::Start | Self::Pause => {}
                Self::SetupOutputs {
                    frequency_hz,
                    names,
                } => {
                    if version >= PROTOCOL_V2 {
                        o.put_f64(*frequency_hz);
                    }
                    o.put_slice(join_names(names).as_bytes());
                }
                Self::SetupInputs { names } => o.put_slice(join_names(names).as_bytes()),
                Self::Data { recipe_id, payload } => {
                    o.put_u8(*recipe_id);
                    o.put_slice(payload);
                }
                Self::TextMessage(m) => m.encode(version, o)?,
            }
            Ok(())
        })
    }

    /// Decode a frame received by the controller.
    pub fn decode(frame: &Frame, version: u16) -> Result<Self, DecodeError> {
        let ty = PackageType::from_u8(frame.type_byte)
            .ok_or(DecodeError::UnknownType(frame.type_byte))?;
        let p = &frame.payload[..];
        let pkg = match ty {
            PackageType::RequestProtocolVersion => {
                let mut r = Reader::new("protocol version request", p);
                let v = r.u16()?;
                r.finish()?;
                Self::RequestProtocolVersion(v)
            }
            PackageType::GetUrControlVersion => {
                Reader::new("controller version request", p).finish()?;
                Self::GetUrControlVersion
            }
            PackageType::SetupOutputs => {
                let mut r = Reader::new("output setup", p);
                let frequency_hz = if version >= PROTOCOL_V2 {
                    r.f64()?
                } else {
                    125.0
                };
                let names = split_names(&r.rest_str()?);
                Self::SetupOutputs {
                    frequency_hz,
                    names,
                }
            }
            PackageType::SetupInputs => {
                let mut r = Reader::new("input setup", p);
                Self::SetupInputs {
                    names: split_names(&r.rest_str()?),
                }
            }
            PackageType::Start => {
                Reader::new("start", p).finish()?;
                Self::Start
            }
            PackageType::Pause => {
                Reader::new("pause", p).finish()?;
                Self::Pause
            }
            PackageType::DataPackage => {
                let mut r = Reader::new("data package", p);
                let recipe_id = r.u8()?;
                Self::Data {
                    recipe_id,
                    payload: frame.payload.slice(1..),
                }
            }
            PackageType::TextMessage => Self::TextMessage(TextMessage::decode(version, p)?),
        };
        Ok(pkg)
    }
}

impl ServerPackage {
    pub fn package_type(&self) -> PackageType {
        match self {
            Self::ProtocolVersion { .. } => PackageType::RequestProtocolVersion,
            Self::UrControlVersion { .. } => PackageType::GetUrControlVersion,
            Self::OutputSetup { .. } => PackageType::SetupOutputs,
            Self::InputSetup { .. } => PackageType::SetupInputs,
            Self::StartReply { .. } => PackageType::Start,
            Self::PauseReply { .. } => PackageType::Pause,
            Self::Data { .. } => PackageType::DataPackage,
            Self::TextMessage(_) => PackageType::TextMessage,
        }
    }

    /// Append this package, header included, to `out`.
    pub fn encode(&self, version: u16, out: &mut BytesMut) -> Result<(), EncodeError> {
        put_package(out, self.package_type(), |o| {
            match self {
                Self::ProtocolVersion { accepted }
                | Self::StartReply { accepted }
                | Self::PauseReply { accepted } => o.put_u8(*accepted as u8),
                Self::UrControlVersion {
                    major,
                    minor,
                    bugfix,
                    build,
                } => {
                    for v in [major, minor, bugfix, build] {
                        o.put_u32(*v);
                    }
                }
                Self::OutputSetup { recipe_id, types } => {
                    if version >= PROTOCOL_V2 {
                        o.put_u8(recipe_id.unwrap_or(1));
                    }
                    put_types(o, types);
                }
                Self::InputSetup { recipe_id, types } => {
                    o.put_u8(*recipe_id);
                    put_types(o, types);
                }
                Self::Data { recipe_id, payload } => {
                    if version >= PROTOCOL_V2 {
                        o.put_u8(recipe_id.unwrap_or(1));
                    }
                    o.put_slice(payload);
                }
                Self::TextMessage(m) => m.encode(version, o)?,
            }
            Ok(())
        })
    }

    /// Decode a frame received by a client.
    pub fn decode(frame: &Frame, version: u16) -> Result<Self, DecodeError> {
        let ty = PackageType::from_u8(frame.type_byte)
            .ok_or(DecodeError::UnknownType(frame.type_byte))?;
        let p = &frame.payload[..];
        let accepted = |name: &'static str| -> Result<bool, DecodeError> {
            let mut r = Reader::new(name, p);
            let a = r.u8()? != 0;
            r.finish()?;
            Ok(a)
        };
        let pkg = match ty {
            PackageType::RequestProtocolVersion => Self::ProtocolVersion {
                accepted: accepted("protocol version reply")?,
            },
            PackageType::GetUrControlVersion => {
                let mut r = Reader::new("controller version reply", p);
                let (major, minor, bugfix, build) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
                r.finish()?;
                Self::UrControlVersion {
                    major,
                    minor,
                    bugfix,
                    build,
                }
            }
            PackageType::SetupOutputs => {
                let mut r = Reader::new("output setup reply", p);
                let recipe_id = if version >= PROTOCOL_V2 {
                    Some(r.u8()?)
                } else {
                    None
                };
                Self::OutputSetup {
                    recipe_id,
                    types: read_types(&mut r)?,
                }
            }
            PackageType::SetupInputs => {
                let mut r = Reader::new("input setup reply", p);
                let recipe_id = r.u8()?;
                Self::InputSetup {
                    recipe_id,
                    types: read_types(&mut r)?,
                }
            }
            PackageType::Start => Self::StartReply {
                accepted: accepted("start reply")?,
            },
            PackageType::Pause => Self::PauseReply {
                accepted: accepted("pause reply")?,
            },
            PackageType::DataPackage => {
                if version >= PROTOCOL_V2 {
                    let recipe_id = Reader::new("data package", p).u8()?;
                    Self::Data {
                        recipe_id: Some(recipe_id),
                        payload: frame.payload.slice(1..),
                    }
                } else {
                    Self::Data {
                        recipe_id: None,
                        payload: frame.payload.clone(),
                    }
                }
            }
            PackageType::TextMessage => Self::TextMessage(TextMessage::decode(version, p)?),
        };
        Ok(pkg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames_of(bytes: &[u8]) -> Vec<Frame> {
        let mut d = FrameDecoder::new();
        d.push(bytes);
        let mut out = Vec::new();
        while let Some(f) = d.next_frame().unwrap() {
            out.push(f);
        }
        out
    }

    #[test]
    fn protocol_version_request_matches_the_guide_bytes() {
        let mut out = BytesMut::new();
        ClientPackage::RequestProtocolVersion(2)
            .encode(PROTOCOL_V2, &mut out)
            .unwrap();
        // size 5 (header 3 + u16), type 'V' = 86, version 2.
        assert_eq!(&out[..], &[0, 5, 86, 0, 2]);
    }

    #[test]
    fn output_setup_v2_carries_frequency_then_names() {
        let mut out = BytesMut::new();
        ClientPackage::SetupOutputs {
            frequency_hz: 500.0,
            names: vec!["timestamp".into(), "actual_TCP_pose".into()],
        }
        .encode(PROTOCOL_V2, &mut out)
        .unwrap();
        let names = b"timestamp,actual_TCP_pose";
        assert_eq!(out.len(), 3 + 8 + names.len());
        assert_eq!(out[2], b'O');
        assert_eq!(&out[3..11], &500.0f64.to_be_bytes());
        assert_eq!(&out[11..], names);
    }

    #[test]
    fn output_setup_reply_with_not_found_decodes() {
        let mut payload = vec![1u8];
        payload.extend_from_slice(b"DOUBLE,NOT_FOUND,VECTOR6D");
        let f = Frame {
            type_byte: b'O',
            payload: Bytes::from(payload),
        };
        let p = ServerPackage::decode(&f, PROTOCOL_V2).unwrap();
        assert_eq!(
            p,
            ServerPackage::OutputSetup {
                recipe_id: Some(1),
                types: vec![
                    FieldType::Known(DataType::Double),
                    FieldType::NotFound,
                    FieldType::Known(DataType::Vector6d)
                ]
            }
        );
    }

    #[test]
    fn split_and_coalesced_reads_frame_identically() {
        let mut bytes = BytesMut::new();
        let msgs = [
            ServerPackage::ProtocolVersion { accepted: true },
            ServerPackage::TextMessage(TextMessage {
                message: "hello".into(),
                source: "RTDE".into(),
                level: MessageLevel::Info,
            }),
            ServerPackage::StartReply { accepted: true },
        ];
        for m in &msgs {
            m.encode(PROTOCOL_V2, &mut bytes).unwrap();
        }
        let whole = frames_of(&bytes);
        assert_eq!(whole.len(), 3);
        // One byte at a time.
        let mut d = FrameDecoder::new();
        let mut got = Vec::new();
        for b in bytes.iter() {
            d.push(std::slice::from_ref(b));
            while let Some(f) = d.next_frame().unwrap() {
                got.push(f);
            }
        }
        assert_eq!(got, whole);
        let decoded: Vec<_> = got
            .iter()
            .map(|f| ServerPackage::decode(f, PROTOCOL_V2).unwrap())
            .collect();
        assert_eq!(decoded, msgs);
    }

    #[test]
    fn size_below_header_is_an_error_not_a_panic() {
        let mut d = FrameDecoder::new();
        d.push(&[0, 2, b'V']);
        assert_eq!(d.next_frame(), Err(DecodeError::SizeTooSmall(2)));
    }

    #[test]
    fn unknown_type_is_framed_and_reported() {
        let f = frames_of(&[0, 4, b'Z', 9]);
        assert_eq!(f.len(), 1);
        assert_eq!(
            ServerPackage::decode(&f[0], PROTOCOL_V2),
            Err(DecodeError::UnknownType(b'Z'))
        );
    }

    #[test]
    fn truncated_controller_version_reports_need_and_have() {
        let f = Frame {
            type_byte: b'v',
            payload: Bytes::from_static(&[0, 0, 0, 5, 0, 0]),
        };
        assert!(matches!(
            ServerPackage::decode(&f, PROTOCOL_V2),
            Err(DecodeError::Truncated {
                need: 4,
                have: 2,
                ..
            })
        ));
    }

    #[test]
    fn data_values_round_trip_and_reject_wrong_lengths() {
        let values = [
            Value::Double(1.5),
            Value::Int32(-7),
            Value::Vector6d([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
            Value::Bool(true),
        ];
        let types: Vec<_> = values.iter().map(Value::data_type).collect();
        let mut buf = BytesMut::new();
        encode_values(&values, &mut buf);
        assert_eq!(buf.len(), 8 + 4 + 48 + 1);
        assert_eq!(decode_values(&types, &buf).unwrap(), values);
        assert!(matches!(
            decode_values(&types, &buf[..buf.len() - 1]),
            Err(DecodeError::Truncated { .. })
        ));
        let mut longer = buf.to_vec();
        longer.push(0);
        assert!(matches!(
            decode_values(&types, &longer),
            Err(DecodeError::TrailingBytes { extra: 1, .. })
        ));
    }

    #[test]
    fn v1_text_message_has_level_then_text() {
        let m = TextMessage {
            message: "boot".into(),
            source: String::new(),
            level: MessageLevel::Warning,
        };
        let mut out = BytesMut::new();
        ServerPackage::TextMessage(m.clone())
            .encode(PROTOCOL_V1, &mut out)
            .unwrap();
        assert_eq!(&out[..], &[0, 8, b'M', 2, b'b', b'o', b'o', b't']);
        let f = frames_of(&out);
        assert_eq!(
            ServerPackage::decode(&f[0], PROTOCOL_V1).unwrap(),
            ServerPackage::TextMessage(m)
        );
    }

    #[test]
    fn oversize_package_is_refused_and_leaves_output_untouched() {
        let mut out = BytesMut::new();
        out.put_slice(b"keep");
        let names = vec!["x".repeat(70_000)];
        let err = ClientPackage::SetupInputs { names }
            .encode(PROTOCOL_V2, &mut out)
            .unwrap_err();
        assert!(matches!(err, EncodeError::TooLong(_)));
        assert_eq!(&out[..], b"keep");
    }
}
