//! The live view of a run: a Foxglove WebSocket server (subprotocol `foxglove.websocket.v1`)
//! on localhost, so the Foxglove app shows the frames, the wrench, the TCP pose and the paired
//! wrench while the robot moves (`rig run --live [ADDR]`).
//!
//! What it speaks (the protocol's core; no client publishing, services or parameters): on
//! connect the server sends `serverInfo` and one `advertise` listing every channel of a
//! recording ([`crate::record::CHANNELS`], with the recording's encodings: `protobuf`
//! messages, each schema its `FileDescriptorSet` in base64 with `schemaEncoding` `protobuf`,
//! as the protocol specifies for protobuf channels). A client `subscribe`s with its own
//! subscription ids and `unsubscribe`s them; each record then goes to it as a binary
//! `messageData` frame: opcode `0x01`, the subscription id (u32 LE), the log time (u64 LE, ns)
//! and the protobuf body the recording holds.
//!
//! It never slows the run: [`LiveView::publish`] encodes a record only when somebody
//! subscribes to its topic, once for all clients, and hands it to each client's bounded queue
//! without waiting; a client too slow to keep up loses messages (counted in
//! [`LiveStats::dropped`]), not the recording.
//!
//! It is safe to leave running next to the robot:
//! - Only loopback addresses are bound and only loopback peers served: the rig serves no one
//!   on the lab network (use an SSH tunnel to watch from elsewhere).
//! - A handshake whose `Origin` header names a page not served by this machine gets HTTP 403,
//!   so a web page open in a browser on the rig's machine cannot read the run; clients
//!   without `Origin` (scripts, non-browser clients) and `http(s)://localhost[:port]`,
//!   `127.0.0.1`, `[::1]` pages are served. A hosted web app, such as Foxglove's own
//!   `https://app.foxglove.dev`, is a foreign origin: refused unless the operator names it
//!   ([`AllowedOrigin`], `--live-allow-origin`), and then that origin exactly.
//! - [`LiveLimits`] bounds what clients can make it hold: [`MAX_CLIENTS`] connections (one past
//!   it gets an error `status` and a close frame), [`MAX_SUBSCRIPTIONS`] per client (the excess
//!   of a `subscribe` is refused with an error `status`), [`MAX_MESSAGE_BYTES`] per incoming
//!   message (a bigger one closes that client), [`HANDSHAKE_TIMEOUT`] to complete the
//!   handshake (a connection that stalls in it is closed), [`MAX_PENDING_HANDSHAKES`]
//!   connections in the handshake at once (one more is closed at once, before any byte is
//!   read), and [`IDLE_TIMEOUT`] for a client to read: the server pings every client a few
//!   times per period, and one that has answered none of them for that long (it does not read
//!   its socket, or is gone) is closed and its place freed.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Semaphore, mpsc, oneshot};
use tokio::task::JoinHandle;
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tokio_tungstenite::tungstenite::http::{HeaderValue, StatusCode};
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::tungstenite::protocol::frame::CloseFrame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode;
use tokio_tungstenite::tungstenite::{Error as WsError, Message};

use crate::record::Record;
use crate::record::channels::{CHANNELS, ENCODING, schema_data};
use crate::record::legacy::base64;

mod origin;
#[cfg(test)]
mod tests;

pub use origin::AllowedOrigin;

