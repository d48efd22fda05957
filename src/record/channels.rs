//! The channels of a trajectory file: topics, JSON schemas and message bodies.
//!
//! Every channel uses `message_encoding = "json"` with a `jsonschema` schema, which the Foxglove
//! app decodes and plots natively and any MCAP reader can parse without code generation. The
//! image and pose channels use the shapes (and names) of Foxglove's well-known schemas
//! `foxglove.CompressedImage` and `foxglove.PoseInFrame`, so Foxglove's Image and 3D panels show
//! them; in JSON, Foxglove's `bytes` fields are base64 strings. The rig's own channels use
//! `rig.*` schema names. All times are host-clock nanoseconds (`t_host_ns` of the rig's clock)
//! as `{sec, nsec}`, and the MCAP `log_time` of every message is the same instant in ns.

use rig_core::pose::Pose;
use rig_core::wrench::Wrench;
use serde::{Deserialize, Serialize};

use crate::plan::StageName;
use crate::sync::PairedFrame;

/// Frames as lossless PNG (`foxglove.CompressedImage`).
pub const TOPIC_IMAGE: &str = "/camera/image";
/// The full-rate wrench (`rig.Wrench`).
pub const TOPIC_WRENCH: &str = "/ft/wrench";
/// The TCP pose stream (`foxglove.PoseInFrame`).
pub const TOPIC_POSE: &str = "/robot/tcp_pose";
/// The wrench paired with each frame (`rig.PairedWrench`).
pub const TOPIC_PAIRED: &str = "/sync/paired_wrench";
/// Stage changes: down, shear, reverse, up (`rig.StageLabel`).
pub const TOPIC_STAGE: &str = "/plan/stage";
/// Simulated rig only: the simulator's true wrench at each frame's capture time
/// (`rig.TrueWrench`), the ground truth the paired wrench is checked against.
pub const TOPIC_TRUTH: &str = "/sim/true_wrench";

/// Every channel: topic, schema name, JSON schema.
pub const CHANNELS: [(&str, &str, &str); 6] = [
    (TOPIC_IMAGE, "foxglove.CompressedImage", IMAGE_SCHEMA),
    (TOPIC_WRENCH, "rig.Wrench", WRENCH_SCHEMA),
    (TOPIC_POSE, "foxglove.PoseInFrame", POSE_SCHEMA),
    (TOPIC_PAIRED, "rig.PairedWrench", PAIRED_SCHEMA),
    (TOPIC_STAGE, "rig.StageLabel", STAGE_SCHEMA),
    (TOPIC_TRUTH, "rig.TrueWrench", TRUTH_SCHEMA),
];

const TIME: &str = r#"{"type":"object","title":"time","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}}}"#;

const IMAGE_SCHEMA: &str = r#"{"title":"foxglove.CompressedImage","description":"A compressed image","type":"object","properties":{"timestamp":TIME,"frame_id":{"type":"string"},"data":{"type":"string","contentEncoding":"base64"},"format":{"type":"string"},"seq":{"type":"integer","description":"camera sequence number (unwrapped)"}}}"#;

const WRENCH_SCHEMA: &str = r#"{"title":"rig.Wrench","description":"Force (N) and torque (N·mm) in the F/T sensor frame","type":"object","properties":{"timestamp":TIME,"seq":{"type":["integer","null"]},"force_n":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3},"torque_nmm":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3}}}"#;

const POSE_SCHEMA: &str = r#"{"title":"foxglove.PoseInFrame","description":"TCP pose in the robot base frame","type":"object","properties":{"timestamp":TIME,"frame_id":{"type":"string"},"pose":{"type":"object","properties":{"position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}}}}"#;

const PAIRED_SCHEMA: &str = r#"{"title":"rig.PairedWrench","description":"The wrench at a frame's mid-exposure time","type":"object","properties":{"timestamp":TIME,"frame_seq":{"type":"integer"},"force_n":{"type":["array","null"],"items":{"type":"number"}},"torque_nmm":{"type":["array","null"],"items":{"type":"number"}},"sync_error_ns":{"type":["number","null"]},"status":{"type":"string","enum":["ok","held","out_of_range","gap","no_data"]},"stage":{"type":["string","null"]},"tcp_pose":{"type":["array","null"],"items":{"type":"number"},"description":"UR pose [x,y,z (m), rx,ry,rz (rad)]"}}}"#;

