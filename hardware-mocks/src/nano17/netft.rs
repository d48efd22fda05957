//! A simulated ATI Net F/T on UDP (see `rig_core::ft::netft` for RDT).
//!
//! Listens on a UDP port (49152 on the real box; tests use an ephemeral one). A start request
//! (command 2, or 3 for buffered: simulated as real-time) from a client streams records to that
//! client's address at the configured rate, `sample_count` of them or until a stop (command 0).
//! `rdt_sequence` starts at 1 for each stream and counts every record the box *meant* to send,
//! so injected drops show as gaps exactly as network loss would; `ft_sequence` counts the box's
//! internal samples since power-up. Command 0x42 makes the present reading the zero (software
//! bias). Requests with a bad header or length are ignored, as the box does.
//!
//! Faults: drop every n-th record, hold every n-th back until after the next (reordering),
//! send every n-th twice, forced saturation (status bit 31 and the saturated bit), garbage
//! datagrams (sent as one datagram before the next record).

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use rig_core::clock::Clock;
use rig_core::ft::netft::{
    FACTORY_COUNTS_PER_FORCE, FACTORY_COUNTS_PER_TORQUE, MAX_RDT_RATE_HZ, RdtCommand, RdtRecord,
    RdtRequest, STATUS_ERROR,
};
use rig_core::ft::wrench_to_counts;
use tokio::net::UdpSocket;
use tokio::sync::oneshot;

use super::{
    Faults, MockConfig, MockHandle, MockStats, SensorModel, SharedWrenchSource, sample_time_ns,
};

/// Status bits of a record taken while a gauge is saturated (bit 31 "error" plus the mock's
/// saturation bit 16).
pub const STATUS_SATURATED: u32 = STATUS_ERROR | (1 << 16);

/// Configuration of the simulated Net F/T.
#[derive(Debug, Clone)]
pub struct NetFtMockConfig {
    /// Address to bind (port 0: ephemeral).
    pub bind: SocketAddr,
    /// Records per second (the real box: up to [`MAX_RDT_RATE_HZ`], the default).
    pub rate_hz: f64,
    /// Counts per newton (default: the factory's, [`FACTORY_COUNTS_PER_FORCE`]).
    pub counts_per_force: f64,
    /// Counts per N·mm (default: the factory's, [`FACTORY_COUNTS_PER_TORQUE`]).
    pub counts_per_torque: f64,
    pub seed: u64,
}

impl Default for NetFtMockConfig {
    fn default() -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            rate_hz: MAX_RDT_RATE_HZ,
            counts_per_force: FACTORY_COUNTS_PER_FORCE,
            counts_per_torque: FACTORY_COUNTS_PER_TORQUE,
            seed: 49152,
        }
    }
}

/// A running simulated Net F/T.
pub type NetFtMock = MockHandle<NetFtMockConfig>;

impl MockConfig for NetFtMockConfig {
    type Endpoint = SocketAddr;
}

impl NetFtMock {
    /// Binds the socket and starts the box.
    pub async fn start(
        cfg: NetFtMockConfig,
        model: SensorModel,
        source: SharedWrenchSource,
        clock: Clock,
    ) -> io::Result<Self> {
        let sock = UdpSocket::bind(cfg.bind).await?;
        let addr = sock.local_addr()?;
        Ok(Self::spawn(addr, |faults, stats, stop| {
            run(sock, cfg, model, source, clock, faults, stats, stop)
        }))
    }
}

struct Stream {
    peer: SocketAddr,
    t0_ns: u64,
    k: u64,
    remaining: Option<u64>,
    held: Option<RdtRecord>,
}

