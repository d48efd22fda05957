//! Async RTDE client: handshake, typed streaming, input writes and reconnection.
//!
//! RTDE (UR's "Real-Time Data Exchange (RTDE) Guide", TCP port 30004) is a request/reply
//! handshake followed by a one-way stream: the client asks for protocol v2 (falling back to
//! v1, which CB3 software before 3.5 speaks), reads the controller version, sets up one output
//! recipe (the variables it wants, at a frequency: up to 500 Hz on e-Series, 125 Hz on CB3)
//! and its input recipes (the registers it will write), then sends Start. From then on the
//! controller sends a data package every cycle and accepts input data packages at any time.
//!
//! The code is split the way tokio's mini-redis splits a protocol:
//!
//! - [`Session`] is the handshake and stream as a sans-IO state machine: it is fed whole
//!   frames, queues the packages to send ([`Session::poll_transmit`]) and the things that
//!   happened ([`Session::poll_event`]). It never touches a socket or a clock, so each
//!   handshake corner (text messages mid-handshake, data before the Start reply, NOT_FOUND,
//!   IN_USE, a v1-only controller) is a plain unit test.
//! - [`FrameReader`] / [`FrameWriter`] own the two halves of the socket and turn bytes into
//!   frames and packages into bytes ([`rig_core::rtde::FrameDecoder`] does the cutting, so
//!   reads that split or coalesce packages do not matter).
//! - [`RtdeClient`] runs one reader task that owns the read half: it decodes every data
//!   package into a [`RobotState`], publishes the latest one on a `watch` channel and every
//!   one on a bounded `broadcast` (for logging), and, when the link fails, reconnects with
//!   bounded retries and backoff on the shared [`Clock`], sending the recipes again (RTDE
//!   forgets them with the connection, and refuses connections while the controller reboots).
//!   Writes go through [`RtdeHandle`], which shares the current write half behind a mutex.
//!
//! Bad input never panics. A size field below 3 means the stream is out of sync: the
//! connection is dropped and re-made. A frame of an unknown type, or one that is truncated or
//! too long for its type, is counted ([`RtdeStats`]) and skipped. Text messages are logged
//! with `tracing` at their level, and the last few are kept for error reports.

use std::collections::VecDeque;
use std::fmt;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex as StdMutex};
use std::time::Duration;

use bytes::{Bytes, BytesMut};
use rig_core::clock::Clock;
use rig_core::rtde::{
    ClientPackage, DataType, DecodeError, EncodeError, FieldType, Frame, FrameDecoder,
    MessageLevel, PROTOCOL_V1, PROTOCOL_V2, ServerPackage, TextMessage, Value, encode_values,
    fields,
};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::{Mutex, broadcast, mpsc, oneshot, watch};
use tokio::task::JoinHandle;

use super::state::{RobotState, StateDecoder};

/// How many text messages are kept for error reports.
pub const KEPT_TEXT_MESSAGES: usize = 16;

/// Output frequency when the controller is e-Series (software major ≥ 5), Hz (RTDE guide).
pub const E_SERIES_HZ: f64 = 500.0;
/// Output frequency on CB3 (software major 3), Hz (RTDE guide).
pub const CB3_HZ: f64 = 125.0;

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

/// Which way a recipe goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecipeKind {
    Output,
    Input,
}

impl fmt::Display for RecipeKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Output => "output",
            Self::Input => "input",
        })
    }
}

