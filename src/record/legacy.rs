//! The first recording format (before issue 16), kept for reading: every channel JSON with a
//! `jsonschema` schema, frames as base64 PNG inside JSON, unchunked files. [`super::reader`]
//! decodes a channel with these types when its message encoding is `json`; nothing writes
//! this format any more (`tests/data/legacy-json` holds files it wrote). Its [`base64`] also
//! encodes the live view's protobuf schemas.

use serde::{Deserialize, Serialize};

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
}
