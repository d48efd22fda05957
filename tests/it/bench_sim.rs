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
    // The run's physics stepped along a trajectory: on its default grid against the finest
    // (quick: 0.4 against 0.8 mm, each a few percent apart), and the cheaper models beside it.
    let sensor = |cell: f64| {
        rows.iter()
            .find(|r| r.model == "sensor" && r.cell_mm == Some(cell))
            .unwrap()
    };
    assert_eq!(sensor(0.4).rel_error, 0.0);
    let (fz, ft) = (sensor(0.4).force_n, sensor(0.4).shear_n.unwrap().0);
    // Sliding 1 mm at 0.5 mm deep: a real shear, never above Coulomb's bound μ|Fz| (|Fz| at
    // its peak; the shear peaks later, while Fz relaxes).
    let mu = rig_core::config::ElastomerConfig::default().friction_coefficient;
    assert!(
        ft > 0.3 * fz && ft <= mu * fz * 1.001,
        "Ft {ft}, Fz {fz}, μ {mu}"
    );
    assert!(
        sensor(0.8).rel_error > 0.0 && sensor(0.8).rel_error < 0.2,
        "{:?}",
        sensor(0.8)
    );
    for model in [
        "sensor, no relaxation",
        "half-space + friction",
        "winkler + friction",
    ] {
        let r = rows.iter().find(|r| r.model == model).unwrap();
        assert!(r.rel_error > 0.0 && r.rel_error.is_finite(), "{r:?}");
    }

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