/// The WebSocket subprotocol of the Foxglove WebSocket protocol.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// Messages queued per client before new ones are dropped for it.
const CLIENT_QUEUE: usize = 256;
/// Most clients served at once. The Foxglove app opens one connection per window: eight leave
/// room for a few windows and a script, and bound the work of each [`LiveView::publish`] (one
/// queue push per subscription) and the memory the queues can hold (each up to
/// `CLIENT_QUEUE` messages, image frames included).
pub const MAX_CLIENTS: usize = 8;
/// Most subscriptions one client holds. A recording has six channels and the Foxglove app
/// subscribes to each once: 32 leave room for a client that subscribes twice, and bound how
/// many frames one record becomes for one client.
pub const MAX_SUBSCRIPTIONS: usize = 32;
/// Largest incoming WebSocket message (and frame), bytes. Clients only send small JSON
/// requests (a `subscribe` of [`MAX_SUBSCRIPTIONS`] subscriptions is under 2 KiB); the
/// WebSocket library's own limit (64 MiB) would let one client make the server buffer that
/// much.
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;
/// Time a TCP connection has to complete the WebSocket handshake, and a refused or closed
/// client to answer the close. A local client needs milliseconds; 5 s cover a loaded host,
/// and a connection that never completes the handshake does not hold a task and a socket for
/// good.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);
/// Connections in the handshake (or being refused past [`MAX_CLIENTS`]) at once; one more is
/// closed as soon as it is accepted. Twice the clients served leaves room for every window of
/// the Foxglove app reconnecting at once, and bounds the tasks and sockets that connections
/// which never complete a handshake can hold for [`HANDSHAKE_TIMEOUT`] each.
pub const MAX_PENDING_HANDSHAKES: usize = 2 * MAX_CLIENTS;
/// How long a client may go without reading before it is closed: the server pings it
/// `PINGS_PER_IDLE` times per period, and a client that answered none for this long does not
/// read its socket (or is gone). Browsers answer pings in their network stack, even for a
/// background tab, so a Foxglove window left open is never idle; 30 s let a loaded machine
/// catch up with a burst of image frames first.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// Pings sent per [`IDLE_TIMEOUT`].
const PINGS_PER_IDLE: u32 = 3;

/// Foxglove `status` levels.
const STATUS_ERROR: u8 = 2;

/// What a [`LiveView`] lets its clients make it hold (defaults: the constants above).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LiveLimits {
    /// Clients served at once; one more gets an error `status` and a close frame.
    pub max_clients: usize,
    /// Subscriptions per client; a `subscribe` past it is refused with an error `status`.
    pub max_subscriptions: usize,
    /// Largest incoming message, bytes; a bigger one closes that client (close code 1009).
    pub max_message_bytes: usize,
    /// Time to complete the handshake (and to answer a close) before the socket is closed.
    pub handshake_timeout: Duration,
    /// Connections in the handshake at once; one more is closed at once.
    pub max_pending_handshakes: usize,
    /// Time without answering a ping before a client is closed.
    pub idle_timeout: Duration,
}

impl Default for LiveLimits {
    fn default() -> Self {
        Self {
            max_clients: MAX_CLIENTS,
            max_subscriptions: MAX_SUBSCRIPTIONS,
            max_message_bytes: MAX_MESSAGE_BYTES,
            handshake_timeout: HANDSHAKE_TIMEOUT,
            max_pending_handshakes: MAX_PENDING_HANDSHAKES,
            idle_timeout: IDLE_TIMEOUT,
        }
    }
}

/// What a [`LiveView`] starts with besides its address.
#[derive(Debug, Clone, Default)]
pub struct LiveOptions {
    pub limits: LiveLimits,
    /// Channels advertised after the recording's.
    pub extra: Vec<ExtraChannel>,
    /// Origins served besides this machine's pages (`--live-allow-origin`).
    pub allowed_origins: Vec<AllowedOrigin>,
}

/// Counters of a [`LiveView`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveStats {
    pub clients: u64,
    pub sent: u64,
    /// Messages a slow client's full queue refused.
    pub dropped: u64,
    /// Connections closed unread because [`LiveLimits::max_pending_handshakes`] were pending.
    pub handshakes_refused: u64,
    /// Clients closed for not reading ([`LiveLimits::idle_timeout`]).
    pub idle_closed: u64,
}

struct Client {
    tx: mpsc::Sender<Message>,
    /// Subscription id → channel id.
    subs: HashMap<u32, u32>,
}

/// A channel beyond the recording's (`rig predict`'s `/predict/wrench`): JSON messages with a
/// JSON schema, advertised after [`CHANNELS`] (ids `CHANNELS.len() + 1`, …) and published with
/// [`LiveView::publish_extra`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExtraChannel {
    pub topic: String,
    pub schema_name: String,
    /// The JSON schema's text.
    pub schema: String,
}

