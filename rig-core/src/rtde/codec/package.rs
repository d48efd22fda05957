//! The packages of each direction: what a client sends ([`ClientPackage`]) and what the
//! controller sends ([`ServerPackage`]), encoded with their header and decoded from a [`Frame`]
//! for the negotiated protocol version.

use bytes::{BufMut, Bytes, BytesMut};

use super::text::TextMessage;
use super::value::FieldType;
use super::wire::{DecodeError, EncodeError, Frame, PROTOCOL_V2, PackageType, Reader, put_package};

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
    /// 'U': input values for a recipe; the payload is encoded by [`encode_values`](super::value::encode_values).
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
        let (ty, p) = (frame.package_type()?, &frame.payload[..]);
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
        let (ty, p) = (frame.package_type()?, &frame.payload[..]);
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
