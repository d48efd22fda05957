//! Protobuf for the recordings, written by hand: the wire encoding of the messages the rig
//! writes, a small field reader to decode them back, and each schema's descriptor as the
//! serialized `google.protobuf.FileDescriptorSet` that MCAP (schema encoding `protobuf`) and
//! Foxglove WebSocket (base64 of the same bytes) carry.
//!
//! Why by hand: the rig writes ten small message types; `prost` would need `protoc` (or a
//! vendored descriptor) to produce the FileDescriptorSet, and a generated-code crate for ten
//! messages costs more build time than the two hundred lines here. The descriptors below are
//! written from the schemas' published field numbers; the tests below check them against the encoder
//! and `tests/python` decodes recordings with the Python `protobuf` runtime, which validates the
//! descriptors independently.
//!
//! The schemas (`.proto` text in [`PROTO_TEXT`], for people):
//! - `google.protobuf.Timestamp` (`seconds` = 1, `nanos` = 2).
//! - `foxglove.Vector3` (`x, y, z` = 1..3), `foxglove.Quaternion` (`x, y, z, w` = 1..4),
//!   `foxglove.Pose` (`position` = 1, `orientation` = 2), `foxglove.PoseInFrame`
//!   (`timestamp` = 1, `frame_id` = 2, `pose` = 3), `foxglove.CompressedImage` (`timestamp` = 1,
//!   `data` = 2, `format` = 3, `frame_id` = 4): Foxglove's own schemas, so its Image, 3D and
//!   Plot panels show the channels.
//! - `rig.Wrench`, `rig.PairedWrench`, `rig.StageLabel`, `rig.TrueWrench`: the rig's own, in one
//!   file `rig/recording.proto`.

/// Protobuf wire types.
const VARINT: u8 = 0;
const FIXED64: u8 = 1;
const LEN: u8 = 2;
const FIXED32: u8 = 5;

/// Append-only protobuf writer.
#[derive(Debug, Default, Clone)]
pub struct Enc {
    pub buf: Vec<u8>,
}

impl Enc {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            buf: Vec::with_capacity(n),
        }
    }
    fn varint(&mut self, mut v: u64) {
        while v >= 0x80 {
            self.buf.push(v as u8 | 0x80);
            v >>= 7;
        }
        self.buf.push(v as u8);
    }
    fn key(&mut self, field: u32, wire: u8) {
        self.varint(u64::from(field) << 3 | u64::from(wire));
    }
    /// A `double` field (written even when 0: a reader sees the same value either way).
    pub fn double(&mut self, field: u32, v: f64) {
        self.key(field, FIXED64);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// An `int64` / `int32` field (two's complement varint).
    pub fn int(&mut self, field: u32, v: i64) {
        self.key(field, VARINT);
        self.varint(v as u64);
    }
    /// A `bytes` / `string` field.
    pub fn bytes(&mut self, field: u32, v: &[u8]) {
        self.key(field, LEN);
        self.varint(v.len() as u64);
        self.buf.extend_from_slice(v);
    }
    pub fn string(&mut self, field: u32, v: &str) {
        self.bytes(field, v.as_bytes());
    }
    /// A packed `repeated double` field.
    pub fn packed_doubles(&mut self, field: u32, v: &[f64]) {
        self.key(field, LEN);
        self.varint(v.len() as u64 * 8);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }
    /// A message field, its body written by `body`.
    pub fn message(&mut self, field: u32, body: impl FnOnce(&mut Enc)) {
        let mut inner = Enc::with_capacity(64);
        body(&mut inner);
        self.bytes(field, &inner.buf);
    }
    /// `google.protobuf.Timestamp` of host-clock ns.
    pub fn timestamp(&mut self, field: u32, t_ns: u64) {
        self.message(field, |m| {
            m.int(1, (t_ns / 1_000_000_000) as i64);
            m.int(2, (t_ns % 1_000_000_000) as i64);
        });
    }
    /// `foxglove.Vector3`.
    pub fn vector3(&mut self, field: u32, v: [f64; 3]) {
        self.message(field, |m| {
            m.double(1, v[0]);
            m.double(2, v[1]);
            m.double(3, v[2]);
        });
    }
}

/// One field as read: its number and value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value<'a> {
    Varint(u64),
    Fixed64(u64),
    Len(&'a [u8]),
    Fixed32(u32),
}

