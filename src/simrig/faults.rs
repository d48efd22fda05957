//! Faults injected into the simulated rig during a run: operator drills (`rig run --sim-fault`)
//! and the fault tests. Each fires when its trajectory's stage starts, plus its delay in clock
//! time, through the simulated device's own fault handle, so the rig meets it as it would meet
//! the real thing.

use std::sync::Arc;
use std::time::Duration;

use hardware_mocks::camera::CameraFaults;
use hardware_mocks::nano17::Faults;
use hardware_mocks::ur5e::Ur5e;
use rig_core::clock::Clock;
use tokio::sync::watch;

use crate::plan::StageName;

/// A fault injected into the simulated rig during a run (fault tests, operator drills).
#[derive(Debug, Clone, PartialEq)]
pub struct SimFault {
    pub kind: SimFaultKind,
    /// The trajectory (id) and stage in which it happens.
    pub trajectory: String,
    pub stage: StageName,
    /// Clock time after the stage's start, ms.
    pub after_ms: f64,
}

/// What [`SimFault`] injects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimFaultKind {
    /// The UR5e enters a protective stop.
    ProtectiveStop,
    /// The UR5e closes every connection and refuses new ones for 1 s of clock time.
    RtdeDrop,
    /// The F/T front end is unplugged (a serial front end closes its pty; an NI card is
    /// removed, `-200045`).
    FtUnplug,
    /// The camera stops sending frames.
    CameraStall,
    /// The rig's own safety supervisor hangs (no checks, no heartbeat): the controller's RTDE
    /// watchdog must stop the arm by itself.
    SupervisorFreeze,
    /// The recording's disk stops answering: the recorder's writer is held for good (it never
    /// returns from its next write). The run must still stop and retract the arm on a trip, and
    /// end with a clear error once its bookkeeping has waited the recorder's stall limit.
    DiskStall,
}

/// The longest delay after its stage's start a fault may be scheduled for, ms: an hour of
/// clock time, far longer than any stage.
pub const MAX_FAULT_DELAY_MS: f64 = 3_600_000.0;

impl std::str::FromStr for SimFault {
    type Err = String;
    /// `KIND@TRAJECTORY/STAGE[+MS]`, e.g. `protective-stop@p0-d0.4-a030/shear+200`.
    fn from_str(s: &str) -> Result<Self, String> {
        let usage = "expected KIND@TRAJECTORY/STAGE[+MS], e.g. protective-stop@p0-d0.4-a030/shear+200 \
                     (KIND: protective-stop, rtde-drop, ft-unplug, camera-stall, supervisor-freeze, disk-stall)";
        let (kind, rest) = s.split_once('@').ok_or_else(|| format!("{s:?}: {usage}"))?;
        let kind = match kind {
            "protective-stop" => SimFaultKind::ProtectiveStop,
            "rtde-drop" => SimFaultKind::RtdeDrop,
            "ft-unplug" => SimFaultKind::FtUnplug,
            "camera-stall" => SimFaultKind::CameraStall,
            "supervisor-freeze" => SimFaultKind::SupervisorFreeze,
            "disk-stall" => SimFaultKind::DiskStall,
            other => return Err(format!("unknown fault kind {other:?}: {usage}")),
        };
        let (traj, stage_ms) = rest
            .rsplit_once('/')
            .ok_or_else(|| format!("{s:?}: {usage}"))?;
        let (stage, ms) = match stage_ms.split_once('+') {
            Some((st, ms)) => (
                st,
                ms.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| format!("{s:?}: bad delay {ms:?}: {usage}"))
                    .and_then(|v| {
                        if v <= MAX_FAULT_DELAY_MS {
                            Ok(v)
                        } else {
                            Err(format!(
                                "{s:?}: delay {ms} ms is longer than any stage; at most {MAX_FAULT_DELAY_MS} ms (an hour of clock time)"
                            ))
                        }
                    })?,
            ),
            None => (stage_ms, 0.0),
        };
        let stage = match stage {
            "down" => StageName::Down,
            "shear" => StageName::Shear,
            "reverse" => StageName::Reverse,
            "up" => StageName::Up,
            other => return Err(format!("unknown stage {other:?}: {usage}")),
        };
        Ok(SimFault {
            kind,
            trajectory: traj.to_owned(),
            stage,
            after_ms: ms,
        })
    }
}

/// The rig's own parts that faults act on, besides the simulated devices.
#[derive(Clone)]
pub struct RigHooks {
    /// Freezes the rig's safety supervisor.
    pub freeze_supervisor: Arc<dyn Fn() + Send + Sync>,
    /// Holds the recorder's writer for good (a disk that never comes back).
    pub stall_disk: Arc<dyn Fn() + Send + Sync>,
}

/// Handles of the simulated rig that faults are injected through.
pub(super) struct FaultTargets {
    pub ur5e: Arc<Ur5e>,
    pub ft: Arc<Faults>,
    pub camera: Option<CameraFaults>,
    pub rig: RigHooks,
}

/// Injects `faults` when their stage starts (plus their delay).
pub(super) async fn inject_faults(
    faults: Vec<SimFault>,
    targets: FaultTargets,
    clock: Clock,
    mut stages: watch::Receiver<Option<(String, StageName)>>,
) {
    let mut pending = faults;
    while !pending.is_empty() {
        if stages.changed().await.is_err() {
            return;
        }
        let Some((id, stage)) = stages.borrow_and_update().clone() else {
            continue;
        };
        let (now, later): (Vec<_>, Vec<_>) = pending
            .into_iter()
            .partition(|f| f.trajectory == id && f.stage == stage);
        pending = later;
        for f in now {
            let (ur, ft, cam, rig, clock) = (
                targets.ur5e.clone(),
                targets.ft.clone(),
                targets.camera.clone(),
                targets.rig.clone(),
                clock.clone(),
            );
            tokio::spawn(async move {
                clock
                    .sleep(Duration::from_secs_f64(f.after_ms * 1e-3))
                    .await;
                tracing::warn!(
                    "simulated fault: {:?} in {}/{}",
                    f.kind,
                    f.trajectory,
                    f.stage
                );
                match f.kind {
                    SimFaultKind::ProtectiveStop => ur.faults().protective_stop(),
                    SimFaultKind::RtdeDrop => ur.faults().drop_connections(Duration::from_secs(1)),
                    SimFaultKind::FtUnplug => ft.unplug(),
                    SimFaultKind::CameraStall => {
                        if let Some(c) = cam {
                            c.set_stalled(true);
                        }
                    }
                    SimFaultKind::SupervisorFreeze => (rig.freeze_supervisor)(),
                    SimFaultKind::DiskStall => (rig.stall_disk)(),
                }
            });
        }
    }
}
