//! The channels of a trajectory file: topics, schemas and message bodies.
//!
//! Every channel is protobuf (`message_encoding = "protobuf"`, schema encoding `protobuf`, the
//! schema a serialized `FileDescriptorSet`, see [`super::proto`]):
//! - the frames and the TCP pose use Foxglove's own schemas `foxglove.CompressedImage` and
//!   `foxglove.PoseInFrame`, so Foxglove's Image and 3D panels show them and the image bytes are
//!   stored as bytes (JPEG from an MJPEG camera, untouched; PNG otherwise);
//! - the rig's own channels (`rig.Wrench`, `rig.PairedWrench`, `rig.StageLabel`,
//!   `rig.TrueWrench`) are protobuf too. JSON would do for the small ones, but the wrench runs
//!   at 1 kHz (a protobuf sample is 70 bytes, its JSON 190) and one encoding for every channel
//!   lets any reader decode a whole file with one decoder (the Python `mcap-protobuf-support`
//!   `DecoderFactory`, the rig's [`super::reader`]).
//!
//! All times are host-clock nanoseconds (`t_host_ns` of the rig's clock): `timestamp` fields
//! are `google.protobuf.Timestamp`, and the MCAP `log_time` of every message is the same
//! instant. The frame's camera sequence number is its MCAP message `sequence` (the
//! `CompressedImage` schema has no field for it); `rig.PairedWrench.frame_seq` and
//! `rig.TrueWrench.frame_seq` refer to it. The first recordings were JSON; [`super::legacy`]
//! still reads them.

use rig_core::pose::Pose;
use rig_core::wrench::Wrench;

use super::proto::Enc;
use crate::plan::StageName;
use crate::sync::PairedFrame;

/// Frames as stored (`foxglove.CompressedImage`).
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

/// Message encoding of every channel, and the encoding of their schemas.
pub const ENCODING: &str = "protobuf";

/// Every channel: topic and schema (message type) name.
pub const CHANNELS: [(&str, &str); 6] = [
    (TOPIC_IMAGE, "foxglove.CompressedImage"),
    (TOPIC_WRENCH, "rig.Wrench"),
    (TOPIC_POSE, "foxglove.PoseInFrame"),
    (TOPIC_PAIRED, "rig.PairedWrench"),
    (TOPIC_STAGE, "rig.StageLabel"),
    (TOPIC_TRUTH, "rig.TrueWrench"),
];

/// The schema data of a channel's message type: its serialized `FileDescriptorSet`.
pub fn schema_data(schema_name: &str) -> Vec<u8> {
    // Every name in CHANNELS is described in proto.rs (a unit test checks it).
    super::proto::descriptor_set(schema_name).unwrap_or_default()
}

/// How a frame's image is stored (`foxglove.CompressedImage.format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageFormat {
    /// Lossless PNG: raw-pixel cameras (RGB, YUYV) and the simulated camera.
    Png,
    /// JPEG exactly as an MJPEG camera sent it.
    Jpeg,
}

impl ImageFormat {
    pub fn as_str(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Jpeg => "jpeg",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "png" => Some(ImageFormat::Png),
            "jpeg" | "jpg" => Some(ImageFormat::Jpeg),
            _ => None,
        }
    }
    /// File name extension of an image in this format.
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Jpeg => "jpg",
        }
    }
}

/// One thing to record.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// A camera frame: its image as stored (PNG, or the camera's own JPEG).
    Frame {
        seq: i64,
        t_ns: u64,
        format: ImageFormat,
        data: Vec<u8>,
    },
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
    /// The record's topic.
    pub fn topic(&self) -> &'static str {
        match self {
            Record::Frame { .. } => TOPIC_IMAGE,
            Record::Wrench { .. } => TOPIC_WRENCH,
            Record::Pose { .. } => TOPIC_POSE,
            Record::Paired(_) => TOPIC_PAIRED,
            Record::Stage { .. } => TOPIC_STAGE,
            Record::Truth { .. } => TOPIC_TRUTH,
        }
    }

    /// Topic, log time (ns) and protobuf body.
    pub fn encode(&self) -> (&'static str, u64, Vec<u8>) {
        let topic = self.topic();
        match self {
            Record::Frame {
                t_ns, format, data, ..
            } => {
                let mut e = Enc::with_capacity(data.len() + 48);
                e.timestamp(1, *t_ns);
                e.bytes(2, data);
                e.string(3, format.as_str());
                e.string(4, "gelsight");
                (topic, *t_ns, e.buf)
            }
            Record::Wrench { t_ns, seq, wrench } => {
                let mut e = Enc::with_capacity(80);
                e.timestamp(1, *t_ns);
                e.vector3(2, wrench.force_n);
                e.vector3(3, wrench.torque_nmm);
                if let Some(s) = seq {
                    e.int(4, *s);
                }
                (topic, *t_ns, e.buf)
            }
            Record::Pose { t_ns, pose } => {
                let q = pose.quaternion();
                let mut e = Enc::with_capacity(96);
                e.timestamp(1, *t_ns);
                e.string(2, "base");
                e.message(3, |p| {
                    p.vector3(1, [pose.x, pose.y, pose.z]);
                    p.message(2, |o| {
                        o.double(1, q.i);
                        o.double(2, q.j);
                        o.double(3, q.k);
                        o.double(4, q.w);
                    });
                });
                (topic, *t_ns, e.buf)
            }
            Record::Paired(p) => {
                let t_ns = if p.t_frame_ns.is_finite() && p.t_frame_ns > 0.0 {
                    p.t_frame_ns.round() as u64
                } else {
                    0
                };
                let mut e = Enc::with_capacity(160);
                e.timestamp(1, t_ns);
                e.int(2, p.frame_seq);
                if let Some(w) = p.wrench {
                    e.vector3(3, w.force_n);
                    e.vector3(4, w.torque_nmm);
                }
                if let Some(s) = p.sync_error_ns {
                    e.double(5, s);
                }
                e.string(6, p.status.as_str());
                if let Some(s) = p.stage {
                    e.string(7, s.as_str());
                }
                if let Some(q) = p.tcp_pose {
                    e.packed_doubles(8, &q.to_array());
                }
                (topic, t_ns, e.buf)
            }
            Record::Stage { t_ns, stage } => {
                let mut e = Enc::with_capacity(24);
                e.timestamp(1, *t_ns);
                e.string(2, stage.as_str());
                (topic, *t_ns, e.buf)
            }
            Record::Truth {
                frame_seq,
                t_ns,
                wrench,
            } => {
                let mut e = Enc::with_capacity(80);
                e.timestamp(1, *t_ns);
                e.int(2, *frame_seq);
                e.vector3(3, wrench.force_n);
                e.vector3(4, wrench.torque_nmm);
                (topic, *t_ns, e.buf)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_channel_has_a_descriptor() {
        for (_, schema) in CHANNELS {
            assert!(!schema_data(schema).is_empty(), "{schema}");
        }
    }

    #[test]
    fn formats_parse_back() {
        for f in [ImageFormat::Png, ImageFormat::Jpeg] {
            assert_eq!(ImageFormat::parse(f.as_str()), Some(f));
        }
        assert_eq!(ImageFormat::parse("webp"), None);
    }
}
