//! Files that survive a crash or a power cut: written whole or not at all.
//!
//! [`write_atomic`] writes a temporary beside the target, fsyncs it, renames it over the target
//! and fsyncs the directory, so a reader sees the old file or the new one, never a torn one.
//! The recorder's manifest and trajectory files and the trainer's models, caches and reports
//! all go through here.

use std::fs::{self, File};
use std::io::Write;
use std::path::Path;

/// `fsync` a directory so that a rename in it is durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

/// Write `bytes` to `path` atomically: a temporary beside it, fsync, rename, fsync the directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp"));
    let res = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        fs::rename(&tmp, path)?;
        sync_dir(dir)
    })();
    if res.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    res
}
