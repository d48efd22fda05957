//! [`RigConfig::validate`]: every value checked, each problem naming its TOML key path and the
//! reason, e.g. `plan.depths_mm[2]: 1.2 mm exceeds safety.max_depth_mm = 1.0 mm`.

use super::ids::{format_angle_deg, format_depth_mm, is_id};
use super::schema::{CameraKind, Controller, ForceSensorKind, RigConfig};
use crate::problem::Problem;

/// Most trajectories one plan may hold (the paper's plan has 240), so a typo cannot make a plan
/// that exhausts memory or runs for months.
pub const MAX_TRAJECTORIES: usize = 100_000;

/// The camera rates a config may ask for, frames per second: below one frame a second a
/// trajectory has almost no frames (and the stream watchdogs count seconds); above 1000 no
/// V4L2 tactile camera delivers.
pub const MIN_FPS: f64 = 1.0;
pub const MAX_FPS: f64 = 1000.0;

impl RigConfig {
    /// Checks every value; returns all problems found, each naming its key path.
    ///
    /// Contract: a configuration that passes is safe to plan with — depths within
    /// `safety.max_depth_mm` and the elastomer thickness, contact points and their shear paths on
    /// the gel, speeds within `safety.max_speed_mm_s`, a non-empty envelope, an RTDE frequency the
    /// controller offers. Whether the envelope contains the plan's waypoints is checked when the
    /// plan is built (that needs the pose maths).
    pub fn validate(&self) -> Result<(), Vec<Problem>> {
        let mut v = Validator::default();
        self.validate_robot(&mut v);
        self.validate_sensor(&mut v);
        self.validate_elastomer(&mut v);
        self.validate_safety(&mut v);
        self.validate_plan(&mut v);
        self.validate_devices(&mut v);
        self.validate_optics(&mut v);
        if v.problems.is_empty() {
            Ok(())
        } else {
            Err(v.problems)
        }
    }

    fn validate_robot(&self, v: &mut Validator) {
        let r = &self.robot;
        if r.host.trim().is_empty() {
            v.push(
                "robot.host",
                "must not be empty (an IP address or host name)",
            );
        }
        for (key, port) in [
            ("robot.rtde_port", r.rtde_port),
            ("robot.dashboard_port", r.dashboard_port),
            ("robot.script_port", r.script_port),
        ] {
            if port == 0 {
                v.push(key, "port 0 is not a usable TCP port");
            }
        }
        let max_hz = r.controller.max_rtde_frequency_hz();
        if v.positive("robot.rtde_frequency_hz", r.rtde_frequency_hz)
            && r.rtde_frequency_hz > max_hz
        {
            let ctrl = match r.controller {
                Controller::ESeries => "e-series",
                Controller::Cb3 => "cb3",
            };
            v.push(
                "robot.rtde_frequency_hz",
                format!(
                    "{:?} Hz exceeds the {:?} Hz a {ctrl} controller offers (robot.controller = \"{ctrl}\")",
                    r.rtde_frequency_hz, max_hz
                ),
            );
        }
        if v.positive("robot.watchdog_min_hz", r.watchdog_min_hz)
            && r.watchdog_min_hz > r.rtde_frequency_hz
        {
            v.push(
                "robot.watchdog_min_hz",
                format!(
                    "{:?} Hz is above robot.rtde_frequency_hz = {:?} Hz; the watchdog would always fire",
                    r.watchdog_min_hz, r.rtde_frequency_hz
                ),
            );
        }
        if let Some(tcp) = &r.tcp_offset {
            for (i, x) in tcp.iter().enumerate() {
                v.finite(&format!("robot.tcp_offset[{i}]"), *x);
            }
        }
    }

    fn validate_sensor(&self, v: &mut Validator) {
        let s = &self.sensor;
        if s.id.is_empty() {
            v.push("sensor.id", "must not be empty");
        } else if !is_id(&s.id) {
            v.push(
                "sensor.id",
                format!(
                    "{:?} may only contain letters, digits, '_', '-' and '.' (it names dataset files)",
                    s.id
                ),
            );
        }
        for (i, x) in s.surface_frame.to_array().iter().enumerate() {
            v.finite(&format!("sensor.surface_frame[{i}]"), *x);
        }
    }