#[derive(Default)]
struct Shared {
    /// Channels advertised after the recording's.
    extra: Vec<ExtraChannel>,
    /// Origins served besides this machine's pages.
    allowed_origins: Vec<AllowedOrigin>,
    clients: Mutex<HashMap<u64, Client>>,
    next_client: AtomicU64,
    sent: AtomicU64,
    dropped: AtomicU64,
    handshakes_refused: AtomicU64,
    idle_closed: AtomicU64,
}

impl Shared {
    /// The client map. Its lock is taken only in synchronous code (never across an `.await`),
    /// for map lookups and queue pushes: [`LiveView::publish`] waits on it for microseconds.
    fn clients(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Client>> {
        self.clients.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The running live view.
pub struct LiveView {
    addr: SocketAddr,
    shared: Arc<Shared>,
    task: JoinHandle<()>,
}

/// Channel id of a topic (its 1-based index in [`CHANNELS`]).
fn channel_id(topic: &str) -> Option<u32> {
    CHANNELS
        .iter()
        .position(|(t, _)| *t == topic)
        .map(|i| i as u32 + 1)
}

/// Channel id of an extra channel's topic (after the recording's).
fn extra_channel_id(extra: &[ExtraChannel], topic: &str) -> Option<u32> {
    extra
        .iter()
        .position(|c| c.topic == topic)
        .map(|i| (CHANNELS.len() + i) as u32 + 1)
}

/// The recording's channels (protobuf, their FileDescriptorSets base64-encoded), then the
/// extra ones (JSON with a JSON schema).
fn advertise(extra: &[ExtraChannel]) -> String {
    let recorded = CHANNELS.iter().map(|(topic, schema_name)| {
        (
            *topic,
            *schema_name,
            ENCODING,
            base64(&schema_data(schema_name)),
            ENCODING,
        )
    });
    let extras = extra.iter().map(|c| {
        (
            c.topic.as_str(),
            c.schema_name.as_str(),
            "json",
            c.schema.clone(),
            "jsonschema",
        )
    });
    let channels: Vec<serde_json::Value> = recorded
        .chain(extras)
        .enumerate()
        .map(
            |(i, (topic, schema_name, encoding, schema, schema_encoding))| {
                serde_json::json!({
                    "id": i as u32 + 1,
                    "topic": topic,
                    "encoding": encoding,
                    "schemaName": schema_name,
                    "schema": schema,
                    "schemaEncoding": schema_encoding,
                })
            },
        )
        .collect();
    serde_json::json!({ "op": "advertise", "channels": channels }).to_string()
}

fn server_info() -> String {
    serde_json::json!({
        "op": "serverInfo",
        "name": "TransForce rig",
        "capabilities": [],
        "supportedEncodings": [],
        "metadata": {},
        "sessionId": format!("{}", std::process::id()),
    })
    .to_string()
}

/// A Foxglove `status` message (the app shows it to the user).
fn status(level: u8, message: &str) -> Message {
    Message::Text(
        serde_json::json!({ "op": "status", "level": level, "message": message })
            .to_string()
            .into(),
    )
}

impl LiveView {
    /// Binds `bind` (a loopback address only) and serves clients in the background, with the
    /// default [`LiveLimits`].
    pub async fn start(bind: SocketAddr) -> std::io::Result<LiveView> {
        Self::start_with(bind, LiveLimits::default()).await
    }

    /// [`LiveView::start`] with other limits (every one at least 1).
    pub async fn start_with(bind: SocketAddr, limits: LiveLimits) -> std::io::Result<LiveView> {
        Self::start_with_channels(bind, limits, Vec::new()).await
    }

    /// [`LiveView::start_with`], advertising `extra` channels after the recording's.
    pub async fn start_with_channels(
        bind: SocketAddr,
        limits: LiveLimits,
        extra: Vec<ExtraChannel>,
    ) -> std::io::Result<LiveView> {
        Self::start_with_options(
            bind,
            LiveOptions {
                limits,
                extra,
                ..LiveOptions::default()
            },
        )
        .await
    }

    /// Binds `bind` (a loopback address only) and serves clients in the background, as
    /// `options` say.
    pub async fn start_with_options(
        bind: SocketAddr,
        options: LiveOptions,
    ) -> std::io::Result<LiveView> {
        let LiveOptions {
            limits,
            extra,
            allowed_origins,
        } = options;
        let invalid = |msg: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, msg);
        if !bind.ip().is_loopback() {
            return Err(invalid(format!(
                "the live view serves localhost only; {bind} is not a loopback address \
                 (use 127.0.0.1:PORT and an SSH tunnel to watch from another machine)"
            )));
        }
        if limits.max_clients == 0
            || limits.max_subscriptions == 0
            || limits.max_message_bytes == 0
            || limits.handshake_timeout.is_zero()
            || limits.max_pending_handshakes == 0
            || limits.idle_timeout.is_zero()
        {
            return Err(invalid(format!(
                "every live view limit must be at least 1 (got {limits:?})"
            )));
        }
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            extra,
            allowed_origins,
            ..Shared::default()
        });
        let s = shared.clone();
        let pending = Arc::new(Semaphore::new(limits.max_pending_handshakes));
        let task = tokio::spawn(async move {
            loop {
                match listener.accept().await {
                    Ok((stream, peer)) => {
                        // A place among the pending handshakes, held until the client is
                        // admitted or refused; none left: closed before anything is read.
                        let Ok(place) = pending.clone().try_acquire_owned() else {
                            let n = s.handshakes_refused.fetch_add(1, Ordering::Relaxed);
                            if n.is_multiple_of(100) {
                                tracing::warn!(
                                    "live view: closed {peer} unread: {} connections are already \
                                     in the handshake ({} refused so far)",
                                    limits.max_pending_handshakes,
                                    n + 1
                                );
                            }
                            drop(stream);
                            continue;
                        };
                        tokio::spawn(serve(stream, peer, s.clone(), limits, place));
                    }
                    Err(e) => {
                        tracing::warn!("live view: accept failed: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                }
            }
        });
        tracing::info!("live view (Foxglove WebSocket) on ws://{addr}");
        Ok(LiveView { addr, shared, task })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Sends `rec` to every client subscribed to its topic. Never blocks the caller (the
    /// recording path): it is synchronous, holds the client map's lock only to find the
    /// subscriptions that want the record, encodes it (once) after releasing it, and hands a
    /// frame to each client's bounded queue with `try_send`: a full queue drops the frame
    /// (counted in [`LiveStats::dropped`]) instead of waiting for the client.
    pub fn publish(&self, rec: &Record) {
        let Some(cid) = channel_id(rec.topic()) else {
            return;
        };
        self.send(cid, || rec.encode());
    }

    /// Sends a JSON `body` logged at `t_ns` on an extra channel (see [`ExtraChannel`]) to every
    /// client subscribed to it, as [`Self::publish`] does (never blocking). An unknown topic is
    /// ignored.
    pub fn publish_extra(&self, topic: &str, t_ns: u64, body: &[u8]) {
        let Some(cid) = extra_channel_id(&self.shared.extra, topic) else {
            return;
        };
        self.send(cid, || ("", t_ns, body.to_vec()));
    }

    /// Hands channel `cid`'s message (encoded by `encode` only when somebody subscribes) to
    /// each subscription's queue without waiting.
    fn send(&self, cid: u32, encode: impl FnOnce() -> (&'static str, u64, Vec<u8>)) {
        let targets: Vec<(u32, mpsc::Sender<Message>)> = {
            let clients = self.shared.clients();
            clients
                .values()
                .flat_map(|c| {
                    c.subs
                        .iter()
                        .filter(move |&(_, &ch)| ch == cid)
                        .map(|(&sub, _)| (sub, c.tx.clone()))
                })
                .collect()
        };
        if targets.is_empty() {
            return;
        }
        let (_, t_ns, body) = encode();
        for (sub, tx) in targets {
            let mut frame = Vec::with_capacity(13 + body.len());
            frame.push(0x01);
            frame.extend_from_slice(&sub.to_le_bytes());
            frame.extend_from_slice(&t_ns.to_le_bytes());
            frame.extend_from_slice(&body);
            let counter = match tx.try_send(Message::Binary(frame.into())) {
                Ok(()) => &self.shared.sent,
                Err(_) => &self.shared.dropped,
            };
            counter.fetch_add(1, Ordering::Relaxed);
        }
    }

    pub fn stats(&self) -> LiveStats {
        LiveStats {
            clients: self.shared.clients().len() as u64,
            sent: self.shared.sent.load(Ordering::Relaxed),
            dropped: self.shared.dropped.load(Ordering::Relaxed),
            handshakes_refused: self.shared.handshakes_refused.load(Ordering::Relaxed),
            idle_closed: self.shared.idle_closed.load(Ordering::Relaxed),
        }
    }

    /// Closes every connection and stops serving.
    pub async fn shutdown(self) {
        self.task.abort();
        // Dropping the senders ends each client's writer, which closes its socket.
        self.shared.clients().clear();
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// The handshake's check: a local `Origin`, one of `allowed`, or none (else HTTP 403), and
/// the Foxglove subprotocol picked when offered.
#[allow(clippy::result_large_err)] // the callback's signature is tungstenite's
fn check_handshake(
    allowed: &[AllowedOrigin],
    req: &Request,
    mut resp: Response,
) -> Result<Response, ErrorResponse> {
    let origins: Vec<&HeaderValue> = req.headers().get_all("Origin").iter().collect();
    let admitted = |o: &str| origin::is_local_origin(o) || allowed.iter().any(|a| a.admits(o));
    if let Some(bad) = origins
        .iter()
        .find(|o| origins.len() > 1 || !o.to_str().is_ok_and(admitted))
    {
        let named = if allowed.is_empty() {
            String::new()
        } else {
            format!(
                " and the origins allowed with --live-allow-origin ({})",
                allowed
                    .iter()
                    .map(AllowedOrigin::as_str)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        let mut refusal = ErrorResponse::new(Some(format!(
            "The rig's live view serves pages of this machine only (http://localhost, \
             127.0.0.1 or [::1]){named}; Origin {bad:?} is refused. Connect from a client that \
             sends no Origin or from a page served by localhost, on the rig's machine (or \
             through an SSH tunnel); to admit a hosted app such as Foxglove's, start the rig \
             with --live-allow-origin and its origin (e.g. https://app.foxglove.dev).\n"
        )));
        *refusal.status_mut() = StatusCode::FORBIDDEN;
        return Err(refusal);
    }
    let offered = req
        .headers()
        .get("Sec-WebSocket-Protocol")
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default();
    if offered.split(',').any(|p| p.trim() == SUBPROTOCOL) {
        resp.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            HeaderValue::from_static(SUBPROTOCOL),
        );
    }
    Ok(resp)
}

/// Applies one client request to its subscriptions. Returns an error `status` for the client
/// when subscriptions were refused. Synchronous, so the client map's lock it takes can never
/// be held across an `.await`.
fn handle_request(shared: &Shared, id: u64, text: &str, max_subs: usize) -> Option<Message> {
    let Ok(v) = serde_json::from_str::<serde_json::Value>(text) else {
        tracing::debug!("live view: client {id} sent bad JSON");
        return None;
    };
    let mut clients = shared.clients();
    let client = clients.get_mut(&id)?;
    match v["op"].as_str() {
        Some("subscribe") => {
            let mut refused = Vec::new();
            for s in v["subscriptions"].as_array().into_iter().flatten() {
                let (Some(sub), Some(ch)) = (s["id"].as_u64(), s["channelId"].as_u64()) else {
                    continue;
                };
                let (Ok(sub), Ok(ch)) = (u32::try_from(sub), u32::try_from(ch)) else {
                    continue;
                };
                if !(1..=(CHANNELS.len() + shared.extra.len()) as u32).contains(&ch) {
                    continue;
                }
                if client.subs.len() < max_subs || client.subs.contains_key(&sub) {
                    client.subs.insert(sub, ch);
                } else {
                    refused.push(sub);
                }
            }
            if refused.is_empty() {
                return None;
            }
            tracing::warn!(
                "live view: client {id} is past {max_subs} subscriptions; refused {refused:?}"
            );
            Some(status(
                STATUS_ERROR,
                &format!(
                    "The rig's live view allows at most {max_subs} subscriptions per client; \
                     subscriptions {refused:?} were refused. Unsubscribe from topics you do \
                     not watch (close panels), then subscribe again."
                ),
            ))
        }
        Some("unsubscribe") => {
            for s in v["subscriptionIds"].as_array().into_iter().flatten() {
                if let Some(sub) = s.as_u64().and_then(|s| u32::try_from(s).ok()) {
                    client.subs.remove(&sub);
                }
            }
            None
        }
        other => {
            tracing::debug!("live view: client {id}: unsupported op {other:?}");
            None
        }
    }
}

/// One client: handshake (within the time limit), admission (within the client limit),
/// serverInfo + advertise, then its requests while it keeps reading. `place` is its place
/// among the pending handshakes, given back once it is admitted or refused.
async fn serve(
    stream: TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    limits: LiveLimits,
    place: tokio::sync::OwnedSemaphorePermit,
) {
    if !peer.ip().is_loopback() {
        tracing::warn!("live view: refused {peer}, not a loopback peer");
        return;
    }
    let config = WebSocketConfig::default()
        .max_message_size(Some(limits.max_message_bytes))
        .max_frame_size(Some(limits.max_message_bytes));
    let check = {
        let shared = shared.clone();
        // The callback's signature is tungstenite's.
        #[allow(clippy::result_large_err)]
        move |req: &Request, resp: Response| check_handshake(&shared.allowed_origins, req, resp)
    };
    let handshake = tokio_tungstenite::accept_hdr_async_with_config(stream, check, Some(config));
    let ws = match tokio::time::timeout(limits.handshake_timeout, handshake).await {
        Ok(Ok(ws)) => ws,
        Ok(Err(e)) => {
            tracing::info!("live view: handshake with {peer} refused or failed: {e}");
            return;
        }
        Err(_) => {
            tracing::info!(
                "live view: {peer} did not complete the handshake within {:?}; closed",
                limits.handshake_timeout
            );
            return;
        }
    };
    let (tx, rx) = mpsc::channel::<Message>(CLIENT_QUEUE);
    // The queue is new and empty: both fit.
    if tx.try_send(Message::Text(server_info().into())).is_err()
        || tx
            .try_send(Message::Text(advertise(&shared.extra).into()))
            .is_err()
    {
        return;
    }
    let id = shared.next_client.fetch_add(1, Ordering::Relaxed);
    let admitted = {
        let mut clients = shared.clients();
        let room = clients.len() < limits.max_clients;
        if room {
            clients.insert(
                id,
                Client {
                    tx,
                    subs: HashMap::new(),
                },
            );
        }
        room
    };
    if !admitted {
        refuse_client(ws, peer, limits).await;
        return;
    }
    drop(place);
    tracing::info!("live view: {peer} connected");
    let (sink, mut source) = ws.split();
    let (close_tx, close_rx) = oneshot::channel();
    let mut close_tx = Some(close_tx);
    let pings = Pings::new();
    let mut writer = tokio::spawn(write_loop(
        sink,
        rx,
        close_rx,
        pings.clone(),
        limits.idle_timeout / PINGS_PER_IDLE,
    ));
    // The last sign that the client reads: the handshake, then each answer to a ping.
    let mut last_read = tokio::time::Instant::now();
    loop {
        let msg = tokio::select! {
            m = source.next() => match m {
                Some(m) => m,
                None => break,
            },
            () = tokio::time::sleep_until(last_read + limits.idle_timeout) => {
                shared.idle_closed.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    "live view: {peer} answered no ping for {:?} (it does not read); closing it",
                    limits.idle_timeout
                );
                if let Some(close) = close_tx.take() {
                    let _ = close.send(CloseFrame {
                        code: CloseCode::Policy,
                        reason: "not reading".into(),
                    });
                }
                break;
            }
        };
        let text = match msg {
            Ok(Message::Text(t)) => t,
            Ok(Message::Pong(payload)) => {
                if pings.answered(&payload) {
                    last_read = tokio::time::Instant::now();
                }
                continue;
            }
            Ok(Message::Close(_)) => break,
            Err(WsError::Capacity(e)) => {
                tracing::warn!(
                    "live view: {peer} sent more than {} bytes at once ({e}); closing it",
                    limits.max_message_bytes
                );
                if let Some(close) = close_tx.take() {
                    let _ = close.send(CloseFrame {
                        code: CloseCode::Size,
                        reason: "message too big".into(),
                    });
                }
                break;
            }
            Err(e) => {
                tracing::debug!("live view: {peer}: {e}");
                break;
            }
            Ok(_) => continue,
        };
        if let Some(reply) = handle_request(&shared, id, &text, limits.max_subscriptions) {
            // Through the client's queue, after what is queued for it; a full queue drops it.
            if let Some(Err(e)) = shared.clients().get(&id).map(|c| c.tx.try_send(reply)) {
                tracing::debug!("live view: status for {peer} not sent: {e}");
            }
        }
    }
    shared.clients().remove(&id);
    if close_tx.is_none() {
        // A close frame is due: give the writer the handshake's time to send it.
        let _ = tokio::time::timeout(limits.handshake_timeout, &mut writer).await;
    }
    writer.abort();
    tracing::info!("live view: {peer} disconnected");
}

/// The pings sent to one client, so that only an answer to one of them counts as reading: a
/// client that never reads cannot keep its place with pongs of its own. Each ping's payload is
/// this client's random key and the ping's number.
#[derive(Clone)]
struct Pings {
    key: u64,
    sent: Arc<AtomicU64>,
}

impl Pings {
    fn new() -> Self {
        use std::hash::{BuildHasher, Hasher};
        // std's per-process random keys: unguessable enough for a loopback client.
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u64(u64::from(std::process::id()));
        Self {
            key: h.finish(),
            sent: Arc::new(AtomicU64::new(0)),
        }
    }

    /// The payload of the next ping.
    fn next(&self) -> Vec<u8> {
        let n = self.sent.fetch_add(1, Ordering::Relaxed) + 1;
        [self.key.to_le_bytes(), n.to_le_bytes()].concat()
    }

    /// Whether `payload` answers a ping sent to this client.
    fn answered(&self, payload: &[u8]) -> bool {
        let (Some(key), Some(n)) = (payload.get(..8), payload.get(8..16)) else {
            return false;
        };
        let n = u64::from_le_bytes(n.try_into().unwrap_or_default());
        payload.len() == 16
            && key == self.key.to_le_bytes()
            && (1..=self.sent.load(Ordering::Relaxed)).contains(&n)
    }
}

/// Sends a client's queue to it, and a ping every `ping_every`, until the queue ends (the
/// client was removed) or a close frame is due, then closes the connection.
async fn write_loop(
    mut sink: SplitSink<WebSocketStream<TcpStream>, Message>,
    mut rx: mpsc::Receiver<Message>,
    mut close: oneshot::Receiver<CloseFrame>,
    pings: Pings,
    ping_every: Duration,
) {
    let mut ticks = tokio::time::interval_at(tokio::time::Instant::now() + ping_every, ping_every);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            biased;
            frame = &mut close => {
                if let Ok(frame) = frame {
                    let _ = sink.send(Message::Close(Some(frame))).await;
                }
                break;
            }
            _ = ticks.tick() => {
                if sink.send(Message::Ping(pings.next().into())).await.is_err() {
                    break;
                }
            }
            m = rx.recv() => match m {
                Some(m) => {
                    if sink.send(m).await.is_err() {
                        break;
                    }
                }
                None => break,
            },
        }
    }
    let _ = sink.close().await;
}

/// A client past the limit: an error `status` saying so, a close frame (1013, try again
/// later), and the client's close reply awaited within the handshake time.
async fn refuse_client(mut ws: WebSocketStream<TcpStream>, peer: SocketAddr, limits: LiveLimits) {
    tracing::warn!(
        "live view: refused {peer}: {} clients are connected already",
        limits.max_clients
    );
    let message = format!(
        "The rig's live view serves at most {} clients at once and all are connected. Close \
         another connection to the rig (a Foxglove window or tab), then reconnect.",
        limits.max_clients
    );
    let refuse = async {
        ws.send(status(STATUS_ERROR, &message)).await?;
        ws.close(Some(CloseFrame {
            code: CloseCode::Again,
            reason: "too many clients".into(),
        }))
        .await?;
        while let Some(m) = ws.next().await {
            m?;
        }
        Ok::<(), WsError>(())
    };
    let _ = tokio::time::timeout(limits.handshake_timeout, refuse).await;
}
