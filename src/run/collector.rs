//! The collector task: pairs frames with the wrench for the whole run and writes the open
//! trajectory's records.
//!
//! One [`Pairer`] lives for the whole run and is fed everything the streams deliver (wrench
//! samples, frames) and every RTDE state (TCP poses), between trajectories too, so its clock
//! estimators keep converging across the run instead of restarting per trajectory. What is
//! *recorded* is decided by the orchestrator's commands:
//!
//! - [`CollectCmd::Begin`] after the tare: from now on wrench samples received and frames
//!   captured are written;
//! - [`CollectCmd::Stage`] at each stage's start: a stage record; TCP poses are written from the
//!   first stage's start;
//! - [`CollectCmd::End`] with the time of the last state of the motion: frames captured and poses
//!   received after it are not written; wrench samples are, for a short grace so the last
//!   frames have samples on both sides. Once a frame captured after the end has arrived (every
//!   frame of the trajectory is in), every recorded frame still held by the pairer is released
//!   and its paired wrench written, and the trajectory's [`TrajStats`] come back;
//! - [`CollectCmd::Abort`]: stop writing at once (the orchestrator aborts the file).
//!
//! Every frame written gets exactly one paired record (and, on the simulated rig, one truth
//! record), so the file's counts say at once whether anything went missing. Without an F/T
//! sensor (a target recorded for its images) there is nothing to pair: frames, poses and
//! stages are written, and no paired record.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::wrench::Wrench;
use tokio::sync::broadcast::{self, error::RecvError};
use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinHandle;

use super::events::Event;
use crate::plan::StageName;
use crate::record::{Record, Recorder};
use crate::robot::RobotState;
use crate::sync::{
    ClockEstimator, DeviceStamp, EstimatorConfig, FrameIn, PairedFrame, Pairer, PairerConfig,
    SyncStatus, WrenchIn,
};

/// Commands of the orchestrator.
#[derive(Debug)]
pub enum CollectCmd {
    /// Start writing the open trajectory's records.
    Begin,
    /// A stage begins at `t_ns`.
    Stage { t_ns: u64, stage: StageName },
    /// The motion's last state was at `t_end_ns`: finish the trajectory's records.
    End {
        t_end_ns: u64,
        reply: oneshot::Sender<Result<TrajStats, String>>,
    },
    /// Stop writing at once.
    Abort { reply: oneshot::Sender<()> },
}

/// What one trajectory's recording holds.
#[derive(Debug, Clone, Default)]
pub struct TrajStats {
    pub frames: u64,
    pub wrench: u64,
    pub poses: u64,
    /// Paired frames by status.
    pub paired_ok: u64,
    pub paired_held: u64,
    pub paired_refused: u64,
    /// Frames the camera's sequence numbers say were lost between two recorded frames.
    pub frames_dropped: u64,
    /// Distance of each paired frame to its nearest wrench sample, ns.
    pub sync_errors_ns: Vec<f64>,
    /// Per-axis force range of the recorded wrench samples, N.
    pub force_min: [f64; 3],
    pub force_max: [f64; 3],
    /// Simulated rig: largest |paired − true| force component over the frames, N.
    pub truth_max_error_n: Option<f64>,
    /// Clock time of the first and last recorded frame (for the frame rate), ns.
    pub first_frame_ns: Option<u64>,
    pub last_frame_ns: Option<u64>,
}

/// Settings of the collector.
#[derive(Debug, Clone)]
pub struct CollectorSettings {
    pub pairer: PairerConfig,
    /// Wrench samples written after the motion's end so the last frames are bracketed, ns.
    pub grace_ns: u64,
    /// Longest wait for that grace (a stalled F/T), clock time.
    pub end_timeout: Duration,
    /// Whether frames come: the end of a trajectory then also waits for a frame captured
    /// after it, so every frame captured during it has arrived.
    pub camera: bool,
    /// Whether wrench samples come (an F/T sensor is fitted). Without, frames are written
    /// unpaired (no paired records) and the end waits for the frames only.
    pub wrench: bool,
    /// The estimator mapping the controller's RTDE `timestamp` onto the host clock.
    pub rtde_clock: EstimatorConfig,
}