const STAGE_SCHEMA: &str = r#"{"title":"rig.StageLabel","description":"The stage that begins at timestamp","type":"object","properties":{"timestamp":TIME,"stage":{"type":"string","enum":["down","shear","reverse","up"]}}}"#;

const TRUTH_SCHEMA: &str = r#"{"title":"rig.TrueWrench","description":"Simulated rig: the simulator's wrench (on the gel, at the indenter tip, surface-frame axes) at a frame's true capture time","type":"object","properties":{"timestamp":TIME,"frame_seq":{"type":"integer"},"force_n":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3},"torque_nmm":{"type":"array","items":{"type":"number"},"minItems":3,"maxItems":3}}}"#;

/// The JSON schema text of a channel (the `TIME` placeholder expanded).
pub fn schema_text(raw: &str) -> String {
    raw.replace("TIME", TIME)
}

/// `{sec, nsec}` of a host-clock time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: u64,
    pub nsec: u32,
}

impl Time {
    pub fn from_ns(t_ns: u64) -> Self {
        Self {
            sec: t_ns / 1_000_000_000,
            nsec: (t_ns % 1_000_000_000) as u32,
        }
    }
    pub fn to_ns(self) -> u64 {
        self.sec
            .saturating_mul(1_000_000_000)
            .saturating_add(self.nsec as u64)
    }
}

