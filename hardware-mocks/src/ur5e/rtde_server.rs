//! The RTDE server (TCP 30004 on a real controller): one task per connection.
//!
//! Each connection task owns its socket, a [`FrameDecoder`], its recipes and a subscription to
//! the controller's per-tick snapshots. Data packages are derived from controller ticks, never
//! from a timer of their own: at the recipe frequency `f` and the controller rate `F`, each tick
//! adds `f / F` to a phase accumulator and a package is sent whenever it reaches 1 (500 Hz on a
//! 500 Hz controller: every tick; 125 Hz: every 4th; 100 Hz: every 5th; 300 Hz: 3 of every 5).
//!
//! Protocol rules enforced, as a controller does (RTDE guide):
//! - protocol versions 1 and 2 are accepted, anything else is answered `accepted = false`; until
//!   a version is negotiated the connection speaks version 1;
//! - one output recipe per connection (a new setup replaces the old one); its frequency must be
//!   in `(0, max_frequency_hz]`, otherwise the reply carries recipe id 0 and a text message says
//!   why; any unknown name comes back `NOT_FOUND` and makes the recipe invalid (id 0); outputs
//!   cannot be set up while streaming;
//! - input recipes get ids 1, 2, …; an unknown name is `NOT_FOUND`, a variable held by another
//!   live connection's input recipe is `IN_USE` (either makes the recipe invalid, id 0); a
//!   connection's variables are released when it closes;
//! - `S` is refused without a valid output recipe;
//! - malformed input never panics: a size field below 3 drops the connection (the stream cannot
//!   be re-framed), an unknown type or a payload that does not decode is answered with an error
//!   text message and skipped, and an input package for an unknown recipe or of the wrong
//!   length likewise.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use bytes::BytesMut;
use rig_core::rtde::{
    ClientPackage, DataType, DecodeError, FieldType, FrameDecoder, MessageLevel, PROTOCOL_V1,
    PROTOCOL_V2, ServerPackage, TextMessage, decode_values, encode_values, fields,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::broadcast;

use super::shared::{Shared, accept_loop};
use super::snapshot::ControllerSnapshot;
use super::variables::{InputSink, OutputSource, resolve_input, resolve_output};

/// Source name the mock puts on its text messages.
const MESSAGE_SOURCE: &str = "RTDE";

struct OutputRecipe {
    id: u8,
    frequency_hz: f64,
    sources: Vec<OutputSource>,
}

struct InputRecipe {
    names: Vec<String>,
    sinks: Vec<InputSink>,
    types: Vec<DataType>,
}

struct Connection {
    id: u64,
    peer: SocketAddr,
    version: u16,
    output: Option<OutputRecipe>,
    inputs: HashMap<u8, InputRecipe>,
    next_input_id: u8,
    streaming: bool,
    phase: f64,
    sent: u64,
    first_sent_ns: Option<u64>,
    last_sent_ns: u64,
    /// Clock time at which a delayed `S` reply is due.
    start_ack_due_ns: Option<u64>,
    out: BytesMut,
}

pub(super) async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    accept_loop(listener, shared, "RTDE", |sock, peer, shared| {
        let now = shared.clock.now_ns();
        if now < shared.faults().refuse_until_ns {
            tracing::info!(%peer, "RTDE restarting (injected fault): closing new connection");
            drop(sock);
            return;
        }
        let _ = sock.set_nodelay(true);
        let id = shared.next_conn.fetch_add(1, Ordering::Relaxed);
        tokio::spawn(run_connection(sock, peer, id, shared.clone()));
    })
    .await;
}

async fn sleep_until_opt(shared: &Shared, t_ns: Option<u64>) {
    match t_ns {
        Some(t) => shared.clock.sleep_until_ns(t).await,
        None => std::future::pending().await,
    }
}