/// What went wrong on the RTDE link. Messages say what the operator should check.
#[derive(Debug, Clone, thiserror::Error)]
pub enum RtdeError {
    #[error(
        "cannot reach the UR controller's RTDE port at {addr}: {reason}; check that the robot is powered, on the network, and that RTDE is enabled (Settings > Security > Services)"
    )]
    Connect { addr: SocketAddr, reason: String },
    #[error(
        "RTDE {kind} recipe: `{variable}` is not a controller {kind} variable (RTDE guide); fix the recipe"
    )]
    UnknownVariable { kind: RecipeKind, variable: String },
    #[error(
        "controller refused the RTDE {kind} recipe: no variable named `{variable}` (NOT_FOUND); the controller software may be too old for it"
    )]
    NotFound { kind: RecipeKind, variable: String },
    #[error(
        "controller refused the RTDE input recipe: `{variable}` is IN_USE by another client (a fieldbus, another RTDE program such as ur_rtde, or a second rig); close that client or choose free registers"
    )]
    InUse { variable: String },
    #[error("controller answered the {kind} recipe with {got} types for {sent} variables")]
    RecipeLength {
        kind: RecipeKind,
        sent: usize,
        got: usize,
    },
    #[error(
        "controller refused RTDE protocol versions 2 and 1; is port {0} really a UR controller's RTDE port?"
    )]
    ProtocolRefused(SocketAddr),
    #[error("controller refused to start RTDE streaming{messages}")]
    StartRefused { messages: String },
    #[error(
        "RTDE handshake stalled waiting for the {phase} reply ({timeout:?} of clock time){messages}"
    )]
    HandshakeTimeout {
        phase: &'static str,
        timeout: Duration,
        messages: String,
    },
    #[error("RTDE stream out of sync: {0}; the connection was dropped")]
    OutOfSync(DecodeError),
    #[error("the controller closed the RTDE connection{messages}")]
    Closed { messages: String },
    #[error("no RTDE data for {0:?} of clock time; is the controller still running?")]
    Stalled(Duration),
    #[error("RTDE I/O error: {0}")]
    Io(String),
    #[error("RTDE package could not be encoded: {0}")]
    Encode(#[from] EncodeError),
    #[error("RTDE link is down (reconnecting); try again when it is up")]
    NotConnected,
    #[error("no input recipe number {0}")]
    NoSuchRecipe(usize),
    #[error("input values do not match recipe {recipe}: expected {expected:?}, got {got:?}")]
    InputTypes {
        recipe: usize,
        expected: Vec<DataType>,
        got: Vec<DataType>,
    },
    #[error("gave up on the RTDE link after {attempts} attempts; last error: {last}")]
    GaveUp { attempts: u32, last: Box<RtdeError> },
    #[error("the RTDE client was shut down")]
    Shutdown,
    #[error("cannot {action} RTDE streaming while the link is {phase}")]
    WrongPhase {
        action: &'static str,
        phase: &'static str,
    },
    #[error("the controller refused to pause RTDE streaming{messages}")]
    PauseRefused { messages: String },
}

impl RtdeError {
    fn io(e: std::io::Error) -> Self {
        Self::Io(e.to_string())
    }
}

fn describe_messages(msgs: &[TextMessage]) -> String {
    if msgs.is_empty() {
        return String::new();
    }
    let mut s = String::from("; controller messages: ");
    for (i, m) in msgs.iter().enumerate() {
        if i > 0 {
            s.push_str(" | ");
        }
        s.push_str(&format!("[{:?}] {}: {}", m.level, m.source, m.message));
    }
    s
}

// ---------------------------------------------------------------------------------------------
// Sans-IO session
// ---------------------------------------------------------------------------------------------

/// What the session needs to know before it starts.
#[derive(Debug, Clone)]
pub struct SessionConfig {
    /// `None`: 500 Hz on e-Series, 125 Hz on CB3.
    pub frequency_hz: Option<f64>,
    pub output_names: Vec<String>,
    pub input_recipes: Vec<Vec<String>>,
}

/// The controller's software version ('v' reply).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ControllerVersion {
    pub major: u32,
    pub minor: u32,
    pub bugfix: u32,
    pub build: u32,
}

impl fmt::Display for ControllerVersion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}.{}.{}.{}",
            self.major, self.minor, self.bugfix, self.build
        )
    }
}

/// Where the handshake is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    NotStarted,
    ProtocolV2,
    ProtocolV1,
    ControllerVersion,
    OutputSetup,
    InputSetup(usize),
    Start,
    Streaming,
    /// Pause sent, reply awaited (data may still arrive).
    Pausing,
    /// Paused by request: no data is expected until a resume.
    Paused,
    Failed,
}

impl Phase {
    fn name(self) -> &'static str {
        match self {
            Self::NotStarted => "not started",
            Self::ProtocolV2 => "protocol version 2",
            Self::ProtocolV1 => "protocol version 1",
            Self::ControllerVersion => "controller version",
            Self::OutputSetup => "output setup",
            Self::InputSetup(_) => "input setup",
            Self::Start => "start",
            Self::Streaming => "streaming",
            Self::Pausing => "pausing",
            Self::Paused => "paused",
            Self::Failed => "failed",
        }
    }
}

