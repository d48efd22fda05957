//! The RTDE link: the framed socket and the reader task that keeps it up.
//!
//! One task owns the read half and the [`Session`], so frames are handled in order and
//! pause/resume requests (which change the session) are served between frames rather than
//! racing them. It publishes what it learns on channels that any number of readers can
//! subscribe to, and it is the one place that decides a link is lost (an error, a close, or
//! no data for the stall timeout while streaming) and re-makes it: RTDE forgets the recipes
//! with the connection, so every reconnect runs the whole handshake again, with bounded
//! retries and backoff on the shared clock because the controller refuses connections while
//! it reboots. The write half sits behind a mutex beside the channels, so input writes from
//! the client's handles never wait on a read.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex as StdMutex};
use std::time::Duration;

use bytes::BytesMut;
use rig_core::clock::Clock;
use rig_core::rtde::{
    ClientPackage, DataType, Frame, FrameDecoder, MessageLevel, TextMessage, Value, encode_values,
};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::{Mutex, broadcast, mpsc, oneshot, watch};

use super::error::{RtdeError, describe_messages};
use super::session::{ControllerVersion, Phase, Session, SessionConfig, SessionEvent, SkipReason};
use crate::robot::state::{RobotState, StateDecoder, output_recipe};

/// How many text messages are kept for error reports.
pub const KEPT_TEXT_MESSAGES: usize = 16;

// ---------------------------------------------------------------------------------------------
// Framed socket halves
// ---------------------------------------------------------------------------------------------

/// The read half of a connection plus its framer.
#[derive(Debug)]
pub struct FrameReader<R> {
    io: R,
    decoder: FrameDecoder,
}

impl<R: AsyncRead + Unpin> FrameReader<R> {
    pub fn new(io: R) -> Self {
        Self {
            io,
            decoder: FrameDecoder::new(),
        }
    }

    /// The next whole frame; `Ok(None)` on a clean end of stream. Cancel-safe: bytes read
    /// before a cancellation stay buffered.
    pub async fn read_frame(&mut self) -> Result<Option<Frame>, RtdeError> {
        loop {
            if let Some(f) = self.decoder.next_frame().map_err(RtdeError::OutOfSync)? {
                return Ok(Some(f));
            }
            let n = self
                .io
                .read_buf(self.decoder.buffer_mut())
                .await
                .map_err(RtdeError::io)?;
            if n == 0 {
                return if self.decoder.buffered() == 0 {
                    Ok(None)
                } else {
                    Err(RtdeError::Io(format!(
                        "connection closed inside a package ({} bytes pending)",
                        self.decoder.buffered()
                    )))
                };
            }
        }
    }
}

/// The write half of a connection.
#[derive(Debug)]
pub struct FrameWriter<W> {
    io: W,
    buf: BytesMut,
}

impl<W: AsyncWrite + Unpin> FrameWriter<W> {
    pub fn new(io: W) -> Self {
        Self {
            io,
            buf: BytesMut::with_capacity(256),
        }
    }

    /// Encode and write one package.
    pub async fn write_package(
        &mut self,
        pkg: &ClientPackage,
        version: u16,
    ) -> Result<(), RtdeError> {
        self.buf.clear();
        pkg.encode(version, &mut self.buf)?;
        self.io.write_all(&self.buf).await.map_err(RtdeError::io)?;
        Ok(())
    }
}

/// A TCP connection to the controller's RTDE port, `TCP_NODELAY` set (packages are small and
/// latency matters more than throughput).
#[derive(Debug)]
pub struct Connection {
    pub reader: FrameReader<OwnedReadHalf>,
    pub writer: FrameWriter<OwnedWriteHalf>,
}

