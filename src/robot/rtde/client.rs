//! The RTDE client API: what the rest of the rig holds.
//!
//! [`RtdeClient`] starts the reader task and reads what it publishes, so its getters never
//! wait on the socket. Pause and resume change the session, which the task owns, so they are
//! handed to the task and answered on a oneshot (with a clock timeout). Input writes go
//! through [`RtdeHandle`], a cheap clone, because they come from other tasks (the robot's
//! heartbeat and its command writes) that must not own the client.

use std::sync::Arc;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::rtde::{TextMessage, Value};
use tokio::sync::{broadcast, mpsc, oneshot, watch};
use tokio::task::JoinHandle;

use super::connection::{
    Control, LinkStatus, RtdeConfig, RtdeStats, Shared, establish_with_retries, reader_task,
};
use super::error::RtdeError;
use crate::robot::state::RobotState;

/// The async RTDE client. Dropping it stops the reader task.
pub struct RtdeClient {
    shared: Arc<Shared>,
    task: JoinHandle<()>,
    control: mpsc::UnboundedSender<Control>,
    handshake_timeout: Duration,
}

impl Drop for RtdeClient {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl RtdeClient {
    /// Connect, run the handshake (with the configured retries) and start streaming.
    pub async fn connect(cfg: RtdeConfig, clock: Clock) -> Result<Self, RtdeError> {
        let shared = Arc::new(Shared::new(clock, cfg.sample_buffer));
        let est = establish_with_retries(&cfg, &shared, None).await?;
        let (control, control_rx) = mpsc::unbounded_channel();
        let handshake_timeout = cfg.handshake_timeout;
        let task = tokio::spawn(reader_task(est, cfg, shared.clone(), control_rx));
        Ok(Self {
            shared,
            task,
            control,
            handshake_timeout,
        })
    }

    /// Pause streaming ('P') and wait for the controller's reply. While paused no data is
    /// expected (no stall detection), and a link re-made meanwhile is paused again.
    pub async fn pause(&self) -> Result<(), RtdeError> {
        self.request(Control::Pause).await
    }

    /// Resume streaming after [`pause`](Self::pause) ('S' with the same recipes) and wait for
    /// the controller's reply.
    pub async fn resume(&self) -> Result<(), RtdeError> {
        self.request(Control::Resume).await
    }

    async fn request(
        &self,
        make: fn(oneshot::Sender<Result<(), RtdeError>>) -> Control,
    ) -> Result<(), RtdeError> {
        let (tx, rx) = oneshot::channel();
        self.control
            .send(make(tx))
            .map_err(|_| RtdeError::Shutdown)?;
        match self.shared.clock.timeout(self.handshake_timeout, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(RtdeError::NotConnected),
            Err(_) => Err(RtdeError::HandshakeTimeout {
                phase: "pause/start",
                timeout: self.handshake_timeout,
                messages: self.shared.messages_suffix(),
            }),
        }
    }

    /// The latest state (`None` before the first data package).
    pub fn latest(&self) -> Option<RobotState> {
        *self.shared.state_tx.borrow()
    }
    /// Latest state, updated on every data package.
    pub fn watch_state(&self) -> watch::Receiver<Option<RobotState>> {
        self.shared.state_tx.subscribe()
    }
    /// Every state from now on (bounded; a slow receiver sees `Lagged`).
    pub fn samples(&self) -> broadcast::Receiver<RobotState> {
        self.shared.samples_tx.subscribe()
    }
    pub fn link(&self) -> watch::Receiver<LinkStatus> {
        self.shared.link_tx.subscribe()
    }
    pub fn link_status(&self) -> LinkStatus {
        self.shared.link_tx.borrow().clone()
    }
    /// The last text messages from the controller (oldest first).
    pub fn recent_text_messages(&self) -> Vec<TextMessage> {
        self.shared.recent_texts()
    }
    pub fn stats(&self) -> RtdeStats {
        self.shared.stats()
    }
    /// A cloneable handle for writing inputs.
    pub fn handle(&self) -> RtdeHandle {
        RtdeHandle {
            shared: self.shared.clone(),
        }
    }
    /// Stop the reader task and close the connection.
    pub async fn shutdown(self) {
        self.task.abort();
        self.shared.close().await;
    }
}

/// Writes input data packages on the current connection.
#[derive(Clone)]
pub struct RtdeHandle {
    shared: Arc<Shared>,
}

impl RtdeHandle {
    /// Send `values` for input recipe number `recipe` (index into `RtdeConfig::input_recipes`).
    /// Fails with [`RtdeError::NotConnected`] while the link is being re-made.
    pub async fn send_inputs(&self, recipe: usize, values: &[Value]) -> Result<(), RtdeError> {
        self.shared.send_inputs(recipe, values).await
    }

    /// The link's status now.
    pub fn link_status(&self) -> LinkStatus {
        self.shared.link_tx.borrow().clone()
    }
}