struct Recording {
    begin_ns: u64,
    started_ns: Option<u64>,
    end: Option<(u64, oneshot::Sender<Result<TrajStats, String>>)>,
    /// Recorded frames still waiting for their pair: seq → true wrench (simulated rig).
    waiting: HashMap<i64, Option<Wrench>>,
    last_frame_seq: Option<u64>,
    stats: TrajStats,
    error: Option<String>,
}

impl Recording {
    fn new(begin_ns: u64) -> Self {
        Self {
            begin_ns,
            started_ns: None,
            end: None,
            waiting: HashMap::new(),
            last_frame_seq: None,
            stats: TrajStats {
                force_min: [f64::INFINITY; 3],
                force_max: [f64::NEG_INFINITY; 3],
                ..Default::default()
            },
            error: None,
        }
    }
}

/// Sees every record written (the live view).
pub type Tap = Arc<dyn Fn(&Record) + Send + Sync>;

struct Collector {
    rec: Arc<Recorder>,
    live: Option<Tap>,
    pairer: Pairer,
    clock: Clock,
    settings: CollectorSettings,
    cur: Option<Recording>,
    newest_wrench_ns: u64,
    newest_frame_ns: u64,
    rtde_clock: ClockEstimator,
}

/// Spawns the collector. It ends when `cmds` closes.
pub fn spawn(
    rec: Arc<Recorder>,
    live: Option<Tap>,
    settings: CollectorSettings,
    clock: Clock,
    events: mpsc::Receiver<Event>,
    samples: broadcast::Receiver<RobotState>,
    cmds: mpsc::UnboundedReceiver<CollectCmd>,
) -> JoinHandle<()> {
    let task = Collector {
        rec,
        live,
        pairer: Pairer::new(settings.pairer.clone()),
        clock,
        cur: None,
        newest_wrench_ns: 0,
        newest_frame_ns: 0,
        rtde_clock: ClockEstimator::new(settings.rtde_clock.clone()),
        settings,
    };
    tokio::spawn(task.run(events, samples, cmds))
}

impl Collector {
    async fn run(
        mut self,
        mut events: mpsc::Receiver<Event>,
        mut samples: broadcast::Receiver<RobotState>,
        mut cmds: mpsc::UnboundedReceiver<CollectCmd>,
    ) {
        let mut samples_open = true;
        let mut events_open = true;
        loop {
            let deadline = self
                .cur
                .as_ref()
                .and_then(|r| r.end.as_ref())
                .map(|(t_end, _)| {
                    t_end
                        + self.settings.grace_ns
                        + self.settings.end_timeout.as_nanos().min(u64::MAX as u128) as u64
                })
                .unwrap_or(u64::MAX);
            tokio::select! {
                biased;
                c = cmds.recv() => match c {
                    Some(c) => self.command(c).await,
                    None => return,
                },
                s = samples.recv(), if samples_open => match s {
                    Ok(s) => self.pose(&s).await,
                    Err(RecvError::Lagged(n)) => {
                        if let Some(r) = &mut self.cur {
                            r.error.get_or_insert_with(|| format!(
                                "the recording fell {n} RTDE states behind the robot's state \
                                 stream (the machine or disk is too slow); the trajectory cannot \
                                 be recorded completely"
                            ));
                        }
                    }
                    Err(RecvError::Closed) => samples_open = false,
                },
                e = events.recv(), if events_open => match e {
                    Some(e) => self.event(e).await,
                    None => events_open = false,
                },
                _ = self.clock.sleep_until_ns(deadline) => {
                    if let Some(r) = &mut self.cur {
                        r.error.get_or_insert_with(|| {
                            "the streams did not deliver the trajectory's last frames and \
                             samples in time (a stalled camera or F/T?)"
                                .into()
                        });
                    }
                    self.complete().await;
                }
            }
            if self.end_reached() {
                self.complete().await;
            }
        }
    }