impl Connection {
    pub async fn connect(addr: SocketAddr) -> Result<Self, RtdeError> {
        let stream = TcpStream::connect(addr)
            .await
            .map_err(|e| RtdeError::Connect {
                addr,
                reason: e.to_string(),
            })?;
        stream.set_nodelay(true).map_err(RtdeError::io)?;
        let (r, w) = stream.into_split();
        Ok(Self {
            reader: FrameReader::new(r),
            writer: FrameWriter::new(w),
        })
    }
}
// ---------------------------------------------------------------------------------------------
// Link settings, status and counters
// ---------------------------------------------------------------------------------------------

/// Client settings.
#[derive(Debug, Clone)]
pub struct RtdeConfig {
    pub addr: SocketAddr,
    /// `None`: 500 Hz on e-Series, 125 Hz on CB3.
    pub frequency_hz: Option<f64>,
    pub output_names: Vec<String>,
    pub input_recipes: Vec<Vec<String>>,
    /// Limit on one TCP connect.
    pub connect_timeout: Duration,
    /// Limit on waiting for any one handshake reply.
    pub handshake_timeout: Duration,
    /// No data for this long while streaming counts as a lost link.
    pub stall_timeout: Duration,
    /// Connection attempts (first connect and each reconnect) before giving up.
    pub max_attempts: u32,
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// Capacity of the every-sample broadcast channel.
    pub sample_buffer: usize,
}

impl RtdeConfig {
    /// Defaults for the rig's own recipe at `addr`; input recipes empty.
    pub fn new(addr: SocketAddr) -> Self {
        Self {
            addr,
            frequency_hz: None,
            output_names: output_recipe(),
            input_recipes: Vec::new(),
            connect_timeout: Duration::from_secs(2),
            handshake_timeout: Duration::from_secs(2),
            stall_timeout: Duration::from_secs(1),
            max_attempts: 20,
            backoff_initial: Duration::from_millis(100),
            backoff_max: Duration::from_secs(2),
            sample_buffer: 16_384,
        }
    }
}

/// Link status as published by the reader task.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkStatus {
    /// Streaming. `generation` counts connections (1 for the first).
    Up {
        generation: u64,
        protocol: u16,
        controller: ControllerVersion,
        frequency_hz: f64,
    },
    /// The link failed and the reader task is reconnecting.
    Reconnecting { attempt: u32, last_error: String },
    /// Reconnection gave up; the client is dead.
    Failed(String),
    /// Shut down on request.
    Closed,
}

impl LinkStatus {
    pub fn is_up(&self) -> bool {
        matches!(self, Self::Up { .. })
    }
}

/// Counters since the client was made.
#[derive(Debug, Default)]
struct Counters {
    frames: AtomicU64,
    data: AtomicU64,
    unknown_type: AtomicU64,
    malformed: AtomicU64,
    unexpected: AtomicU64,
    text: AtomicU64,
    early_data: AtomicU64,
    connections: AtomicU64,
    link_failures: AtomicU64,
}

/// A snapshot of the client's counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RtdeStats {
    pub frames: u64,
    /// Data packages decoded into states.
    pub data_packages: u64,
    /// Frames with a type byte RTDE does not define (skipped).
    pub unknown_type: u64,
    /// Frames truncated or too long for their type, or data that does not fit the recipe.
    pub malformed: u64,
    /// Replies nobody asked for and data for foreign recipes (skipped).
    pub unexpected: u64,
    pub text_messages: u64,
    /// Data packages that arrived before the Start reply.
    pub early_data: u64,
    /// Successful handshakes (1 + reconnects).
    pub connections: u64,
    /// Links that failed after being up.
    pub link_failures: u64,
}

/// The write half of the current link and what the handshake assigned to its input recipes.
struct LinkWriter {
    writer: FrameWriter<OwnedWriteHalf>,
    version: u16,
    input_ids: Vec<u8>,
    input_types: Vec<Vec<DataType>>,
}

