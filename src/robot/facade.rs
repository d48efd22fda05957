//! The [`Robot`] facade: the I/O around the sans-IO motion sequencer.
//!
//! [`MotionSequencer`] decides what to write and what the registers mean; this file only
//! writes commands, waits on the RTDE stream and the link status, and drives the dashboard
//! and the program upload. Every wait is on clock time and ends in an error that says which
//! step did not finish. Link loss during a move is handled here (see the
//! [module docs](super) for the policy) because it needs the link status and the program
//! upload, which the sequencer does not see.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::control::{self, CommandKind};
use rig_core::pose::{self, Pose};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;

use super::config::{LinkLossPolicy, RobotEndpoints, RobotOptions};
use super::dashboard::Dashboard;
use super::error::MotionError;
use super::motion::{self, CommandWrite, FaultRecord, MotionSequencer, SeqEvent, SequencerConfig};
use super::moves::{LoggedState, Move, MoveReport, MovesLog};
use super::rtde::{LinkStatus, RtdeClient, RtdeConfig, RtdeError, RtdeHandle};
use super::safety_line::{LineState, SafetyLine};
use super::state::RobotState;
use super::urscript;

/// How long a state may take when one is needed now: the stream runs at 125 to 500 Hz, so
/// this runs out only when no data comes at all.
const STATE_TIMEOUT: Duration = Duration::from_secs(2);

/// Index of the command recipe in the RTDE client's input recipes (the safety recipe follows).
const CMD_RECIPE: usize = 0;

/// The robot: RTDE client, dashboard, sequencer and heartbeat.
pub struct Robot {
    rtde: RtdeClient,
    handle: RtdeHandle,
    dashboard: Dashboard,
    endpoints: RobotEndpoints,
    opts: RobotOptions,
    clock: Clock,
    seq: MotionSequencer,
    heartbeat: JoinHandle<()>,
    line: Arc<LineState>,
    prepared: bool,
}

impl Drop for Robot {
    fn drop(&mut self) {
        self.heartbeat.abort();
    }
}

/// Send the URScript program over the secondary interface: connect, write, close.
pub async fn upload_program(
    addr: SocketAddr,
    text: &str,
    clock: &Clock,
    timeout: Duration,
) -> Result<(), MotionError> {
    let err = |reason: String| MotionError::Upload { addr, reason };
    let fut = async {
        let mut s = TcpStream::connect(addr).await?;
        s.set_nodelay(true)?;
        s.write_all(text.as_bytes()).await?;
        s.flush().await?;
        s.shutdown().await
    };
    clock
        .timeout(timeout, fut)
        .await
        .map_err(|_| err(format!("no progress within {timeout:?}")))?
        .map_err(|e| err(e.to_string()))
}

impl Robot {
    /// Connect RTDE (recipes: the state recipe; inputs: command registers and heartbeat) and
    /// the dashboard, and start the heartbeat. Does not power on or move anything.
    pub async fn connect(
        endpoints: RobotEndpoints,
        opts: RobotOptions,
        clock: Clock,
    ) -> Result<Self, MotionError> {
        let mut cfg = RtdeConfig::new(endpoints.rtde);
        cfg.frequency_hz = opts.frequency_hz;
        cfg.input_recipes = vec![motion::command_recipe(), motion::safety_recipe()];
        cfg.max_attempts = opts.rtde_max_attempts;
        cfg.backoff_initial = opts.rtde_backoff_initial;
        cfg.backoff_max = opts.rtde_backoff_max;
        cfg.stall_timeout = opts.rtde_stall_timeout;
        let rtde = RtdeClient::connect(cfg, clock.clone()).await?;
        let dashboard =
            Dashboard::connect(endpoints.dashboard, clock.clone(), opts.dashboard_timeout).await?;
        let handle = rtde.handle();
        let line = LineState::new(opts.stop_accel_m_s2);
        let heartbeat = tokio::spawn(heartbeat_task(
            rtde.watch_state(),
            rtde.handle(),
            line.clone(),
        ));
        let seq = MotionSequencer::new(SequencerConfig {
            ack_timeout: opts.ack_timeout,
            move_timeout_margin: opts.move_timeout_margin,
            move_timeout_factor: opts.move_timeout_factor,
        });
        let mut robot = Self {
            rtde,
            handle,
            dashboard,
            endpoints,
            opts,
            clock,
            seq,
            heartbeat,
            line,
            prepared: false,
        };
        let s = robot
            .current_state("waiting for the first RTDE state")
            .await?;
        robot.seq.sync_seq(s.input_cmd_seq);
        Ok(robot)
    }

