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
//!
//! Files: `wire.rs` (header, [`PackageType`], errors, [`FrameDecoder`], the payload reader),
//! `text.rs` ([`TextMessage`], both directions), `value.rs` ([`DataType`], [`FieldType`],
//! [`Value`]), `package.rs` ([`ClientPackage`], [`ServerPackage`]). Everything is re-exported
//! here (and from [`crate::rtde`]).

mod package;
mod text;
mod value;
mod wire;

pub use package::{ClientPackage, ServerPackage};
pub use text::{MessageLevel, TextMessage};
pub use value::{DataType, FieldType, Value, decode_values, encode_values};
pub use wire::{
    DecodeError, EncodeError, Frame, FrameDecoder, HEADER_LEN, MAX_PACKAGE_LEN, PROTOCOL_V1,
    PROTOCOL_V2, PackageType, RTDE_PORT,
};

#[cfg(test)]
mod tests;