impl<'a> Value<'a> {
    pub fn as_f64(self) -> Result<f64, String> {
        match self {
            Value::Fixed64(b) => Ok(f64::from_bits(b)),
            other => Err(format!("expected a double, found {other:?}")),
        }
    }
    pub fn as_i64(self) -> Result<i64, String> {
        match self {
            Value::Varint(v) => Ok(v as i64),
            other => Err(format!("expected an integer, found {other:?}")),
        }
    }
    pub fn as_bytes(self) -> Result<&'a [u8], String> {
        match self {
            Value::Len(b) => Ok(b),
            other => Err(format!(
                "expected a length-delimited field, found {other:?}"
            )),
        }
    }
    pub fn as_str(self) -> Result<&'a str, String> {
        std::str::from_utf8(self.as_bytes()?).map_err(|e| format!("string is not UTF-8: {e}"))
    }
    /// A `repeated double`, packed or (one element) unpacked.
    pub fn doubles(self, out: &mut Vec<f64>) -> Result<(), String> {
        match self {
            Value::Fixed64(b) => out.push(f64::from_bits(b)),
            Value::Len(b) if b.len() % 8 == 0 => out.extend(
                b.chunks_exact(8)
                    .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8]))),
            ),
            other => return Err(format!("expected packed doubles, found {other:?}")),
        }
        Ok(())
    }
    /// `google.protobuf.Timestamp` → ns.
    pub fn timestamp_ns(self) -> Result<u64, String> {
        let (mut s, mut n) = (0i64, 0i64);
        for f in fields(self.as_bytes()?) {
            match f? {
                (1, v) => s = v.as_i64()?,
                (2, v) => n = v.as_i64()?,
                _ => {}
            }
        }
        if s < 0 || !(0..1_000_000_000).contains(&n) {
            return Err(format!("timestamp {s} s {n} ns is out of range"));
        }
        Ok((s as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(n as u64))
    }
    /// `foxglove.Vector3`.
    pub fn vector3(self) -> Result<[f64; 3], String> {
        let mut v = [0.0; 3];
        for f in fields(self.as_bytes()?) {
            if let (k @ 1..=3, x) = f? {
                v[k as usize - 1] = x.as_f64()?;
            }
        }
        Ok(v)
    }
}

/// The fields of a message body in wire order; an error on a truncated or malformed body.
pub fn fields(mut buf: &[u8]) -> impl Iterator<Item = Result<(u32, Value<'_>), String>> {
    fn varint(buf: &mut &[u8]) -> Result<u64, String> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let (&b, rest) = buf.split_first().ok_or("truncated varint")?;
            *buf = rest;
            v |= u64::from(b & 0x7f) << shift;
            if b < 0x80 {
                return Ok(v);
            }
        }
        Err("varint longer than 10 bytes".into())
    }
    fn take<'a>(buf: &mut &'a [u8], n: usize) -> Result<&'a [u8], String> {
        if buf.len() < n {
            return Err(format!("field needs {n} bytes, {} left", buf.len()));
        }
        let (a, b) = buf.split_at(n);
        *buf = b;
        Ok(a)
    }
    let mut failed = false;
    std::iter::from_fn(move || {
        if buf.is_empty() || failed {
            return None;
        }
        let one = (|| {
            let key = varint(&mut buf)?;
            let field = u32::try_from(key >> 3).map_err(|_| "field number out of range")?;
            let v = match (key & 7) as u8 {
                VARINT => Value::Varint(varint(&mut buf)?),
                FIXED64 => Value::Fixed64(u64::from_le_bytes(
                    take(&mut buf, 8)?.try_into().map_err(|_| "short fixed64")?,
                )),
                LEN => {
                    let n = usize::try_from(varint(&mut buf)?).map_err(|_| "length too large")?;
                    Value::Len(take(&mut buf, n)?)
                }
                FIXED32 => Value::Fixed32(u32::from_le_bytes(
                    take(&mut buf, 4)?.try_into().map_err(|_| "short fixed32")?,
                )),
                w => return Err(format!("unsupported wire type {w} (field {field})")),
            };
            Ok((field, v))
        })();
        failed = one.is_err();
        Some(one)
    })
}

// ---- Descriptors ----------------------------------------------------------------------------

