//! `rig bench sim --quick`: measures every model, writes the table, the SVG plot and the CSV.

use rig::cli::bench::sim::{SimBenchArgs, measure, run, table};

#[test]
fn quick_sim_bench_measures_every_model_and_writes_a_plot() {
    let rows = measure(true).unwrap();
    for model in ["hertz", "winkler", "half-space", "layer-thick", "layer"] {
        assert!(rows.iter().any(|r| r.model == model), "{model}");
    }
    for r in &rows {
        assert!(r.ms_per_frame >= 0.0 && r.force_n > 0.0, "{r:?}");
        assert!(r.rel_error.is_finite(), "{r:?}");
    }
    // Hertz is its own reference; the BEM half-space at 0.2 mm is within 2% of it.
    assert_eq!(rows[0].rel_error, 0.0);
    let hs = rows
        .iter()
        .find(|r| r.model == "half-space" && r.cell_mm == Some(0.2))
        .unwrap();
    assert!(hs.rel_error < 0.02, "{hs:?}");
    assert!(table(&rows).lines().count() == rows.len() + 2);

    let dir = tempfile::tempdir().unwrap();
    run(&SimBenchArgs {
        quick: true,
        out: dir.path().to_owned(),
    })
    .unwrap();
    let svg = std::fs::read_to_string(dir.path().join("sim.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("half-space"));
    let csv = std::fs::read_to_string(dir.path().join("sim.csv")).unwrap();
    assert!(csv.lines().count() > 5);
}
