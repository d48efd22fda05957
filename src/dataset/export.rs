//! `rig dataset export DIR --format folder [--out DIR]`: a recorded dataset in the layout other
//! tools read.
//!
//! `folder` (the layout the TransForce authors' public code reads: images and a force table per
//! trajectory) writes, for every complete trajectory of the manifest:
//!
//! ```text
//! OUT/<trajectory>/images/000000.png   every frame in file order, as stored (PNG, or the
//!                                      MJPEG camera's JPEG as .jpg), byte for byte
//! OUT/<trajectory>/force.csv           one row per frame, in the same order
//! ```
//!
//! `force.csv` columns: `frame` (the camera sequence number), `image` (file name under
//! `images/`), `t_ns` (the frame's capture time on the host clock, ns), `fx_n, fy_n, fz_n`,
//! `mx_nmm, my_nmm, mz_nmm` (the frame's paired wrench, N and N·mm, at the indenter tip),
//! `stage` (down, shear, reverse, up), `status` (the pairing: ok, held, …), `tcp_x_m, tcp_y_m,
//! tcp_z_m, tcp_rx_rad, tcp_ry_rad, tcp_rz_rad` (the UR TCP pose then). Cells are empty where the
//! recording has no value (a refused pairing has no wrench). Numbers are written with Rust's
//! shortest round-trip formatting, so they read back exactly.
//!
//! The output directory must not exist yet or be empty: an export never mixes with an older
//! one. Failed or pending trajectories are skipped and listed.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use crate::record::reader::{Message, Paired, messages};
use crate::record::{ImageFormat, Manifest, Status};

/// Export layouts (`--format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ExportFormat {
    /// One directory per trajectory: `images/` and `force.csv`.
    Folder,
}

/// What an export wrote.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ExportReport {
    pub out: PathBuf,
    /// Per exported trajectory: id and frames written.
    pub trajectories: Vec<(String, usize)>,
    /// Trajectories not exported (not complete): id and status.
    pub skipped: Vec<(String, String)>,
}

/// The CSV header of `force.csv`.
pub const CSV_HEADER: &str = "frame,image,t_ns,fx_n,fy_n,fz_n,mx_nmm,my_nmm,mz_nmm,stage,status,\
tcp_x_m,tcp_y_m,tcp_z_m,tcp_rx_rad,tcp_ry_rad,tcp_rz_rad";

/// The default output directory: `<DIR>-<format>` beside the dataset.
pub fn default_out(dir: &Path, format: ExportFormat) -> PathBuf {
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".into());
    let suffix = match format {
        ExportFormat::Folder => "folder",
    };
    dir.with_file_name(format!("{name}-{suffix}"))
}

/// Export the dataset in `dir` to `out`.
pub fn export(dir: &Path, out: &Path, format: ExportFormat) -> anyhow::Result<ExportReport> {
    let manifest = Manifest::load(dir).map_err(|e| {
        anyhow::anyhow!("{e}; `rig dataset export` needs a `rig run` output directory")
    })?;
    if out.exists()
        && std::fs::read_dir(out)
            .with_context(|| format!("cannot read {}", out.display()))?
            .next()
            .is_some()
    {
        bail!(
            "{} exists and is not empty: choose another --out or remove it",
            out.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut report = ExportReport {
        out: out.to_owned(),
        ..Default::default()
    };
    for entry in &manifest.trajectories {
        let file = match (&entry.status, &entry.file) {
            (Status::Complete, Some(f)) => f,
            (status, _) => {
                report
                    .skipped
                    .push((entry.id.clone(), format!("{status:?}").to_lowercase()));
                continue;
            }
        };
        let n = match format {
            ExportFormat::Folder => export_folder(&dir.join(file), &out.join(&entry.id))
                .with_context(|| {
                    format!(
                        "exporting trajectory {} ({})",
                        entry.id,
                        dir.join(file).display()
                    )
                })?,
        };
        report.trajectories.push((entry.id.clone(), n));
    }
    Ok(report)
}

fn cell(out: &mut String, v: Option<f64>) {
    out.push(',');
    if let Some(v) = v {
        let _ = write!(out, "{v}");
    }
}

/// One trajectory as `images/` and `force.csv` in `dest`; returns the frames written.
fn export_folder(file: &Path, dest: &Path) -> anyhow::Result<usize> {
    let bytes = std::fs::read(file).context("cannot read the trajectory file")?;
    let images = dest.join("images");
    std::fs::create_dir_all(&images)
        .with_context(|| format!("cannot create {}", images.display()))?;
    let mut frames: Vec<(i64, u64, String)> = Vec::new();
    let mut paired: BTreeMap<i64, Paired> = BTreeMap::new();
    for msg in messages(&bytes).map_err(anyhow::Error::msg)? {
        match msg.map_err(anyhow::Error::msg)? {
            Message::Frame {
                seq,
                t_ns,
                format,
                data,
            } => {
                let name = format!("{:06}.{}", frames.len(), extension(format));
                std::fs::write(images.join(&name), &data)
                    .with_context(|| format!("cannot write {}", images.join(&name).display()))?;
                frames.push((seq, t_ns, name));
            }
            Message::Paired(p) => {
                paired.insert(p.frame_seq, p);
            }
            _ => {}
        }
    }
    let mut csv = String::with_capacity(160 * (frames.len() + 1));
    csv.push_str(CSV_HEADER);
    csv.push('\n');
    for (seq, t_frame, name) in &frames {
        let p = paired.get(seq);
        let _ = write!(csv, "{seq},{name},{}", p.map_or(*t_frame, |p| p.t_ns));
        for k in 0..3 {
            cell(&mut csv, p.and_then(|p| p.force_n).map(|f| f[k]));
        }
        for k in 0..3 {
            cell(&mut csv, p.and_then(|p| p.torque_nmm).map(|t| t[k]));
        }
        let _ = write!(
            csv,
            ",{},{}",
            p.and_then(|p| p.stage.as_deref()).unwrap_or(""),
            p.map_or("", |p| p.status.as_str())
        );
        for k in 0..6 {
            cell(&mut csv, p.and_then(|p| p.tcp_pose).map(|q| q[k]));
        }
        csv.push('\n');
    }
    let path = dest.join("force.csv");
    std::fs::write(&path, csv).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(frames.len())
}

fn extension(f: ImageFormat) -> &'static str {
    f.extension()
}