/// Field types of `FieldDescriptorProto.Type` that the schemas use.
#[derive(Debug, Clone, Copy)]
enum Ty {
    Double = 1,
    Int64 = 3,
    Int32 = 5,
    String = 9,
    Message = 11,
    Bytes = 12,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Label {
    Single,
    /// proto3 `optional` (explicit presence; a synthetic oneof `_<name>` in the descriptor).
    Optional,
    Repeated,
}

struct FieldDef {
    name: &'static str,
    number: u32,
    ty: Ty,
    label: Label,
    /// Fully qualified message type (`.foxglove.Vector3`) for message fields.
    type_name: &'static str,
}

struct MessageDef {
    name: &'static str,
    fields: &'static [FieldDef],
}

struct FileDef {
    name: &'static str,
    package: &'static str,
    deps: &'static [&'static str],
    messages: &'static [MessageDef],
}

const fn f(name: &'static str, number: u32, ty: Ty) -> FieldDef {
    FieldDef {
        name,
        number,
        ty,
        label: Label::Single,
        type_name: "",
    }
}
const fn m(name: &'static str, number: u32, type_name: &'static str) -> FieldDef {
    FieldDef {
        name,
        number,
        ty: Ty::Message,
        label: Label::Single,
        type_name,
    }
}
const fn opt(name: &'static str, number: u32, ty: Ty) -> FieldDef {
    FieldDef {
        name,
        number,
        ty,
        label: Label::Optional,
        type_name: "",
    }
}

const TIMESTAMP: &str = ".google.protobuf.Timestamp";
const VECTOR3: &str = ".foxglove.Vector3";

const FILES: &[FileDef] = &[
    FileDef {
        name: "google/protobuf/timestamp.proto",
        package: "google.protobuf",
        deps: &[],
        messages: &[MessageDef {
            name: "Timestamp",
            fields: &[f("seconds", 1, Ty::Int64), f("nanos", 2, Ty::Int32)],
        }],
    },
    FileDef {
        name: "foxglove/Vector3.proto",
        package: "foxglove",
        deps: &[],
        messages: &[MessageDef {
            name: "Vector3",
            fields: &[
                f("x", 1, Ty::Double),
                f("y", 2, Ty::Double),
                f("z", 3, Ty::Double),
            ],
        }],
    },
    FileDef {
        name: "foxglove/Quaternion.proto",
        package: "foxglove",
        deps: &[],
        messages: &[MessageDef {
            name: "Quaternion",
            fields: &[
                f("x", 1, Ty::Double),
                f("y", 2, Ty::Double),
                f("z", 3, Ty::Double),
                f("w", 4, Ty::Double),
            ],
        }],
    },
    FileDef {
        name: "foxglove/Pose.proto",
        package: "foxglove",
        deps: &["foxglove/Quaternion.proto", "foxglove/Vector3.proto"],
        messages: &[MessageDef {
            name: "Pose",
            fields: &[
                m("position", 1, VECTOR3),
                m("orientation", 2, ".foxglove.Quaternion"),
            ],
        }],
    },
    FileDef {
        name: "foxglove/PoseInFrame.proto",
        package: "foxglove",
        deps: &["foxglove/Pose.proto", "google/protobuf/timestamp.proto"],
        messages: &[MessageDef {
            name: "PoseInFrame",
            fields: &[
                m("timestamp", 1, TIMESTAMP),
                f("frame_id", 2, Ty::String),
                m("pose", 3, ".foxglove.Pose"),
            ],
        }],
    },
    FileDef {
        name: "foxglove/CompressedImage.proto",
        package: "foxglove",
        deps: &["google/protobuf/timestamp.proto"],
        messages: &[MessageDef {
            name: "CompressedImage",
            fields: &[
                m("timestamp", 1, TIMESTAMP),
                f("data", 2, Ty::Bytes),
                f("format", 3, Ty::String),
                f("frame_id", 4, Ty::String),
            ],
        }],
    },
    FileDef {
        name: "rig/recording.proto",
        package: "rig",
        deps: &["foxglove/Vector3.proto", "google/protobuf/timestamp.proto"],
        messages: &[
            MessageDef {
                name: "Wrench",
                fields: &[
                    m("timestamp", 1, TIMESTAMP),
                    m("force", 2, VECTOR3),
                    m("torque", 3, VECTOR3),
                    opt("seq", 4, Ty::Int64),
                ],
            },
            MessageDef {
                name: "PairedWrench",
                fields: &[
                    m("timestamp", 1, TIMESTAMP),
                    f("frame_seq", 2, Ty::Int64),
                    m("force", 3, VECTOR3),
                    m("torque", 4, VECTOR3),
                    opt("sync_error_ns", 5, Ty::Double),
                    f("status", 6, Ty::String),
                    opt("stage", 7, Ty::String),
                    FieldDef {
                        name: "tcp_pose",
                        number: 8,
                        ty: Ty::Double,
                        label: Label::Repeated,
                        type_name: "",
                    },
                ],
            },
            MessageDef {
                name: "StageLabel",
                fields: &[m("timestamp", 1, TIMESTAMP), f("stage", 2, Ty::String)],
            },
            MessageDef {
                name: "TrueWrench",
                fields: &[
                    m("timestamp", 1, TIMESTAMP),
                    f("frame_seq", 2, Ty::Int64),
                    m("force", 3, VECTOR3),
                    m("torque", 4, VECTOR3),
                ],
            },
        ],
    },
];