/// What the reader task shares with the client and its handles.
pub(super) struct Shared {
    /// `None` while the link is being re-made.
    writer: Mutex<Option<LinkWriter>>,
    pub(super) state_tx: watch::Sender<Option<RobotState>>,
    pub(super) samples_tx: broadcast::Sender<RobotState>,
    pub(super) link_tx: watch::Sender<LinkStatus>,
    counters: Counters,
    texts: StdMutex<VecDeque<TextMessage>>,
    pub(super) clock: Clock,
    /// The user paused streaming: a re-made link is paused again right after its handshake.
    paused_wanted: AtomicBool,
}

/// Requests from the client handle to the reader task, which owns the session.
pub(super) enum Control {
    Pause(oneshot::Sender<Result<(), RtdeError>>),
    Resume(oneshot::Sender<Result<(), RtdeError>>),
}

/// Send whatever the session queued (pause/start) on the current link.
async fn flush_transmit(session: &mut Session, shared: &Shared) -> Result<(), RtdeError> {
    let mut guard = shared.writer.lock().await;
    let Some(w) = guard.as_mut() else {
        return Err(RtdeError::NotConnected);
    };
    while let Some(pkg) = session.poll_transmit() {
        w.writer.write_package(&pkg, session.version()).await?;
    }
    Ok(())
}

impl Shared {
    /// Channels with no link yet; `sample_buffer` is the capacity of the every-sample channel.
    pub(super) fn new(clock: Clock, sample_buffer: usize) -> Self {
        let (state_tx, _) = watch::channel(None);
        let (samples_tx, _) = broadcast::channel(sample_buffer.max(16));
        let (link_tx, _) = watch::channel(LinkStatus::Reconnecting {
            attempt: 0,
            last_error: "not connected yet".into(),
        });
        Self {
            writer: Mutex::new(None),
            state_tx,
            samples_tx,
            link_tx,
            counters: Counters::default(),
            texts: StdMutex::new(VecDeque::new()),
            clock,
            paused_wanted: AtomicBool::new(false),
        }
    }

    fn note_text(&self, m: TextMessage) {
        self.counters.text.fetch_add(1, Ordering::Relaxed);
        match m.level {
            MessageLevel::Exception | MessageLevel::Error => {
                tracing::error!(source = %m.source, "controller: {}", m.message)
            }
            MessageLevel::Warning => {
                tracing::warn!(source = %m.source, "controller: {}", m.message)
            }
            MessageLevel::Info => tracing::info!(source = %m.source, "controller: {}", m.message),
            MessageLevel::Other(l) => {
                tracing::info!(source = %m.source, level = l, "controller: {}", m.message)
            }
        }
        let mut t = self.texts.lock().unwrap_or_else(|p| p.into_inner());
        if t.len() == KEPT_TEXT_MESSAGES {
            t.pop_front();
        }
        t.push_back(m);
    }

    pub(super) fn recent_texts(&self) -> Vec<TextMessage> {
        let t = self.texts.lock().unwrap_or_else(|p| p.into_inner());
        t.iter().cloned().collect()
    }

    pub(super) fn messages_suffix(&self) -> String {
        describe_messages(&self.recent_texts())
    }

    pub(super) fn stats(&self) -> RtdeStats {
        let c = &self.counters;
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        RtdeStats {
            frames: g(&c.frames),
            data_packages: g(&c.data),
            unknown_type: g(&c.unknown_type),
            malformed: g(&c.malformed),
            unexpected: g(&c.unexpected),
            text_messages: g(&c.text),
            early_data: g(&c.early_data),
            connections: g(&c.connections),
            link_failures: g(&c.link_failures),
        }
    }