    /// The RTDE client (state, samples, link status, counters, controller messages).
    pub fn rtde(&self) -> &RtdeClient {
        &self.rtde
    }
    pub fn dashboard(&mut self) -> &mut Dashboard {
        &mut self.dashboard
    }
    pub fn endpoints(&self) -> RobotEndpoints {
        self.endpoints
    }
    pub fn options(&self) -> &RobotOptions {
        &self.opts
    }
    /// The latest state.
    pub fn state(&self) -> Option<RobotState> {
        self.rtde.latest()
    }
    /// Hand the heartbeat and the stop to a safety supervisor (see [`SafetyLine`]): until the
    /// line is dropped, only its owner feeds the controller's watchdog.
    pub fn safety_line(&self) -> SafetyLine {
        SafetyLine::take(self.rtde.handle(), self.line.clone())
    }

    /// The fault that blocks motion, if any.
    pub fn fault(&self) -> Option<&FaultRecord> {
        self.seq.fault()
    }

    fn messages(&self) -> String {
        let m = self.rtde.recent_text_messages();
        if m.is_empty() {
            String::new()
        } else {
            let last: Vec<String> = m
                .iter()
                .rev()
                .take(3)
                .map(|t| format!("{}: {}", t.source, t.message))
                .collect();
            format!("; last controller messages: {}", last.join(" | "))
        }
    }

    /// Wait (clock time) until the latest state satisfies `pred`.
    async fn wait_state(
        &self,
        step: &'static str,
        timeout: Duration,
        pred: impl Fn(&RobotState) -> bool,
    ) -> Result<RobotState, MotionError> {
        let mut rx = self.rtde.watch_state();
        let r = self
            .clock
            .timeout(timeout, async {
                loop {
                    if let Some(s) = *rx.borrow_and_update()
                        && pred(&s)
                    {
                        return Some(s);
                    }
                    if rx.changed().await.is_err() {
                        return None;
                    }
                }
            })
            .await;
        match r {
            Ok(Some(s)) => Ok(s),
            Ok(None) => Err(MotionError::Prepare {
                step,
                reason: "the RTDE client stopped".into(),
            }),
            Err(_) => Err(MotionError::Prepare {
                step,
                reason: format!(
                    "not reached within {timeout:?} of clock time; state: {}{}",
                    self.rtde
                        .latest()
                        .map(|s| s.modes_description())
                        .unwrap_or_else(|| "no RTDE data".into()),
                    self.messages()
                ),
            }),
        }
    }

    /// The latest state, waiting for the first one if none has arrived yet.
    async fn current_state(&self, step: &'static str) -> Result<RobotState, MotionError> {
        self.wait_state(step, STATE_TIMEOUT, |_| true).await
    }

    async fn wait_link_up(&self, timeout: Duration) -> Result<(), String> {
        let mut rx = self.rtde.link();
        let r = self
            .clock
            .timeout(timeout, async {
                loop {
                    match &*rx.borrow_and_update() {
                        LinkStatus::Up { .. } => return Ok(()),
                        LinkStatus::Failed(e) => return Err(e.clone()),
                        LinkStatus::Closed => return Err("RTDE client closed".into()),
                        LinkStatus::Reconnecting { .. } => {}
                    }
                    if rx.changed().await.is_err() {
                        return Err("RTDE client gone".into());
                    }
                }
            })
            .await;
        r.unwrap_or_else(|_| Err(format!("RTDE link not back within {timeout:?}")))
    }

    async fn write_cmd(&self, c: &CommandWrite) -> Result<(), RtdeError> {
        self.handle.send_inputs(CMD_RECIPE, &c.values()).await
    }

    /// Power on, release the brakes, wait for RUNNING, upload the control program and wait
    /// until it plays. Each step has a timeout and an error that says what to check.
    pub async fn prepare(&mut self) -> Result<(), MotionError> {
        let s = self.current_state("waiting for RTDE state").await?;
        if !s.safety_ok() {
            return Err(MotionError::Prepare {
                step: "safety check",
                reason: format!(
                    "robot is not in NORMAL safety mode ({}); inspect it, then call recover()",
                    s.modes_description()
                ),
            });
        }
        self.power_up().await?;
        self.upload_and_start().await
    }