    fn validate_elastomer(&self, v: &mut Validator) {
        let e = &self.elastomer;
        v.positive("elastomer.size_x_mm", e.size_x_mm);
        v.positive("elastomer.size_y_mm", e.size_y_mm);
        v.positive("elastomer.thickness_mm", e.thickness_mm);
        v.positive("elastomer.youngs_modulus_mpa", e.youngs_modulus_mpa);
        if !(e.poisson_ratio.is_finite() && (0.0..0.5).contains(&e.poisson_ratio)) {
            v.push(
                "elastomer.poisson_ratio",
                format!("{:?} must be in [0, 0.5)", e.poisson_ratio),
            );
        }
        if !(e.friction_coefficient.is_finite() && e.friction_coefficient >= 0.0) {
            v.push(
                "elastomer.friction_coefficient",
                format!("{:?} must be finite and ≥ 0", e.friction_coefficient),
            );
        }
        if !(e.instant_modulus_ratio.is_finite() && e.instant_modulus_ratio >= 1.0) {
            v.push(
                "elastomer.instant_modulus_ratio",
                format!(
                    "{:?} must be finite and ≥ 1 (1 turns relaxation off)",
                    e.instant_modulus_ratio
                ),
            );
        }
        v.positive("elastomer.relaxation_time_s", e.relaxation_time_s);
    }

    fn validate_safety(&self, v: &mut Validator) {
        let s = &self.safety;
        let env = &s.envelope;
        let mut finite = true;
        for (key, value, _, _) in env.limits() {
            finite &= v.finite(&format!("safety.envelope.{key}"), value);
        }
        if finite {
            for (axis, lo, hi) in [
                ("x", env.min_x, env.max_x),
                ("y", env.min_y, env.max_y),
                ("z", env.min_z, env.max_z),
            ] {
                if lo >= hi {
                    v.push(
                        format!("safety.envelope.min_{axis}"),
                        format!(
                            "{lo:?} m is not below safety.envelope.max_{axis} = {hi:?} m (empty envelope)"
                        ),
                    );
                }
            }
        }
        if v.positive("safety.max_depth_mm", s.max_depth_mm)
            && self.elastomer.thickness_mm.is_finite()
            && s.max_depth_mm > self.elastomer.thickness_mm
        {
            v.push(
                "safety.max_depth_mm",
                format!(
                    "{:?} mm exceeds elastomer.thickness_mm = {:?} mm (the indenter would reach the sensor's window)",
                    s.max_depth_mm, self.elastomer.thickness_mm
                ),
            );
        }
        v.positive("safety.max_force_n", s.max_force_n);
        v.positive("safety.max_speed_mm_s", s.max_speed_mm_s);
    }

