//! The output directory of a run: refused or continued (`--resume`) before anything moves,
//! and the manifest a new recording starts with.

use std::path::Path;

use anyhow::{Context, bail};
use rig_core::config::RigConfig;

use crate::plan::Plan;
use crate::record::{self, Manifest, SensorInfo};

/// The recording to write into: the manifest to start the [`Recorder`] with, and the planned
/// trajectories an earlier run already recorded completely.
pub(super) struct Output {
    pub manifest: Manifest,
    pub complete: Vec<String>,
    /// The lock on the directory ([`lock_dir`]); held until the run ends.
    pub lock: Option<std::fs::File>,
}

/// Takes an exclusive advisory lock (`flock`) on the output directory, creating it if need be,
/// so that two runs never write into the same `--out`: the second is refused at once, before
/// it touches anything (a resume would otherwise delete the first run's partial file). The
/// lock goes with the process, so a killed run leaves none behind.
fn lock_dir(dir: &Path) -> anyhow::Result<std::fs::File> {
    std::fs::create_dir_all(dir).with_context(|| {
        format!(
            "cannot create the output directory {}; check the path and its permissions, or choose another --out",
            dir.display()
        )
    })?;
    let f = std::fs::File::open(dir)
        .with_context(|| format!("cannot open the output directory {}", dir.display()))?;
    match f.try_lock() {
        Ok(()) => Ok(f),
        Err(std::fs::TryLockError::WouldBlock) => bail!(
            "another rig run is writing into {} (it holds the directory's lock); wait for it to \
             finish, or choose another --out",
            dir.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => {
            Err(e).with_context(|| format!("cannot lock the output directory {}", dir.display()))
        }
    }
}

/// Whether `dir` holds anything at all.
fn dir_has_entries(dir: &Path) -> anyhow::Result<bool> {
    match std::fs::read_dir(dir) {
        Ok(mut rd) => Ok(rd.next().is_some()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(e).with_context(|| {
            format!(
                "cannot read the output directory {}; check its permissions or choose another --out",
                dir.display()
            )
        }),
    }
}

/// Check the output directory against `--resume` before anything moves, and work out what is
/// left to record. `fresh` is the manifest of a new recording of this plan.
fn prepare_output(
    dir: &Path,
    resume: bool,
    ids: &[String],
    fresh: Manifest,
) -> anyhow::Result<Output> {
    if dir.exists() && !dir.is_dir() {
        bail!(
            "--out {} is a file, not a directory; choose another --out",
            dir.display()
        );
    }
    let has_manifest = dir.join(record::MANIFEST_NAME).exists();
    let non_empty = dir_has_entries(dir)?;
    if !resume {
        if has_manifest && non_empty {
            bail!(
                "{} already holds a recording ({}); add --resume to continue it, or choose another --out",
                dir.display(),
                record::MANIFEST_NAME
            );
        }
        if non_empty {
            bail!(
                "{} is not empty and holds no {}, so it is not a rig recording; choose another (or an empty) --out",
                dir.display(),
                record::MANIFEST_NAME
            );
        }
        return Ok(Output {
            manifest: fresh,
            complete: Vec::new(),
            lock: None,
        });
    }
    if !has_manifest {
        if non_empty {
            bail!(
                "--resume: {} holds files but no {}, so it is not a rig recording; choose another --out",
                dir.display(),
                record::MANIFEST_NAME
            );
        }
        eprintln!(
            "--resume: nothing recorded in {} yet; starting a new recording",
            dir.display()
        );
        return Ok(Output {
            manifest: fresh,
            complete: Vec::new(),
            lock: None,
        });
    }
    // Compare before `resume` touches anything (it deletes stale partial files).
    let mut old = Manifest::load(dir).map_err(|e| {
        anyhow::anyhow!(
            "--resume: {e}; the recording in {} cannot be continued, choose another --out",
            dir.display()
        )
    })?;
    if old.indenter != fresh.indenter {
        bail!(
            "--resume: {} was recorded with indenter `{}`, not `{}`; resume it with --indenter {}, \
             or choose another --out for `{}`",
            dir.display(),
            old.indenter,
            fresh.indenter,
            old.indenter,
            fresh.indenter
        );
    }
    if old.config != fresh.config {
        bail!(
            "--resume: {} was recorded with a different rig config (differs in: {}; see config in \
             its {}); resume it with the same --config, or choose another --out",
            dir.display(),
            differing_keys(&old.config, &fresh.config),
            record::MANIFEST_NAME
        );
    }
    let verdict = record::resume(dir, ids)
        .with_context(|| format!("--resume: cannot inspect {}", dir.display()))?;
    for name in &verdict.removed_partials {
        eprintln!("--resume: removed the interrupted recording {name}");
    }
    for (id, why) in &verdict.redo {
        tracing::debug!("--resume: {id} is redone ({why})");
    }
    eprintln!(
        "--resume: {} of {} trajectories already complete in {}; {} to record",
        verdict.complete.len(),
        ids.len(),
        dir.display(),
        verdict.redo.len()
    );
    // Every planned trajectory is listed, so an unfinished run shows what is still pending.
    for id in ids {
        old.entry_mut(id);
    }
    Ok(Output {
        manifest: old,
        complete: verdict.complete,
        lock: None,
    })
}

/// The top-level config sections in which two configs differ, for an operator message.
/// The top-level keys whose values differ between two JSON objects, sorted and each once,
/// leaving out `ignore`; `None` when either is not an object.
pub(super) fn differing_top_keys(
    a: &serde_json::Value,
    b: &serde_json::Value,
    ignore: &[&str],
) -> Option<Vec<String>> {
    let (a, b) = (a.as_object()?, b.as_object()?);
    let mut keys: Vec<String> = a
        .keys()
        .chain(b.keys())
        .filter(|k| !ignore.contains(&k.as_str()) && a.get(*k) != b.get(*k))
        .cloned()
        .collect();
    keys.sort_unstable();
    keys.dedup();
    Some(keys)
}

fn differing_keys(a: &serde_json::Value, b: &serde_json::Value) -> String {
    match differing_top_keys(a, b, &[]) {
        Some(keys) if !keys.is_empty() => keys
            .iter()
            .map(|k| format!("[{k}]"))
            .collect::<Vec<_>>()
            .join(", "),
        _ => "the whole config".into(),
    }
}

/// Checks the output directory for a run of `ids` of `plan` (see [`prepare_output`]). The
/// manifest's calibration is filled in once the F/T is open.
pub(super) fn prepare(
    config: &RigConfig,
    plan: &Plan,
    ids: &[String],
    dir: &Path,
    resume: bool,
) -> anyhow::Result<Output> {
    let role = serde_json::to_value(config.sensor.role)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_else(|| "source".into());
    let config_json =
        serde_json::to_value(config).context("serialising the rig config for the manifest")?;
    let fresh = Manifest::new(
        &plan.indenter,
        SensorInfo {
            id: plan.sensor_id.clone(),
            role,
        },
        config_json,
        serde_json::Value::Null,
        ids,
    );
    if dir.exists() && !dir.is_dir() {
        bail!(
            "--out {} is a file, not a directory; choose another --out",
            dir.display()
        );
    }
    let lock = lock_dir(dir)?;
    let mut out = prepare_output(dir, resume, ids, fresh)?;
    out.lock = Some(lock);
    Ok(out)
}
