//! Reading a trajectory file back: the one reader of recordings, used by `rig dataset check`,
//! `--resume` and the trainer.
//!
//! [`read_file`] reads a file completely (every record parsed, every message decoded, the
//! summary's counts cross-checked) into [`FileContents`]; [`messages`] yields the decoded
//! messages one by one, frames with their image bytes (PNG or JPEG, as stored), for readers
//! that keep the images.
//!
//! Both recording formats read: each message is decoded by its channel's message encoding,
//! `protobuf` (today's files, [`super::channels`]) or `json` (the first format,
//! [`super::legacy`]; unchunked files of JSON messages). Chunked files are read chunk by chunk
//! (zstd decompressed, CRCs checked).

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use rig_core::wrench::Wrench;

use super::channels::{
    ImageFormat, TOPIC_IMAGE, TOPIC_PAIRED, TOPIC_POSE, TOPIC_STAGE, TOPIC_TRUTH, TOPIC_WRENCH,
};
use super::legacy;
use super::manifest::Counts;
use super::proto::fields;

/// What a complete trajectory file holds.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct FileContents {
    pub counts: Counts,
    /// Topics found, with their schema names.
    pub channels: BTreeMap<String, String>,
    /// Sync error (ns) of every paired frame that has one.
    pub sync_errors_ns: Vec<f64>,
    /// Paired frames whose wrench was refused or held, by status.
    pub paired_status: BTreeMap<String, u64>,
    /// Frame sequence numbers in file order.
    pub frame_seqs: Vec<i64>,
    /// Wrench counter values in file order (when the device has a counter).
    pub wrench_seqs: Vec<i64>,
    /// Log times of wrench messages, ns.
    pub wrench_times_ns: Vec<u64>,
    /// Every paired-wrench message in file order: its frame and its wrench (absent when the
    /// pairing was refused).
    pub paired: Vec<PairedRead>,
    /// Simulated rig only: every true-wrench message in file order (one per frame).
    pub truth: Vec<TruthRead>,
    /// The MCAP summary's message count per topic (cross-check of the linear read).
    pub summary_counts: BTreeMap<String, u64>,
    /// Message encoding per topic (`protobuf`, or `json` in the first format).
    pub encodings: BTreeMap<String, String>,
    /// Chunks in the summary's chunk index (0: an unchunked file of the first format).
    pub chunks: usize,
}

/// One `/sync/paired_wrench` message as read back: the frame it belongs to and its wrench.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PairedRead {
    pub frame_seq: i64,
    /// Force, N (`None` when the pairing was refused).
    pub force_n: Option<[f64; 3]>,
    /// Torque, N·mm (`None` when the pairing was refused).
    pub torque_nmm: Option<[f64; 3]>,
}

/// One `/sim/true_wrench` message as read back: the simulator's wrench at the frame's true
/// capture time.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TruthRead {
    pub frame_seq: i64,
    pub wrench: Wrench,
}

/// Read a trajectory file completely: every record parsed, every message decoded.
pub fn read_file(path: &Path) -> Result<FileContents, String> {
    let bytes = fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    read_bytes(&bytes)
}

/// [`read_file`] over bytes in memory.
pub fn read_bytes(bytes: &[u8]) -> Result<FileContents, String> {
    let summary = mcap::read::Summary::read(bytes)
        .map_err(|e| format!("unreadable MCAP summary: {e}"))?
        .ok_or("no MCAP summary section (file not finished)")?;
    let mut out = FileContents::default();
    if let Some(stats) = &summary.stats {
        for (cid, n) in &stats.channel_message_counts {
            if let Some(ch) = summary.channels.get(cid) {
                out.summary_counts.insert(ch.topic.clone(), *n);
            }
        }
    }
    for ch in summary.channels.values() {
        let schema = ch
            .schema
            .as_ref()
            .map(|s| s.name.clone())
            .unwrap_or_default();
        out.channels.insert(ch.topic.clone(), schema);
        out.encodings
            .insert(ch.topic.clone(), ch.message_encoding.clone());
    }
    out.chunks = summary.chunk_indexes.len();
    for msg in messages(bytes)? {
        match msg? {
            Message::Frame { seq, .. } => {
                out.frame_seqs.push(seq);
                out.counts.frames += 1;
            }
            Message::Wrench { seq, log_time_ns } => {
                if let Some(s) = seq {
                    out.wrench_seqs.push(s);
                }
                out.wrench_times_ns.push(log_time_ns);
                out.counts.wrench += 1;
            }
            Message::Pose => out.counts.poses += 1,
            Message::Paired(m) => {
                if let Some(e) = m.sync_error_ns {
                    out.sync_errors_ns.push(e);
                }
                *out.paired_status.entry(m.status).or_default() += 1;
                out.paired.push(PairedRead {
                    frame_seq: m.frame_seq,
                    force_n: m.force_n,
                    torque_nmm: m.torque_nmm,
                });
                out.counts.paired += 1;
            }
            Message::Stage => out.counts.stages += 1,
            Message::Truth(t) => {
                out.truth.push(t);
                out.counts.truth += 1;
            }
        }
    }
    for (topic, n) in &out.summary_counts {
        let seen = out.counts.of_topic(topic);
        if seen != *n {
            return Err(format!(
                "summary says {n} messages on {topic}, the file holds {seen}"
            ));
        }
    }
    Ok(out)
}

