//! The simulated rig: the one room of the `rig` crate that knows `hardware-mocks`.
//!
//! With no lab rig configured (`robot.simulated = true`, as in the embedded default config),
//! `rig run` runs on the simulated rig of `hardware-mocks`, started in-process: a UR5e on
//! loopback RTDE, dashboard and secondary-interface sockets, a Nano17 behind a Net F/T on
//! loopback UDP (or an F/T controller on a pty, or an NI card behind the stand-in NI-DAQmx
//! library, [`nidaqmx`]), and a GelSight camera, all driven by one
//! contact scene whose indenter follows the simulated UR5e's TCP. Its clock may run faster than
//! real time. Everything here hands the rest of the crate lab-shaped things: robot endpoints,
//! an [`FtStream`] read by the lab's own front-end code, and a [`FrameSource`]. The lab code
//! never learns it is talking to a simulator, and the simulator's ground truth travels with the
//! simulated frames ([`crate::camera::Frame::truth`]), not through lab traits.
//!
//! - [`start`]: the simulated rig for `rig run`, with its physics defaults
//!   ([`default_physics`]);
//! - [`SimFrameSource`]: the simulated camera as a frame source;
//! - [`open_ft`]: the simulated Nano17 on its own (`rig ft` with `kind = "sim"`);
//! - [`SimFault`]: fault injection (`rig run --sim-fault`);
//! - [`govern`]: the clock governor, which slows simulated time when the camera lags;
//! - [`render`] and [`sim`]: the contact + optics simulator for `rig sim` and the benchmarks.

mod camera;
mod faults;
pub mod forces;
mod ft;
mod governor;
pub mod nidaqmx;
pub mod render;

use std::sync::Arc;

use anyhow::Context;
use hardware_mocks::camera::{CameraFaults, SimCameraConfig};
use hardware_mocks::rig_sim::{SimRig, SimRigOptions};
use rig_core::clock::Clock;
use rig_core::config::RigConfig;
use rig_core::control::robot_mode;
use rig_core::indenter::Indenter;
use rig_core::pose::Pose;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::camera::FrameSource;
use crate::force::{self, FrontEndSettings, FtStream};
use crate::plan::StageName;
use crate::robot::RobotEndpoints;

pub use camera::{SimFrameSource, frame_as_sent};
pub use faults::{RigHooks, SimFault, SimFaultKind};
pub use ft::open_ft;
pub use governor::govern;
pub use hardware_mocks::rig_sim::{
    DEFAULT_PHYSICS_RATE_HZ, PhysicsConfig, PhysicsStats, SimFtFrontEnd, TapeStats,
};
/// The contact + optics simulator itself (scenes, contact models, rendering), for `rig sim`
/// and `rig bench sim|render`.
pub use hardware_mocks::sim;

/// The `tracing` filter directive that keeps the simulated devices' own chatter (connections,
/// program starts) to warnings; `RUST_LOG` overrides it.
pub const QUIET_DEVICES_LOG: &str = "hardware_mocks=warn";

/// The contact physics of a simulated run: the sensor physics every command uses
/// ([`sim::Effects::sensor`]: the finite layer, Coulomb friction on the gel's material points,
/// the elastomer's relaxation), stepped on a 50 Hz grid of clock time. Its F/T twin reads the
/// pose of each sample off the line of the last two steps and solves only where the motion
/// leaves that line (see `ContactPhysics`'s `wrench_at`).
pub fn default_physics() -> PhysicsConfig {
    PhysicsConfig::default()
}

/// How `rig run` wants the simulated rig.
#[derive(Debug, Clone)]
pub struct StartOptions {
    /// The UR5e's TCP at start (the first trajectory's start, at approach height).
    pub home: Pose,
    /// How many times faster than real time the clock runs (at most; the governor slows it).
    pub speed_factor: f64,
    pub physics: PhysicsConfig,
    pub ft_front_end: SimFtFrontEnd,
    /// The contact cache's root directory (see `RunOptions::sim_contact_cache`).
    pub contact_cache: Option<std::path::PathBuf>,
}

/// The simulated rig, started, and the lab-shaped handles a run reads it through.
pub struct Started {
    pub rig: RunningSimRig,
    pub endpoints: RobotEndpoints,
    /// The simulated Nano17, read by the lab's Net F/T or serial front end (`None`: the config
    /// has no `[force_sensor]`).
    pub ft: Option<FtStream>,
    /// The front-end settings the stream was opened with (for the manifest).
    pub ft_settings: Option<FrontEndSettings>,
    pub camera: Option<Box<dyn FrameSource>>,
}

/// The running simulated rig. Dropping it stops every task; [`Self::shutdown`] closes it in
/// order.
pub struct RunningSimRig {
    rig: SimRig,
    camera_faults: Option<CameraFaults>,
}

impl RunningSimRig {
    /// Injects `faults` as the run's stages (sent on `stages`) start.
    pub fn inject(
        &self,
        faults: Vec<SimFault>,
        clock: Clock,
        stages: watch::Receiver<Option<(String, StageName)>>,
        rig: RigHooks,
    ) -> JoinHandle<()> {
        let targets = faults::FaultTargets {
            ur5e: self.rig.ur5e_arc(),
            ft: self.rig.ft().faults().clone(),
            camera: self.camera_faults.clone(),
            rig,
        };
        tokio::spawn(faults::inject_faults(faults, targets, clock, stages))
    }

    /// The largest gap between a simulated frame's capture time and the time of the contact
    /// it shows, ms (see `PhysicsStats::max_field_age_ns`).
    pub fn image_lag_max_ms(&self) -> f64 {
        self.rig.physics().stats().max_field_age_ns as f64 * 1e-6
    }

