//! Files that survive a crash or a power cut: written whole or not at all.
//!
//! [`write_atomic`] writes a temporary beside the target, fsyncs it, renames it over the target
//! and fsyncs the directory, so a reader sees the old file or the new one, never a torn one.
//! The recorder's manifest and trajectory files and the trainer's models, caches and reports
//! all go through here.
//!
//! [`FileSet`] does the same for several files that belong together (a trainer checkpoint:
//! weights, resume weights, optimiser state and description): after a crash the directory
//! holds the old set or the new one, never files of two epochs.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;

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

/// Files of one directory replaced together, as one.
///
/// [`FileSet::replace`] has the new files written into a staging directory inside the set's
/// directory ([`FileSet::STAGING`], a `.tmp`), fsyncs each and the staging directory, and
/// renames it to [`FileSet::READY`]: that rename is the commit. Then each file is renamed over
/// its old one (the `last` one last, so a reader of the plain files sees the description change
/// after the rest) and the emptied directory removed, with the directory fsynced after each
/// step.
///
/// After a crash, [`FileSet::recover`] removes a staging directory (an incomplete set: the old
/// one is still in place) and finishes installing a ready one (complete, perhaps partly
/// installed). Until then [`FileSet::path`] reads a consistent set without changing anything:
/// a file of the ready set where there is one, the installed one otherwise. Only the set's
/// writer (one process) may call `replace` or `recover`.
#[derive(Debug, Clone, Copy)]
pub struct FileSet<'a> {
    dir: &'a Path,
    last: &'a str,
}

impl<'a> FileSet<'a> {
    /// The staging directory of a set being written; a leftover is incomplete and removed.
    pub const STAGING: &'static str = ".next.tmp";
    /// A complete set whose files are being moved into place.
    pub const READY: &'static str = ".next.ready";

    /// The set of files in `dir`; `last` is the file installed last (the set's description).
    pub fn new(dir: &'a Path, last: &'a str) -> Self {
        Self { dir, last }
    }

    /// Where to read the set's file `name`: in the ready set if a crash interrupted its
    /// installation, else in the directory.
    pub fn path(&self, name: &str) -> PathBuf {
        let staged = self.dir.join(Self::READY).join(name);
        if staged.is_file() {
            staged
        } else {
            self.dir.join(name)
        }
    }

    /// Replaces the set by the files `fill` writes into the directory it is given (file names
    /// as in the set's directory). Fails (leaving the old set) if `fill` or a write fails.
    pub fn replace(&self, fill: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
        self.recover()?;
        self.stage(fill)?;
        self.recover()
    }

    /// The first half of [`FileSet::replace`]: the new set written, fsynced and committed as
    /// [`FileSet::READY`], not yet installed.
    pub fn stage(&self, fill: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
        let staging = self.dir.join(Self::STAGING);
        let res: anyhow::Result<()> = (|| {
            remove_dir_if_present(&staging)?;
            fs::create_dir(&staging)
                .with_context(|| format!("cannot create {}", staging.display()))?;
            fill(&staging)?;
            for entry in fs::read_dir(&staging)? {
                let path = entry?.path();
                File::open(&path)
                    .and_then(|f| f.sync_all())
                    .with_context(|| format!("cannot sync {}", path.display()))?;
            }
            sync_dir(&staging)?;
            fs::rename(&staging, self.dir.join(Self::READY))?;
            sync_dir(self.dir)?;
            Ok(())
        })();
        if res.is_err() {
            let _ = fs::remove_dir_all(&staging);
        }
        res.with_context(|| format!("cannot write the new files of {}", self.dir.display()))
    }