async fn run_connection(sock: TcpStream, peer: SocketAddr, id: u64, shared: Arc<Shared>) {
    tracing::info!(%peer, conn = id, "RTDE client connected");
    let mut conn = Connection {
        id,
        peer,
        version: PROTOCOL_V1,
        output: None,
        inputs: HashMap::new(),
        next_input_id: 1,
        streaming: false,
        phase: 0.0,
        sent: 0,
        first_sent_ns: None,
        last_sent_ns: 0,
        start_ack_due_ns: None,
        out: BytesMut::with_capacity(4096),
    };
    let (mut rd, mut wr) = sock.into_split();
    let mut samples = shared.samples.subscribe();
    let mut drops = shared.drop_gen.subscribe();
    drops.borrow_and_update();
    let mut shutdown = shared.shutdown.subscribe();
    let mut decoder = FrameDecoder::new();
    let reason: String = loop {
        tokio::select! {
            r = rd.read_buf(decoder.buffer_mut()) => match r {
                Ok(0) => break "client closed the connection".into(),
                Err(e) => break format!("read error: {e}"),
                Ok(_) => {
                    if let Err(why) = conn.process_frames(&mut decoder, &shared) {
                        break why;
                    }
                }
            },
            s = samples.recv() => match s {
                Ok(snap) => conn.on_tick(&snap, &shared),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!(conn = id, "RTDE connection fell {n} controller ticks behind");
                }
                Err(broadcast::error::RecvError::Closed) => break "controller stopped".into(),
            },
            _ = sleep_until_opt(&shared, conn.start_ack_due_ns) => {
                conn.start_ack_due_ns = None;
                conn.send(&ServerPackage::StartReply { accepted: true });
            }
            _ = drops.changed() => break "connection dropped (injected fault)".into(),
            _ = shutdown.wait_for(|s| *s) => break "controller shut down".into(),
        }
        if !conn.out.is_empty() {
            if let Err(e) = wr.write_all(&conn.out).await {
                break format!("write error: {e}");
            }
            conn.out.clear();
        }
    };
    shared.lock().release_inputs(id);
    let span_s = conn
        .first_sent_ns
        .map(|f| conn.last_sent_ns.saturating_sub(f) as f64 * 1e-9)
        .unwrap_or(0.0);
    let rate_hz = if span_s > 0.0 {
        (conn.sent.saturating_sub(1)) as f64 / span_s
    } else {
        0.0
    };
    tracing::info!(
        %peer, conn = id, data_packages = conn.sent, rate_hz = format!("{rate_hz:.1}"),
        "RTDE client disconnected: {reason}"
    );
}

fn drop_trailing_empty(names: &mut Vec<String>) {
    if names.last().is_some_and(|n| n.is_empty()) {
        names.pop();
    }
}

impl Connection {
    fn send(&mut self, pkg: &ServerPackage) {
        if let Err(e) = pkg.encode(self.version, &mut self.out) {
            tracing::warn!(
                conn = self.id,
                "could not encode {:?}: {e}",
                pkg.package_type()
            );
        }
    }

    fn text(&mut self, level: MessageLevel, message: String) {
        tracing::debug!(conn = self.id, "text message to client: {message}");
        let mut message = message;
        message.truncate(255);
        self.send(&ServerPackage::TextMessage(TextMessage {
            message,
            source: MESSAGE_SOURCE.into(),
            level,
        }));
    }

    fn handshake_noise(&mut self, shared: &Shared, what: &str) {
        if shared.faults().text_in_handshake {
            self.text(
                MessageLevel::Info,
                format!("controller message before the {what} reply (injected)"),
            );
        }
    }