    async fn power_up(&mut self) -> Result<(), MotionError> {
        use control::robot_mode::*;
        let s = self.rtde.latest().unwrap_or_default();
        if s.robot_mode == RUNNING {
            return Ok(());
        }
        if s.robot_mode != IDLE {
            self.dashboard.power_on().await?;
            self.wait_state(
                "power on (waiting for robot_mode IDLE)",
                self.opts.power_timeout,
                |s| matches!(s.robot_mode, IDLE | RUNNING),
            )
            .await?;
        }
        if self.rtde.latest().map(|s| s.robot_mode) != Some(RUNNING) {
            self.dashboard.brake_release().await?;
            self.wait_state(
                "brake release (waiting for robot_mode RUNNING)",
                self.opts.power_timeout,
                |s| s.robot_mode == RUNNING,
            )
            .await?;
        }
        Ok(())
    }

    /// Stop whatever program runs, upload ours, and wait until it plays and has taken over the
    /// current command seq.
    async fn upload_and_start(&mut self) -> Result<(), MotionError> {
        let s = self.current_state("waiting for RTDE state").await?;
        self.seq.sync_seq(s.input_cmd_seq);
        if s.runtime_state == control::runtime_state::PLAYING {
            self.dashboard.stop().await?;
            self.wait_state(
                "stopping the running program",
                self.opts.program_start_timeout,
                |s| s.runtime_state != control::runtime_state::PLAYING,
            )
            .await?;
        }
        // The program starts from the seq in the register: write it (kind None) first.
        let idle = CommandWrite {
            seq: self.seq.last_seq(),
            kind: CommandKind::None,
            target: s.actual_tcp_pose,
            speed_m_s: 0.0,
            accel_m_s2: 0.0,
        };
        self.write_cmd(&idle).await?;
        let text = urscript::program(self.opts.watchdog_min_hz, self.opts.tcp_offset);
        upload_program(
            self.endpoints.script,
            &text,
            &self.clock,
            self.opts.dashboard_timeout,
        )
        .await?;
        let seq = self.seq.last_seq();
        self.wait_state(
            "starting the control program (waiting for PLAYING)",
            self.opts.program_start_timeout,
            |s| s.runtime_state == control::runtime_state::PLAYING && s.ack_seq() == seq,
        )
        .await?;
        self.prepared = true;
        Ok(())
    }

    /// After a protective stop (or any fault): unlock the stop (UR refuses for 5 s after it),
    /// clear the pendant popups, power up if needed, re-upload the program, and allow motion
    /// again. An error leaves motion blocked.
    pub async fn recover(&mut self) -> Result<(), MotionError> {
        use control::safety_mode::*;
        let s = self.current_state("waiting for RTDE state").await?;
        match s.safety_mode {
            NORMAL | REDUCED => {}
            PROTECTIVE_STOP => {
                self.dashboard.unlock_protective_stop().await?;
                self.wait_state(
                    "unlocking the protective stop (waiting for NORMAL safety mode)",
                    self.opts.program_start_timeout,
                    |s| s.safety_ok(),
                )
                .await?;
            }
            SYSTEM_EMERGENCY_STOP | ROBOT_EMERGENCY_STOP => {
                return Err(MotionError::Prepare {
                    step: "recover",
                    reason: "emergency stop is engaged: release the button on the pendant or cell, then call recover() again".into(),
                });
            }
            _ => {
                return Err(MotionError::Prepare {
                    step: "recover",
                    reason: format!(
                        "safety state needs the teach pendant ({}); clear it there, then call recover() again",
                        s.modes_description()
                    ),
                });
            }
        }
        self.dashboard.clear_operator_errors().await;
        self.power_up().await?;
        self.seq.abandon();
        self.upload_and_start().await?;
        self.seq.clear_fault();
        Ok(())
    }

    /// Decelerate to a stop (`stopl`) and wait for the program to confirm.
    pub async fn stop(&mut self) -> Result<(), MotionError> {
        let cmd = self
            .seq
            .stop(self.opts.stop_accel_m_s2, self.clock.now_ns());
        self.write_cmd(&cmd).await?;
        let seq = cmd.seq;
        let r = self
            .wait_state("stop", self.opts.program_start_timeout, |s| {
                s.done_seq() == seq || !s.motion_allowed()
            })
            .await;
        self.seq.abandon();
        r.map(drop)
    }

    /// One moveL; see [`run_moves`](Self::run_moves).
    pub async fn move_l(
        &mut self,
        pose: Pose,
        speed_m_s: f64,
        accel_m_s2: f64,
    ) -> Result<MoveReport, MotionError> {
        let mut log = MovesLog::default();
        self.run_moves_logged(
            &[Move {
                label: "move_l".into(),
                pose,
                speed_m_s,
                accel_m_s2,
            }],
            &mut log,
        )
        .await?;
        log.reports
            .pop()
            .ok_or_else(|| MotionError::BadMove("no report".into()))
    }