    fn validate_plan(&self, v: &mut Validator) {
        let p = &self.plan;
        let e = &self.elastomer;
        let s = &self.safety;

        if p.contact_points_mm.is_empty() {
            v.push("plan.contact_points_mm", "needs at least one [x, y] point");
        }
        if p.depths_mm.is_empty() {
            v.push("plan.depths_mm", "needs at least one depth");
        }
        if p.directions_deg.is_empty() {
            v.push("plan.directions_deg", "needs at least one direction");
        }
        let count = p
            .contact_points_mm
            .len()
            .saturating_mul(p.depths_mm.len())
            .saturating_mul(p.directions_deg.len());
        if count > MAX_TRAJECTORIES {
            v.push(
                "plan",
                format!(
                    "{count} trajectories (points × depths × directions) is more than the {MAX_TRAJECTORIES} a plan may hold"
                ),
            );
        }
        let shear_ok = v.positive("plan.shear_distance_mm", p.shear_distance_mm);
        v.positive("plan.approach_height_mm", p.approach_height_mm);

        // Depths: positive, within the safety limit and the gel, distinct (they name trajectories).
        for (i, &d) in p.depths_mm.iter().enumerate() {
            let key = format!("plan.depths_mm[{i}]");
            if !v.positive(&key, d) {
                continue;
            }
            if d > s.max_depth_mm {
                v.push(
                    &key,
                    format!(
                        "{d:?} mm exceeds safety.max_depth_mm = {:?} mm",
                        s.max_depth_mm
                    ),
                );
            } else if d > e.thickness_mm {
                v.push(
                    &key,
                    format!(
                        "{d:?} mm exceeds elastomer.thickness_mm = {:?} mm",
                        e.thickness_mm
                    ),
                );
            }
            if let Some(j) = p.depths_mm[..i]
                .iter()
                .position(|&o| format_depth_mm(o) == format_depth_mm(d))
            {
                v.push(&key, format!("{d:?} mm repeats plan.depths_mm[{j}]"));
            }
        }

        // Directions: in [0, 360), distinct.
        for (i, &a) in p.directions_deg.iter().enumerate() {
            let key = format!("plan.directions_deg[{i}]");
            if !(a.is_finite() && (0.0..360.0).contains(&a)) {
                v.push(&key, format!("{a:?}° must be in [0, 360)"));
                continue;
            }
            if let Some(j) = p.directions_deg[..i]
                .iter()
                .position(|&o| format_angle_deg(o) == format_angle_deg(a))
            {
                v.push(&key, format!("{a:?}° repeats plan.directions_deg[{j}]"));
            }
        }

        // Contact points and their shear paths must stay on the gel (the indenter axis never
        // leaves it, so the indenter does not press onto the sensor's frame).
        let half_x = e.size_x_mm / 2.0;
        let half_y = e.size_y_mm / 2.0;
        let reach = if shear_ok { p.shear_distance_mm } else { 0.0 };
        for (i, pt) in p.contact_points_mm.iter().enumerate() {
            let key = format!("plan.contact_points_mm[{i}]");
            if !(pt[0].is_finite() && pt[1].is_finite()) {
                v.push(&key, "coordinates must be finite numbers (mm)");
                continue;
            }
            if pt[0].abs() > half_x || pt[1].abs() > half_y {
                v.push(
                    &key,
                    format!(
                        "[{:?}, {:?}] mm lies off the gel (|x| ≤ elastomer.size_x_mm / 2 = {half_x:?} mm, |y| ≤ elastomer.size_y_mm / 2 = {half_y:?} mm)",
                        pt[0], pt[1]
                    ),
                );
                continue;
            }
            for &a in p.directions_deg.iter().filter(|a| a.is_finite()) {
                let (sin, cos) = a.to_radians().sin_cos();
                let end = [pt[0] + reach * cos, pt[1] + reach * sin];
                // A hair of tolerance so that exactly reaching the edge is accepted.
                if end[0].abs() > half_x + 1e-9 || end[1].abs() > half_y + 1e-9 {
                    v.push(
                        &key,
                        format!(
                            "shearing {reach:?} mm at {a:?}° from [{:?}, {:?}] mm ends at [{:.3}, {:.3}] mm, off the gel (|x| ≤ {half_x:?} mm, |y| ≤ {half_y:?} mm); reduce plan.shear_distance_mm or move the point",
                            pt[0], pt[1], end[0], end[1]
                        ),
                    );
                    break;
                }
            }
        }

        for (name, m) in [("down", &p.down), ("shear", &p.shear), ("up", &p.up)] {
            let key = format!("plan.{name}.speed_mm_s");
            if v.positive(&key, m.speed_mm_s) && m.speed_mm_s > s.max_speed_mm_s {
                v.push(
                    &key,
                    format!(
                        "{:?} mm/s exceeds safety.max_speed_mm_s = {:?} mm/s",
                        m.speed_mm_s, s.max_speed_mm_s
                    ),
                );
            }
            v.positive(&format!("plan.{name}.accel_mm_s2"), m.accel_mm_s2);
        }
    }

    fn validate_optics(&self, v: &mut Validator) {
        let Some(optics) = &self.optics else { return };
        v.problems.extend(optics.problems());
        // The simulated camera renders at the optics resolution: the two must agree.
        if let Some(cam) = &self.camera
            && cam.kind == CameraKind::Sim
        {
            for (key, o, c) in [
                ("width_px", optics.width_px, cam.width_px),
                ("height_px", optics.height_px, cam.height_px),
            ] {
                if o != c {
                    v.push(
                        format!("optics.{key}"),
                        format!(
                            "{o} differs from camera.{key} = {c}; the simulated camera renders \
                             at the optics resolution, so set both to the same value"
                        ),
                    );
                }
            }
        }
    }