#[allow(clippy::too_many_arguments)]
async fn run(
    sock: UdpSocket,
    cfg: NetFtMockConfig,
    mut model: SensorModel,
    source: SharedWrenchSource,
    clock: Clock,
    faults: Arc<Faults>,
    stats: Arc<MockStats>,
    mut stop: oneshot::Receiver<()>,
) {
    let mut bias = [0.0; 6];
    let mut ft_sequence: u32 = 0;
    let mut stream: Option<Stream> = None;
    let mut buf = [0u8; 64];
    let every = |a: &std::sync::atomic::AtomicU32, seq: u32| {
        let n = a.load(Ordering::Acquire);
        n != 0 && seq.is_multiple_of(n)
    };
    loop {
        if faults.unplugged() {
            return;
        }
        let next_due = stream
            .as_ref()
            .map(|s| sample_time_ns(s.t0_ns, s.k, cfg.rate_hz));
        tokio::select! {
            _ = &mut stop => return,
            r = sock.recv_from(&mut buf) => {
                let Ok((n, peer)) = r else { continue };
                let Ok(req) = RdtRequest::decode(&buf[..n]) else { continue };
                stats.commands.fetch_add(1, Ordering::AcqRel);
                match req.command {
                    RdtCommand::StartRealtime | RdtCommand::StartBuffered | RdtCommand::StartMultiUnit => {
                        stream = Some(Stream {
                            peer,
                            t0_ns: clock.now_ns(),
                            k: 0,
                            remaining: (req.sample_count != 0).then_some(u64::from(req.sample_count)),
                            held: None,
                        });
                    }
                    RdtCommand::Stop => stream = None,
                    RdtCommand::SetSoftwareBias => {
                        let truth = source.wrench_at(clock.now_ns()).to_array();
                        let m = model.measure(&truth, faults.saturated());
                        bias = model.resolve(&m);
                    }
                    _ => {}
                }
            }
            _ = async {
                match next_due {
                    Some(t) => clock.sleep_until_ns(t).await,
                    None => std::future::pending().await,
                }
            } => {
                let Some(s) = stream.as_mut() else { continue };
                let now = clock.now_ns();
                let mut finished = false;
                loop {
                    let t = sample_time_ns(s.t0_ns, s.k, cfg.rate_hz);
                    if t > now { break; }
                    if s.remaining == Some(0) { finished = true; break; }
                    if faults.muted() { s.k += 1; continue; }
                    s.k += 1;
                    if let Some(r) = s.remaining.as_mut() { *r -= 1; }
                    ft_sequence = ft_sequence.wrapping_add(1);
                    let rdt_sequence = s.k as u32; // starts at 1
                    let truth = source.wrench_at(t).to_array();
                    let m = model.measure(&truth, faults.saturated());
                    let w = model.resolve(&m);
                    let biased: [f64; 6] = std::array::from_fn(|i| w[i] - bias[i]);
                    let counts = wrench_to_counts(&biased, cfg.counts_per_force, cfg.counts_per_torque);
                    let status = if m.saturated_gauges != 0 { STATUS_SATURATED } else { 0 };
                    let rec = RdtRecord { rdt_sequence, ft_sequence, status, counts };
                    let garbage = faults.take_garbage();
                    if !garbage.is_empty() {
                        stats.garbage_bytes.fetch_add(garbage.len() as u64, Ordering::AcqRel);
                        let _ = sock.send_to(&garbage, s.peer).await;
                    }
                    if every(&faults.drop_every, rdt_sequence) {
                        stats.dropped.fetch_add(1, Ordering::AcqRel);
                        continue;
                    }
                    if s.held.is_none() && every(&faults.reorder_every, rdt_sequence) {
                        s.held = Some(rec);
                        continue;
                    }
                    let _ = sock.send_to(&rec.encode(), s.peer).await;
                    stats.sent.fetch_add(1, Ordering::AcqRel);
                    if every(&faults.duplicate_every, rdt_sequence) {
                        let _ = sock.send_to(&rec.encode(), s.peer).await;
                        stats.duplicated.fetch_add(1, Ordering::AcqRel);
                    }
                    if let Some(h) = s.held.take() {
                        let _ = sock.send_to(&h.encode(), s.peer).await;
                        stats.sent.fetch_add(1, Ordering::AcqRel);
                        stats.reordered.fetch_add(1, Ordering::AcqRel);
                    }
                }
                if finished {
                    if let Some(h) = s.held.take() {
                        let _ = sock.send_to(&h.encode(), s.peer).await;
                        stats.sent.fetch_add(1, Ordering::AcqRel);
                    }
                    stream = None;
                }
            }
        }
    }
}