    /// Send `values` for input recipe number `recipe` on the current link.
    pub(super) async fn send_inputs(
        &self,
        recipe: usize,
        values: &[Value],
    ) -> Result<(), RtdeError> {
        let mut guard = self.writer.lock().await;
        let Some(w) = guard.as_mut() else {
            return Err(RtdeError::NotConnected);
        };
        let (Some(id), Some(types)) = (w.input_ids.get(recipe), w.input_types.get(recipe)) else {
            return Err(RtdeError::NoSuchRecipe(recipe));
        };
        let got: Vec<DataType> = values.iter().map(Value::data_type).collect();
        if &got != types {
            return Err(RtdeError::InputTypes {
                recipe,
                expected: types.clone(),
                got,
            });
        }
        let mut payload = BytesMut::new();
        encode_values(values, &mut payload);
        let pkg = ClientPackage::Data {
            recipe_id: *id,
            payload: payload.freeze(),
        };
        let version = w.version;
        if let Err(e) = w.writer.write_package(&pkg, version).await {
            // A failed write leaves the stream in an unknown state; the reader will notice the
            // broken socket and reconnect.
            *guard = None;
            return Err(e);
        }
        Ok(())
    }

    /// Drop the write half and publish [`LinkStatus::Closed`] (the reader task is stopped).
    pub(super) async fn close(&self) {
        *self.writer.lock().await = None;
        self.link_tx.send_replace(LinkStatus::Closed);
    }

    /// Count one received frame, feed it to the session and act on what that queued.
    fn handle_frame(
        &self,
        session: &mut Session,
        decoder: &mut Option<StateDecoder>,
        frame: &Frame,
    ) -> Result<(), RtdeError> {
        self.counters.frames.fetch_add(1, Ordering::Relaxed);
        let r = session.handle_frame(frame);
        self.drain(session, decoder);
        r
    }

    /// Act on every queued session event.
    fn drain(&self, session: &mut Session, decoder: &mut Option<StateDecoder>) {
        while let Some(ev) = session.poll_event() {
            match ev {
                SessionEvent::Text(m) => self.note_text(m),
                SessionEvent::Ready => {
                    match StateDecoder::new(session.output_names(), session.output_types()) {
                        Ok(d) => *decoder = Some(d),
                        Err(e) => tracing::error!("RTDE: {e}"),
                    }
                }
                SessionEvent::Data(payload) => {
                    let Some(d) = decoder.as_ref() else {
                        self.counters.unexpected.fetch_add(1, Ordering::Relaxed);
                        continue;
                    };
                    match d.decode(&payload, self.clock.now_ns()) {
                        Ok(s) => {
                            self.counters.data.fetch_add(1, Ordering::Relaxed);
                            self.state_tx.send_replace(Some(s));
                            let _ = self.samples_tx.send(s);
                        }
                        Err(e) => {
                            self.counters.malformed.fetch_add(1, Ordering::Relaxed);
                            tracing::debug!("RTDE: skipped data package: {e}");
                        }
                    }
                }
                SessionEvent::Skipped(r) => {
                    let c = match &r {
                        SkipReason::UnknownType(_) => &self.counters.unknown_type,
                        SkipReason::Malformed(_) => &self.counters.malformed,
                        SkipReason::UnexpectedData | SkipReason::UnexpectedReply(_) => {
                            &self.counters.unexpected
                        }
                    };
                    c.fetch_add(1, Ordering::Relaxed);
                    tracing::debug!("RTDE: skipped frame: {r:?}");
                }
            }
        }
    }
}

/// One connected, started link, ready to stream.
pub(super) struct Established {
    reader: FrameReader<OwnedReadHalf>,
    session: Session,
    decoder: Option<StateDecoder>,
}