/// `foxglove.CompressedImage` in JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ImageMsg {
    pub timestamp: Time,
    pub frame_id: String,
    /// Base64 of the PNG bytes.
    pub data: String,
    pub format: String,
    pub seq: i64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WrenchMsg {
    pub timestamp: Time,
    pub seq: Option<i64>,
    pub force_n: [f64; 3],
    pub torque_nmm: [f64; 3],
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Vec3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Quat {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PoseBody {
    pub position: Vec3,
    pub orientation: Quat,
}

/// `foxglove.PoseInFrame` in JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PoseMsg {
    pub timestamp: Time,
    pub frame_id: String,
    pub pose: PoseBody,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairedMsg {
    pub timestamp: Time,
    pub frame_seq: i64,
    pub force_n: Option<[f64; 3]>,
    pub torque_nmm: Option<[f64; 3]>,
    pub sync_error_ns: Option<f64>,
    pub status: String,
    pub stage: Option<String>,
    pub tcp_pose: Option<[f64; 6]>,
}

/// `rig.TrueWrench` in JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TruthMsg {
    /// The frame's true capture time (simulated clock = host clock).
    pub timestamp: Time,
    pub frame_seq: i64,
    pub force_n: [f64; 3],
    pub torque_nmm: [f64; 3],
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageMsg {
    pub timestamp: Time,
    pub stage: String,
}

/// One thing to record.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// A camera frame, already PNG-encoded (lossless).
    Frame { seq: i64, t_ns: u64, png: Vec<u8> },
    /// A wrench sample at its host time.
    Wrench {
        t_ns: u64,
        seq: Option<i64>,
        wrench: Wrench,
    },
    /// A TCP pose at its host time.
    Pose { t_ns: u64, pose: Pose },
    /// A frame's paired wrench.
    Paired(PairedFrame),
    /// A stage begins.
    Stage { t_ns: u64, stage: StageName },
    /// Simulated rig only: the true wrench at frame `frame_seq`'s capture time `t_ns`.
    Truth {
        frame_seq: i64,
        t_ns: u64,
        wrench: Wrench,
    },
}

impl Record {
    /// Topic, log time (ns) and JSON body.
    pub fn encode(&self) -> (&'static str, u64, Vec<u8>) {
        // Serialising these plain structs to a Vec cannot fail (no maps with non-string keys,
        // no failing Serialize impls); the fallback keeps a bug from becoming a panic.
        fn json<T: Serialize>(v: &T) -> Vec<u8> {
            serde_json::to_vec(v).unwrap_or_else(|_| b"{}".to_vec())
        }
        match self {
            Record::Frame { seq, t_ns, png } => (
                TOPIC_IMAGE,
                *t_ns,
                json(&ImageMsg {
                    timestamp: Time::from_ns(*t_ns),
                    frame_id: "gelsight".into(),
                    data: base64(png),
                    format: "png".into(),
                    seq: *seq,
                }),
            ),
            Record::Wrench { t_ns, seq, wrench } => (
                TOPIC_WRENCH,
                *t_ns,
                json(&WrenchMsg {
                    timestamp: Time::from_ns(*t_ns),
                    seq: *seq,
                    force_n: wrench.force_n,
                    torque_nmm: wrench.torque_nmm,
                }),
            ),
            Record::Pose { t_ns, pose } => {
                let q = pose.quaternion();
                (
                    TOPIC_POSE,
                    *t_ns,
                    json(&PoseMsg {
                        timestamp: Time::from_ns(*t_ns),
                        frame_id: "base".into(),
                        pose: PoseBody {
                            position: Vec3 {
                                x: pose.x,
                                y: pose.y,
                                z: pose.z,
                            },
                            orientation: Quat {
                                x: q.i,
                                y: q.j,
                                z: q.k,
                                w: q.w,
                            },
                        },
                    }),
                )
            }
            Record::Paired(p) => {
                let t_ns = if p.t_frame_ns.is_finite() && p.t_frame_ns > 0.0 {
                    p.t_frame_ns.round() as u64
                } else {
                    0
                };
                (
                    TOPIC_PAIRED,
                    t_ns,
                    json(&PairedMsg {
                        timestamp: Time::from_ns(t_ns),
                        frame_seq: p.frame_seq,
                        force_n: p.wrench.map(|w| w.force_n),
                        torque_nmm: p.wrench.map(|w| w.torque_nmm),
                        sync_error_ns: p.sync_error_ns,
                        status: p.status.as_str().into(),
                        stage: p.stage.map(|s| s.as_str().into()),
                        tcp_pose: p.tcp_pose.map(|q| q.to_array()),
                    }),
                )
            }
            Record::Stage { t_ns, stage } => (
                TOPIC_STAGE,
                *t_ns,
                json(&StageMsg {
                    timestamp: Time::from_ns(*t_ns),
                    stage: stage.as_str().into(),
                }),
            ),
            Record::Truth {
                frame_seq,
                t_ns,
                wrench,
            } => (
                TOPIC_TRUTH,
                *t_ns,
                json(&TruthMsg {
                    timestamp: Time::from_ns(*t_ns),
                    frame_seq: *frame_seq,
                    force_n: wrench.force_n,
                    torque_nmm: wrench.torque_nmm,
                }),
            ),
        }
    }
}

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (c.get(1).copied().unwrap_or(0) as u32) << 8
            | c.get(2).copied().unwrap_or(0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(B64[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Decode standard base64; `None` on a malformed string.
pub fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let s = s.as_bytes();
    if !s.len().is_multiple_of(4) {
        return None;
    }
    let val = |c: u8| B64.iter().position(|&b| b == c).map(|v| v as u32);
    let mut out = Vec::with_capacity(s.len() / 4 * 3);
    for (i, q) in s.chunks(4).enumerate() {
        let last = i == s.len() / 4 - 1;
        let pad = q.iter().rev().take_while(|&&c| c == b'=').count();
        if pad > 2 || (pad > 0 && !last) {
            return None;
        }
        let mut n = 0u32;
        for &c in &q[..4 - pad] {
            n = n << 6 | val(c)?;
        }
        n <<= 6 * pad as u32;
        let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
        out.extend_from_slice(&bytes[..3 - pad]);
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_rfc4648_vectors() {
        for (raw, enc) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(raw.as_bytes()), enc);
            assert_eq!(base64_decode(enc).unwrap(), raw.as_bytes());
        }
        assert_eq!(base64_decode("Zm9v!A=="), None);
    }

    #[test]
    fn schemas_are_valid_json() {
        for (_, _, s) in CHANNELS {
            let v: serde_json::Value = serde_json::from_str(&schema_text(s)).unwrap();
            assert_eq!(v["type"], "object");
        }
    }
}