/// Why a received frame was skipped.
#[derive(Debug, Clone, PartialEq)]
pub enum SkipReason {
    UnknownType(u8),
    Malformed(DecodeError),
    /// A data package for a recipe id that is not ours, or before Start was sent.
    UnexpectedData,
    /// A reply to something we did not ask for (now).
    UnexpectedReply(char),
}

/// What happened, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionEvent {
    Text(TextMessage),
    /// The handshake is complete; data follows.
    Ready,
    /// An output data payload (after the recipe id), to be decoded with the output types.
    Data(Bytes),
    Skipped(SkipReason),
}

/// The RTDE handshake and stream as a state machine over frames.
#[derive(Debug)]
pub struct Session {
    cfg: SessionConfig,
    phase: Phase,
    version: u16,
    controller: Option<ControllerVersion>,
    frequency_hz: f64,
    output_id: Option<u8>,
    output_types: Vec<DataType>,
    input_ids: Vec<u8>,
    input_types: Vec<Vec<DataType>>,
    transmit: VecDeque<ClientPackage>,
    events: VecDeque<SessionEvent>,
    early_data: u64,
}

impl Session {
    /// Checks every recipe name against the controller's variable table
    /// ([`fields::output_type`], [`fields::input_type`]) before anything is sent.
    pub fn new(cfg: SessionConfig) -> Result<Self, RtdeError> {
        for n in &cfg.output_names {
            if fields::output_type(n).is_none() {
                return Err(RtdeError::UnknownVariable {
                    kind: RecipeKind::Output,
                    variable: n.clone(),
                });
            }
        }
        for n in cfg.input_recipes.iter().flatten() {
            if fields::input_type(n).is_none() {
                return Err(RtdeError::UnknownVariable {
                    kind: RecipeKind::Input,
                    variable: n.clone(),
                });
            }
        }
        Ok(Self {
            cfg,
            phase: Phase::NotStarted,
            version: PROTOCOL_V1,
            controller: None,
            frequency_hz: CB3_HZ,
            output_id: None,
            output_types: Vec::new(),
            input_ids: Vec::new(),
            input_types: Vec::new(),
            transmit: VecDeque::new(),
            events: VecDeque::new(),
            early_data: 0,
        })
    }

    /// Begin the handshake: queues the protocol v2 request.
    pub fn start(&mut self) {
        self.phase = Phase::ProtocolV2;
        self.transmit
            .push_back(ClientPackage::RequestProtocolVersion(PROTOCOL_V2));
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Ask the controller to stop sending data ('P'). Only while streaming; returns whether a
    /// pause was queued.
    pub fn pause(&mut self) -> bool {
        if self.phase != Phase::Streaming {
            return false;
        }
        self.phase = Phase::Pausing;
        self.transmit.push_back(ClientPackage::Pause);
        true
    }

    /// Start streaming again after a pause ('S', the same recipes). Returns whether a start
    /// was queued.
    pub fn resume(&mut self) -> bool {
        if self.phase != Phase::Paused {
            return false;
        }
        self.phase = Phase::Start;
        self.transmit.push_back(ClientPackage::Start);
        true
    }
    pub fn phase_name(&self) -> &'static str {
        self.phase.name()
    }
    pub fn is_streaming(&self) -> bool {
        self.phase == Phase::Streaming
    }
    /// The negotiated protocol version (1 until v2 is accepted).
    pub fn version(&self) -> u16 {
        self.version
    }
    pub fn controller(&self) -> Option<ControllerVersion> {
        self.controller
    }
    pub fn frequency_hz(&self) -> f64 {
        self.frequency_hz
    }
    pub fn output_names(&self) -> &[String] {
        &self.cfg.output_names
    }
    pub fn output_types(&self) -> &[DataType] {
        &self.output_types
    }
    /// Recipe ids the controller assigned to the input recipes, in configuration order.
    pub fn input_ids(&self) -> &[u8] {
        &self.input_ids
    }
    pub fn input_types(&self) -> &[Vec<DataType>] {
        &self.input_types
    }
    /// Data packages that arrived before the Start reply.
    pub fn early_data(&self) -> u64 {
        self.early_data
    }

