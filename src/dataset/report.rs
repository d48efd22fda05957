//! The human-readable report of `rig dataset check`, and why its exit status is non-zero.

use super::DatasetReport;

fn us(ns: f64) -> String {
    format!("{:.1} µs", ns * 1e-3)
}

fn pct(p: f64) -> String {
    format!("{p:.2} %")
}

/// A percentage limit as the operator typed it (`2`, `0.5`).
fn limit(p: f64) -> String {
    format!("{p} %")
}

/// The report as an operator reads it.
pub fn render(r: &DatasetReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "dataset {}", r.dir.display());
    if let Some(e) = &r.manifest_error {
        let _ = writeln!(s, "  manifest: {e}");
    }
    let _ = writeln!(
        s,
        "  {:<28} {:<10} {:>6} {:>7} {:>6} {:>5} {:>6} {:>10} {:>10} {:>10} {:>9}",
        "trajectory",
        "verdict",
        "frames",
        "wrench",
        "poses",
        "drops",
        "unexpl",
        "sync p50",
        "sync p99",
        "sync max",
        "true err"
    );
    for t in &r.trajectories {
        let _ = writeln!(
            s,
            "  {:<28} {:<10} {:>6} {:>7} {:>6} {:>5} {:>6} {:>10} {:>10} {:>10} {:>9}",
            t.id,
            serde_json::to_value(t.verdict)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default(),
            t.counts.frames,
            t.counts.wrench,
            t.counts.poses,
            t.frames_dropped,
            t.frames_dropped_unexplained,
            us(t.sync_error.p50_ns),
            us(t.sync_error.p99_ns),
            us(t.sync_error.max_ns),
            t.truth
                .as_ref()
                .filter(|c| c.compared > 0)
                .map_or_else(|| "-".to_owned(), |c| pct(c.worst_axis_max_pct))
        );
        if let Some(why) = &t.reason {
            let _ = writeln!(s, "      {why}");
        }
        if t.frames_dropped_unexplained > 0 {
            let _ = writeln!(
                s,
                "      frames: {} missing from the sequence, {} reported lost by the camera: {} unexplained",
                t.frames_dropped, t.frames_dropped_reported, t.frames_dropped_unexplained
            );
        }
        if !t.wrench_seq_gaps.is_empty() || t.wrench_time_gaps > 0 {
            let _ = writeln!(
                s,
                "      wrench: {} counter gaps ({} samples lost), {} time gaps, longest {}",
                t.wrench_seq_gaps.len(),
                t.wrench_seq_gaps.iter().map(|g| g.missing).sum::<u64>(),
                t.wrench_time_gaps,
                us(t.wrench_longest_gap_ns)
            );
        }
        if let Some(c) = &t.truth
            && (c.frames_above_2pct > 0 || c.unpaired > 0 || c.paired_without_truth > 0)
        {
            let worst = c
                .worst
                .as_ref()
                .map(|w| format!(" (worst: frame {}, {} {})", w.frame_seq, w.axis, pct(w.pct)))
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "      true wrench: {} frames above 2 %{worst}, {} unpaired, {} paired without truth",
                c.frames_above_2pct, c.unpaired, c.paired_without_truth
            );
        }
    }
    for p in &r.stale_partials {
        let _ = writeln!(s, "  stale partial file: {p} (rerun with --resume)");
    }
    let _ = writeln!(
        s,
        "  {} complete, {} with problems; {} frames, {} wrench samples",
        r.complete, r.problems, r.frames, r.wrench_samples
    );
    let _ = writeln!(
        s,
        "  sync error p50 {} p99 {} max {}",
        us(r.sync_error.p50_ns),
        us(r.sync_error.p99_ns),
        us(r.sync_error.max_ns)
    );
    let _ = writeln!(
        s,
        "  frame drops: {} ({} unexplained)",
        r.frames_dropped, r.frames_dropped_unexplained
    );
    match &r.truth {
        None => {
            let _ = writeln!(
                s,
                "  paired vs true wrench: no simulator truth (/sim/true_wrench) in this dataset"
            );
        }
        Some(c) => {
            let unpaired = if c.unpaired > 0 {
                format!("; {} unpaired", c.unpaired)
            } else {
                String::new()
            };
            if c.compared == 0 {
                let _ = writeln!(s, "  paired vs true wrench: no frame has both{unpaired}");
            } else {
                let _ = writeln!(
                    s,
                    "  paired vs true wrench: worst axis max {} of full range, p99 {}, {} frames above 2 %; max |ΔF| {:.3} N{unpaired}",
                    pct(c.worst_axis_max_pct),
                    pct(c.worst_axis_p99_pct),
                    c.frames_above_2pct,
                    c.max_force_error_n
                );
            }
            if let Some(note) = &r.full_range.note {
                let l = r.full_range.max_loads;
                let _ = writeln!(
                    s,
                    "  full range: Nano17 SI-25-0.25 fallback [{}, {}, {}, {}, {}, {}] (N, N·mm): {note}",
                    l[0], l[1], l[2], l[3], l[4], l[5]
                );
            }
        }
    }
    if let Some(l) = &r.error_limit {
        if !l.applied {
            let _ = writeln!(
                s,
                "  error limit {}: not applied (no simulator truth)",
                limit(l.max_error_pct)
            );
        } else {
            let worst = r
                .truth
                .as_ref()
                .and_then(|c| c.worst.as_ref())
                .filter(|_| l.frames_above > 0)
                .map(|w| {
                    format!(
                        "; worst: {} frame {}, {} {}",
                        w.trajectory,
                        w.frame_seq,
                        w.axis,
                        pct(w.pct)
                    )
                })
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "  error limit {}: {} frames above{worst}",
                limit(l.max_error_pct),
                l.frames_above
            );
        }
    }
    s
}

/// Why the exit is non-zero, if it is.
pub fn failure(r: &DatasetReport) -> Option<String> {
    let mut why = Vec::new();
    if !r.ok() {
        why.push(format!(
            "dataset {} is not complete: {} trajectories with problems, {} stale partial files{}",
            r.dir.display(),
            r.problems,
            r.stale_partials.len(),
            r.manifest_error
                .as_ref()
                .map(|e| format!(", {e}"))
                .unwrap_or_default()
        ));
    }
    if let Some(l) = &r.error_limit
        && l.frames_above > 0
    {
        let worst = r
            .truth
            .as_ref()
            .and_then(|c| c.worst.as_ref())
            .map(|w| {
                let unit = if w.axis.starts_with('F') {
                    "N"
                } else {
                    "N·mm"
                };
                format!(
                    "; worst: trajectory {} frame {}, {} off by {} ({:.4} {unit})",
                    w.trajectory,
                    w.frame_seq,
                    w.axis,
                    pct(w.pct),
                    w.abs_error
                )
            })
            .unwrap_or_default();
        why.push(format!(
            "dataset {}: {} frames' paired wrench is off the true wrench by more than {} of full range{worst}",
            r.dir.display(),
            l.frames_above,
            limit(l.max_error_pct)
        ));
    }
    (!why.is_empty()).then(|| why.join("\n"))
}
