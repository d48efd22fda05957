//! Reading a trajectory file back: the one reader of recordings, used by `rig dataset check`,
//! `--resume` and the trainer.
//!
//! [`read_file`] reads a file completely (every record parsed, every message decoded, the
//! summary's counts cross-checked) into [`FileContents`]; [`messages`] yields the decoded
//! messages one by one, frames with their PNG bytes, for readers that keep the images.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use rig_core::wrench::Wrench;

use super::channels::{self, PairedMsg, TOPIC_IMAGE, TOPIC_PAIRED};
use super::manifest::Counts;

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
    }
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

/// One message of a trajectory file, decoded.
#[derive(Debug, Clone)]
pub enum Message {
    /// A camera frame: its sequence number and its PNG bytes.
    Frame { seq: i64, png: Vec<u8> },
    /// A wrench sample: its device counter (when the device has one) and its log time, ns.
    Wrench { seq: Option<i64>, log_time_ns: u64 },
    /// A TCP pose.
    Pose,
    /// A frame's paired wrench.
    Paired(PairedMsg),
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
        Ok(msg) => {
            keep(&msg.channel.topic).then(|| decode(&msg.channel.topic, &msg.data, msg.log_time))
        }
    }))
}

fn decode(topic: &str, data: &[u8], log_time_ns: u64) -> Result<Message, String> {
    let bad = |e: serde_json::Error| format!("bad {topic} message: {e}");
    Ok(match topic {
        TOPIC_IMAGE => {
            let m: channels::ImageMsg = serde_json::from_slice(data).map_err(bad)?;
            let png = (m.format == "png")
                .then(|| channels::base64_decode(&m.data))
                .flatten()
                .ok_or_else(|| format!("frame {} is not base64 PNG", m.seq))?;
            Message::Frame { seq: m.seq, png }
        }
        channels::TOPIC_WRENCH => {
            let m: channels::WrenchMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Wrench {
                seq: m.seq,
                log_time_ns,
            }
        }
        channels::TOPIC_POSE => {
            let _: channels::PoseMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Pose
        }
        TOPIC_PAIRED => Message::Paired(serde_json::from_slice(data).map_err(bad)?),
        channels::TOPIC_STAGE => {
            let _: channels::StageMsg = serde_json::from_slice(data).map_err(bad)?;
            Message::Stage
        }
        channels::TOPIC_TRUTH => {
            let m: channels::TruthMsg = serde_json::from_slice(data).map_err(bad)?;
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
