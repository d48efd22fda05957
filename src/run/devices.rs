//! The rig a run drives: the lab's (robot endpoints, the configured F/T front end and V4L2
//! camera) or the simulated one ([`crate::simrig`]), its clock, and the robot connection.

use std::sync::Arc;

use anyhow::{Context, bail};
use rig_core::clock::Clock;
use rig_core::config::{CameraKind, ForceSensorKind, RigConfig};
use rig_core::indenter::Indenter;
use rig_core::pose::Pose;

use super::options::RunOptions;
use crate::camera::FrameSource;
use crate::force::{self, FrontEndSettings, FtStream};
use crate::record::{Manifest, Recorder, RecorderConfig, WriterGate};
use crate::robot::{Robot, RobotEndpoints, RobotOptions};
use crate::simrig::{self, RunningSimRig, SimFaultKind};

/// The F/T stream and the camera of the rig.
pub(super) struct Devices {
    /// `None`: no `[force_sensor]` (a target recorded for its images; forces are watched on the
    /// UR5e's flange sensor).
    pub ft: Option<FtStream>,
    pub camera: Option<Box<dyn FrameSource>>,
    /// The F/T's full range and front end, for the manifest (`null` without an F/T sensor).
    pub calibration: serde_json::Value,
    pub ft_rate_hz: f64,
    /// The F/T counts its samples on the host's own clock (the simulated rig's twins): its
    /// drift is zero by construction, so the clock map fits only the offset. A lab's F/T has a
    /// crystal of its own, whose drift is estimated.
    pub ft_on_host_clock: bool,
}

fn calibration_json(settings: &FrontEndSettings, description: &str) -> serde_json::Value {
    serde_json::json!({
        "front_end": description,
        "max_loads": settings.max_loads,
        "max_loads_units": "Fx Fy Fz in N, Tx Ty Tz in N·mm",
        "counts_per_force": settings.counts_per_force,
        "counts_per_torque": settings.counts_per_torque,
        "rate_hz": settings.rate_hz,
        "calibration_file": settings.calibration.as_ref().map(|c| serde_json::json!({
            "serial": c.serial,
            "max_loads": c.max_loads,
        })),
    })
}

/// The calibration keys in which a recording's and the open F/T's calibration differ, the front
/// end's description (its address) aside.
fn calibration_differences(recorded: &serde_json::Value, now: &serde_json::Value) -> Vec<String> {
    match super::output::differing_top_keys(recorded, now, &["front_end"]) {
        Some(keys) => keys,
        None if recorded == now => Vec::new(),
        None => vec!["the whole calibration".into()],
    }
}

/// The lab's F/T stream, its calibration for the manifest and its rate; `None` without a
/// `[force_sensor]` (the run checked that the role allows it: [`super::flange::guard`]).
async fn open_lab_ft(
    config: &RigConfig,
    clock: &Clock,
) -> anyhow::Result<Option<(FtStream, serde_json::Value, f64)>> {
    let Some(fs) = config.force_sensor.as_ref() else {
        return Ok(None);
    };
    if fs.kind == ForceSensorKind::Sim {
        bail!(
            "force_sensor.kind = \"sim\" needs the simulated rig (robot.simulated = true): a lab \
             robot pressing on a simulated sensor would record nothing real"
        );
    }
    let settings = FrontEndSettings::from_config(fs)?;
    let ft = force::open(fs, clock.clone()).await?;
    let calibration = calibration_json(&settings, &ft.description);
    Ok(Some((ft, calibration, settings.rate_hz)))
}

/// Nominal F/T rate when none is fitted (nothing is paced by it), Hz.
const NO_FT_RATE_HZ: f64 = 1000.0;