    pub fn poll_transmit(&mut self) -> Option<ClientPackage> {
        self.transmit.pop_front()
    }
    pub fn poll_event(&mut self) -> Option<SessionEvent> {
        self.events.pop_front()
    }

    fn decode(&self, frame: &Frame) -> Result<ServerPackage, DecodeError> {
        match ServerPackage::decode(frame, self.version) {
            // A text message may arrive before the version is settled; try the other layout.
            Err(e) if frame.type_byte == b'M' => {
                let other = if self.version == PROTOCOL_V2 {
                    PROTOCOL_V1
                } else {
                    PROTOCOL_V2
                };
                ServerPackage::decode(frame, other).map_err(|_| e)
            }
            r => r,
        }
    }

    /// Feed one received frame. Errors end the session (the caller drops the connection);
    /// a frame that cannot be used is reported as [`SessionEvent::Skipped`] instead.
    pub fn handle_frame(&mut self, frame: &Frame) -> Result<(), RtdeError> {
        let pkg = match self.decode(frame) {
            Ok(p) => p,
            Err(DecodeError::UnknownType(t)) => {
                self.skip(SkipReason::UnknownType(t));
                return Ok(());
            }
            Err(e) => {
                self.skip(SkipReason::Malformed(e));
                return Ok(());
            }
        };
        match pkg {
            ServerPackage::TextMessage(m) => self.events.push_back(SessionEvent::Text(m)),
            ServerPackage::ProtocolVersion { accepted } => match self.phase {
                Phase::ProtocolV2 if accepted => {
                    self.version = PROTOCOL_V2;
                    self.ask_controller_version();
                }
                Phase::ProtocolV2 => {
                    self.phase = Phase::ProtocolV1;
                    self.transmit
                        .push_back(ClientPackage::RequestProtocolVersion(PROTOCOL_V1));
                }
                Phase::ProtocolV1 if accepted => {
                    self.version = PROTOCOL_V1;
                    self.ask_controller_version();
                }
                Phase::ProtocolV1 => {
                    self.phase = Phase::Failed;
                    return Err(RtdeError::ProtocolRefused(SocketAddr::from((
                        [0, 0, 0, 0],
                        0,
                    ))));
                }
                _ => self.skip(SkipReason::UnexpectedReply('V')),
            },
            ServerPackage::UrControlVersion {
                major,
                minor,
                bugfix,
                build,
            } => {
                if self.phase != Phase::ControllerVersion {
                    self.skip(SkipReason::UnexpectedReply('v'));
                    return Ok(());
                }
                self.controller = Some(ControllerVersion {
                    major,
                    minor,
                    bugfix,
                    build,
                });
                self.frequency_hz = match self.cfg.frequency_hz {
                    Some(f) => f,
                    None if major >= 5 => E_SERIES_HZ,
                    None => CB3_HZ,
                };
                if self.version < PROTOCOL_V2 {
                    // v1 has no frequency field: the controller streams at 125 Hz.
                    self.frequency_hz = CB3_HZ;
                }
                self.phase = Phase::OutputSetup;
                self.transmit.push_back(ClientPackage::SetupOutputs {
                    frequency_hz: self.frequency_hz,
                    names: self.cfg.output_names.clone(),
                });
            }
            ServerPackage::OutputSetup { recipe_id, types } => {
                if self.phase != Phase::OutputSetup {
                    self.skip(SkipReason::UnexpectedReply('O'));
                    return Ok(());
                }
                self.output_types = check_types(RecipeKind::Output, &self.cfg.output_names, &types)
                    .inspect_err(|_| self.phase = Phase::Failed)?;
                self.output_id = recipe_id;
                self.next_input_or_start(0);
            }
            ServerPackage::InputSetup { recipe_id, types } => {
                let Phase::InputSetup(i) = self.phase else {
                    self.skip(SkipReason::UnexpectedReply('I'));
                    return Ok(());
                };
                let t = check_types(RecipeKind::Input, &self.cfg.input_recipes[i], &types)
                    .inspect_err(|_| self.phase = Phase::Failed)?;
                self.input_ids.push(recipe_id);
                self.input_types.push(t);
                self.next_input_or_start(i + 1);
            }
            ServerPackage::StartReply { accepted } => match self.phase {
                Phase::Start if accepted => self.ready(),
                Phase::Start => {
                    self.phase = Phase::Failed;
                    return Err(RtdeError::StartRefused {
                        messages: String::new(),
                    });
                }
                // The Start reply can trail data packages that already told us we stream.
                Phase::Streaming => {}
                _ => self.skip(SkipReason::UnexpectedReply('S')),
            },
            ServerPackage::PauseReply { accepted } => match self.phase {
                Phase::Pausing if accepted => self.phase = Phase::Paused,
                // Refused: the controller keeps streaming, and so do we.
                Phase::Pausing => self.phase = Phase::Streaming,
                _ => self.skip(SkipReason::UnexpectedReply('P')),
            },
            ServerPackage::Data { recipe_id, payload } => {
                let ours = match (recipe_id, self.output_id) {
                    (Some(got), Some(want)) => got == want,
                    _ => true,
                };
                match self.phase {
                    // Data sent before the controller saw our Pause is still valid data.
                    Phase::Streaming | Phase::Pausing if ours => {
                        self.events.push_back(SessionEvent::Data(payload))
                    }
                    // Data before the Start reply: the controller has started; so have we.
                    Phase::Start if ours => {
                        self.early_data += 1;
                        self.ready();
                        self.events.push_back(SessionEvent::Data(payload));
                    }
                    _ => self.skip(SkipReason::UnexpectedData),
                }
            }
        }
        Ok(())
    }

