//! `rig sim render` and `rig sim contact-sheet` from the command line.

use std::path::Path;
use std::process::{Command, Output};

fn rig_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run rig")
}

#[test]
fn render_writes_a_frame_and_prints_the_wrench_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let out = rig_in(
        dir.path(),
        &[
            "sim",
            "render",
            "--indenter",
            "sphere",
            "--depth",
            "0.6",
            "--shear",
            "0.5,90",
            "--out",
            "frame.png",
            "--json",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let w: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let get = |k: &str| {
        w[k].as_f64()
            .unwrap_or_else(|| panic!("{k} missing in {w}"))
    };
    // Pressing: force on the gel along −z; shear towards +y (90°): Fy > 0, Fx ≈ 0.
    assert!(get("fz") < -0.1, "{w}");
    assert!(get("fy") > 0.01, "{w}");
    assert!(get("fx").abs() < 0.05 * get("fy").abs() + 1e-6, "{w}");
    for k in ["tx", "ty", "tz"] {
        assert!(get(k).is_finite());
    }
    let img = image::open(dir.path().join("frame.png")).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (320, 240));
}

#[test]
fn the_target_config_renders_the_same_contact_in_other_colours_on_its_stiffer_gel() {
    let dir = tempfile::tempdir().unwrap();
    let target = Path::new(env!("CARGO_MANIFEST_DIR")).join("rig-configs/sim-target.toml");
    let args = |cfg: Option<&str>, out: &'static str| {
        let mut a = vec![
            "sim",
            "render",
            "--indenter",
            "cone",
            "--depth",
            "0.6",
            "--out",
            out,
        ];
        if let Some(c) = cfg {
            a.extend(["--config", c]);
        }
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let run = |a: Vec<String>| {
        let refs: Vec<&str> = a.iter().map(String::as_str).collect();
        let out = rig_in(dir.path(), &refs);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    let s = run(args(None, "s.png"));
    let t = run(args(Some(target.to_str().unwrap()), "t.png"));
    // The same contact on the same gel recipe: the target's gel batch is stiffer by its modulus
    // ratio (rig-configs/sim-target.toml), and a displacement-controlled elastic contact's force
    // scales with the modulus. The printed Fz has 4 decimals: 0.1 % of 0.14 N.
    let fz = |out: &str| -> f64 {
        let line = out.lines().next().unwrap();
        line.split_whitespace().last().unwrap().parse().unwrap()
    };
    let ratio = fz(&t) / fz(&s);
    let (e_s, e_t) = (
        rig_core::config::RigConfig::sim_source()
            .elastomer
            .youngs_modulus_mpa,
        rig_core::config::RigConfig::sim_target()
            .elastomer
            .youngs_modulus_mpa,
    );
    assert!(
        (ratio - e_t / e_s).abs() < 2e-3,
        "Fz ratio {ratio} vs modulus ratio {}",
        e_t / e_s
    );
    let a = image::open(dir.path().join("s.png")).unwrap().to_rgb8();
    let b = image::open(dir.path().join("t.png")).unwrap().to_rgb8();
    assert_ne!(a, b);
}

#[test]
fn bad_arguments_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    for (args, needle) in [
        (vec!["--shear", "1.0"], "--shear"),
        (vec!["--depth=-1"], "--depth"),
        (vec!["--depth", "5"], "thickness"),
        (vec!["--indenter", "nosuch"], "nosuch"),
    ] {
        let mut all = vec!["sim", "render", "--out", "f.png"];
        if !args.contains(&"--indenter") {
            all.extend(["--indenter", "cone"]);
        }
        if !args.iter().any(|a| a.starts_with("--depth")) {
            all.extend(["--depth", "0.5"]);
        }
        all.extend(args.iter().copied());
        let out = rig_in(dir.path(), &all);
        assert_eq!(out.status.code(), Some(1), "{all:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{all:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn the_contact_sheet_holds_every_indenter() {
    let dir = tempfile::tempdir().unwrap();
    let out = rig_in(
        dir.path(),
        &[
            "sim",
            "contact-sheet",
            "--depth",
            "0.4",
            "--out",
            "sheet/indenters.png",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(dir.path().join("sheet/indenters.png"))
        .unwrap()
        .to_rgb8();
    // 19 tiles of 320 × 240 in 5 columns, 4 rows, with 6 px padding and 20 px labels.
    assert_eq!(img.width(), 5 * 326 + 6);
    assert_eq!(img.height(), 26 + 4 * (240 + 20 + 6) + 6);
}