    /// Handle every whole frame buffered; `Err` closes the connection.
    fn process_frames(
        &mut self,
        decoder: &mut FrameDecoder,
        shared: &Shared,
    ) -> Result<(), String> {
        loop {
            let frame = match decoder.next_frame() {
                Ok(Some(f)) => f,
                Ok(None) => return Ok(()),
                Err(e) => {
                    tracing::warn!(conn = self.id, peer = %self.peer, "dropping RTDE connection: {e}");
                    return Err(e.to_string());
                }
            };
            match ClientPackage::decode(&frame, self.version) {
                Ok(pkg) => self.handle(pkg, shared),
                Err(DecodeError::UnknownType(b)) => {
                    tracing::warn!(
                        conn = self.id,
                        "unknown RTDE package type 0x{b:02x} skipped"
                    );
                    self.text(
                        MessageLevel::Error,
                        format!("unknown package type 0x{b:02x}"),
                    );
                }
                Err(e) => {
                    tracing::warn!(conn = self.id, "malformed RTDE package skipped: {e}");
                    self.text(MessageLevel::Error, format!("malformed package: {e}"));
                }
            }
        }
    }

    fn handle(&mut self, pkg: ClientPackage, shared: &Shared) {
        match pkg {
            ClientPackage::RequestProtocolVersion(v) => {
                let accepted = v == PROTOCOL_V1 || v == PROTOCOL_V2;
                if accepted {
                    self.version = v;
                }
                self.handshake_noise(shared, "protocol version");
                self.send(&ServerPackage::ProtocolVersion { accepted });
            }
            ClientPackage::GetUrControlVersion => {
                self.handshake_noise(shared, "controller version");
                let (major, minor, bugfix, build) = shared.cfg.controller_version;
                self.send(&ServerPackage::UrControlVersion {
                    major,
                    minor,
                    bugfix,
                    build,
                });
            }
            ClientPackage::SetupOutputs {
                frequency_hz,
                mut names,
            } => {
                // ur_rtde ends its name list with a comma; the controller accepts that.
                drop_trailing_empty(&mut names);
                self.handshake_noise(shared, "output setup");
                self.setup_outputs(frequency_hz, names, shared);
            }
            ClientPackage::SetupInputs { mut names } => {
                drop_trailing_empty(&mut names);
                self.handshake_noise(shared, "input setup");
                self.setup_inputs(names, shared);
            }
            ClientPackage::Start => {
                if self.output.is_none() {
                    self.text(
                        MessageLevel::Error,
                        "cannot start: no valid output recipe has been set up".into(),
                    );
                    self.send(&ServerPackage::StartReply { accepted: false });
                    return;
                }
                self.streaming = true;
                self.phase = 0.0;
                match shared.faults().delay_start_ack.take() {
                    Some(d) => {
                        let due = shared.clock.now_ns() + d.as_nanos() as u64;
                        self.start_ack_due_ns = Some(due);
                    }
                    None => self.send(&ServerPackage::StartReply { accepted: true }),
                }
            }
            ClientPackage::Pause => {
                self.streaming = false;
                self.send(&ServerPackage::PauseReply { accepted: true });
            }
            ClientPackage::Data { recipe_id, payload } => {
                let Some(recipe) = self.inputs.get(&recipe_id) else {
                    self.text(
                        MessageLevel::Error,
                        format!("data package for unknown input recipe id {recipe_id}"),
                    );
                    return;
                };
                match decode_values(&recipe.types, &payload) {
                    Ok(values) => {
                        let now = shared.clock.now_ns();
                        shared
                            .lock()
                            .write_inputs(&recipe.names, &recipe.sinks, &values, now);
                    }
                    Err(e) => self.text(
                        MessageLevel::Error,
                        format!("input recipe {recipe_id}: {e}"),
                    ),
                }
            }
            ClientPackage::TextMessage(m) => {
                tracing::info!(conn = self.id, source = %m.source, level = ?m.level, "client says: {}", m.message);
            }
        }
    }

