//! `rig reproduce` at its tiny scale: the whole protocol (collection on two sensors, the
//! translator, FID for seen and unseen, 3 methods × 3 modalities, evaluation, verdicts, sample
//! grids and figures) runs and writes its report; run again into the same `--out`, it redoes nothing but
//! the evaluation and gives the same numbers; with `--match-marker-pitch` FID's I_s stays the
//! source's own frames.

use std::process::Command;

use crate::common;

fn reproduce(out: &std::path::Path) -> std::process::Output {
    reproduce_with(out, &[])
}

fn reproduce_with(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let _rig = common::one_rig_at_a_time();
    Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["reproduce", "--scale", "tiny", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn the_tiny_protocol_runs_reports_and_resumes_without_redoing_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("repro");
    let first = reproduce(&out);
    assert!(first.status.success(), "{}", common::output_text(&first));

    let report = std::fs::read_to_string(out.join("results/reproduce.md")).unwrap();
    for section in [
        "## Image translation",
        "## Verdicts",
        "## Wall time per phase",
    ] {
        assert!(report.contains(section), "no {section} in:\n{report}");
    }
    assert!(report.contains("**the paper** (real sensors)"), "{report}");

    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results/rows.json")).unwrap()).unwrap();
    // The paper's 3 methods × its 3 modalities and the 2 marker-displacement methods × D and
    // D+S, for the seen and the unseen group at least.
    let agg = json["aggregate"].as_array().unwrap();
    for group in ["seen", "unseen"] {
        let rows: Vec<_> = agg.iter().filter(|a| a["group"] == group).collect();
        assert_eq!(rows.len(), 13, "{group}: {rows:?}");
        let modalities = |method: &str| -> Vec<&str> {
            let mut m: Vec<&str> = rows
                .iter()
                .filter(|r| r["method"] == method)
                .map(|r| r["modality"].as_str().unwrap())
                .collect();
            m.sort();
            m
        };
        assert_eq!(modalities("TransForce"), ["M", "R", "R+M"]);
        assert_eq!(modalities("marker flow"), ["D", "D+S"]);
        assert_eq!(modalities("marker flow (no LSTM)"), ["D", "D+S"]);
        for r in rows {
            assert_eq!(r["seeds"], 1);
            for a in 0..3 {
                let mae = r["mae"][a].as_f64().unwrap();
                assert!(mae.is_finite() && mae >= 0.0, "{r}");
            }
        }
    }
    let range: Vec<f64> = json["range_n"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(range.iter().all(|r| *r > 0.05), "{range:?}");
    // The translation is measured for the unseen indenters too.
    let fid = json["fid"].as_array().unwrap();
    for group in ["seen", "unseen"] {
        for pair in ["I_s–I_t", "Î_t–I_t", "I_s–Î_t"] {
            assert!(
                fid.iter().any(|f| f["group"] == group && f["pair"] == pair),
                "no {pair} for {group}: {fid:?}"
            );
        }
    }
    let verdicts = json["verdicts"].as_array().unwrap();
    // The paper's 6 claims, the LSTM's for marker flow (2) and marker flow's own 4.
    assert_eq!(verdicts.len(), 12, "{verdicts:?}");
    for v in verdicts {
        let o = v["outcome"].as_str().unwrap();
        assert!(
            ["reproduced", "refuted", "inconclusive", "not measured"].contains(&o),
            "{v}"
        );
    }
    for name in ["seen", "unseen"] {
        let img = image::open(out.join(format!("figures/samples-{name}.png")))
            .unwrap()
            .to_rgb8();
        // I_s | Î_t | I_t, 4 rows, at the network's 32 × 24, enlarged 5 times.
        assert_eq!(img.dimensions(), (480, 480), "{name}");
    }
    // The error violins (2 groups × 3 axes) and the force over time (sphere and hemisphere
    // seen, the cone unseen: 3 rows), each with every method's colour drawn.
    for (file, size) in [
        ("error-by-force-range.png", (1500, 860)),
        ("force-over-time.png", (1500, 3 * 250 + 50)),
    ] {
        let img = image::open(out.join("figures").join(file))
            .unwrap()
            .to_rgb8();
        assert_eq!(img.dimensions(), size, "{file}");
        for (method, rgb) in [
            ("source-only", [214, 39, 40]),
            ("TransForce (no LSTM)", [44, 160, 44]),
            ("TransForce", [31, 119, 180]),
            ("marker flow (no LSTM)", [148, 103, 189]),
            ("marker flow", [255, 127, 14]),
        ] {
            let n = img.pixels().filter(|p| p.0 == rgb).count();
            assert!(n > 200, "{file}: {n} pixels of {method}'s colour");
        }
    }

    // Again into the same directory: nothing recorded, translated or trained anew.
    let models = |o: &std::path::Path| -> Vec<std::time::SystemTime> {
        let mut v: Vec<_> = std::fs::read_dir(o.join("models"))
            .unwrap()
            .map(|e| {
                let p = e.unwrap().path().join("model.safetensors");
                std::fs::metadata(p).unwrap().modified().unwrap()
            })
            .collect();
        v.sort();
        v
    };
    let before = models(&out);
    assert_eq!(before.len(), 13);
    // Marker flow trains on mirrored sequences through a pooled head (the protocol's
    // marker_force); the paper's methods as the paper does, on the flattened map.
    for e in std::fs::read_dir(out.join("models")).unwrap() {
        let path = e.unwrap().path().join("model.json");
        let info: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        let ours = info["method"].as_str().unwrap().starts_with("marker flow");
        assert_eq!(info["config"]["mirror"], ours, "{}", path.display());
        assert_eq!(info["config"]["global_pool"], ours, "{}", path.display());
        assert_eq!(
            info["shape"]["spatial"].is_null(),
            ours,
            "{}",
            path.display()
        );
    }
    let second = reproduce(&out);
    assert!(second.status.success(), "{}", common::output_text(&second));
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(stderr.contains("translation: done earlier"), "{stderr}");
    assert_eq!(models(&out), before, "a model was trained again");
    let again: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results/rows.json")).unwrap()).unwrap();
    assert_eq!(again["aggregate"], json["aggregate"]);

    // With the marker pitches matched, on the same recordings (hard links): the translator sees
    // the source magnified, but FID's I_s is still the source sensor's own frames, so the
    // I_s–I_t rows are those of the run without it, and the translation's rows are not.
    let pitched = dir.path().join("pitched");
    link_tree(&out.join("data"), &pitched.join("data"));
    let third = reproduce_with(&pitched, &["--match-marker-pitch"]);
    assert!(third.status.success(), "{}", common::output_text(&third));
    let stderr = String::from_utf8_lossy(&third.stderr);
    assert!(stderr.contains("magnified 1.222 ×"), "{stderr}");
    let p: serde_json::Value =
        serde_json::from_slice(&std::fs::read(pitched.join("results/rows.json")).unwrap()).unwrap();
    let row = |j: &serde_json::Value, group: &str, pair: &str| {
        j["fid"]
            .as_array()
            .unwrap()
            .iter()
            .find(|f| f["group"] == group && f["pair"] == pair)
            .unwrap()
            .clone()
    };
    for group in ["seen", "unseen"] {
        assert_eq!(row(&p, group, "I_s–I_t"), row(&json, group, "I_s–I_t"));
        let (a, b) = (row(&p, group, "Î_t–I_t"), row(&json, group, "Î_t–I_t"));
        // FID where the weights are installed, the colour statistics always.
        assert_ne!(a["colour_fd"], b["colour_fd"], "{group}: {a} {b}");
        if !a["fid"].is_null() {
            assert_ne!(a["fid"], b["fid"], "{group}: {a} {b}");
        }
    }
}

/// `from` rebuilt under `to`, every file a hard link.
fn link_tree(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            link_tree(&e.path(), &dest);
        } else {
            std::fs::hard_link(e.path(), dest).unwrap();
        }
    }
}

/// Without Inception weights, the two-hour scale stops before it records anything and says how
/// to get them or how to go on without FID; `--no-fid` and `--inception` cannot both be given.
#[test]
fn the_cpu_scale_without_inception_weights_stops_at_once_and_says_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("repro");
    let o = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["reproduce", "--scale", "cpu", "--out"])
        .arg(&out)
        .env("XDG_CACHE_HOME", dir.path().join("empty-cache"))
        .env_remove("RIG_INCEPTION_WEIGHTS")
        .output()
        .unwrap();
    let text = common::output_text(&o);
    assert!(!o.status.success(), "{text}");
    let missing = dir.path().join("empty-cache/rig/inception-fid.safetensors");
    assert!(text.contains(&missing.display().to_string()), "{text}");
    assert!(text.contains("scripts/fetch-inception"), "{text}");
    assert!(text.contains("--no-fid"), "{text}");
    assert!(
        !out.join("data").exists(),
        "it recorded before stopping:\n{text}"
    );

    let o = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args([
            "reproduce",
            "--no-fid",
            "--inception",
            "w.safetensors",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let text = common::output_text(&o);
    assert!(!o.status.success(), "{text}");
    assert!(text.contains("cannot be used with"), "{text}");
}