/// Connect and run the handshake once.
async fn establish(cfg: &RtdeConfig, shared: &Shared) -> Result<Established, RtdeError> {
    let clock = &shared.clock;
    let conn = clock
        .timeout(cfg.connect_timeout, Connection::connect(cfg.addr))
        .await
        .map_err(|_| RtdeError::Connect {
            addr: cfg.addr,
            reason: format!("no answer within {:?}", cfg.connect_timeout),
        })??;
    let Connection {
        mut reader,
        mut writer,
    } = conn;
    let mut session = Session::new(SessionConfig {
        frequency_hz: cfg.frequency_hz,
        output_names: cfg.output_names.clone(),
        input_recipes: cfg.input_recipes.clone(),
    })?;
    let mut decoder = None;
    session.start();
    loop {
        while let Some(pkg) = session.poll_transmit() {
            writer.write_package(&pkg, session.version()).await?;
        }
        if session.is_streaming() {
            break;
        }
        let phase = session.phase_name();
        let frame = match clock
            .timeout(cfg.handshake_timeout, reader.read_frame())
            .await
        {
            Err(_) => {
                return Err(RtdeError::HandshakeTimeout {
                    phase,
                    timeout: cfg.handshake_timeout,
                    messages: shared.messages_suffix(),
                });
            }
            Ok(Ok(Some(f))) => f,
            Ok(Ok(None)) => {
                return Err(RtdeError::Closed {
                    messages: shared.messages_suffix(),
                });
            }
            Ok(Err(e)) => return Err(e),
        };
        match shared.handle_frame(&mut session, &mut decoder, &frame) {
            Ok(()) => {}
            Err(RtdeError::ProtocolRefused(_)) => return Err(RtdeError::ProtocolRefused(cfg.addr)),
            Err(RtdeError::StartRefused { .. }) => {
                return Err(RtdeError::StartRefused {
                    messages: shared.messages_suffix(),
                });
            }
            Err(e) => return Err(e),
        }
    }
    shared
        .counters
        .early_data
        .fetch_add(session.early_data(), Ordering::Relaxed);
    let generation = shared.counters.connections.fetch_add(1, Ordering::Relaxed) + 1;
    *shared.writer.lock().await = Some(LinkWriter {
        writer,
        version: session.version(),
        input_ids: session.input_ids().to_vec(),
        input_types: session.input_types().to_vec(),
    });
    let controller = session.controller().unwrap_or_default();
    tracing::info!(
        "RTDE up: {} protocol v{}, controller {}, {} Hz (connection {generation})",
        cfg.addr,
        session.version(),
        controller,
        session.frequency_hz()
    );
    shared.link_tx.send_replace(LinkStatus::Up {
        generation,
        protocol: session.version(),
        controller,
        frequency_hz: session.frequency_hz(),
    });
    Ok(Established {
        reader,
        session,
        decoder,
    })
}

/// Connect with bounded retries and exponential backoff on the clock.
pub(super) async fn establish_with_retries(
    cfg: &RtdeConfig,
    shared: &Shared,
    first_error: Option<String>,
) -> Result<Established, RtdeError> {
    let mut backoff = cfg.backoff_initial;
    let mut last = first_error;
    let attempts = cfg.max_attempts.max(1);
    for attempt in 1..=attempts {
        if let Some(e) = &last {
            shared.link_tx.send_replace(LinkStatus::Reconnecting {
                attempt,
                last_error: e.clone(),
            });
        }
        match establish(cfg, shared).await {
            Ok(e) => return Ok(e),
            // Recipe errors will not fix themselves by retrying.
            Err(
                e @ (RtdeError::UnknownVariable { .. }
                | RtdeError::NotFound { .. }
                | RtdeError::RecipeLength { .. }
                | RtdeError::ProtocolRefused(_)),
            ) => return Err(e),
            Err(e) if attempt == attempts => {
                return Err(RtdeError::GaveUp {
                    attempts,
                    last: Box::new(e),
                });
            }
            Err(e) => {
                tracing::warn!(
                    "RTDE attempt {attempt}/{attempts} failed: {e}; retrying in {backoff:?}"
                );
                last = Some(e.to_string());
                shared.clock.sleep(backoff).await;
                backoff = (backoff * 2).min(cfg.backoff_max);
            }
        }
    }
    unreachable!("the loop returns on its last attempt")
}

