//! The Net F/T over UDP (RDT).
//!
//! One tokio task owns a UDP socket connected to the box: it sends the start request
//! (command 2, sample count 0 = until stopped), optionally a software bias (0x42) first, and
//! then receives datagrams. Each record's `rdt_sequence` goes through the
//! [`SequenceTracker`], which also gives the unwrapped `device_seq`: a sample after a gap is
//! flagged `AFTER_GAP`, a late packet is delivered flagged `REORDERED` (the consumer sorts by
//! `device_seq` if it needs order), a duplicate is dropped
//! ([`Arrival::sample_flags`](rig_core::ft::sequence::Arrival::sample_flags)); all are counted
//! exactly. Datagrams that are not whole records are counted as garbage. On stop the task
//! sends command 0. No datagram for [`SILENCE_TIMEOUT`] ends the stream with an error.

use std::net::SocketAddr;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::ft::netft::{RDT_PORT, RdtCommand, RdtRecord, RdtRequest};
use rig_core::ft::sequence::SequenceTracker;
use tokio::net::UdpSocket;

use super::conditioning::FrontEndSettings;
use super::error::FtError;
use super::stream::{Control, FtStats, FtStream};

/// Clock time without any datagram after which the box counts as gone.
pub const SILENCE_TIMEOUT: Duration = Duration::from_secs(2);

/// Resolves `host` or `host:port` (default port 49152).
pub async fn resolve(address: &str) -> Result<SocketAddr, FtError> {
    let with_port = if address.parse::<SocketAddr>().is_ok()
        || address
            .rsplit_once(':')
            .is_some_and(|(_, p)| p.parse::<u16>().is_ok())
    {
        address.to_owned()
    } else {
        format!("{address}:{RDT_PORT}")
    };
    tokio::net::lookup_host(&with_port)
        .await
        .ok()
        .and_then(|mut it| it.next())
        .ok_or_else(|| {
            FtError::Config(format!("force_sensor.address {address:?} does not resolve"))
        })
}

/// The receive buffer asked for, bytes (see `open`).
const RECV_BUFFER: usize = 4 << 20;

/// Connects to the box at `address` and starts streaming.
pub async fn open(
    address: &str,
    device_bias: bool,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    let addr = resolve(address).await?;
    let bind: SocketAddr = if addr.is_ipv4() {
        ([0, 0, 0, 0], 0).into()
    } else {
        ([0u16; 8], 0).into()
    };
    let io = |e: std::io::Error| FtError::Io {
        device: format!("Net F/T {addr}"),
        reason: e.to_string(),
    };
    let sock = UdpSocket::bind(bind).await.map_err(io)?;
    sock.connect(addr).await.map_err(io)?;
    // A big receive buffer: 7 kHz × 36 B is little data, but the kernel charges each datagram
    // its buffer overhead (about 0.8 kB), so the default (208 KiB) holds only about 40 ms of
    // records and a consumer stalled longer loses them. 4 MiB (Linux caps it at
    // net.core.rmem_max) holds about 0.7 s. Loss the kernel causes is still counted, as a gap.
    if let Err(e) =
        nix::sys::socket::setsockopt(&sock, nix::sys::socket::sockopt::RcvBuf, &RECV_BUFFER)
    {
        tracing::debug!("Net F/T {addr}: receive buffer of {RECV_BUFFER} B not set: {e}");
    }
    if device_bias {
        let req = RdtRequest {
            command: RdtCommand::SetSoftwareBias,
            sample_count: 0,
        };
        sock.send(&req.encode()).await.map_err(io)?;
    }
    let start = RdtRequest {
        command: RdtCommand::StartRealtime,
        sample_count: 0,
    };
    sock.send(&start.encode()).await.map_err(io)?;
    let (stream, sink, mut ctl, done) = FtStream::channel(format!("Net F/T {addr}"));
    let mut cond = settings.counts_conditioner();
    tokio::spawn(async move {
        let mut tracker = SequenceTracker::new();
        let mut buf = vec![0u8; 2048];
        loop {
            let recv = clock.timeout(SILENCE_TIMEOUT, sock.recv(&mut buf));
            tokio::select! {
                c = ctl.recv() => match c {
                    Some(Control::Tare { samples, reply }) => { cond.start_tare(samples, reply); continue; }
                    Some(Control::Stop) | None => break,
                },
                r = recv => {
                    let n = match r {
                        Err(_) => {
                            sink.fail(FtError::NoAnswer { device: format!("Net F/T {addr}"), what: "RDT records".into(), timeout_ms: SILENCE_TIMEOUT.as_millis() as u64 });
                            break;
                        }
                        // ICMP port unreachable shows up as a receive error on a connected socket.
                        Ok(Err(e)) => {
                            sink.fail(FtError::PortClosed { port: format!("Net F/T {addr}"), reason: e.to_string() });
                            break;
                        }
                        Ok(Ok(n)) => n,
                    };
                    let t_host_ns = clock.now_ns();
                    let Ok(records) = RdtRecord::decode_datagram(&buf[..n]) else {
                        FtStats::add(&sink.stats.garbage, n as u64);
                        continue;
                    };
                    let mut stop = false;
                    for rec in records {
                        let (arrival, seq) = tracker.observe_unwrapped(rec.rdt_sequence);
                        let Some(flags) = arrival.sample_flags() else { continue };
                        let raw = rec.counts.map(f64::from);
                        if !sink.condition_and_deliver(&mut cond, &raw, None, rec.status, flags, t_host_ns, seq) {
                            stop = true;
                            break;
                        }
                    }
                    let s = tracker.stats();
                    FtStats::set(&sink.stats.lost, s.lost);
                    FtStats::set(&sink.stats.reordered, s.reordered);
                    FtStats::set(&sink.stats.duplicates, s.duplicates);
                    if stop { break; }
                }
            }
        }
        let stop = RdtRequest {
            command: RdtCommand::Stop,
            sample_count: 0,
        };
        let _ = sock.send(&stop.encode()).await;
        let _ = done.send(());
    });
    Ok(stream)
}
