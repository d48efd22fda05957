//! `rig plan` and `rig indenters` through the built binary: output shape, safety refusals and
//! operator-facing errors.

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

const SIM_SOURCE: &str = include_str!("../../rig-configs/sim-source.toml");

/// Runs `rig` in `dir` (a scratch directory, so no stray ./rig.toml is picked up).
fn rig_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(args)
        .current_dir(dir)
        .env("RUST_LOG", "warn")
        .output()
        .expect("run the rig binary")
}

fn rig(args: &[&str]) -> Output {
    let dir = tempfile::tempdir().unwrap();
    rig_in(dir.path(), args)
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A copy of the simulated rig config with one substring replaced, written to a temp file.
fn config_with(from: &str, to: &str) -> tempfile::NamedTempFile {
    assert!(
        SIM_SOURCE.contains(from),
        "test setup: {from:?} not in sim-source.toml"
    );
    let file = tempfile::Builder::new().suffix(".toml").tempfile().unwrap();
    std::fs::write(file.path(), SIM_SOURCE.replacen(from, to, 1)).unwrap();
    file
}

fn plan_json(args: &[&str]) -> Value {
    let o = rig(args);
    assert!(o.status.success(), "rig {args:?} failed: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).expect("stdout is JSON")
}

#[test]
fn plan_json_prints_240_trajectories_with_four_stages() {
    let doc = plan_json(&["plan", "--indenter", "cone", "--json"]);
    assert_eq!(doc["indenter"], "cone");
    assert!(doc["config"].as_str().unwrap().contains("sim-source"));
    let trajectories = doc["trajectories"].as_array().unwrap();
    assert_eq!(trajectories.len(), 240);
    let mut ids = std::collections::HashSet::new();
    for t in trajectories {
        let id = t["id"].as_str().unwrap();
        assert!(ids.insert(id.to_owned()), "duplicate id {id}");
        assert!(
            id.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-.".contains(c)),
            "{id} is not filename-safe"
        );
        assert!(t["point"].is_u64());
        assert_eq!(t["point_mm"].as_array().unwrap().len(), 2);
        assert!(t["depth_mm"].is_f64());
        assert!(t["angle_deg"].is_f64());
        let names: Vec<&str> = t["stages"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["down", "shear", "reverse", "up"], "{id}");
        for s in t["stages"].as_array().unwrap() {
            assert!(s["speed_mm_s"].as_f64().unwrap() > 0.0);
            assert!(s["accel_mm_s2"].as_f64().unwrap() > 0.0);
            for w in s["waypoints"].as_array().unwrap() {
                assert_eq!(w.as_array().unwrap().len(), 6);
            }
        }
    }
    // Ordered point → depth → direction.
    assert_eq!(trajectories[0]["id"], "p0-d0.2-a000");
    assert_eq!(trajectories[1]["id"], "p0-d0.2-a030");
    assert_eq!(trajectories[12]["id"], "p0-d0.4-a000");
    assert_eq!(trajectories[239]["id"], "p4-d0.8-a330");
}

#[test]
fn down_stage_ends_exactly_at_the_planned_depth() {
    let doc = plan_json(&["plan", "--indenter", "sphere_s", "--json"]);
    let frame: Vec<f64> = doc["surface_frame"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // The shipped simulated rig's surface faces straight up, so depth is along −z of the base.
    assert_eq!(frame[3..], [0.0, 0.0, 0.0]);
    let surface_z = frame[2];
    for t in doc["trajectories"].as_array().unwrap() {
        let depth_m = t["depth_mm"].as_f64().unwrap() / 1000.0;
        let point = t["point_mm"].as_array().unwrap();
        let down = &t["stages"][0];
        let wps = down["waypoints"].as_array().unwrap();
        let first = wps.first().unwrap().as_array().unwrap();
        let last = wps.last().unwrap().as_array().unwrap();
        let z = |w: &Vec<Value>, k: usize| w[k].as_f64().unwrap();
        assert!(
            (z(last, 2) - (surface_z - depth_m)).abs() < 1e-12,
            "{}: down ends at z = {}, planned {}",
            t["id"],
            z(last, 2),
            surface_z - depth_m
        );
        // Straight down: same x/y at the start and end, above the surface at the start.
        assert!((z(first, 0) - z(last, 0)).abs() < 1e-12);
        assert!((z(first, 1) - z(last, 1)).abs() < 1e-12);
        assert!(z(first, 2) > surface_z);
        let px = frame[0] + point[0].as_f64().unwrap() / 1000.0;
        assert!((z(last, 0) - px).abs() < 1e-12);
        // The shear and reverse stages stay at that depth.
        for k in [1, 2] {
            for w in t["stages"][k]["waypoints"].as_array().unwrap() {
                assert!((w[2].as_f64().unwrap() - (surface_z - depth_m)).abs() < 1e-12);
            }
        }
    }
}

#[test]
fn envelope_that_excludes_a_waypoint_is_refused_naming_the_trajectory() {
    // The deepest waypoints (0.8 mm, z = 0.1992 m) lie below this floor.
    let cfg = config_with("min_z = 0.199", "min_z = 0.1993");
    let o = rig(&[
        "plan",
        "--indenter",
        "cone",
        "--config",
        cfg.path().to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        o.stdout.is_empty(),
        "nothing is printed on stdout: {}",
        stdout(&o)
    );
    let err = stderr(&o);
    assert!(err.contains("trajectory p0-d0.8-a000"), "{err}");
    assert!(err.contains("stage down"), "{err}");
    assert!(err.contains("safety.envelope.min_z"), "{err}");
    assert!(err.contains("nothing was moved"), "{err}");
}

#[test]
fn envelope_side_violation_names_the_shear_stage() {
    // x reaches 0.405 m when shearing 2 mm from (3, ·) mm towards +x.
    let cfg = config_with("max_x = 0.42", "max_x = 0.4035");
    let o = rig(&[
        "plan",
        "--indenter",
        "cone",
        "--config",
        cfg.path().to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(
        err.contains("trajectory p2-d0.2-a000, stage shear, waypoint 1: x = 0.4050 m is above safety.envelope.max_x = 0.4035 m"),
        "{err}"
    );
}

#[test]
fn unknown_indenter_lists_the_known_ones() {
    let o = rig(&["plan", "--indenter", "spoon"]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("unknown indenter `spoon`"), "{err}");
    for name in ["cone", "sphere_s", "pacman", "paralines", "wave"] {
        assert!(err.contains(name), "{name} missing from: {err}");
    }
}

#[test]
fn invalid_config_names_the_key() {
    let cfg = config_with("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.2, 1.2]");
    let o = rig(&[
        "plan",
        "--indenter",
        "cone",
        "--config",
        cfg.path().to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(
        err.contains("plan.depths_mm[1]: 1.2 mm exceeds safety.max_depth_mm = 1.0 mm"),
        "{err}"
    );

    let cfg = config_with("approach_height_mm = 2.0", "approach_hieght_mm = 2.0");
    let o = rig(&[
        "plan",
        "--indenter",
        "cone",
        "--config",
        cfg.path().to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("plan.approach_hieght_mm"), "{err}");
    assert!(err.contains("unknown field"), "{err}");
}

#[test]
fn missing_config_file_is_named() {
    let o = rig(&[
        "plan",
        "--indenter",
        "cone",
        "--config",
        "/nonexistent/lab.toml",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("/nonexistent/lab.toml"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn config_resolution_prefers_local_rig_toml_and_announces_the_fallback() {
    let dir = tempfile::tempdir().unwrap();
    let o = rig_in(dir.path(), &["plan", "--indenter", "cone"]);
    assert!(o.status.success());
    assert!(
        stderr(&o).contains("built-in simulated rig"),
        "{}",
        stderr(&o)
    );
    assert!(stdout(&o).contains("240 trajectories"), "{}", stdout(&o));

    // A ./rig.toml with a single depth is used without the note.
    std::fs::write(
        dir.path().join("rig.toml"),
        SIM_SOURCE.replacen("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.5]", 1),
    )
    .unwrap();
    let o = rig_in(dir.path(), &["plan", "--indenter", "cone", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        !stderr(&o).contains("built-in simulated rig"),
        "{}",
        stderr(&o)
    );
    let doc: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(doc["config"], "rig.toml");
    assert_eq!(doc["trajectories"].as_array().unwrap().len(), 60);
}

#[test]
fn usage_errors_exit_with_2() {
    let o = rig(&["plan"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--indenter"));
    let o = rig(&["fly"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn indenters_lists_every_builtin_with_a_description() {
    let o = rig(&["indenters"]);
    assert!(o.status.success());
    let out = stdout(&o);
    for name in rig_core::indenter::Indenter::list_builtin() {
        let line = out
            .lines()
            .find(|l| l.split_whitespace().next() == Some(name))
            .unwrap_or_else(|| panic!("{name} not listed:\n{out}"));
        assert!(line.len() > name.len() + 5, "{name} has no description");
    }
}

#[test]
fn plan_accepts_an_indenter_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("knob.toml"),
        "name = \"knob\"\ndescription = \"test knob\"\n[[shape]]\nkind = \"sphere_cap\"\nradius_mm = 3.0\n",
    )
    .unwrap();
    let o = rig_in(dir.path(), &["plan", "--indenter", "knob.toml", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let doc: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(doc["indenter"], "knob");
}