/// A `/sync/paired_wrench` message, decoded (either format).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Paired {
    /// The frame's capture time, host ns (the message's timestamp).
    pub t_ns: u64,
    pub frame_seq: i64,
    /// Force, N (`None` when the pairing was refused).
    pub force_n: Option<[f64; 3]>,
    /// Torque, N·mm (`None` when the pairing was refused).
    pub torque_nmm: Option<[f64; 3]>,
    pub sync_error_ns: Option<f64>,
    /// `ok`, `held`, `out_of_range`, `gap` or `no_data`.
    pub status: String,
    /// `down`, `shear`, `reverse` or `up`.
    pub stage: Option<String>,
    /// UR pose `[x, y, z (m), rx, ry, rz (rad)]` at the frame's time.
    pub tcp_pose: Option<[f64; 6]>,
}

/// One message of a trajectory file, decoded.
#[derive(Debug, Clone)]
pub enum Message {
    /// A camera frame: its sequence number, time (host ns) and image as stored.
    Frame {
        seq: i64,
        t_ns: u64,
        format: ImageFormat,
        data: Vec<u8>,
    },
    /// A wrench sample: its device counter (when the device has one) and its log time, ns.
    Wrench { seq: Option<i64>, log_time_ns: u64 },
    /// A TCP pose.
    Pose,
    /// A frame's paired wrench.
    Paired(Paired),
    /// A stage label.
    Stage,
    /// Simulated rig only: the true wrench at a frame's true capture time.
    Truth(TruthRead),
}

/// The messages of a trajectory file in file order, each decoded; an error names the record or
/// message that is wrong.
pub fn messages(
    bytes: &[u8],
) -> Result<impl Iterator<Item = Result<Message, String>> + '_, String> {
    messages_on(bytes, |_| true)
}

/// [`messages`] on the topics `keep` accepts only: the others' records are still read (a
/// corrupt record is an error) but their messages are not decoded.
pub fn messages_on<'a>(
    bytes: &'a [u8],
    keep: impl Fn(&str) -> bool + 'a,
) -> Result<impl Iterator<Item = Result<Message, String>> + 'a, String> {
    let stream =
        mcap::read::MessageStream::new(bytes).map_err(|e| format!("unreadable MCAP: {e}"))?;
    Ok(stream.filter_map(move |msg| match msg {
        Err(e) => Some(Err(format!("corrupt MCAP record: {e}"))),
        Ok(msg) => keep(&msg.channel.topic).then(|| {
            let topic = &msg.channel.topic;
            match msg.channel.message_encoding.as_str() {
                "protobuf" => decode_proto(topic, &msg.data, msg.sequence, msg.log_time),
                "json" => decode_json(topic, &msg.data, msg.log_time),
                other => Err(format!("{topic}: unknown message encoding {other:?}")),
            }
        }),
    }))
}