    fn skip(&mut self, r: SkipReason) {
        self.events.push_back(SessionEvent::Skipped(r));
    }

    fn ready(&mut self) {
        self.phase = Phase::Streaming;
        self.events.push_back(SessionEvent::Ready);
    }

    fn ask_controller_version(&mut self) {
        self.phase = Phase::ControllerVersion;
        self.transmit.push_back(ClientPackage::GetUrControlVersion);
    }

    fn next_input_or_start(&mut self, i: usize) {
        if let Some(names) = self.cfg.input_recipes.get(i) {
            self.phase = Phase::InputSetup(i);
            self.transmit.push_back(ClientPackage::SetupInputs {
                names: names.clone(),
            });
        } else {
            self.phase = Phase::Start;
            self.transmit.push_back(ClientPackage::Start);
        }
    }
}

fn check_types(
    kind: RecipeKind,
    names: &[String],
    types: &[FieldType],
) -> Result<Vec<DataType>, RtdeError> {
    if names.len() != types.len() {
        return Err(RtdeError::RecipeLength {
            kind,
            sent: names.len(),
            got: types.len(),
        });
    }
    names
        .iter()
        .zip(types)
        .map(|(n, t)| match t {
            FieldType::Known(d) => Ok(*d),
            FieldType::NotFound => Err(RtdeError::NotFound {
                kind,
                variable: n.clone(),
            }),
            FieldType::InUse => Err(RtdeError::InUse {
                variable: n.clone(),
            }),
        })
        .collect()
}

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
// Client
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
            output_names: super::state::output_recipe(),
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

struct LinkWriter {
    writer: FrameWriter<OwnedWriteHalf>,
    version: u16,
    input_ids: Vec<u8>,
    input_types: Vec<Vec<DataType>>,
}

struct Shared {
    writer: Mutex<Option<LinkWriter>>,
    state_tx: watch::Sender<Option<RobotState>>,
    samples_tx: broadcast::Sender<RobotState>,
    link_tx: watch::Sender<LinkStatus>,
    counters: Counters,
    texts: StdMutex<VecDeque<TextMessage>>,
    clock: Clock,
    /// The user paused streaming: a re-made link is paused again right after its handshake.
    paused_wanted: AtomicBool,
}

/// Requests from the client handle to the reader task, which owns the session.
enum Control {
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

    fn recent_texts(&self) -> Vec<TextMessage> {
        let t = self.texts.lock().unwrap_or_else(|p| p.into_inner());
        t.iter().cloned().collect()
    }

