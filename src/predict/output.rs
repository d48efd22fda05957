//! Where `rig predict`'s estimates go: JSON or CSV lines on stdout, an MCAP file, the live
//! view's `/predict/wrench` channel.
//!
//! The MCAP file is written with the `mcap` crate directly, the way [`crate::record::writer`]
//! writes trajectories (uncompressed, unchunked, JSON messages with a JSON schema, written as
//! `<file>.partial` and renamed when complete), because the recorder's writer declares the
//! recording's fixed channels only and has no place for an estimate. It holds one channel,
//! `/predict/wrench` ([`PREDICTED_SCHEMA_NAME`]); the Foxglove app opens it beside the
//! recording it came from.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use serde::Serialize;

use super::{Estimate, Truth};
use crate::live::{ExtraChannel, LiveView};
use crate::record::legacy::Time;

/// The predicted force's topic (live view and MCAP file).
pub const TOPIC_PREDICTED: &str = "/predict/wrench";
pub const PREDICTED_SCHEMA_NAME: &str = "rig.PredictedWrench";
const PREDICTED_SCHEMA: &str = r#"{
  "type": "object",
  "title": "rig.PredictedWrench",
  "description": "The force model's estimate for one camera frame (rig predict), N",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
    "frame_seq": {"type": "integer"},
    "force_n": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
    "raw_force_n": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
  }
}"#;

/// The live view's channel of estimates.
pub fn predicted_channel() -> ExtraChannel {
    ExtraChannel {
        topic: TOPIC_PREDICTED.into(),
        schema_name: PREDICTED_SCHEMA_NAME.into(),
        schema: PREDICTED_SCHEMA.into(),
    }
}

/// `rig.PredictedWrench` in JSON.
#[derive(Debug, Clone, Serialize)]
struct PredictedMsg<'a> {
    timestamp: Time,
    frame_seq: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    trajectory: Option<&'a str>,
    force_n: [f64; 3],
    raw_force_n: [f64; 3],
}

/// One estimate with what is known of its frame.
#[derive(Debug, Clone, Copy)]
pub struct Row<'a> {
    pub traj_id: Option<&'a str>,
    pub seq: i64,
    pub estimate: &'a Estimate,
    pub truth: &'a Truth,
}

/// Lines on stdout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// One JSON object per line.
    Json,
    /// CSV with a header line.
    Csv,
    /// Nothing (the summary only).
    Quiet,
}

pub const CSV_HEADER: &str = "t_ns,trajectory,seq,fx_n,fy_n,fz_n,paired_fx_n,paired_fy_n,\
                              paired_fz_n,true_fx_n,true_fy_n,true_fz_n";

/// Where estimates go.
pub struct Output {
    format: Format,
    lines: Box<dyn Write + Send>,
    header_done: bool,
    mcap: Option<McapOut>,
    live: Option<Arc<LiveView>>,
}

struct McapOut {
    partial: PathBuf,
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    channel: u16,
    sequence: u32,
}

impl Output {
    /// Lines in `format` to `lines`.
    pub fn new(format: Format, lines: Box<dyn Write + Send>) -> Self {
        Self {
            format,
            lines,
            header_done: false,
            mcap: None,
            live: None,
        }
    }

    /// Also into an MCAP file at `path` (written as `<path>.partial`, renamed by
    /// [`Self::finish`]).
    pub fn with_mcap(mut self, path: &Path) -> anyhow::Result<Self> {
        let name = path
            .file_name()
            .with_context(|| format!("--out {}: not a file name", path.display()))?;
        let partial = path.with_file_name(format!("{}.partial", name.to_string_lossy()));
        let file = File::create(&partial)
            .with_context(|| format!("cannot create {}", partial.display()))?;
        let mcap_err = |e: mcap::McapError| anyhow::anyhow!("{}: {e}", partial.display());
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .use_chunks(false)
            .profile("")
            .library(concat!("transforce-rig/", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 16, file))
            .map_err(mcap_err)?;
        let schema = writer
            .add_schema(
                PREDICTED_SCHEMA_NAME,
                "jsonschema",
                PREDICTED_SCHEMA.as_bytes(),
            )
            .map_err(mcap_err)?;
        let channel = writer
            .add_channel(schema, TOPIC_PREDICTED, "json", &BTreeMap::new())
            .map_err(mcap_err)?;
        self.mcap = Some(McapOut {
            partial,
            path: path.to_owned(),
            writer,
            channel,
            sequence: 0,
        });
        Ok(self)
    }

    /// Also to the live view's [`TOPIC_PREDICTED`] (started with [`predicted_channel`]).
    pub fn with_live(mut self, live: Arc<LiveView>) -> Self {
        self.live = Some(live);
        self
    }

    /// One estimate to every destination.
    pub fn emit(&mut self, row: &Row) -> anyhow::Result<()> {
        let e = row.estimate;
        match self.format {
            Format::Quiet => {}
            Format::Json => {
                let line = serde_json::json!({
                    "t_ns": e.t_ns,
                    "trajectory": row.traj_id,
                    "seq": row.seq,
                    "force_n": e.force_n,
                    "raw_force_n": e.raw_force_n,
                    "paired_force_n": row.truth.paired,
                    "true_force_n": row.truth.sim,
                });
                writeln!(self.lines, "{line}")?;
            }
            Format::Csv => {
                if !self.header_done {
                    writeln!(self.lines, "{CSV_HEADER}")?;
                    self.header_done = true;
                }
                let opt = |v: Option<[f64; 3]>| match v {
                    Some(f) => format!("{:.5},{:.5},{:.5}", f[0], f[1], f[2]),
                    None => ",,".into(),
                };
                writeln!(
                    self.lines,
                    "{},{},{},{:.5},{:.5},{:.5},{},{}",
                    e.t_ns,
                    row.traj_id.unwrap_or(""),
                    row.seq,
                    e.force_n[0],
                    e.force_n[1],
                    e.force_n[2],
                    opt(row.truth.paired),
                    opt(row.truth.sim)
                )?;
            }
        }
        if self.mcap.is_none() && self.live.is_none() {
            return Ok(());
        }
        let body = serde_json::to_vec(&PredictedMsg {
            timestamp: Time::from_ns(e.t_ns),
            frame_seq: row.seq,
            trajectory: row.traj_id,
            force_n: e.force_n,
            raw_force_n: e.raw_force_n,
        })?;
        if let Some(live) = &self.live {
            live.publish_extra(TOPIC_PREDICTED, e.t_ns, &body);
        }
        if let Some(m) = &mut self.mcap {
            m.sequence = m.sequence.wrapping_add(1);
            m.writer
                .write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: m.channel,
                        sequence: m.sequence,
                        log_time: e.t_ns,
                        publish_time: e.t_ns,
                    },
                    &body,
                )
                .map_err(|err| anyhow::anyhow!("{}: {err}", m.partial.display()))?;
        }
        Ok(())
    }

    /// Flushes the lines and completes the MCAP file.
    pub fn finish(&mut self) -> anyhow::Result<()> {
        self.lines.flush()?;
        if let Some(mut m) = self.mcap.take() {
            m.writer
                .finish()
                .map_err(|e| anyhow::anyhow!("{}: {e}", m.partial.display()))?;
            let file = m
                .writer
                .into_inner()
                .into_inner()
                .map_err(|e| e.into_error())?;
            file.sync_all()?;
            std::fs::rename(&m.partial, &m.path)
                .with_context(|| format!("cannot rename to {}", m.path.display()))?;
        }
        Ok(())
    }
}