fn decode_proto(
    topic: &str,
    data: &[u8],
    sequence: u32,
    log_time_ns: u64,
) -> Result<Message, String> {
    let bad = |e: String| format!("bad {topic} message: {e}");
    let mut t_ns = log_time_ns;
    Ok(match topic {
        TOPIC_IMAGE => {
            let (mut bytes, mut format) = (Vec::new(), String::new());
            for f in fields(data) {
                match f.map_err(bad)? {
                    (1, v) => t_ns = v.timestamp_ns().map_err(bad)?,
                    (2, v) => bytes = v.as_bytes().map_err(bad)?.to_vec(),
                    (3, v) => format = v.as_str().map_err(bad)?.to_owned(),
                    _ => {}
                }
            }
            let format = ImageFormat::parse(&format).ok_or_else(|| {
                format!("frame {sequence}: image format {format:?} is neither png nor jpeg")
            })?;
            Message::Frame {
                seq: i64::from(sequence),
                t_ns,
                format,
                data: bytes,
            }
        }
        TOPIC_WRENCH => {
            let mut seq = None;
            for f in fields(data) {
                match f.map_err(bad)? {
                    (1, v) => {
                        v.timestamp_ns().map_err(bad)?;
                    }
                    (2 | 3, v) => {
                        v.vector3().map_err(bad)?;
                    }
                    (4, v) => seq = Some(v.as_i64().map_err(bad)?),
                    _ => {}
                }
            }
            Message::Wrench { seq, log_time_ns }
        }
        TOPIC_POSE => {
            for f in fields(data) {
                if let (1, v) = f.map_err(bad)? {
                    v.timestamp_ns().map_err(bad)?;
                }
            }
            Message::Pose
        }
        TOPIC_PAIRED => {
            let mut p = Paired {
                t_ns,
                frame_seq: 0,
                force_n: None,
                torque_nmm: None,
                sync_error_ns: None,
                status: String::new(),
                stage: None,
                tcp_pose: None,
            };
            let mut pose = Vec::new();
            for f in fields(data) {
                match f.map_err(bad)? {
                    (1, v) => p.t_ns = v.timestamp_ns().map_err(bad)?,
                    (2, v) => p.frame_seq = v.as_i64().map_err(bad)?,
                    (3, v) => p.force_n = Some(v.vector3().map_err(bad)?),
                    (4, v) => p.torque_nmm = Some(v.vector3().map_err(bad)?),
                    (5, v) => p.sync_error_ns = Some(v.as_f64().map_err(bad)?),
                    (6, v) => p.status = v.as_str().map_err(bad)?.to_owned(),
                    (7, v) => p.stage = Some(v.as_str().map_err(bad)?.to_owned()),
                    (8, v) => v.doubles(&mut pose).map_err(bad)?,
                    _ => {}
                }
            }
            p.tcp_pose = match pose.len() {
                0 => None,
                6 => Some([pose[0], pose[1], pose[2], pose[3], pose[4], pose[5]]),
                n => return Err(bad(format!("tcp_pose has {n} values, not 6"))),
            };
            Message::Paired(p)
        }
        TOPIC_STAGE => {
            for f in fields(data) {
                f.map_err(bad)?;
            }
            Message::Stage
        }
        TOPIC_TRUTH => {
            let mut t = TruthRead {
                frame_seq: 0,
                wrench: Wrench::default(),
            };
            for f in fields(data) {
                match f.map_err(bad)? {
                    (2, v) => t.frame_seq = v.as_i64().map_err(bad)?,
                    (3, v) => t.wrench.force_n = v.vector3().map_err(bad)?,
                    (4, v) => t.wrench.torque_nmm = v.vector3().map_err(bad)?,
                    _ => {}
                }
            }
            Message::Truth(t)
        }
        other => return Err(format!("unexpected channel {other}")),
    })
}

fn decode_json(topic: &str, data: &[u8], log_time_ns: u64) -> Result<Message, String> {
    let bad = |e: serde_json::Error| format!("bad {topic} message: {e}");
    Ok(match topic {
        TOPIC_IMAGE => {
            let m: legacy::ImageMsg = serde_json::from_slice(data).map_err(bad)?;
            let png = (m.format == "png")
                .then(|| legacy::base64_decode(&m.data))
                .flatten()
                .ok_or_else(|| format!("frame {} is not base64 PNG", m.seq))?;
            Message::Frame {
                seq: m.seq,
                t_ns: m.timestamp.to_ns(),
                format: ImageFormat::Png,
                data: png,
            }
        }
        TOPIC_WRENCH => {
            let m: legacy::WrenchMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Wrench {
                seq: m.seq,
                log_time_ns,
            }
        }
        TOPIC_POSE => {
            let _: legacy::PoseMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Pose
        }
        TOPIC_PAIRED => {
            let m: legacy::PairedMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Paired(Paired {
                t_ns: m.timestamp.to_ns(),
                frame_seq: m.frame_seq,
                force_n: m.force_n,
                torque_nmm: m.torque_nmm,
                sync_error_ns: m.sync_error_ns,
                status: m.status,
                stage: m.stage,
                tcp_pose: m.tcp_pose,
            })
        }
        TOPIC_STAGE => {
            let _: legacy::StageMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Stage
        }
        TOPIC_TRUTH => {
            let m: legacy::TruthMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Truth(TruthRead {
                frame_seq: m.frame_seq,
                wrench: Wrench {
                    force_n: m.force_n,
                    torque_nmm: m.torque_nmm,
                },
            })
        }
        other => return Err(format!("unexpected channel {other}")),
    })
}
