//! `rig demo --quick` end to end on the simulated rig: collect source and target datasets,
//! translate, train TransForce, its no-LSTM control and the source-only baseline, evaluate on the
//! target sensor. The table must be written, translation must bring the source images closer to
//! the target's (colour statistics; and Inception FID when CI has fetched the weights), and
//! TransForce must beat source-only on the target on every axis and on the force magnitude, with
//! a positive R² on Fz over all frames and over the unseen indenters' frames (it learnt normal
//! force through the translation, and it carries over to indenters it was not trained on;
//! source-only, trained on the source sensor's colours, has not learnt it for the target).
//! The unseen group is the cone and sphere_s (the cone alone, |Fz| under 0.47 N, left its R² at
//! the mercy of a small offset).
//!
//! The marker-displacement method (`marker flow`, trained on the source's recordings without
//! translation) must carry shear: R² > 0.3 on Fx and Fy, seen and unseen.
//!
//! The TransForce shear comparison is made only on an axis one of the two models learnt (R² > 0):
//! at this scale no image model learns sim-target's shear through the translation, and
//! TransForce wins Fx and Fy by predicting less spurious shear than source-only, by a margin that
//! can be thin on Fx (as little as ×1.08). If CI fails on Fx or Fy there, that is the reason.
//! The runs: docs/experiments.md, *The quick demo's settings*.

use std::process::Command;

#[test]
fn the_quick_demo_runs_the_whole_story_and_transforce_beats_source_only() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["demo", "--quick", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "demo failed:\n{stdout}\n{stderr}");
    for f in ["results.md", "results.csv", "results.json"] {
        assert!(out.join("results").join(f).is_file(), "{f} missing");
    }
    let md = std::fs::read_to_string(out.join("results/results.md")).unwrap();
    for method in ["TransForce", "TransForce (no LSTM)", "source-only"] {
        assert!(
            md.contains(method),
            "{method} missing from the table:\n{md}"
        );
    }
    // The translator wrote its dataset and sample grids.
    assert!(out.join("translate/translated/prepared.json").is_file());
    assert!(
        std::fs::read_dir(out.join("translate/samples"))
            .unwrap()
            .count()
            > 0
    );

    let table: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results/results.json")).unwrap()).unwrap();
    let rows = table["rows"].as_array().expect("rows");
    let row = |method: &str, group: &str| {
        rows.iter()
            .find(|r| r["method"] == method && r["group"] == group)
            .unwrap_or_else(|| panic!("no {method} row for the group {group}:\n{md}"))
    };
    let (tf, so) = (row("TransForce", "all"), row("source-only", "all"));
    let mae = |r: &serde_json::Value, a: usize| r["mae"][a].as_f64().unwrap();
    let r2 = |r: &serde_json::Value, a: usize| r["r2"][a].as_f64().unwrap();
    for (a, axis) in [(0, "Fx"), (1, "Fy"), (2, "Fz")] {
        // An axis neither model learnt (R² ≤ 0: no better than the mean) has MAEs whose order
        // is chance, as `rig reproduce`'s verdicts say: on sim-target's shear that is the case
        // for every image model, and source-only won Fy by 0.003 N once (2026-12-02).
        if r2(tf, a) <= 0.0 && r2(so, a) <= 0.0 {
            eprintln!("{axis}: neither TransForce nor source-only learnt it; not compared");
            continue;
        }
        let (t, s) = (mae(tf, a), mae(so, a));
        assert!(
            t < s,
            "{axis}: TransForce MAE {t:.3} N is not below source-only {s:.3} N\n{md}"
        );
    }
    // The marker-displacement method carries shear to the target sensor, on the indenters it
    // trained on and on those it did not (one run on the quick demo's recordings, 2026-12-02:
    // R² Fx, Fy 0.98 / 0.98 seen and 0.95 / 0.96 unseen, 160 × 120 frames, 32 × 24 input).
    for group in ["seen", "unseen"] {
        let flow = row("marker flow", group);
        for (a, axis) in [(0, "Fx"), (1, "Fy")] {
            assert!(
                r2(flow, a) > 0.3,
                "{axis}: marker flow's R² on the {group} indenters is {:.3}\n{md}",
                r2(flow, a)
            );
        }
    }
    let r2 = tf["r2"][2].as_f64().unwrap();
    assert!(
        r2 > 0.0,
        "Fz: TransForce R² {r2:.3} on the target: no better than its mean\n{md}"
    );
    // The unseen group (the cone and sphere_s, indenters no model trained on): normal force
    // carries over to them too.
    let r2 = row("TransForce", "unseen")["r2"][2].as_f64().unwrap();
    assert!(
        r2 > 0.0,
        "Fz: TransForce R² {r2:.3} on the unseen indenters: no better than their mean\n{md}"
    );
    let (t, s) = (
        tf["total_mae"].as_f64().unwrap(),
        so["total_mae"].as_f64().unwrap(),
    );
    assert!(
        t < s,
        "|F|: TransForce MAE {t:.3} N is not below source-only {s:.3} N\n{md}"
    );
    eprintln!("{md}");
    assert!(stdout.contains("TransForce beats source-only"), "{stdout}");

    // Translation brings the source images towards the target's (seen group): in colour
    // statistics, by more than half.
    let fid_row = |pair: &str| {
        table["fid"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["pair"] == pair && r["group"] == "seen")
            .unwrap_or_else(|| panic!("no FID row for {pair}\n{md}"))
            .clone()
    };
    let colour = |pair: &str| fid_row(pair)["colour_fd"].as_f64().unwrap();
    assert!(colour("Î_t–I_t") < 0.5 * colour("I_s–I_t"), "{md}");
    // With the Inception weights (CI fetches them): real FID and KID on the demo's fixed
    // samples of 64 images, KID over 100 subsets of 64 (said in a note).
    if std::env::var("RIG_REQUIRE_INCEPTION").as_deref() == Ok("1") {
        for pair in ["I_s–I_t", "Î_t–I_t", "I_s–Î_t"] {
            let r = fid_row(pair);
            assert_eq!(r["n"], serde_json::json!([64, 64]), "{pair}\n{md}");
            let (fid, kid) = (r["fid"].as_f64(), r["kid"].as_f64());
            assert!(
                fid.is_some_and(|f| f.is_finite() && f > 0.0),
                "{pair}\n{md}"
            );
            assert!(kid.is_some_and(f64::is_finite), "{pair}\n{md}");
            assert_eq!(
                r["kid_subsets"],
                serde_json::json!([100, 64]),
                "{pair}\n{md}"
            );
        }
        // The translation shows in Inception's features too. Release runs of this demo on
        // 2026-11-28: FID Î_t–I_t 141.9 and 137.9 against I_s–I_t 328.0 and 329.2 (×0.43,
        // ×0.42). Generators that upsample by resizing instead of transposed convolutions gave
        // ×0.68 (nearest) and ×0.77 (bilinear) with Fz errors nearly twice as large; the bound
        // catches a translator that has fallen back that far. (An earlier version of this demo
        // measured it the other way, 163 against 102, and asserted no order: 7dfb8bb.)
        let fid = |pair: &str| fid_row(pair)["fid"].as_f64().unwrap();
        let (after, before) = (fid("Î_t–I_t"), fid("I_s–I_t"));
        assert!(
            after < 0.6 * before,
            "FID Î_t–I_t {after:.1} is not below 0.6 × FID I_s–I_t {before:.1}\n{md}"
        );
        assert!(
            md.contains("KID subsets are smaller than the reference 1000"),
            "{md}"
        );
    }
}
