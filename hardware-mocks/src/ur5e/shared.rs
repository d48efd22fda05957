//! What the controller task, the three servers and the handles share ([`Shared`]), and the
//! accept loop every server runs.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::pose::Pose;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, watch};

use super::config::Ur5eConfig;
use super::controller::Controller;
use super::flange::FlangeSensor;
use super::snapshot::ControllerSnapshot;

#[derive(Debug, Default)]
pub(super) struct FaultState {
    pub(super) refuse_until_ns: u64,
    pub(super) delay_start_ack: Option<Duration>,
    pub(super) text_in_handshake: bool,
}

/// State shared by the controller task, the servers and the handles.
pub(super) struct Shared {
    pub(super) clock: Clock,
    pub(super) cfg: Ur5eConfig,
    pub(super) state: Mutex<Controller>,
    pub(super) samples: broadcast::Sender<Arc<ControllerSnapshot>>,
    /// Clock time of the last tick the controller has processed.
    pub(super) ticks_done: watch::Sender<u64>,
    pub(super) shutdown: watch::Sender<bool>,
    /// Bumped by [`Faults::drop_connections`]; every RTDE connection closes on a change.
    pub(super) drop_gen: watch::Sender<u64>,
    pub(super) faults: Mutex<FaultState>,
    pub(super) packages_sent: AtomicU64,
    pub(super) next_conn: AtomicU64,
    pub(super) t0_ns: u64,
    pub(super) tick_period_ns: u64,
    /// Clock time of the next tick to process; held while ticks are processed, so the
    /// controller task and [`Ur5e::snapshot_now`] never process one tick twice or out of order.
    pub(super) next_tick_ns: Mutex<u64>,
    /// The reported TCP pose and the physical tool tip's pose of each of the last
    /// [`POSE_HISTORY`] ticks, oldest first, for [`Ur5e::tcp_pose_at`](super::Ur5e::tcp_pose_at)
    /// and [`Ur5e::tip_pose_at`](super::Ur5e::tip_pose_at).
    pub(super) poses: Mutex<VecDeque<TickPoses>>,
    /// The flange force/torque sensor, read on every tick (none: `actual_TCP_force` is zero).
    /// A leaf lock: its contact source never calls back into the controller.
    pub(super) flange: Mutex<Option<FlangeSensor>>,
}

/// The poses of one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct TickPoses {
    pub(super) t_ns: u64,
    /// The TCP pose the controller reports.
    pub(super) tcp: Pose,
    /// Where the physical tool tip is.
    pub(super) tip: Pose,
}

/// Ticks of TCP pose history kept: 5 s at 500 Hz, far more than any simulated device lags and
/// longer than any stage of a plan, so a stage's path can be read back once it has ended.
pub(super) const POSE_HISTORY: usize = 2500;

impl Shared {
    /// Process every tick due at clock time `now`, in order, broadcasting each snapshot.
    pub(super) fn process_due_ticks(&self, now: u64) {
        let mut next = self.next_tick_ns.lock().unwrap_or_else(|p| p.into_inner());
        while *next <= now {
            let t_ns = *next;
            *next += self.tick_period_ns;
            // Read before the controller is locked: the reading takes the physics' buffer
            // lock, which nothing should wait on while holding the controller.
            let force = self
                .flange
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .as_mut()
                .map(FlangeSensor::read);
            let (snap, tip) = {
                let mut c = self.lock();
                if let Some(f) = force {
                    c.tcp_force = f;
                }
                let snap = c.tick(t_ns);
                (Arc::new(snap), c.tip_pose())
            };
            {
                let mut poses = self.poses.lock().unwrap_or_else(|p| p.into_inner());
                if poses.len() == POSE_HISTORY {
                    poses.pop_front();
                }
                poses.push_back(TickPoses {
                    t_ns,
                    tcp: snap.actual_tcp_pose,
                    tip,
                });
            }
            // No receivers is fine: nobody streams yet.
            let _ = self.samples.send(snap);
            self.ticks_done.send_replace(t_ns);
        }
    }

    pub(super) fn lock(&self) -> MutexGuard<'_, Controller> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
    pub(super) fn faults(&self) -> MutexGuard<'_, FaultState> {
        self.faults.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Accepts connections on `listener` until the task is aborted and hands each to `connection`,
/// which starts whatever serves it. A failed accept is logged, naming the `port`, and retried
/// after 10 ms of clock time.
pub(super) async fn accept_loop(
    listener: TcpListener,
    shared: Arc<Shared>,
    port: &'static str,
    mut connection: impl FnMut(TcpStream, SocketAddr, &Arc<Shared>),
) {
    loop {
        match listener.accept().await {
            Ok((sock, peer)) => connection(sock, peer, &shared),
            Err(e) => {
                tracing::warn!("{port} accept failed: {e}");
                shared.clock.sleep(Duration::from_millis(10)).await;
            }
        }
    }
}

/// Serves one client of `port` on its own task until `serve` ends or the controller shuts down.
pub(super) fn spawn_until_shutdown(
    shared: &Shared,
    port: &'static str,
    peer: SocketAddr,
    serve: impl Future<Output = ()> + Send + 'static,
) {
    let mut shutdown = shared.shutdown.subscribe();
    tokio::spawn(async move {
        tokio::select! {
            _ = serve => {}
            _ = shutdown.wait_for(|s| *s) => {}
        }
        tracing::debug!(%peer, "{port} client gone");
    });
}