/// Stream until the link fails; returns why. Pause/resume requests are served here because
/// this task owns the session; while paused, silence is expected and is not a stall.
async fn stream(
    est: &mut Established,
    cfg: &RtdeConfig,
    shared: &Shared,
    control: &mut mpsc::UnboundedReceiver<Control>,
) -> RtdeError {
    // The request being served and the phase that completes it.
    let mut pending: Option<(Phase, oneshot::Sender<Result<(), RtdeError>>)> = None;
    loop {
        let paused = est.session.phase() == Phase::Paused;
        let reader = &mut est.reader;
        let read = async {
            if paused {
                Ok(reader.read_frame().await)
            } else {
                shared
                    .clock
                    .timeout(cfg.stall_timeout, reader.read_frame())
                    .await
            }
        };
        let frame = tokio::select! {
            Some(ctl) = control.recv() => {
                let (want, action, queued, reply) = match ctl {
                    Control::Pause(tx) => {
                        shared.paused_wanted.store(true, Ordering::Relaxed);
                        (Phase::Paused, "pause", est.session.pause(), tx)
                    }
                    Control::Resume(tx) => {
                        shared.paused_wanted.store(false, Ordering::Relaxed);
                        (Phase::Streaming, "resume", est.session.resume(), tx)
                    }
                };
                if est.session.phase() == want {
                    let _ = reply.send(Ok(()));
                } else if !queued {
                    let phase = est.session.phase_name();
                    let _ = reply.send(Err(RtdeError::WrongPhase { action, phase }));
                } else if let Err(e) = flush_transmit(&mut est.session, shared).await {
                    let _ = reply.send(Err(RtdeError::NotConnected));
                    return e;
                } else {
                    pending = Some((want, reply));
                }
                continue;
            }
            r = read => r,
        };
        let frame = match frame {
            Err(_) => return RtdeError::Stalled(cfg.stall_timeout),
            Ok(Ok(Some(f))) => f,
            Ok(Ok(None)) => {
                return RtdeError::Closed {
                    messages: shared.messages_suffix(),
                };
            }
            Ok(Err(e)) => return e,
        };
        if let Err(e) = shared.handle_frame(&mut est.session, &mut est.decoder, &frame) {
            if let Some((_, tx)) = pending.take() {
                let _ = tx.send(Err(RtdeError::NotConnected));
            }
            return e;
        }
        let phase = est.session.phase();
        pending = match pending.take() {
            Some((want, tx)) if phase == want => {
                let _ = tx.send(Ok(()));
                None
            }
            // A refused pause puts the session back to streaming.
            Some((Phase::Paused, tx)) if phase == Phase::Streaming => {
                shared.paused_wanted.store(false, Ordering::Relaxed);
                let _ = tx.send(Err(RtdeError::PauseRefused {
                    messages: shared.messages_suffix(),
                }));
                None
            }
            other => other,
        };
    }
}

/// Stream, and re-make the link whenever it fails, until reconnection gives up.
pub(super) async fn reader_task(
    mut est: Established,
    cfg: RtdeConfig,
    shared: Arc<Shared>,
    mut control: mpsc::UnboundedReceiver<Control>,
) {
    loop {
        let err = stream(&mut est, &cfg, &shared, &mut control).await;
        shared
            .counters
            .link_failures
            .fetch_add(1, Ordering::Relaxed);
        tracing::warn!("RTDE link lost: {err}; reconnecting");
        *shared.writer.lock().await = None;
        match establish_with_retries(&cfg, &shared, Some(err.to_string())).await {
            Ok(e) => {
                est = e;
                // The handshake always ends streaming; honour a pause the user asked for.
                if shared.paused_wanted.load(Ordering::Relaxed)
                    && est.session.pause()
                    && let Err(e) = flush_transmit(&mut est.session, &shared).await
                {
                    tracing::warn!("RTDE: could not pause the re-made link: {e}");
                }
            }
            Err(e) => {
                tracing::error!("RTDE: {e}");
                shared
                    .link_tx
                    .send_replace(LinkStatus::Failed(e.to_string()));
                return;
            }
        }
    }
}