    async fn write(&mut self, rec: Record) {
        if let Some(live) = &self.live {
            live(&rec);
        }
        if let Err(e) = self.rec.send(rec).await
            && let Some(r) = &mut self.cur
        {
            r.error.get_or_insert_with(|| e.to_string());
        }
    }

    async fn command(&mut self, c: CollectCmd) {
        match c {
            CollectCmd::Begin => {
                self.cur = Some(Recording::new(self.clock.now_ns()));
            }
            CollectCmd::Stage { t_ns, stage } => {
                self.pairer.set_stage(t_ns as f64, stage);
                if let Some(r) = &mut self.cur {
                    r.started_ns.get_or_insert(t_ns);
                    self.write(Record::Stage { t_ns, stage }).await;
                }
            }
            CollectCmd::End { t_end_ns, reply } => match &mut self.cur {
                Some(r) => r.end = Some((t_end_ns, reply)),
                None => {
                    let _ = reply.send(Err("no trajectory was being recorded".into()));
                }
            },
            CollectCmd::Abort { reply } => {
                self.cur = None;
                let _ = reply.send(());
            }
        }
    }

    /// The host time of a state: its controller `timestamp` mapped by the estimator (the
    /// time the controller sampled it, free of the delivery's jitter), else its arrival.
    fn state_time(&mut self, s: &RobotState) -> u64 {
        if !(s.timestamp_s.is_finite() && s.timestamp_s >= 0.0 && s.timestamp_s < 9.0e9) {
            return s.t_host_ns;
        }
        let dev = (s.timestamp_s * 1e9).round() as i64;
        self.rtde_clock.observe(dev, s.t_host_ns);
        match self.rtde_clock.to_host(dev) {
            Some(t) if t.is_finite() && t >= 0.0 => (t.round() as u64).min(s.t_host_ns),
            _ => s.t_host_ns,
        }
    }

    async fn pose(&mut self, s: &RobotState) {
        let t = self.state_time(s);
        self.pairer.push_pose(t as f64, s.actual_tcp_pose);
        let write = self.cur.as_ref().is_some_and(|r| {
            r.started_ns.is_some_and(|t0| t >= t0)
                && r.end.as_ref().is_none_or(|(t_end, _)| t <= *t_end)
        });
        if write {
            if let Some(r) = &mut self.cur {
                r.stats.poses += 1;
            }
            self.write(Record::Pose {
                t_ns: t,
                pose: s.actual_tcp_pose,
            })
            .await;
        }
        self.drain_pairs().await;
    }

