//! Rig configuration: the shipped files parse, defaults match the paper, and every kind of
//! mistake is reported with its key path.

use rig_core::config::{
    CameraKind, ConfigError, Controller, ForceSensorKind, OnFailure, RigConfig, SensorRole,
    format_angle_deg, format_depth_mm,
};

fn repo_file(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// The embedded sim-source text with one line replaced (`from` must occur).
fn sim_with(from: &str, to: &str) -> String {
    let text = rig_core::config::SIM_SOURCE_TOML;
    assert!(
        text.contains(from),
        "test setup: {from:?} not in sim-source.toml"
    );
    text.replacen(from, to, 1)
}

fn error_of(text: &str) -> ConfigError {
    match RigConfig::from_toml_str(text) {
        Ok(_) => panic!("config was accepted:\n{text}"),
        Err(e) => e,
    }
}

#[test]
fn sim_source_matches_the_paper_defaults() {
    let c = RigConfig::sim_source();
    assert_eq!(c.sensor.id, "sim-source");
    assert_eq!(c.sensor.role, SensorRole::Source);
    assert_eq!(c.robot.controller, Controller::ESeries);
    assert_eq!(c.robot.rtde_frequency_hz, 500.0);
    assert_eq!(c.plan.contact_points_mm.len(), 5);
    assert_eq!(c.plan.depths_mm, vec![0.2, 0.4, 0.6, 0.8]);
    assert_eq!(c.plan.directions_deg.len(), 12);
    assert_eq!(c.elastomer.size_x_mm, 10.0);
    assert_eq!(c.elastomer.size_y_mm, 8.0);
    assert_eq!(c.elastomer.thickness_mm, 3.0);
    assert_eq!(c.safety.on_failure, OnFailure::Stop);
    assert_eq!(
        c.force_sensor.as_ref().map(|f| f.kind),
        Some(ForceSensorKind::Sim)
    );
    assert_eq!(c.camera.as_ref().map(|c| c.kind), Some(CameraKind::Sim));
    // The file spells out the defaults: the built-in defaults and the file agree.
    assert_eq!(c.plan, rig_core::config::PlanConfig::default());
    assert_eq!(c.elastomer, rig_core::config::ElastomerConfig::default());
}

#[test]
fn sim_target_differs_only_in_identity() {
    let s = RigConfig::sim_source();
    let t = RigConfig::sim_target();
    assert_eq!(t.sensor.id, "sim-target");
    assert_eq!(t.sensor.role, SensorRole::Target);
    assert_eq!(t.sensor.surface_frame, s.sensor.surface_frame);
    assert_eq!(t.plan, s.plan);
    assert_eq!(t.safety, s.safety);
    // The same recipe, another batch: only the modulus differs, by 5 %.
    assert_eq!(
        rig_core::config::ElastomerConfig {
            youngs_modulus_mpa: s.elastomer.youngs_modulus_mpa,
            ..t.elastomer.clone()
        },
        s.elastomer
    );
    let ratio = t.elastomer.youngs_modulus_mpa / s.elastomer.youngs_modulus_mpa;
    assert!((ratio - 1.0545).abs() < 1e-3, "{ratio}");
}

/// The target sensor is another build of the same design: beside its LEDs, background and
/// markers, its camera is mounted a fraction of a mm off centre and turned a degree or two
/// (assembly tolerance), and it is noisier; both record their markers.
#[test]
fn sim_target_camera_sits_otherwise_and_is_noisier() {
    let s = RigConfig::sim_source().optics.unwrap();
    let t = RigConfig::sim_target().optics.unwrap();
    assert_eq!(s.camera_offset_mm, [0.0, 0.0]);
    assert_eq!(s.camera_rotation_deg, 0.0);
    let off = t.camera_offset_mm[0].hypot(t.camera_offset_mm[1]);
    assert!(off > 0.1 && off < 0.5, "{:?}", t.camera_offset_mm);
    assert!(
        t.camera_rotation_deg.abs() >= 0.5 && t.camera_rotation_deg.abs() <= 3.0,
        "{}",
        t.camera_rotation_deg
    );
    assert!(s.effects.markers && t.effects.markers);
    assert!(s.effects.noise_sigma > 0.0);
    assert!(t.effects.noise_sigma > s.effects.noise_sigma);
    assert_eq!(
        (s.width_px, s.height_px, s.mm_per_px),
        (t.width_px, t.height_px, t.mm_per_px)
    );
}

#[test]
fn shipped_files_load_from_disk() {
    for name in ["sim-source", "sim-target", "lab-example"] {
        let path = repo_file(&format!("rig-configs/{name}.toml"));
        let c = RigConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(!c.sensor.id.is_empty());
    }
    let lab = RigConfig::load(repo_file("rig-configs/lab-example.toml")).unwrap();
    assert_eq!(lab.force_sensor.unwrap().kind, ForceSensorKind::Serial);
    assert_eq!(lab.camera.unwrap().kind, CameraKind::V4l2);
    assert_ne!(lab.robot.host, "127.0.0.1");
}

#[test]
fn minimal_config_fills_defaults() {
    let text = r#"
        [sensor]
        id = "s1"
        role = "target"
        surface_frame = [0.4, 0.0, 0.2, 0.0, 0.0, 0.0]

        [safety.envelope]
        min_x = 0.3
        max_x = 0.5
        min_y = -0.1
        max_y = 0.1
        min_z = 0.199
        max_z = 0.3
    "#;
    let c = RigConfig::from_toml_str(text).unwrap();
    assert_eq!(c.robot.host, "127.0.0.1");
    assert_eq!(c.robot.rtde_port, 30004);
    assert_eq!(c.robot.dashboard_port, 29999);
    assert_eq!(c.robot.script_port, 30002);
    assert_eq!(c.robot.watchdog_min_hz, 10.0);
    assert_eq!(c.safety.max_depth_mm, 1.0);
    assert!(c.force_sensor.is_none());
    assert!(c.camera.is_none());
    assert_eq!(c.plan.shear_distance_mm, 2.0);
    assert_eq!(c.plan.approach_height_mm, 2.0);
}

#[test]
fn serialised_config_parses_back_equal() {
    let c = RigConfig::sim_source();
    let text = toml::to_string(&c).unwrap();
    assert_eq!(RigConfig::from_toml_str(&text).unwrap(), c);
}

#[test]
fn depth_beyond_safety_limit_names_the_index() {
    let e = error_of(&sim_with(
        "depths_mm = [0.2, 0.4, 0.6, 0.8]",
        "depths_mm = [0.2, 0.4, 1.2]",
    ));
    assert_eq!(
        e.to_string(),
        "rig config <string>: plan.depths_mm[2]: 1.2 mm exceeds safety.max_depth_mm = 1.0 mm"
    );
    assert_eq!(e.keys(), vec!["plan.depths_mm[2]".to_string()]);
}

#[test]
fn unknown_key_is_rejected_with_its_path() {
    let e = error_of(&sim_with("shear_distance_mm = 2.0", "shear_distance = 2.0"));
    let msg = e.to_string();
    assert!(msg.contains("plan.shear_distance"), "{msg}");
    assert!(msg.contains("unknown field"), "{msg}");
    assert!(msg.contains("line "), "{msg}");

    let e = error_of(&sim_with("min_z = 0.199", "min_z = 0.199\nfloor_z = 0.1"));
    assert_eq!(e.keys(), vec!["safety.envelope.floor_z".to_string()]);

    let e = error_of(&format!(
        "{}\n[robto]\nhost = \"x\"\n",
        rig_core::config::SIM_SOURCE_TOML
    ));
    assert_eq!(e.keys(), vec!["robto".to_string()], "{e}");

    let e = error_of(&sim_with("[safety.envelope]", "[safety.envelop]"));
    assert_eq!(e.keys(), vec!["safety.envelop".to_string()], "{e}");

    // Inside an inline table.
    let e = error_of(&sim_with("down = { speed_mm_s", "down = { sped_mm_s"));
    assert_eq!(e.keys(), vec!["plan.down.sped_mm_s".to_string()], "{e}");
    assert!(
        e.to_string()
            .contains("expected `speed_mm_s` or `accel_mm_s2`"),
        "{e}"
    );
}

#[test]
fn wrong_type_names_the_key() {
    let e = error_of(&sim_with("rtde_port = 30004", "rtde_port = \"30004\""));
    assert_eq!(e.keys(), vec!["robot.rtde_port".to_string()], "{e}");

    let e = error_of(&sim_with(
        "controller = \"e-series\"",
        "controller = \"cb2\"",
    ));
    assert_eq!(e.keys(), vec!["robot.controller".to_string()], "{e}");
    assert!(
        e.to_string().contains("cb3"),
        "the message lists the options: {e}"
    );
}

#[test]
fn missing_key_names_the_table_and_field() {
    let e = error_of(&sim_with("min_z = 0.199\n", ""));
    assert_eq!(e.keys(), vec!["safety.envelope.min_z".to_string()], "{e}");

    let text = rig_core::config::SIM_SOURCE_TOML;
    let start = text.find("[sensor]").unwrap();
    let end = text.find("[elastomer]").unwrap();
    let without_sensor = format!("{}{}", &text[..start], &text[end..]);
    let e = error_of(&without_sensor);
    assert_eq!(e.keys(), vec!["sensor".to_string()], "{e}");

    // Also when the document starts with a table header.
    let e = error_of("[robot]\nhost = \"10.0.0.2\"\n");
    assert_eq!(e.keys(), vec!["sensor".to_string()], "{e}");
    assert!(matches!(e, ConfigError::Parse { line: None, .. }), "{e:?}");

    let e = error_of(&sim_with("down = { speed_mm_s = 1.0, ", "down = { "));
    assert_eq!(e.keys(), vec!["plan.down.speed_mm_s".to_string()], "{e}");
}

#[test]
fn cb3_cannot_stream_at_500_hz() {
    let e = error_of(&sim_with(
        "controller = \"e-series\"",
        "controller = \"cb3\"",
    ));
    let msg = e.to_string();
    assert!(
        msg.contains("robot.rtde_frequency_hz: 500.0 Hz exceeds the 125"),
        "{msg}"
    );
}

#[test]
fn empty_envelope_is_refused() {
    let e = error_of(&sim_with("max_z = 0.25", "max_z = 0.1"));
    assert_eq!(e.keys(), vec!["safety.envelope.min_z".to_string()], "{e}");
}

#[test]
fn max_depth_may_not_exceed_the_gel() {
    let e = error_of(&sim_with("max_depth_mm = 1.0", "max_depth_mm = 3.5"));
    assert!(
        e.to_string()
            .contains("safety.max_depth_mm: 3.5 mm exceeds elastomer.thickness_mm"),
        "{e}"
    );
}

#[test]
fn points_and_shear_paths_stay_on_the_gel() {
    let e = error_of(&sim_with("[3.0, 2.0]]", "[6.0, 2.0]]"));
    assert_eq!(
        e.keys(),
        vec!["plan.contact_points_mm[4]".to_string()],
        "{e}"
    );

    let e = error_of(&sim_with(
        "shear_distance_mm = 2.0",
        "shear_distance_mm = 2.5",
    ));
    assert!(
        e.to_string().contains("reduce plan.shear_distance_mm"),
        "{e}"
    );
}

#[test]
fn speeds_are_limited() {
    let e = error_of(&sim_with(
        "up = { speed_mm_s = 5.0",
        "up = { speed_mm_s = 80.0",
    ));
    assert_eq!(e.keys(), vec!["plan.up.speed_mm_s".to_string()], "{e}");
}

/// The shipped simulated sensors send MJPEG, as a GelSight Mini does; `raw` and the quality are
/// read, and a quality outside JPEG's 1..=100 names its key (u8 overflow is a parse error).
#[test]
fn the_camera_format_is_read_and_checked() {
    use rig_core::config::CameraFormat;
    for text in [
        rig_core::config::SIM_SOURCE_TOML,
        rig_core::config::SIM_TARGET_TOML,
    ] {
        let c = RigConfig::from_toml_str(text).unwrap();
        let cam = c.camera.unwrap();
        assert_eq!((cam.format, cam.jpeg_quality), (CameraFormat::Mjpeg, 90));
    }
    let raw = sim_with("format = \"mjpeg\"", "format = \"raw\"");
    let cam = RigConfig::from_toml_str(&raw).unwrap().camera.unwrap();
    assert_eq!(cam.format, CameraFormat::Raw);
    let e = error_of(&sim_with("jpeg_quality = 90", "jpeg_quality = 0"));
    assert_eq!(e.keys(), vec!["camera.jpeg_quality".to_string()], "{e}");
    let e = error_of(&sim_with("format = \"mjpeg\"", "format = \"png\""));
    assert!(e.to_string().contains("format"), "{e}");
}

/// Extreme values are config errors naming their key, not panics or a run that stalls later.
#[test]
fn extreme_camera_rates_and_speeds_are_refused() {
    for fps in ["1e-9", "0.5", "1e9", "0.0", "-25.0", "nan", "inf"] {
        let e = error_of(&sim_with("fps = 25.0", &format!("fps = {fps}")));
        assert_eq!(e.keys(), vec!["camera.fps".to_string()], "fps {fps}: {e}");
    }
    for (stage, speed) in [("down", "0.0"), ("down", "-1.0"), ("up", "-5.0")] {
        let from = if stage == "down" {
            "down = { speed_mm_s = 1.0"
        } else {
            "up = { speed_mm_s = 5.0"
        };
        let e = error_of(&sim_with(
            from,
            &format!("{stage} = {{ speed_mm_s = {speed}"),
        ));
        assert_eq!(
            e.keys(),
            vec![format!("plan.{stage}.speed_mm_s")],
            "{stage} {speed}: {e}"
        );
    }
}

/// A hundred thousand contact points make a plan far past the limit: refused with the count.
#[test]
fn a_plan_of_a_hundred_thousand_points_is_refused() {
    let points: Vec<String> = (0..100_000)
        .map(|i| {
            format!(
                "[{:.3}, {:.3}]",
                (i % 300) as f64 * 0.01 - 1.5,
                (i / 300) as f64 * 0.01 - 1.5
            )
        })
        .collect();
    let text = sim_with(
        "contact_points_mm = [[0.0, 0.0], [-3.0, -2.0], [3.0, -2.0], [-3.0, 2.0], [3.0, 2.0]]",
        &format!("contact_points_mm = [{}]", points.join(", ")),
    );
    let e = error_of(&text);
    assert!(e.to_string().contains("4800000 trajectories"), "{e}");
}

#[test]
fn duplicate_and_out_of_range_directions() {
    let e = error_of(&sim_with("330.0]", "330.0, 30.0, 360.0]"));
    assert_eq!(
        e.keys(),
        vec![
            "plan.directions_deg[12]".to_string(),
            "plan.directions_deg[13]".to_string()
        ],
        "{e}"
    );
}

#[test]
fn device_sections_need_their_addresses() {
    let e = error_of(&sim_with(
        "kind = \"sim\"                # the simulated Nano17",
        "kind = \"serial\"",
    ));
    assert_eq!(e.keys(), vec!["force_sensor.port".to_string()], "{e}");
    let e = error_of(&sim_with(
        "kind = \"sim\"                # the simulated GelSight camera",
        "kind = \"v4l2\"",
    ));
    assert_eq!(e.keys(), vec!["camera.device".to_string()], "{e}");
}

#[test]
fn all_problems_are_reported_together() {
    let text = sim_with("thickness_mm = 3.0", "thickness_mm = -1.0").replacen(
        "id = \"sim-source\"",
        "id = \"bad id/\"",
        1,
    );
    let e = error_of(&text);
    let keys = e.keys();
    assert!(keys.contains(&"elastomer.thickness_mm".to_string()), "{e}");
    assert!(keys.contains(&"sensor.id".to_string()), "{e}");
    assert!(e.to_string().contains("problems:"), "{e}");
}

#[test]
fn invalid_toml_syntax_reports_a_line() {
    let e = error_of("[robot\nhost = 1");
    assert!(
        matches!(e, ConfigError::Parse { line: Some(1), .. }),
        "{e:?}"
    );
}

#[test]
fn missing_file_is_an_io_error_naming_the_path() {
    let e = RigConfig::load("/nonexistent/rig.toml").unwrap_err();
    assert!(e.to_string().contains("/nonexistent/rig.toml"), "{e}");
}

#[test]
fn trajectory_id_parts_are_stable() {
    assert_eq!(format_depth_mm(0.2), "0.2");
    assert_eq!(format_depth_mm(0.25), "0.25");
    assert_eq!(format_depth_mm(1.0), "1.0");
    assert_eq!(format_depth_mm(0.6000000000000001), "0.6");
    assert_eq!(format_angle_deg(0.0), "000");
    assert_eq!(format_angle_deg(30.0), "030");
    assert_eq!(format_angle_deg(330.0), "330");
    assert_eq!(format_angle_deg(22.5), "022.5");
}

#[test]
fn the_nidaqmx_route_checks_channels_rate_and_calibration() {
    let ni = |extra: &str| {
        sim_with(
            "kind = \"sim\"",
            &format!("kind = \"nidaqmx\"\ncalibration_file = \"x.cal\"\n{extra}"),
        )
    };
    let c = RigConfig::from_toml_str(&ni("")).unwrap();
    let fs = c.force_sensor.unwrap();
    assert_eq!(fs.kind, ForceSensorKind::Nidaqmx);
    assert_eq!(fs.channels, None);
    assert_eq!(
        fs.terminal_config,
        rig_core::ft::nidaqmx::TerminalConfig::Differential
    );
    RigConfig::from_toml_str(&ni(
        "channels = \"Dev2/ai8:13\"\nthermistor_channel = \"Dev2/ai14\"\nterminal_config = \"rse\"\nlibrary = \"/opt/ni/libnidaqmx.so\"",
    ))
    .unwrap();
    for (extra, key) in [
        ("channels = \"Dev1/ai0:6\"", "force_sensor.channels"),
        ("channels = \"Dev1/ao0:5\"", "force_sensor.channels"),
        (
            "thermistor_channel = \"Dev1/ai0\"",
            "force_sensor.thermistor_channel",
        ),
        ("library = \"\"", "force_sensor.library"),
    ] {
        let e = error_of(&ni(extra));
        assert!(e.keys().contains(&key.to_owned()), "{extra}: {e}");
    }
    let slow = ni("").replacen("rate_hz = 1000.0", "rate_hz = 999.0", 1);
    let e = error_of(&slow);
    assert!(e.to_string().contains("below 1000 Hz"), "{e}");
    assert!(e.keys().contains(&"force_sensor.rate_hz".to_owned()), "{e}");
    let no_cal = sim_with("kind = \"sim\"", "kind = \"nidaqmx\"");
    let e = error_of(&no_cal);
    assert!(
        e.keys()
            .contains(&"force_sensor.calibration_file".to_owned()),
        "{e}"
    );
}