async fn open_lab_devices(config: &RigConfig, clock: &Clock) -> anyhow::Result<Devices> {
    let ft = open_lab_ft(config, clock).await?;
    let camera: Option<Box<dyn FrameSource>> = match &config.camera {
        None => None,
        Some(c) if c.kind == CameraKind::Sim => {
            bail!("camera.kind = \"sim\" needs the simulated rig (robot.simulated = true)")
        }
        Some(c) => Some(open_v4l2(c, clock)?),
    };
    let (ft, calibration, ft_rate_hz) = match ft {
        Some((ft, cal, hz)) => (Some(ft), cal, hz),
        None => (None, serde_json::Value::Null, NO_FT_RATE_HZ),
    };
    Ok(Devices {
        calibration,
        ft,
        camera,
        ft_rate_hz,
        ft_on_host_clock: false,
    })
}

#[cfg(feature = "v4l")]
fn open_v4l2(
    c: &rig_core::config::CameraConfig,
    clock: &Clock,
) -> anyhow::Result<Box<dyn FrameSource>> {
    use crate::camera::v4l2;
    let device = c
        .device
        .as_deref()
        .context("camera.device is required for a V4L2 camera (e.g. /dev/video0)")?;
    let src = v4l2::device::open(
        device,
        clock.clone(),
        &v4l2::Request::for_camera(c),
        &v4l2::V4l2Options::default(),
    )?;
    Ok(Box::new(src))
}

#[cfg(not(feature = "v4l"))]
fn open_v4l2(
    _c: &rig_core::config::CameraConfig,
    _clock: &Clock,
) -> anyhow::Result<Box<dyn FrameSource>> {
    bail!("this rig binary was built without V4L2 support; rebuild with `--features v4l`")
}

/// The rig of a run, open: its clock, where the robot is, its F/T and camera, and the
/// simulated rig itself when it is the simulated one.
pub(super) struct Rig {
    pub clock: Clock,
    pub endpoints: RobotEndpoints,
    pub devices: Devices,
    pub sim: Option<RunningSimRig>,
}

/// Opens the configured rig: the simulated one in-process (its UR5e's TCP starting at `home`),
/// or the lab's.
pub(super) async fn open_rig(
    config: &RigConfig,
    indenter: &Indenter,
    opts: &RunOptions,
    home: Pose,
) -> anyhow::Result<Rig> {
    if !config.robot.simulated {
        let clock = Clock::system();
        let ip = tokio::net::lookup_host((config.robot.host.as_str(), config.robot.rtde_port))
            .await
            .with_context(|| format!("resolving robot.host {:?}", config.robot.host))?
            .next()
            .with_context(|| format!("robot.host {:?} has no address", config.robot.host))?
            .ip();
        let endpoints = RobotEndpoints {
            rtde: std::net::SocketAddr::new(ip, config.robot.rtde_port),
            dashboard: std::net::SocketAddr::new(ip, config.robot.dashboard_port),
            script: std::net::SocketAddr::new(ip, config.robot.script_port),
        };
        let devices = open_lab_devices(config, &clock).await?;
        return Ok(Rig {
            clock,
            endpoints,
            devices,
            sim: None,
        });
    }
    let clock = Clock::governed(opts.speed_factor);
    let started = simrig::start(
        config,
        indenter,
        &clock,
        simrig::StartOptions {
            home: opts.sim_start_pose.unwrap_or(home),
            speed_factor: opts.speed_factor,
            physics: opts.sim_physics.clone(),
            ft_front_end: opts.sim_ft,
            contact_cache: opts.sim_contact_cache.clone(),
        },
    )
    .await?;
    let (calibration, ft_rate_hz) = match (&started.ft, &started.ft_settings) {
        (Some(ft), Some(settings)) => (
            calibration_json(settings, &ft.description),
            settings.rate_hz,
        ),
        _ => (serde_json::Value::Null, NO_FT_RATE_HZ),
    };
    let devices = Devices {
        calibration,
        ft_rate_hz,
        ft: started.ft,
        camera: started.camera,
        ft_on_host_clock: true,
    };
    tracing::info!(
        "simulated rig: UR5e RTDE {}, {}, camera {}; clock ×{}",
        started.endpoints.rtde,
        devices.ft.as_ref().map_or_else(
            || "no F/T sensor (forces on the UR5e's flange sensor)".to_owned(),
            |ft| ft.description.clone()
        ),
        if devices.camera.is_some() {
            "on"
        } else {
            "off"
        },
        opts.speed_factor
    );
    Ok(Rig {
        clock,
        endpoints: started.endpoints,
        devices,
        sim: Some(started.rig),
    })
}