    async fn event(&mut self, e: Event) {
        match e {
            Event::Wrench(s) => {
                self.newest_wrench_ns = self.newest_wrench_ns.max(s.t_host_ns);
                self.pairer.push_wrench(WrenchIn {
                    stamp: DeviceStamp::Counter(s.device_seq),
                    host_rx_ns: s.t_host_ns,
                    wrench: s.wrench,
                });
                let grace = self.settings.grace_ns;
                let write = self.cur.as_ref().is_some_and(|r| {
                    s.t_host_ns >= r.begin_ns
                        && r.end
                            .as_ref()
                            .is_none_or(|(t_end, _)| s.t_host_ns <= t_end + grace)
                });
                if write {
                    if let Some(r) = &mut self.cur {
                        r.stats.wrench += 1;
                        for k in 0..3 {
                            r.stats.force_min[k] = r.stats.force_min[k].min(s.wrench.force_n[k]);
                            r.stats.force_max[k] = r.stats.force_max[k].max(s.wrench.force_n[k]);
                        }
                    }
                    self.write(Record::Wrench {
                        t_ns: s.t_host_ns,
                        seq: i64::try_from(s.device_seq).ok(),
                        wrench: s.wrench,
                    })
                    .await;
                }
            }
            Event::Frame(f) => {
                if self.settings.wrench {
                    self.pairer.push_frame(FrameIn {
                        seq: f.seq,
                        stamp: DeviceStamp::Nanos(f.stamp_ns),
                        host_rx_ns: f.host_rx_ns,
                    });
                }
                self.newest_frame_ns = self.newest_frame_ns.max(f.stamp_ns);
                // A frame belongs to the trajectory by its capture time, however late it
                // arrives (the simulated camera renders after the fact).
                let write = self.cur.as_ref().is_some_and(|r| {
                    f.stamp_ns >= r.begin_ns
                        && r.end.as_ref().is_none_or(|(t_end, _)| f.stamp_ns <= *t_end)
                });
                if write {
                    let seq = f.seq as i64;
                    if let Some(r) = &mut self.cur {
                        if r.last_frame_seq.is_some() {
                            r.stats.frames_dropped += f.dropped_before;
                        }
                        r.last_frame_seq = Some(f.seq);
                        r.stats.frames += 1;
                        r.stats.first_frame_ns.get_or_insert(f.host_rx_ns);
                        r.stats.last_frame_ns = Some(f.host_rx_ns);
                        if self.settings.wrench {
                            r.waiting.insert(seq, f.truth.map(|(_, w)| w));
                        }
                    }
                    let truth = f.truth;
                    self.write(Record::Frame {
                        seq,
                        t_ns: f.host_rx_ns,
                        format: f.format,
                        data: f.data,
                    })
                    .await;
                    if let Some((t_capture, wrench)) = truth {
                        self.write(Record::Truth {
                            frame_seq: seq,
                            t_ns: t_capture,
                            wrench,
                        })
                        .await;
                    }
                }
            }
        }
        self.drain_pairs().await;
    }

    /// Write the pairs of recorded frames the pairer released.
    async fn drain_pairs(&mut self) {
        let pairs = self.pairer.poll();
        self.write_pairs(pairs).await;
    }

    async fn write_pairs(&mut self, pairs: Vec<PairedFrame>) {
        for p in pairs {
            let Some(r) = &mut self.cur else { continue };
            let Some(truth) = r.waiting.remove(&p.frame_seq) else {
                continue;
            };
            match p.status {
                SyncStatus::Ok => r.stats.paired_ok += 1,
                SyncStatus::Held => r.stats.paired_held += 1,
                _ => r.stats.paired_refused += 1,
            }
            if let Some(e) = p.sync_error_ns {
                r.stats.sync_errors_ns.push(e);
            }
            if let (Some(t), Some(w)) = (truth, p.wrench) {
                let err = (0..3)
                    .map(|k| (w.force_n[k] - t.force_n[k]).abs())
                    .fold(0.0, f64::max);
                r.stats.truth_max_error_n = Some(r.stats.truth_max_error_n.unwrap_or(0.0).max(err));
            }
            self.write(Record::Paired(p)).await;
        }
    }

    fn end_reached(&self) -> bool {
        self.cur.as_ref().is_some_and(|r| {
            r.end.as_ref().is_some_and(|(t_end, _)| {
                (!self.settings.wrench || self.newest_wrench_ns >= t_end + self.settings.grace_ns)
                    && (!self.settings.camera || self.newest_frame_ns > *t_end)
            })
        })
    }

    /// End of the trajectory: release its frames still held, reply with its stats.
    async fn complete(&mut self) {
        let pairs = self.pairer.poll();
        self.write_pairs(pairs).await;
        if self.cur.as_ref().is_some_and(|r| !r.waiting.is_empty()) {
            let pairs = self.pairer.finish();
            self.write_pairs(pairs).await;
        }
        let Some(mut r) = self.cur.take() else { return };
        let Some((_, reply)) = r.end.take() else {
            self.cur = Some(r);
            return;
        };
        let result = match r.error {
            Some(e) => Err(e),
            None if !r.waiting.is_empty() => Err(format!(
                "{} recorded frames never came out of the pairing",
                r.waiting.len()
            )),
            None => Ok(r.stats),
        };
        let _ = reply.send(result);
    }
}