    /// Run moves in order, logging every state received meanwhile.
    pub async fn run_moves(&mut self, moves: &[Move]) -> Result<MovesLog, MotionError> {
        let mut log = MovesLog::default();
        self.run_moves_logged(moves, &mut log).await?;
        Ok(log)
    }

    /// As [`run_moves`](Self::run_moves), appending to `log`, so the samples up to a failure
    /// are kept.
    pub async fn run_moves_logged(
        &mut self,
        moves: &[Move],
        log: &mut MovesLog,
    ) -> Result<(), MotionError> {
        let mut samples = self.rtde.samples();
        for m in moves {
            let report = self.run_one(m, &mut samples, log).await?;
            log.reports.push(report);
        }
        Ok(())
    }

    /// Link up, fault-free, program playing (re-uploaded if it stopped while the robot is safe).
    async fn ensure_ready(&mut self, label: &str) -> Result<(), MotionError> {
        if let Some(f) = self.seq.fault() {
            return Err(MotionError::NeedsRecovery {
                label: label.into(),
                previous: format!("{} during move `{}`", f.fault, f.label),
            });
        }
        self.wait_link_up(self.opts.reconnect_timeout)
            .await
            .map_err(|reason| MotionError::LinkLost {
                label: label.into(),
                reason,
            })?;
        let s = self.rtde.latest().unwrap_or_default();
        if !s.motion_allowed()
            && self.prepared
            && s.safety_ok()
            && s.robot_mode == control::robot_mode::RUNNING
            && s.is_stationary()
        {
            tracing::warn!(
                "control program not playing ({}); uploading it again",
                s.modes_description()
            );
            self.upload_and_start().await?;
        }
        Ok(())
    }

    fn fault_error(&self, rec: FaultRecord) -> MotionError {
        MotionError::from_fault(rec, self.messages())
    }

    async fn run_one(
        &mut self,
        m: &Move,
        samples: &mut broadcast::Receiver<RobotState>,
        log: &mut MovesLog,
    ) -> Result<MoveReport, MotionError> {
        self.ensure_ready(&m.label).await?;
        // States queued before the command is written describe the past (a program restart in
        // `ensure_ready` leaves STOPPED states behind). The sequencer skips states stamped
        // before the issue time, but while simulated time holds a stale state and the issue
        // can carry the same stamp, so the queue is emptied here instead.
        *samples = samples.resubscribe();
        let mut link = self.rtde.link();
        let mut generation = match &*link.borrow_and_update() {
            LinkStatus::Up { generation, .. } => *generation,
            _ => 0,
        };
        let state = self.rtde.latest().unwrap_or_default();
        let cmd = self
            .seq
            .start_move(
                &m.label,
                m.pose,
                m.speed_m_s,
                m.accel_m_s2,
                &state,
                self.clock.now_ns(),
            )
            .map_err(|r| MotionError::from_refusal(&m.label, r))?;
        let mut reissued = 0u32;
        let mut need_resume = match self.write_cmd(&cmd).await {
            Ok(()) => false,
            Err(RtdeError::NotConnected) => true,
            Err(e) => {
                self.seq.abandon();
                return Err(e.into());
            }
        };
        loop {
            if need_resume {
                need_resume = false;
                if self.resume_after_link_loss(&m.label).await? {
                    reissued += 1;
                    // The STOPPED states of the reconnection are still queued: drop them, as
                    // before the first issue.
                    *samples = samples.resubscribe();
                }
                generation = match &*link.borrow_and_update() {
                    LinkStatus::Up { generation, .. } => *generation,
                    _ => generation,
                };
            }
            let deadline_ns = self.seq.next_deadline_ns().unwrap_or(u64::MAX);
            tokio::select! {
                // Link changes first: a sample from a new connection must not be judged
                // before the reconnection is handled.
                biased;
                r = link.changed() => {
                    if r.is_err() {
                        self.seq.abandon();
                        return Err(MotionError::LinkLost { label: m.label.clone(), reason: "RTDE client stopped".into() });
                    }
                    let same = matches!(&*link.borrow_and_update(), LinkStatus::Up { generation: g, .. } if *g == generation);
                    if !same {
                        need_resume = true;
                    }
                }
                r = samples.recv() => match r {
                    Ok(s) => {
                        log.samples.push(LoggedState { label: m.label.clone(), state: s });
                        match self.seq.on_state(&s, self.clock.now_ns()) {
                            None | Some(SeqEvent::Acked { .. }) => {}
                            Some(SeqEvent::Done { seq, issued_ns, done_ns, state, .. }) => {
                                return Ok(MoveReport {
                                    label: m.label.clone(),
                                    seq,
                                    target: m.pose,
                                    issued_ns,
                                    done_ns,
                                    final_state: state,
                                    position_error_m: pose::translation_distance(&state.actual_tcp_pose, &m.pose),
                                    rotation_error_rad: pose::rotation_distance(&state.actual_tcp_pose, &m.pose),
                                    reissued,
                                });
                            }
                            Some(SeqEvent::Fault(rec)) => return Err(self.fault_error(rec)),
                        }
                    }
                    Err(RecvError::Lagged(n)) => log.missed_samples += n,
                    Err(RecvError::Closed) => {
                        self.seq.abandon();
                        return Err(MotionError::LinkLost { label: m.label.clone(), reason: "RTDE client stopped".into() });
                    }
                },
                _ = self.clock.sleep_until_ns(deadline_ns) => {
                    if let Some(SeqEvent::Fault(rec)) = self.seq.poll_timeout(self.clock.now_ns()) {
                        return Err(self.fault_error(rec));
                    }
                }
            }
        }
    }