/// Starts the recorder with `manifest` (every trajectory pending) and the F/T's calibration.
/// It starts before the robot's program is armed, so even a run that cannot reach the robot
/// is continued with --resume. A resumed recording keeps the calibration it was recorded with:
/// one opened with another (a replaced calibration file, other counts or ranges) is refused,
/// since its forces would not be comparable. Only the front end's address may differ (the
/// simulated rig's ports change from run to run).
///
/// The writer keeps a duplicate of the output directory's `lock` for as long as it lives (a
/// stalled disk can hold it past the run). A `disk-stall` drill (`--sim-fault`) gives it a
/// gate to close.
pub(super) fn start_recorder(
    opts: &RunOptions,
    mut manifest: Manifest,
    devices: &Devices,
    lock: Option<&std::fs::File>,
) -> anyhow::Result<Arc<Recorder>> {
    if !manifest.calibration.is_null() {
        let differs = calibration_differences(&manifest.calibration, &devices.calibration);
        if !differs.is_empty() {
            bail!(
                "--resume: {} was recorded with another F/T calibration (differs in: {}; see \
                 calibration in its {}); resume it with the sensor and calibration file it was \
                 recorded with, or choose another --out",
                opts.out.display(),
                differs.join(", "),
                crate::record::MANIFEST_NAME
            );
        }
    }
    manifest.calibration = devices.calibration.clone();
    let rec = Recorder::start(
        &opts.out,
        manifest,
        RecorderConfig {
            gate: opts.recorder_gate.clone().or_else(|| {
                opts.sim_faults
                    .iter()
                    .any(|f| f.kind == SimFaultKind::DiskStall)
                    .then(WriterGate::new)
            }),
            dir_lock: lock
                .map(std::fs::File::try_clone)
                .transpose()
                .with_context(|| format!("cannot share the lock on {}", opts.out.display()))?
                .map(Arc::new),
            ..RecorderConfig::default()
        },
    )
    .with_context(|| {
        format!(
            "cannot record into {}; check the path and its permissions, or choose another --out",
            opts.out.display()
        )
    })?;
    Ok(Arc::new(rec))
}

/// Connects to the robot, powers it up and arms its control program.
pub(super) async fn connect_robot(
    config: &RigConfig,
    endpoints: RobotEndpoints,
    speed: f64,
    clock: &Clock,
) -> anyhow::Result<Robot> {
    // The watchdog guards against the rig going silent in real time. On the simulated rig the
    // controller counts clock time, which runs `speed` times faster, so the same real
    // tolerance needs a rate that many times lower.
    // A link lost mid-trajectory fails it (its streams have a hole and the arm paused in the
    // gel); the client reconnects and the run recovers and retracts before going on.
    let robot_opts = RobotOptions {
        frequency_hz: Some(config.robot.rtde_frequency_hz),
        watchdog_min_hz: config.robot.watchdog_min_hz / speed,
        link_loss: crate::robot::LinkLossPolicy::Abort,
        // The TCP is the indenter tip: the plan's waypoints, the envelope and the depth
        // checks are all of the tip.
        tcp_offset: config.robot.tcp_offset,
        ..Default::default()
    };
    let mut robot = Robot::connect(endpoints, robot_opts, clock.clone())
        .await
        .context("connecting to the robot")?;
    robot.prepare().await.context("preparing the robot")?;
    Ok(robot)
}