    fn setup_outputs(&mut self, frequency_hz: f64, names: Vec<String>, shared: &Shared) {
        let max = shared.cfg.max_frequency_hz;
        let types: Vec<FieldType> = names
            .iter()
            .map(|n| match fields::output_type(n) {
                Some(t) => FieldType::Known(t),
                None => FieldType::NotFound,
            })
            .collect();
        let unknown: Vec<&str> = names
            .iter()
            .zip(&types)
            .filter(|(_, t)| **t == FieldType::NotFound)
            .map(|(n, _)| n.as_str())
            .collect();
        let freq_ok = frequency_hz.is_finite() && frequency_hz > 0.0 && frequency_hz <= max;
        let mut valid = unknown.is_empty() && !names.is_empty();
        if !unknown.is_empty() {
            tracing::info!(
                conn = self.id,
                "output recipe asks for unknown variables: {unknown:?}"
            );
        }
        if !freq_ok {
            valid = false;
            self.text(
                MessageLevel::Error,
                format!(
                    "output frequency {frequency_hz} Hz is out of range: must be in (0, {max}]"
                ),
            );
        }
        if self.streaming {
            valid = false;
            self.text(
                MessageLevel::Error,
                "outputs cannot be set up while streaming: pause first".into(),
            );
        }
        let id = if valid { 1 } else { 0 };
        self.output = valid.then(|| OutputRecipe {
            id,
            frequency_hz,
            sources: names
                .iter()
                .map(|n| resolve_output(n).expect("name is in the variable table"))
                .collect(),
        });
        tracing::debug!(
            conn = self.id,
            frequency_hz,
            valid,
            "output recipe: {}",
            names.join(",")
        );
        let recipe_id = (self.version >= PROTOCOL_V2).then_some(id);
        self.send(&ServerPackage::OutputSetup { recipe_id, types });
    }

    fn setup_inputs(&mut self, names: Vec<String>, shared: &Shared) {
        let mut c = shared.lock();
        let types: Vec<FieldType> = names
            .iter()
            .map(|n| match fields::input_type(n) {
                None => FieldType::NotFound,
                Some(_) if c.input_owner(n).is_some_and(|o| o != self.id) => FieldType::InUse,
                Some(t) => FieldType::Known(t),
            })
            .collect();
        let valid = !names.is_empty()
            && types.iter().all(|t| matches!(t, FieldType::Known(_)))
            && self.next_input_id < u8::MAX;
        let id = if valid {
            c.claim_inputs(self.id, &names);
            let id = self.next_input_id;
            self.next_input_id += 1;
            self.inputs.insert(
                id,
                InputRecipe {
                    sinks: names
                        .iter()
                        .map(|n| resolve_input(n).expect("name is in the variable table"))
                        .collect(),
                    types: types
                        .iter()
                        .map(|t| match t {
                            FieldType::Known(t) => *t,
                            _ => unreachable!("checked above"),
                        })
                        .collect(),
                    names: names.clone(),
                },
            );
            id
        } else {
            0
        };
        drop(c);
        tracing::debug!(
            conn = self.id,
            recipe = id,
            "input recipe {names:?} → {types:?}"
        );
        self.send(&ServerPackage::InputSetup {
            recipe_id: id,
            types,
        });
    }

    fn on_tick(&mut self, snap: &ControllerSnapshot, shared: &Shared) {
        if !self.streaming {
            return;
        }
        let Some(recipe) = &self.output else { return };
        self.phase += recipe.frequency_hz / shared.cfg.max_frequency_hz;
        if self.phase < 1.0 - 1e-9 {
            return;
        }
        self.phase = (self.phase - 1.0).max(0.0);
        let values: Vec<_> = recipe.sources.iter().map(|s| snap.value(s)).collect();
        let mut payload = BytesMut::with_capacity(512);
        encode_values(&values, &mut payload);
        let recipe_id = (self.version >= PROTOCOL_V2).then_some(recipe.id);
        self.send(&ServerPackage::Data {
            recipe_id,
            payload: payload.freeze(),
        });
        self.sent += 1;
        self.first_sent_ns.get_or_insert(snap.t_ns);
        self.last_sent_ns = snap.t_ns;
        shared.packages_sent.fetch_add(1, Ordering::Relaxed);
    }
}