    fn validate_devices(&self, v: &mut Validator) {
        if let Some(ft) = &self.force_sensor {
            let missing = |field: &str| -> bool {
                match field {
                    "port" => ft.port.as_deref().is_none_or(|s| s.trim().is_empty()),
                    "address" => ft.address.as_deref().is_none_or(|s| s.trim().is_empty()),
                    _ => false,
                }
            };
            match ft.kind {
                ForceSensorKind::Serial | ForceSensorKind::Daq if missing("port") => v.push(
                    "force_sensor.port",
                    "required when force_sensor.kind is \"serial\" or \"daq\" (e.g. \"/dev/ttyUSB0\")",
                ),
                ForceSensorKind::Netft if missing("address") => v.push(
                    "force_sensor.address",
                    "required when force_sensor.kind is \"netft\" (e.g. \"192.168.1.1\")",
                ),
                _ => {}
            }
            if ft.baud == Some(0) {
                v.push("force_sensor.baud", "must be positive");
            }
            v.positive("force_sensor.rate_hz", ft.rate_hz);
            for (key, val) in [
                ("force_sensor.counts_per_force", ft.counts_per_force),
                ("force_sensor.counts_per_torque", ft.counts_per_torque),
            ] {
                if let Some(x) = val {
                    v.positive(key, x);
                }
            }
            if let Some(m) = ft.max_loads {
                for (i, x) in m.iter().enumerate() {
                    v.positive(&format!("force_sensor.max_loads[{i}]"), *x);
                }
            }
            if ft.kind == ForceSensorKind::Nidaqmx {
                Self::validate_nidaqmx(ft, v);
            }
            if ft.tare_samples < 2 {
                v.push("force_sensor.tare_samples", "must be at least 2");
            }
            let r = ft.tool_rotation_deg.map(f64::to_radians);
            if let Err(e) = crate::ft::transform::ToolTransform::from_angles(ft.tool_offset_mm, r) {
                v.push("force_sensor.tool_offset_mm", e.to_string());
            }
        }
        if let Some(cam) = &self.camera {
            if cam.kind == CameraKind::V4l2
                && cam.device.as_deref().is_none_or(|s| s.trim().is_empty())
            {
                v.push(
                    "camera.device",
                    "required when camera.kind is \"v4l2\" (e.g. \"/dev/video0\")",
                );
            }
            if cam.width_px == 0 {
                v.push("camera.width_px", "must be positive");
            }
            if cam.height_px == 0 {
                v.push("camera.height_px", "must be positive");
            }
            if !(1..=100).contains(&cam.jpeg_quality) {
                v.push(
                    "camera.jpeg_quality",
                    format!("{} is outside 1..=100", cam.jpeg_quality),
                );
            }
            if v.positive("camera.fps", cam.fps) && !(MIN_FPS..=MAX_FPS).contains(&cam.fps) {
                v.push(
                    "camera.fps",
                    format!(
                        "{} is outside {MIN_FPS}..={MAX_FPS} frames per second (a GelSight Mini runs at 25)",
                        cam.fps
                    ),
                );
            }
        }
    }
}

impl RigConfig {
    /// The NI-DAQmx route's keys: the channels, the rate, the calibration file.
    fn validate_nidaqmx(ft: &super::schema::ForceSensorConfig, v: &mut Validator) {
        use crate::ft::nidaqmx;
        let gauges = ft.channels.as_deref().unwrap_or(nidaqmx::DEFAULT_CHANNELS);
        if let Err(e) = nidaqmx::check_channels(gauges, ft.thermistor_channel.as_deref()) {
            let key = if e.contains("thermistor") {
                "force_sensor.thermistor_channel"
            } else {
                "force_sensor.channels"
            };
            v.push(key, e);
        }
        if ft.rate_hz.is_finite() && ft.rate_hz > 0.0 && ft.rate_hz < nidaqmx::MIN_RATE_HZ {
            v.push(
                "force_sensor.rate_hz",
                format!(
                    "{} Hz is below {} Hz, the least the NI route samples at (ATI's default \
                     is 1000 Hz)",
                    ft.rate_hz,
                    nidaqmx::MIN_RATE_HZ
                ),
            );
        }
        if ft.calibration_file.is_none() {
            v.push(
                "force_sensor.calibration_file",
                "required when force_sensor.kind is \"nidaqmx\": the rig applies the sensor's \
                 .cal file to the gauge voltages (it is on the sensor's CD)",
            );
        }
        if ft
            .library
            .as_ref()
            .is_some_and(|p| p.as_os_str().is_empty())
        {
            v.push(
                "force_sensor.library",
                "is empty: give the path of libnidaqmx.so, or leave the key out to search the \
                 system's libraries",
            );
        }
    }
}

#[derive(Default)]
struct Validator {
    problems: Vec<Problem>,
}

impl Validator {
    fn push(&mut self, key: impl Into<String>, reason: impl Into<String>) {
        self.problems.push(Problem {
            key: key.into(),
            reason: reason.into(),
        });
    }

    /// Records a problem unless `x` is finite; returns whether it is.
    fn finite(&mut self, key: &str, x: f64) -> bool {
        if x.is_finite() {
            true
        } else {
            self.push(key, format!("{x:?} is not a finite number"));
            false
        }
    }

    /// Records a problem unless `x` is finite and > 0; returns whether it is.
    fn positive(&mut self, key: &str, x: f64) -> bool {
        if x.is_finite() && x > 0.0 {
            true
        } else {
            self.push(key, format!("{x:?} must be a finite number > 0"));
            false
        }
    }
}