    fn messages_suffix(&self) -> String {
        describe_messages(&self.recent_texts())
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
struct Established {
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
        shared.counters.frames.fetch_add(1, Ordering::Relaxed);
        let r = session.handle_frame(&frame);
        shared.drain(&mut session, &mut decoder);
        match r {
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
async fn establish_with_retries(
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
        shared.counters.frames.fetch_add(1, Ordering::Relaxed);
        let r = est.session.handle_frame(&frame);
        shared.drain(&mut est.session, &mut est.decoder);
        if let Err(e) = r {
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

async fn reader_task(
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
        let (state_tx, _) = watch::channel(None);
        let (samples_tx, _) = broadcast::channel(cfg.sample_buffer.max(16));
        let (link_tx, _) = watch::channel(LinkStatus::Reconnecting {
            attempt: 0,
            last_error: "not connected yet".into(),
        });
        let shared = Arc::new(Shared {
            writer: Mutex::new(None),
            state_tx,
            samples_tx,
            link_tx,
            counters: Counters::default(),
            texts: StdMutex::new(VecDeque::new()),
            clock,
            paused_wanted: AtomicBool::new(false),
        });
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
        let c = &self.shared.counters;
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
    /// A cloneable handle for writing inputs.
    pub fn handle(&self) -> RtdeHandle {
        RtdeHandle {
            shared: self.shared.clone(),
        }
    }
    /// Stop the reader task and close the connection.
    pub async fn shutdown(self) {
        self.task.abort();
        *self.shared.writer.lock().await = None;
        self.shared.link_tx.send_replace(LinkStatus::Closed);
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
        let mut guard = self.shared.writer.lock().await;
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

    /// The link's status now.
    pub fn link_status(&self) -> LinkStatus {
        self.shared.link_tx.borrow().clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rig_core::rtde::encode_values;

    fn frame_of(p: &ServerPackage, v: u16) -> Frame {
        let mut b = BytesMut::new();
        p.encode(v, &mut b).unwrap();
        let mut d = FrameDecoder::new();
        d.push(&b);
        d.next_frame().unwrap().unwrap()
    }

    fn cfg() -> SessionConfig {
        SessionConfig {
            frequency_hz: None,
            output_names: vec!["timestamp".into(), "robot_mode".into()],
            input_recipes: vec![vec!["input_int_register_26".into()]],
        }
    }

    fn types(ts: &[DataType]) -> Vec<FieldType> {
        ts.iter().map(|t| FieldType::Known(*t)).collect()
    }

    fn data(v: u16) -> ServerPackage {
        let mut b = BytesMut::new();
        encode_values(&[Value::Double(1.0), Value::Int32(7)], &mut b);
        ServerPackage::Data {
            recipe_id: (v == PROTOCOL_V2).then_some(1),
            payload: b.freeze(),
        }
    }

    /// Run a session against scripted replies; returns it and the packages it sent.
    fn handshake(v2: bool, major: u32) -> (Session, Vec<ClientPackage>) {
        let mut s = Session::new(cfg()).unwrap();
        s.start();
        let mut sent = Vec::new();
        let v = if v2 { PROTOCOL_V2 } else { PROTOCOL_V1 };
        let mut replies = VecDeque::new();
        if !v2 {
            replies.push_back(ServerPackage::ProtocolVersion { accepted: false });
        }
        replies.extend([
            ServerPackage::ProtocolVersion { accepted: true },
            ServerPackage::UrControlVersion {
                major,
                minor: 1,
                bugfix: 2,
                build: 3,
            },
            ServerPackage::OutputSetup {
                recipe_id: v2.then_some(1),
                types: types(&[DataType::Double, DataType::Int32]),
            },
            ServerPackage::InputSetup {
                recipe_id: 2,
                types: types(&[DataType::Int32]),
            },
            ServerPackage::StartReply { accepted: true },
        ]);
        while let Some(r) = replies.pop_front() {
            while let Some(p) = s.poll_transmit() {
                sent.push(p);
            }
            s.handle_frame(&frame_of(&r, v)).unwrap();
        }
        (s, sent)
    }

    #[test]
    fn v2_handshake_on_e_series_streams_at_500_hz() {
        let (mut s, sent) = handshake(true, 5);
        assert!(s.is_streaming());
        assert_eq!(s.version(), PROTOCOL_V2);
        assert_eq!(s.frequency_hz(), 500.0);
        assert_eq!(s.input_ids(), &[2]);
        assert_eq!(sent[0], ClientPackage::RequestProtocolVersion(2));
        assert!(
            matches!(sent[2], ClientPackage::SetupOutputs { frequency_hz, .. } if frequency_hz == 500.0)
        );
        assert!(std::iter::from_fn(|| s.poll_event()).any(|e| e == SessionEvent::Ready));
        s.handle_frame(&frame_of(&data(PROTOCOL_V2), PROTOCOL_V2))
            .unwrap();
        assert!(matches!(s.poll_event(), Some(SessionEvent::Data(_))));
    }

    #[test]
    fn cb3_v1_fallback_streams_at_125_hz() {
        let (s, sent) = handshake(false, 3);
        assert!(s.is_streaming());
        assert_eq!(s.version(), PROTOCOL_V1);
        assert_eq!(s.frequency_hz(), 125.0);
        assert_eq!(sent[1], ClientPackage::RequestProtocolVersion(1));
    }

    #[test]
    fn unknown_recipe_names_are_refused_before_sending() {
        let mut c = cfg();
        c.output_names.push("actual_tcp_pose".into()); // wrong case
        assert!(matches!(
            Session::new(c),
            Err(RtdeError::UnknownVariable { variable, .. }) if variable == "actual_tcp_pose"
        ));
    }

    #[test]
    fn not_found_and_in_use_name_the_variable() {
        let mut s = Session::new(cfg()).unwrap();
        s.start();
        for r in [
            ServerPackage::ProtocolVersion { accepted: true },
            ServerPackage::UrControlVersion {
                major: 5,
                minor: 0,
                bugfix: 0,
                build: 0,
            },
        ] {
            s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap();
        }
        let r = ServerPackage::OutputSetup {
            recipe_id: Some(1),
            types: vec![FieldType::Known(DataType::Double), FieldType::NotFound],
        };
        let e = s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap_err();
        assert!(e.to_string().contains("robot_mode"), "{e}");

        let mut s = Session::new(cfg()).unwrap();
        s.start();
        for r in [
            ServerPackage::ProtocolVersion { accepted: true },
            ServerPackage::UrControlVersion {
                major: 5,
                minor: 0,
                bugfix: 0,
                build: 0,
            },
            ServerPackage::OutputSetup {
                recipe_id: Some(1),
                types: types(&[DataType::Double, DataType::Int32]),
            },
        ] {
            s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap();
        }
        let r = ServerPackage::InputSetup {
            recipe_id: 0,
            types: vec![FieldType::InUse],
        };
        let e = s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap_err();
        assert!(matches!(&e, RtdeError::InUse { variable } if variable == "input_int_register_26"));
    }

    #[test]
    fn text_messages_mid_handshake_and_data_before_start_reply() {
        let mut s = Session::new(cfg()).unwrap();
        s.start();
        let text = ServerPackage::TextMessage(TextMessage {
            message: "booting".into(),
            source: "RTDE".into(),
            level: MessageLevel::Warning,
        });
        // Before the version is settled the message is v1-framed; after, v2.
        s.handle_frame(&frame_of(&text, PROTOCOL_V1)).unwrap();
        for r in [
            ServerPackage::ProtocolVersion { accepted: true },
            ServerPackage::UrControlVersion {
                major: 5,
                minor: 0,
                bugfix: 0,
                build: 0,
            },
            text.clone(),
            ServerPackage::OutputSetup {
                recipe_id: Some(1),
                types: types(&[DataType::Double, DataType::Int32]),
            },
            ServerPackage::InputSetup {
                recipe_id: 2,
                types: types(&[DataType::Int32]),
            },
            data(PROTOCOL_V2),
        ] {
            s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap();
        }
        assert!(s.is_streaming());
        assert_eq!(s.early_data(), 1);
        s.handle_frame(&frame_of(&ServerPackage::StartReply { accepted: true }, 2))
            .unwrap();
        let evs: Vec<_> = std::iter::from_fn(|| s.poll_event()).collect();
        assert_eq!(
            evs.iter()
                .filter(|e| matches!(e, SessionEvent::Text(_)))
                .count(),
            2
        );
        assert!(matches!(evs.last(), Some(SessionEvent::Data(_))));
        assert!(!evs.iter().any(|e| matches!(e, SessionEvent::Skipped(_))));
    }

    #[test]
    fn unknown_truncated_and_foreign_frames_are_skipped() {
        let (mut s, _) = handshake(true, 5);
        while s.poll_event().is_some() {}
        s.handle_frame(&Frame {
            type_byte: b'Z',
            payload: Bytes::from_static(&[1, 2]),
        })
        .unwrap();
        s.handle_frame(&Frame {
            type_byte: b'v',
            payload: Bytes::from_static(&[0, 0]),
        })
        .unwrap();
        s.handle_frame(&Frame {
            type_byte: b'U',
            payload: Bytes::new(),
        })
        .unwrap();
        s.handle_frame(&frame_of(
            &ServerPackage::Data {
                recipe_id: Some(9),
                payload: Bytes::from_static(&[0; 12]),
            },
            2,
        ))
        .unwrap();
        let evs: Vec<_> = std::iter::from_fn(|| s.poll_event()).collect();
        assert!(matches!(
            evs[0],
            SessionEvent::Skipped(SkipReason::UnknownType(b'Z'))
        ));
        assert!(matches!(
            evs[1],
            SessionEvent::Skipped(SkipReason::Malformed(_))
        ));
        assert!(matches!(
            evs[2],
            SessionEvent::Skipped(SkipReason::Malformed(_))
        ));
        assert!(matches!(
            evs[3],
            SessionEvent::Skipped(SkipReason::UnexpectedData)
        ));
        assert!(s.is_streaming());
    }

    #[test]
    fn start_refused_is_an_error() {
        let mut s = Session::new(SessionConfig {
            input_recipes: vec![],
            ..cfg()
        })
        .unwrap();
        s.start();
        for r in [
            ServerPackage::ProtocolVersion { accepted: true },
            ServerPackage::UrControlVersion {
                major: 5,
                minor: 0,
                bugfix: 0,
                build: 0,
            },
            ServerPackage::OutputSetup {
                recipe_id: Some(1),
                types: types(&[DataType::Double, DataType::Int32]),
            },
        ] {
            s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap();
        }
        assert!(matches!(
            s.handle_frame(&frame_of(&ServerPackage::StartReply { accepted: false }, 2)),
            Err(RtdeError::StartRefused { .. })
        ));
    }

    #[test]
    fn pause_and_resume_follow_the_replies() {
        let (mut s, _) = handshake(true, 5);
        while s.poll_event().is_some() {}
        assert!(!s.resume(), "resume while streaming is refused");
        assert!(s.pause());
        assert_eq!(s.poll_transmit(), Some(ClientPackage::Pause));
        assert_eq!(s.phase(), Phase::Pausing);
        // Data the controller sent before it saw the pause is still delivered.
        s.handle_frame(&frame_of(&data(PROTOCOL_V2), PROTOCOL_V2))
            .unwrap();
        assert!(matches!(s.poll_event(), Some(SessionEvent::Data(_))));
        s.handle_frame(&frame_of(
            &ServerPackage::PauseReply { accepted: true },
            PROTOCOL_V2,
        ))
        .unwrap();
        assert_eq!(s.phase(), Phase::Paused);
        // Data while paused is not ours to use.
        s.handle_frame(&frame_of(&data(PROTOCOL_V2), PROTOCOL_V2))
            .unwrap();
        assert_eq!(
            s.poll_event(),
            Some(SessionEvent::Skipped(SkipReason::UnexpectedData))
        );
        assert!(s.resume());
        assert_eq!(s.poll_transmit(), Some(ClientPackage::Start));
        s.handle_frame(&frame_of(
            &ServerPackage::StartReply { accepted: true },
            PROTOCOL_V2,
        ))
        .unwrap();
        assert!(s.is_streaming());
        assert_eq!(s.poll_event(), Some(SessionEvent::Ready));
    }

    #[test]
    fn a_refused_pause_keeps_streaming() {
        let (mut s, _) = handshake(true, 5);
        assert!(s.pause());
        s.handle_frame(&frame_of(
            &ServerPackage::PauseReply { accepted: false },
            PROTOCOL_V2,
        ))
        .unwrap();
        assert!(s.is_streaming());
    }
}
