//! Typed field values: the RTDE data types with their wire sizes, the type the controller
//! assigns to each requested variable, and the values of a data package.

use bytes::{Buf, BufMut, BytesMut};

use super::wire::{DecodeError, Reader};

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
    pub(super) fn from_name(s: &str) -> Result<Self, DecodeError> {
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
