//! `--resume`: which planned trajectories are already recorded, and which must be redone.
//!
//! A trajectory counts as complete only when all of these hold: its final-name file exists, reads
//! back completely (every record and message, see [`read_file`]), and the manifest marks it
//! complete with the same message counts as the file. Anything else is redone. Stale partial
//! files (a crash mid-trajectory) are deleted, so the redo starts clean.

use std::collections::BTreeSet;
use std::path::Path;

use super::manifest::{Manifest, Status};
use super::reader::read_file;
use super::writer::{final_name, partial_id};

/// The verdict of [`resume`].
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ResumePlan {
    /// Complete trajectories, in plan order: skip them.
    pub complete: Vec<String>,
    /// Trajectories to (re)record, in plan order, each with why.
    pub redo: Vec<(String, String)>,
    /// Partial files deleted.
    pub removed_partials: Vec<String>,
    /// The manifest found, if any (the run continues with it).
    #[serde(skip)]
    pub manifest: Option<Manifest>,
}

/// Inspect `dir` against the plan's trajectory ids. Errors only on I/O failures listing `dir` or
/// deleting a partial; a missing directory or manifest means "redo everything".
pub fn resume(dir: &Path, plan_ids: &[String]) -> std::io::Result<ResumePlan> {
    let mut out = ResumePlan::default();
    if !dir.exists() {
        out.redo = plan_ids
            .iter()
            .map(|id| (id.clone(), "not recorded yet".into()))
            .collect();
        return Ok(out);
    }
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if partial_id(&name).is_some() {
            std::fs::remove_file(entry.path())?;
            out.removed_partials.push(name);
        }
    }
    out.removed_partials.sort();
    let manifest = Manifest::load(dir).ok();
    let planned: BTreeSet<&String> = plan_ids.iter().collect();
    for id in plan_ids {
        let verdict = check_one(dir, manifest.as_ref(), id);
        match verdict {
            Ok(()) => out.complete.push(id.clone()),
            Err(why) => out.redo.push((id.clone(), why)),
        }
    }
    if let Some(m) = &manifest {
        for t in &m.trajectories {
            if !planned.contains(&t.id) {
                tracing::warn!(
                    "{}: trajectory {} is in the manifest but not in the plan; left as is",
                    dir.display(),
                    t.id
                );
            }
        }
    }
    out.manifest = manifest;
    Ok(out)
}

fn check_one(dir: &Path, manifest: Option<&Manifest>, id: &str) -> Result<(), String> {
    let path = dir.join(final_name(id));
    let entry = manifest.and_then(|m| m.entry(id));
    if !path.exists() && entry.is_none_or(|e| e.status != Status::Failed) {
        return Err("not recorded yet".into());
    }
    let Some(m) = manifest else {
        return Err("no readable manifest".into());
    };
    let Some(entry) = m.entry(id) else {
        return Err("file exists but the manifest does not list it".into());
    };
    if entry.status != Status::Complete {
        return Err(format!(
            "manifest says {}{}",
            serde_json::to_value(entry.status)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default(),
            entry
                .reason
                .as_ref()
                .map(|r| format!(": {r}"))
                .unwrap_or_default()
        ));
    }
    let contents = read_file(&path).map_err(|e| format!("file unreadable: {e}"))?;
    if contents.counts != entry.counts {
        return Err(format!(
            "file holds {:?} but the manifest recorded {:?}",
            contents.counts, entry.counts
        ));
    }
    Ok(())
}