    /// The contact physics' counters so far.
    pub fn physics_stats(&self) -> PhysicsStats {
        self.rig.physics().stats()
    }

    /// Where the simulated indenter's tip (the physical tool, not the reported TCP) was at
    /// clock time `t_ns`, while the controller's pose history (5 s) still holds it.
    pub fn tip_pose_at(&self, t_ns: u64) -> Option<rig_core::pose::Pose> {
        self.rig.ur5e_arc().tip_pose_at(t_ns).map(|(_, p)| p)
    }

    /// Every supervisor stop request the simulated controller received: (clock time, request).
    pub fn stop_requests_received(&self) -> Vec<hardware_mocks::ur5e::StopRequestReceived> {
        self.rig.ur5e_arc().stop_requests_received()
    }

    /// Stops the simulated rig; the contact cache's counters once its tapes are written
    /// (`None` without a cache).
    pub async fn shutdown(self) -> Option<hardware_mocks::rig_sim::TapeStats> {
        let physics = self.rig.physics().clone();
        self.rig.shutdown().await;
        physics.tape_stats()
    }
}

/// Starts the simulated rig on loopback for `config` and `indenter`, and opens its F/T and
/// camera with the lab's readers.
pub async fn start(
    config: &RigConfig,
    indenter: &Indenter,
    clock: &Clock,
    opts: StartOptions,
) -> anyhow::Result<Started> {
    // The simulated camera stamps its buffers on the shared clock, as a UVC camera under
    // V4L2 stamps them on the host's CLOCK_MONOTONIC. It keeps as many buffers as give the
    // reader the real-time slack the V4L2 reader's queue has at 1×: at ×10, 16 buffers were
    // 64 ms of real time, and a busy CI machine once let the reader fall that far behind,
    // so a frame was overrun before the governor could slow the clock.
    let real_slack = crate::camera::v4l2::V4l2Options::default().queue_len as f64;
    let buffers = (real_slack * opts.speed_factor).ceil().clamp(16.0, 256.0) as usize;
    let camera = config.camera.as_ref().map(|c| SimCameraConfig {
        device_offset_ns: 0,
        queue_len: buffers,
        ..SimCameraConfig::for_camera(c)
    });
    let sim_opts = SimRigOptions {
        home_pose: Some(opts.home),
        camera,
        initial_robot_mode: robot_mode::POWER_OFF,
        physics: opts.physics,
        ft_front_end: opts.ft_front_end,
        contact_cache: opts.contact_cache,
        ..SimRigOptions::for_config(config)
    };
    let mut rig = SimRig::start(config, Arc::new(indenter.clone()), clock.clone(), sim_opts)
        .await
        .context("starting the simulated rig on loopback")?;
    let endpoints = RobotEndpoints {
        rtde: rig.ur5e().rtde_addr(),
        dashboard: rig.ur5e().dashboard_addr(),
        script: rig.ur5e().script_addr(),
    };

    // Without a [force_sensor] the Nano17 twin still runs, unread: the rig records images,
    // poses and stages, and watches forces on the UR5e's flange sensor.
    let (ft, settings) = match config.force_sensor.as_ref() {
        Some(fs) => {
            let (ft, settings) = open_sim_ft(&rig, fs, opts.ft_front_end, clock).await?;
            (Some(ft), Some(settings))
        }
        None => (None, None),
    };

    let mut camera_faults = None;
    let camera: Option<Box<dyn FrameSource>> = match (&config.camera, rig.take_camera()) {
        (Some(c), Some(cam)) => {
            camera_faults = Some(cam.faults());
            Some(Box::new(
                SimFrameSource::new(cam, clock.clone(), c.width_px, c.height_px)
                    .with_truth(Arc::new(rig.physics().clone())),
            ))
        }
        _ => None,
    };
    Ok(Started {
        rig: RunningSimRig { rig, camera_faults },
        endpoints,
        ft,
        ft_settings: settings,
        camera,
    })
}

/// Opens the simulated rig's Nano17 through `front_end` with the lab's reader, as `fs` says.
async fn open_sim_ft(
    rig: &SimRig,
    fs: &rig_core::config::ForceSensorConfig,
    front_end: SimFtFrontEnd,
    clock: &Clock,
) -> anyhow::Result<(FtStream, FrontEndSettings)> {
    let mut settings = FrontEndSettings::from_config(fs)?;
    let ft = match front_end {
        SimFtFrontEnd::NetFt => {
            let addr = rig
                .netft_addr()
                .context("the simulated Net F/T is not running")?;
            force::netft::open(&addr.to_string(), false, settings.clone(), clock.clone()).await?
        }
        SimFtFrontEnd::Serial => {
            let path = rig
                .ft_serial_path()
                .context("the simulated F/T controller is not running")?
                .to_string_lossy()
                .into_owned();
            // The simulated controller's counts (its factory defaults).
            let mock = hardware_mocks::nano17::serial::SerialMockConfig::default();
            settings.counts_per_force = mock.counts_per_force;
            settings.counts_per_torque = mock.counts_per_torque;
            force::serial::open(
                force::serial::SerialOptions {
                    port: path,
                    baud: 921_600,
                    output: rig_core::ft::serial::OutputMode::Binary,
                    device_bias: false,
                },
                settings.clone(),
                clock.clone(),
            )
            .await?
        }
        SimFtFrontEnd::NiDaqmx => {
            let source: hardware_mocks::truth::SharedWrenchSource = Arc::new(rig.physics().clone());
            let faults = rig.ft().faults().clone();
            nidaqmx::open(fs, &mut settings, source, faults, clock.clone()).await?
        }
    };
    Ok((ft, settings))
}