    /// Handle a lost link during the active move. Returns whether the move was re-issued.
    async fn resume_after_link_loss(&mut self, label: &str) -> Result<bool, MotionError> {
        let lost = |reason: String| MotionError::LinkLost {
            label: label.into(),
            reason,
        };
        tracing::warn!("RTDE link lost during move `{label}`");
        let back = self.wait_link_up(self.opts.reconnect_timeout).await;
        if self.opts.link_loss == LinkLossPolicy::Abort {
            self.seq.abandon();
            if back.is_ok() {
                let cmd = self
                    .seq
                    .stop(self.opts.stop_accel_m_s2, self.clock.now_ns());
                let _ = self.write_cmd(&cmd).await;
                self.seq.abandon();
            }
            return Err(lost(match back {
                Ok(()) => "aborted by policy (LinkLossPolicy::Abort)".into(),
                Err(e) => e,
            }));
        }
        if let Err(e) = back {
            self.seq.abandon();
            return Err(lost(e));
        }
        // A state from the new connection.
        let t0_ns = self.clock.now_ns();
        let s = self
            .wait_state(
                "waiting for RTDE state after reconnecting",
                self.opts.reconnect_timeout,
                |s| s.t_host_ns >= t0_ns,
            )
            .await
            .inspect_err(|_| self.seq.abandon())?;
        let Some((_, seq)) = self.seq.active() else {
            return Err(lost("no move in progress after reconnecting".into()));
        };
        if !s.safety_ok() || s.robot_mode != control::robot_mode::RUNNING {
            // The sequencer turns this state into the matching safety fault.
            if let Some(SeqEvent::Fault(rec)) = self.seq.on_state(&s, self.clock.now_ns()) {
                return Err(self.fault_error(rec));
            }
        }
        if s.runtime_state == control::runtime_state::PLAYING
            && (s.ack_seq() == seq || s.done_seq() == seq)
        {
            return Ok(false); // the program kept going; the move carries on
        }
        if !s.is_stationary() {
            self.seq.abandon();
            return Err(lost(format!(
                "robot moving ({:.4} m/s) without its command; not resuming",
                s.linear_speed_m_s()
            )));
        }
        if s.runtime_state != control::runtime_state::PLAYING {
            tracing::warn!(
                "control program stopped during the link loss (watchdog); uploading it again"
            );
            self.upload_and_start()
                .await
                .inspect_err(|_| self.seq.abandon())?;
        }
        let s = self.rtde.latest().unwrap_or(s);
        let cmd = self
            .seq
            .reissue(&s, self.clock.now_ns())
            .map_err(|r| MotionError::from_refusal(label, r))?;
        tracing::info!("re-issued move `{label}` as seq {}", cmd.seq);
        match self.write_cmd(&cmd).await {
            Ok(()) => Ok(true),
            Err(e) => {
                self.seq.abandon();
                Err(lost(e.to_string()))
            }
        }
    }
}

/// The robot's own heartbeat, one per RTDE state, while no [`SafetyLine`] owns it.
async fn heartbeat_task(
    mut rx: watch::Receiver<Option<RobotState>>,
    h: RtdeHandle,
    line: Arc<LineState>,
) {
    while rx.changed().await.is_ok() {
        if line.external() {
            continue;
        }
        // NotConnected while reconnecting is expected; the next cycle writes again.
        let _ = line.beat(&h).await;
    }
}
