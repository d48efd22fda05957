//! The RTDE handshake and stream as a sans-IO state machine.
//!
//! [`Session`] is fed whole frames and answers with the packages to send and the events that
//! happened; the caller owns the socket and the clock. It needs no time at all: the only
//! deadlines of RTDE (a handshake reply, a stalled stream) are the connection's to enforce.
//! Keeping I/O out is what lets every handshake corner — a v1-only controller, text messages
//! mid-handshake, data before the Start reply, NOT_FOUND or IN_USE replies, a refused pause —
//! be a unit test with scripted replies instead of a fake server.

use std::collections::VecDeque;
use std::fmt;
use std::net::SocketAddr;

use bytes::Bytes;
use rig_core::rtde::{
    ClientPackage, DataType, DecodeError, FieldType, Frame, PROTOCOL_V1, PROTOCOL_V2,
    ServerPackage, TextMessage, fields,
};

use super::error::{RecipeKind, RtdeError};

/// Output frequency when the controller is e-Series (software major ≥ 5), Hz (RTDE guide).
pub const E_SERIES_HZ: f64 = 500.0;
/// Output frequency on CB3 (software major 3), Hz (RTDE guide).
pub const CB3_HZ: f64 = 125.0;

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
        check_names(RecipeKind::Output, &cfg.output_names, fields::output_type)?;
        check_names(
            RecipeKind::Input,
            cfg.input_recipes.iter().flatten(),
            fields::input_type,
        )?;
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
        self.request(Phase::Streaming, Phase::Pausing, ClientPackage::Pause)
    }

    /// Start streaming again after a pause ('S', the same recipes). Returns whether a start
    /// was queued.
    pub fn resume(&mut self) -> bool {
        self.request(Phase::Paused, Phase::Start, ClientPackage::Start)
    }

    /// In phase `from`, queue `pkg` and await its reply in phase `to`; in any other phase do
    /// nothing and return false.
    fn request(&mut self, from: Phase, to: Phase, pkg: ClientPackage) -> bool {
        if self.phase != from {
            return false;
        }
        self.phase = to;
        self.transmit.push_back(pkg);
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

/// The first of `names` that `lookup` (a controller variable table) does not know is an error.
fn check_names<'a>(
    kind: RecipeKind,
    names: impl IntoIterator<Item = &'a String>,
    lookup: fn(&str) -> Option<DataType>,
) -> Result<(), RtdeError> {
    match names.into_iter().find(|n| lookup(n).is_none()) {
        Some(n) => Err(RtdeError::UnknownVariable {
            kind,
            variable: n.clone(),
        }),
        None => Ok(()),
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
