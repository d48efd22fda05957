//! The trainer's decode cache: each recorded trajectory's frames, prepared for one image spec
//! (size, modality, zoom), and their paired forces, kept beside the recording in
//! `.trainer-cache/` so that a second run of any command skips the JPEG/PNG decoding and the
//! marker work. An entry is keyed by the file's length and modification time; a stale,
//! truncated or foreign entry is ignored and rewritten.

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use super::images::ImageSpec;

const DIR: &str = ".trainer-cache";
/// Version 2: R and M derived at the network's size (version 1 derived them from the full
/// frame). Version 3: D+S's shading over the whole view (`SHADING_VIEW_MM`). Older caches are
/// rebuilt.
const MAGIC: &[u8; 8] = b"RIGCACH3";

/// A cache entry: pixels, frame count, forces.
pub(super) type Cached = (Vec<u8>, usize, Option<Vec<[f32; 3]>>);
/// What an entry is valid for: the recording's length and modification time (ns).
pub(super) type Stamp = (u64, u64);

/// The recording's [`Stamp`].
pub(super) fn stamp(path: &Path) -> std::io::Result<Stamp> {
    let meta = fs::metadata(path)?;
    Ok((
        meta.len(),
        meta.modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos() as u64),
    ))
}

/// Where trajectory `id` of the recording at `path` is cached for `spec` (and `zoom`; all its
/// frames when `every_frame`, else the paired ones).
pub(super) fn path_for(
    path: &Path,
    id: &str,
    spec: &ImageSpec,
    zoom: f64,
    every_frame: bool,
) -> PathBuf {
    path.parent()
        .unwrap_or(Path::new("."))
        .join(DIR)
        .join(format!(
            "{id}-{}x{}-{}{}{}.bin",
            spec.width,
            spec.height,
            spec.modality.name().replace('+', "_"),
            if zoom == 1.0 {
                String::new()
            } else {
                format!("-zoom{zoom:.4}")
            },
            if every_frame { "-unpaired" } else { "" }
        ))
}

pub(super) fn read(path: &Path, stamp: Stamp, spec: &ImageSpec) -> Option<Cached> {
    let mut f = fs::File::open(path).ok()?;
    let mut buf = Vec::new();
    f.read_to_end(&mut buf).ok()?;
    let head = 8 + 8 * 3 + 4 * 2;
    if buf.len() < head || &buf[..8] != MAGIC {
        return None;
    }
    let u64_at = |o: usize| u64::from_le_bytes(buf[o..o + 8].try_into().expect("8 bytes"));
    let (len, mtime, frames) = (u64_at(8), u64_at(16), u64_at(24) as usize);
    let w = u32::from_le_bytes(buf[32..36].try_into().ok()?);
    let h = u32::from_le_bytes(buf[36..40].try_into().ok()?);
    if (len, mtime) != stamp || (w, h) != (spec.width, spec.height) {
        return None;
    }
    let px = frames.checked_mul(spec.frame_bytes())?;
    // Forces follow the pixels, or none at all (frames recorded without an F/T sensor).
    let labelled = buf.len() == head + px + frames * 12;
    if !labelled && buf.len() != head + px {
        return None;
    }
    let pixels = buf[head..head + px].to_vec();
    if !labelled {
        return Some((pixels, frames, None));
    }
    let forces = buf[head + px..]
        .chunks_exact(12)
        .map(|c| {
            let v = |k: usize| f32::from_le_bytes(c[k * 4..k * 4 + 4].try_into().expect("4 bytes"));
            [v(0), v(1), v(2)]
        })
        .collect();
    Some((pixels, frames, Some(forces)))
}

/// Best effort: a cache that cannot be written only costs decoding time next run.
pub(super) fn write(
    path: &Path,
    stamp: Stamp,
    spec: &ImageSpec,
    pixels: &[u8],
    frames: usize,
    forces: &[[f32; 3]],
) {
    let mut buf = Vec::with_capacity(40 + pixels.len() + forces.len() * 12);
    buf.extend_from_slice(MAGIC);
    for v in [stamp.0, stamp.1, frames as u64] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    buf.extend_from_slice(&spec.width.to_le_bytes());
    buf.extend_from_slice(&spec.height.to_le_bytes());
    buf.extend_from_slice(pixels);
    for f in forces {
        for v in f {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    if let Some(dir) = path.parent() {
        let _ = fs::create_dir_all(dir);
    }
    let _ = crate::durable::write_atomic(path, &buf);
}
