//! The tasks around the motion, for the whole run: the F/T and camera streams with their
//! safety watch ([`Streams`]), the collector that pairs and writes ([`super::collector`]), and
//! on the simulated rig the clock governor and the fault injector. Started once the robot is
//! ready; shut down in order at the run's end.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::config::RigConfig;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::collector::{self, CollectCmd, CollectorSettings};
use super::devices::Devices;
use super::events::StreamSettings;
use super::options::RunOptions;
use super::safety::SafetyIo;
use super::streams::Streams;
use super::summary::RunSummary;
use crate::plan::StageName;
use crate::record::Recorder;
use crate::robot::Robot;
use crate::simrig::{self, RunningSimRig};
use crate::sync::{DeviceTimebase, EstimatorConfig, InterpMethod, PairerConfig};

pub(super) struct Pipeline {
    pub streams: Streams,
    /// The collector's commands (begin, stage, end, abort of a trajectory's records).
    pub collector: mpsc::UnboundedSender<CollectCmd>,
    collector_task: JoinHandle<()>,
    /// Stage starts, announced to the fault injector (simulated rig).
    pub stage_tx: watch::Sender<Option<(String, StageName)>>,
    governor: Option<JoinHandle<()>>,
    injector: Option<JoinHandle<()>>,
}

impl Pipeline {
    /// Starts the streams of `devices` and the collector writing into `rec`; on the simulated
    /// rig `sim`, the governor (with a camera) and the injector (with faults to inject).
    /// `speed` is how many times faster than real time the clock runs.
    #[allow(clippy::too_many_arguments)]
    pub fn start(
        config: &RigConfig,
        opts: &RunOptions,
        flange: Option<super::flange::FlangeGuard>,
        devices: Devices,
        sim: Option<&RunningSimRig>,
        clock: &Clock,
        speed: f64,
        rec: Arc<Recorder>,
        robot: &Robot,
    ) -> Self {
        let camera_fps = config.camera.as_ref().map_or(30.0, |c| c.fps);
        let has_ft = devices.ft.is_some();
        let (ev_tx, ev_rx) = mpsc::channel(8192);
        let streams = Streams::start(
            devices.ft,
            devices.camera,
            clock.clone(),
            StreamSettings {
                max_force_n: config.safety.max_force_n,
                // Stall limits in real time (a busy machine), expressed in clock time.
                ft_stall: Duration::from_secs_f64(0.5 * speed),
                camera_stall: Duration::from_secs_f64((0.5f64).max(10.0 / camera_fps) * speed),
                envelope: Some(config.safety.envelope),
                flange,
            },
            ev_tx,
            Some(SafetyIo {
                line: robot.safety_line(),
                states: robot.rtde().watch_state(),
            }),
            opts.on_safety_stop.clone(),
        );
        // The controller's and the F/T's clocks are real-time clocks that never jump: a late
        // burst of samples is a delivery stall (a busy machine; tens of ms of clock time on a
        // fast simulated clock), not a new clock.
        let no_jumps = EstimatorConfig {
            jump_tolerance_ns: 1e9 * speed,
            ..EstimatorConfig::default()
        };
        // A skew fitted over the first seconds is mostly the latency's jitter over their span:
        // at ×10 the host's tens of µs of scheduling jitter are hundreds of µs of clock time, and
        // the first trajectory's labels were up to 0.05 N off where the force changes fast (a
        // flat face lifting off). The simulated F/T counts on the host's clock, so its rate is
        // known exactly; a lab's is fitted.
        let pairer = PairerConfig {
            method: InterpMethod::Cubic,
            frame_timebase: DeviceTimebase::HostNanos,
            wrench_timebase: DeviceTimebase::Counter {
                bits: 63,
                nominal_hz: devices.ft_rate_hz,
            },
            wrench_clock: EstimatorConfig {
                estimate_drift: !devices.ft_on_host_clock,
                ..no_jumps.clone()
            },
            ..PairerConfig::default()
        };
        // The disk-stall drill's hold on the writer (the fault injector closes it).
        let disk_gate = rec.gate().cloned();
        let (collector, cmds) = mpsc::unbounded_channel();
        let collector_task = collector::spawn(
            rec,
            opts.tap.clone(),
            CollectorSettings {
                pairer,
                grace_ns: 20_000_000,
                // Longer than the stall limits, so a stalled stream trips first and is named.
                end_timeout: Duration::from_secs_f64(2.0 * speed),
                camera: config.camera.is_some(),
                wrench: has_ft,
                rtde_clock: no_jumps,
            },
            clock.clone(),
            ev_rx,
            robot.rtde().samples(),
            cmds,
        );
        let governor = (sim.is_some() && config.camera.is_some()).then(|| {
            let counters = streams.counters().clone();
            tokio::spawn(simrig::govern(
                clock.clone(),
                opts.speed_factor,
                move || counters.newest_frame_stamp_ns.load(Ordering::Relaxed),
                1e9 / camera_fps,
            ))
        });
        let (stage_tx, stage_rx) = watch::channel(None);
        let injector = match sim {
            Some(s) if !opts.sim_faults.is_empty() => {
                let freeze = streams.freeze_handle();
                let gate = disk_gate.clone();
                Some(s.inject(
                    opts.sim_faults.clone(),
                    clock.clone(),
                    stage_rx,
                    simrig::RigHooks {
                        freeze_supervisor: Arc::new(move || freeze.freeze(true)),
                        stall_disk: Arc::new(move || {
                            if let Some(g) = &gate {
                                g.close();
                            }
                        }),
                    },
                ))
            }
            _ => None,
        };
        Self {
            streams,
            collector,
            collector_task,
            stage_tx,
            governor,
            injector,
        }
    }

    /// The whole run's stream counters, into `summary`.
    pub fn count_into(&self, summary: &mut RunSummary, rec: &Recorder) {
        let c = self.streams.counters();
        summary.frames_received = c.frames();
        summary.frames_lost = c.frames_dropped();
        summary.recording_lost = c.recording_lost();
        summary.tcp_extent_m = self.streams.tcp_extent();
        summary.safety_stops = self.streams.safety_stops();
        summary.backpressure_waits = c.backpressure_waits.load(Ordering::Relaxed)
            + rec.stats().backpressure_waits.load(Ordering::Relaxed);
    }

    /// Stops the injector and governor, the streams, then the collector once it has written
    /// everything queued. With the recorder's writer stalled ([`Recorder::watch`]) the collector
    /// (waiting for room in its queue) is cancelled instead: the streams' frame encoder, which
    /// may wait on the collector in turn, can then end too.
    pub async fn shutdown(self, rec: &Recorder) {
        if let Some(i) = self.injector {
            i.abort();
        }
        if let Some(g) = self.governor {
            g.abort();
        }
        let mut collector_task = self.collector_task;
        let mut streams = std::pin::pin!(self.streams.shutdown());
        if rec
            .watch("stopping the streams", &mut streams)
            .await
            .is_err()
        {
            collector_task.abort();
            let _ = (&mut collector_task).await;
            streams.await;
            return;
        }
        drop(self.collector);
        if rec
            .watch("writing the last queued records", &mut collector_task)
            .await
            .is_err()
        {
            collector_task.abort();
            let _ = collector_task.await;
        }
    }
}