/// The schemas in `.proto` form: documentation for people, the same definitions as the
/// descriptors (a test compares field names and numbers).
pub const PROTO_TEXT: &str = r#"// rig/recording.proto: the rig's own messages (units in the field comments).
syntax = "proto3";
package rig;
import "foxglove/Vector3.proto";
import "google/protobuf/timestamp.proto";

// One F/T sample at the indenter tip, tared at approach height.
message Wrench {
  google.protobuf.Timestamp timestamp = 1;  // host clock
  foxglove.Vector3 force = 2;               // N
  foxglove.Vector3 torque = 3;              // N·mm
  optional int64 seq = 4;                   // device sample counter, when it has one
}

// The wrench at one frame's capture time (absent force/torque: the pairing was refused).
message PairedWrench {
  google.protobuf.Timestamp timestamp = 1;  // the frame's capture time
  int64 frame_seq = 2;                      // = the frame's MCAP message sequence
  foxglove.Vector3 force = 3;               // N
  foxglove.Vector3 torque = 4;              // N·mm
  optional double sync_error_ns = 5;
  string status = 6;                        // ok, held, out_of_range, gap, no_data
  optional string stage = 7;                // down, shear, reverse, up
  repeated double tcp_pose = 8;             // UR pose [x, y, z (m), rx, ry, rz (rad)] or empty
}

// The stage that begins at timestamp: down, shear, reverse, up.
message StageLabel {
  google.protobuf.Timestamp timestamp = 1;
  string stage = 2;
}

// Simulated rig only: the simulator's wrench at a frame's true capture time.
message TrueWrench {
  google.protobuf.Timestamp timestamp = 1;
  int64 frame_seq = 2;
  foxglove.Vector3 force = 3;               // N
  foxglove.Vector3 torque = 4;              // N·mm
}
"#;

fn file_by_name(name: &str) -> Option<&'static FileDef> {
    FILES.iter().find(|f| f.name == name)
}

fn encode_file(file: &FileDef) -> Vec<u8> {
    let mut e = Enc::default();
    e.string(1, file.name);
    e.string(2, file.package);
    for d in file.deps {
        e.string(3, d);
    }
    for msg in file.messages {
        e.message(4, |d| {
            d.string(1, msg.name);
            let mut oneofs = 0;
            for fd in msg.fields {
                d.message(2, |x| {
                    x.string(1, fd.name);
                    x.int(3, i64::from(fd.number));
                    x.int(4, if fd.label == Label::Repeated { 3 } else { 1 });
                    x.int(5, fd.ty as i64);
                    if !fd.type_name.is_empty() {
                        x.string(6, fd.type_name);
                    }
                    if fd.label == Label::Optional {
                        x.int(9, oneofs);
                        x.int(17, 1);
                        oneofs += 1;
                    }
                });
            }
            for fd in msg.fields.iter().filter(|f| f.label == Label::Optional) {
                d.message(8, |o| o.string(1, &format!("_{}", fd.name)));
            }
        });
    }
    e.string(12, "proto3");
    e.buf
}