    /// Brings the directory back to one whole set after a crash: removes an incomplete staging
    /// directory and finishes installing a ready set. Does nothing when neither is there.
    pub fn recover(&self) -> anyhow::Result<()> {
        let context = || format!("cannot complete the files of {}", self.dir.display());
        remove_dir_if_present(&self.dir.join(Self::STAGING)).with_context(context)?;
        let ready = self.dir.join(Self::READY);
        if !ready.is_dir() {
            return Ok(());
        }
        let mut names: Vec<_> = fs::read_dir(&ready)
            .with_context(context)?
            .map(|e| e.map(|e| e.file_name()))
            .collect::<Result<_, _>>()
            .with_context(context)?;
        // Name order, then the description last.
        names.sort_by_key(|n| (n == self.last, n.clone()));
        for name in names {
            fs::rename(ready.join(&name), self.dir.join(&name)).with_context(context)?;
        }
        sync_dir(self.dir).with_context(context)?;
        fs::remove_dir(&ready).with_context(context)?;
        sync_dir(self.dir).with_context(context)
    }
}

/// Removes `dir` and what it holds, if it is there, and makes the removal durable.
fn remove_dir_if_present(dir: &Path) -> std::io::Result<()> {
    match fs::remove_dir_all(dir) {
        Ok(()) => sync_dir(dir.parent().unwrap_or(Path::new("."))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e),
    }
}

/// The names in `dir`, sorted (tests of checkpoint sets).
#[cfg(test)]
pub(crate) fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(dir: &Path, name: &str) -> String {
        fs::read_to_string(dir.join(name)).unwrap()
    }

    fn write_set(epoch: u32) -> impl FnOnce(&Path) -> anyhow::Result<()> {
        move |d| {
            fs::write(d.join("weights"), format!("weights {epoch}"))?;
            fs::write(d.join("info"), format!("info {epoch}"))?;
            Ok(())
        }
    }

    #[test]
    fn a_file_set_is_replaced_whole_and_a_failed_write_keeps_the_old_one() {
        let tmp = tempfile::tempdir().unwrap();
        let set = FileSet::new(tmp.path(), "info");
        set.replace(write_set(1)).unwrap();
        set.replace(write_set(2)).unwrap();
        assert_eq!(entries(tmp.path()), ["info", "weights"]);
        assert_eq!(read(tmp.path(), "weights"), "weights 2");
        assert_eq!(read(tmp.path(), "info"), "info 2");

        let err = set
            .replace(|d| {
                fs::write(d.join("weights"), "weights 3")?;
                anyhow::bail!("disk full")
            })
            .unwrap_err();
        assert!(format!("{err:#}").contains("disk full"), "{err:#}");
        assert_eq!(entries(tmp.path()), ["info", "weights"]);
        assert_eq!(read(tmp.path(), "weights"), "weights 2");
    }

    #[test]
    fn recovery_drops_a_staging_leftover_and_finishes_a_ready_set() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let set = FileSet::new(dir, "info");
        set.replace(write_set(1)).unwrap();

        // A crash while writing: the staging directory holds part of set 2.
        fs::create_dir(dir.join(FileSet::STAGING)).unwrap();
        fs::write(dir.join(FileSet::STAGING).join("weights"), "weig").unwrap();
        assert_eq!(
            fs::read_to_string(set.path("weights")).unwrap(),
            "weights 1"
        );
        set.recover().unwrap();
        assert_eq!(entries(dir), ["info", "weights"]);
        assert_eq!(read(dir, "weights"), "weights 1");

        // A crash while installing set 3: weights moved, info not yet.
        set.stage(write_set(3)).unwrap();
        assert_eq!(entries(dir), [FileSet::READY, "info", "weights"]);
        fs::rename(
            dir.join(FileSet::READY).join("weights"),
            dir.join("weights"),
        )
        .unwrap();
        // Read as it is: set 3 throughout.
        assert_eq!(
            fs::read_to_string(set.path("weights")).unwrap(),
            "weights 3"
        );
        assert_eq!(fs::read_to_string(set.path("info")).unwrap(), "info 3");
        set.recover().unwrap();
        assert_eq!(entries(dir), ["info", "weights"]);
        assert_eq!(read(dir, "info"), "info 3");
        assert_eq!(read(dir, "weights"), "weights 3");
    }
}
