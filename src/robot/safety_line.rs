//! The safety line: the heartbeat that feeds the controller's RTDE watchdog and the stop
//! request, written together in one input recipe of their own ([`rig_core::control::safety_recipe`]).
//!
//! The control program reads two registers besides its commands (`rig_core::control`):
//!
//! - [`control::IN_HEARTBEAT`], watched by the controller's RTDE watchdog
//!   (`rtde_set_watchdog(…, "stop")`, URScript manual): if no input package updates it for
//!   `1 / watchdog_min_hz`, the controller stops the program and the arm decelerates by itself;
//! - [`control::IN_STOP_REQ`], a counter: when it changes, the program kills the move in
//!   progress and decelerates with `stopl(`[`control::IN_STOP_DECEL`]`)`, whatever command it
//!   was executing. The stop never takes a command sequence number, so it never races the
//!   motion sequencer.
//!
//! Whoever writes the heartbeat is the one the watchdog trusts. [`Robot`](super::Robot) writes
//! it on every RTDE state by default. A run's safety supervisor takes the line over with
//! [`Robot::safety_line`](super::Robot::safety_line): from then on only the supervisor beats,
//! so a supervisor that stalls starves the watchdog and the controller stops the arm itself.
//! Dropping the [`SafetyLine`] hands the heartbeat back to the robot's own task.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU64, Ordering};

use rig_core::rtde::Value;

use super::rtde::{RtdeError, RtdeHandle};

/// Index of the safety recipe in the RTDE client's input recipes (after the command recipe).
pub(super) const SAFETY_RECIPE: usize = 1;

/// State of the line shared by the robot's heartbeat task and a [`SafetyLine`].
#[derive(Debug)]
pub(super) struct LineState {
    beat: AtomicI32,
    stop_req: AtomicI32,
    /// `f64` bits of the stop deceleration, m/s².
    stop_decel: AtomicU64,
    /// A [`SafetyLine`] owns the heartbeat: the robot's own task stays silent.
    external: AtomicBool,
}

impl LineState {
    pub(super) fn new(stop_decel_m_s2: f64) -> Arc<Self> {
        Arc::new(Self {
            beat: AtomicI32::new(0),
            stop_req: AtomicI32::new(0),
            stop_decel: AtomicU64::new(stop_decel_m_s2.to_bits()),
            external: AtomicBool::new(false),
        })
    }

    pub(super) fn external(&self) -> bool {
        self.external.load(Ordering::Acquire)
    }

    /// The values of the next package: a new heartbeat, the current stop request.
    fn next_values(&self) -> [Value; 3] {
        let beat = self.beat.fetch_add(1, Ordering::AcqRel).wrapping_add(1);
        [
            Value::Int32(beat),
            Value::Int32(self.stop_req.load(Ordering::Acquire)),
            Value::Double(f64::from_bits(self.stop_decel.load(Ordering::Acquire))),
        ]
    }

    /// Write one heartbeat package.
    pub(super) async fn beat(&self, h: &RtdeHandle) -> Result<(), RtdeError> {
        h.send_inputs(SAFETY_RECIPE, &self.next_values()).await
    }
}

/// The heartbeat and the stop, owned by a safety supervisor (see the module docs).
pub struct SafetyLine {
    handle: RtdeHandle,
    state: Arc<LineState>,
}

impl SafetyLine {
    pub(super) fn take(handle: RtdeHandle, state: Arc<LineState>) -> Self {
        state.external.store(true, Ordering::Release);
        Self { handle, state }
    }

    /// Feed the controller's watchdog (one input package). `NotConnected` while the RTDE
    /// client reconnects; the next beat writes again.
    pub async fn beat(&self) -> Result<(), RtdeError> {
        self.state.beat(&self.handle).await
    }

    /// Command the stop now: a new stop request, written at once. The program kills the move
    /// in progress and decelerates with the configured deceleration.
    pub async fn stop(&self) -> Result<(), RtdeError> {
        self.state.stop_req.fetch_add(1, Ordering::AcqRel);
        self.beat().await
    }

    /// Stop requests written so far.
    pub fn stops(&self) -> i32 {
        self.state.stop_req.load(Ordering::Acquire)
    }
}

impl Drop for SafetyLine {
    fn drop(&mut self) {
        self.state.external.store(false, Ordering::Release);
    }
}