/// The serialized `FileDescriptorSet` of a message type (`foxglove.CompressedImage`,
/// `rig.Wrench`, …): its file and every file it imports, imports first. `None` for a type
/// not described here.
pub fn descriptor_set(type_name: &str) -> Option<Vec<u8>> {
    let (package, name) = type_name.rsplit_once('.')?;
    let file = FILES
        .iter()
        .find(|f| f.package == package && f.messages.iter().any(|m| m.name == name))?;
    let mut order: Vec<&FileDef> = Vec::new();
    fn visit(f: &'static FileDef, order: &mut Vec<&'static FileDef>) {
        if order.iter().any(|o| o.name == f.name) {
            return;
        }
        for d in f.deps {
            if let Some(dep) = file_by_name(d) {
                visit(dep, order);
            }
        }
        order.push(f);
    }
    visit(file, &mut order);
    let mut set = Enc::default();
    for f in order {
        set.bytes(1, &encode_file(f));
    }
    Some(set.buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varints_and_fields_round_trip() {
        let mut e = Enc::default();
        e.int(1, 300);
        e.int(2, -1);
        e.double(3, -1.5);
        e.string(4, "héllo");
        e.packed_doubles(5, &[1.0, 2.0]);
        e.timestamp(6, 12_000_000_345);
        // 300 = 0xAC 0x02 (the protobuf documentation's example).
        assert_eq!(&e.buf[..3], &[0x08, 0xAC, 0x02]);
        let got: Vec<_> = fields(&e.buf).collect::<Result<_, _>>().unwrap();
        assert_eq!(got[0], (1, Value::Varint(300)));
        assert_eq!(got[1].1.as_i64().unwrap(), -1);
        assert_eq!(got[2].1.as_f64().unwrap(), -1.5);
        assert_eq!(got[3].1.as_str().unwrap(), "héllo");
        let mut v = Vec::new();
        got[4].1.doubles(&mut v).unwrap();
        assert_eq!(v, [1.0, 2.0]);
        assert_eq!(got[5].1.timestamp_ns().unwrap(), 12_000_000_345);
    }

    #[test]
    fn truncated_bodies_are_errors_not_panics() {
        let mut e = Enc::default();
        e.string(1, "abcdef");
        e.double(2, 1.0);
        // The string field is 8 bytes (key, length, 6 bytes): a cut there is a whole message.
        assert_eq!(e.buf.len(), 17);
        for cut in 0..e.buf.len() {
            let r: Result<Vec<_>, _> = fields(&e.buf[..cut]).collect();
            assert_eq!(r.is_err(), cut != 0 && cut != 8, "cut at {cut}");
        }
        assert!(fields(&[0xff; 12]).any(|r| r.is_err()));
        assert!(fields(&[0x0b]).any(|r| r.is_err()), "wire type 3 (groups)");
    }

    /// The descriptor set decodes back to the files, names and field numbers it was built from.
    #[test]
    fn descriptor_sets_hold_their_imports_first() {
        let set = descriptor_set("foxglove.PoseInFrame").unwrap();
        let names: Vec<String> = fields(&set)
            .map(|f| {
                let (n, v) = f.unwrap();
                assert_eq!(n, 1);
                let (_, name) = fields(v.as_bytes().unwrap())
                    .map(Result::unwrap)
                    .find(|(k, _)| *k == 1)
                    .unwrap();
                name.as_str().unwrap().to_owned()
            })
            .collect();
        assert_eq!(
            names,
            [
                "foxglove/Quaternion.proto",
                "foxglove/Vector3.proto",
                "foxglove/Pose.proto",
                "google/protobuf/timestamp.proto",
                "foxglove/PoseInFrame.proto"
            ]
        );
        for t in [
            "foxglove.CompressedImage",
            "rig.Wrench",
            "rig.PairedWrench",
            "rig.StageLabel",
            "rig.TrueWrench",
        ] {
            assert!(descriptor_set(t).is_some(), "{t}");
        }
        assert!(descriptor_set("rig.Nothing").is_none());
    }

    /// Every field of the rig's descriptors appears in PROTO_TEXT with the same number.
    #[test]
    fn proto_text_matches_the_descriptors() {
        let rig = file_by_name("rig/recording.proto").unwrap();
        for msg in rig.messages {
            assert!(PROTO_TEXT.contains(&format!("message {} {{", msg.name)));
            for fd in msg.fields {
                let line = format!(" {} = {};", fd.name, fd.number);
                assert!(PROTO_TEXT.contains(&line), "{}.{line}", msg.name);
            }
        }
    }
}
