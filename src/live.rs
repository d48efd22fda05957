//! The live view of a run: a Foxglove WebSocket server (subprotocol `foxglove.websocket.v1`)
//! on localhost, so the Foxglove app shows the frames, the wrench, the TCP pose and the paired
//! wrench while the robot moves (`rig run --live [ADDR]`).
//!
//! What it speaks (the protocol's core; no client publishing, services or parameters): on
//! connect the server sends `serverInfo` and one `advertise` listing every channel of a
//! recording ([`crate::record::CHANNELS`]: JSON messages with their JSON schemas). A client
//! `subscribe`s with its own subscription ids and `unsubscribe`s them; each record then goes
//! to it as a binary `messageData` frame: opcode `0x01`, the subscription id (u32 LE), the log
//! time (u64 LE, ns) and the JSON body the recording holds.
//!
//! It never slows the run: [`LiveView::publish`] encodes a record only when somebody
//! subscribes to its topic, once for all clients, and hands it to each client's bounded queue
//! without waiting; a client too slow to keep up loses messages (counted in
//! [`LiveStats::dropped`]), not the recording. Only loopback addresses are accepted: the rig
//! serves no one on the lab network.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use futures_util::{SinkExt, StreamExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::handshake::server::{Request, Response};
use tokio_tungstenite::tungstenite::http::HeaderValue;

use crate::record::Record;
use crate::record::channels::{CHANNELS, schema_text};

/// The WebSocket subprotocol of the Foxglove WebSocket protocol.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";
/// Messages queued per client before new ones are dropped for it.
const CLIENT_QUEUE: usize = 256;

/// Counters of a [`LiveView`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveStats {
    pub clients: u64,
    pub sent: u64,
    /// Messages a slow client's full queue refused.
    pub dropped: u64,
}

struct Client {
    tx: mpsc::Sender<Message>,
    /// Subscription id → channel id.
    subs: HashMap<u32, u32>,
}

#[derive(Default)]
struct Shared {
    clients: Mutex<HashMap<u64, Client>>,
    next_client: AtomicU64,
    sent: AtomicU64,
    dropped: AtomicU64,
}

impl Shared {
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
        .position(|(t, _, _)| *t == topic)
        .map(|i| i as u32 + 1)
}

fn advertise() -> String {
    let channels: Vec<serde_json::Value> = CHANNELS
        .iter()
        .enumerate()
        .map(|(i, (topic, schema_name, schema))| {
            serde_json::json!({
                "id": i as u32 + 1,
                "topic": topic,
                "encoding": "json",
                "schemaName": schema_name,
                "schema": schema_text(schema),
                "schemaEncoding": "jsonschema",
            })
        })
        .collect();
    serde_json::json!({ "op": "advertise", "channels": channels }).to_string()
}

impl LiveView {
    /// Binds `bind` (a loopback address only) and serves clients in the background.
    pub async fn start(bind: SocketAddr) -> std::io::Result<LiveView> {
        if !bind.ip().is_loopback() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "the live view serves localhost only; {bind} is not a loopback address \
                     (use 127.0.0.1:PORT and an SSH tunnel to watch from another machine)"
                ),
            ));
        }
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared::default());
        let s = shared.clone();
        let task = tokio::spawn(async move {
            loop {
                match listener.accept().await {
                    Ok((stream, peer)) => {
                        tokio::spawn(serve(stream, peer, s.clone()));
                    }
                    Err(e) => {
                        tracing::warn!("live view: accept failed: {e}");
                        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
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

    /// Sends `rec` to every client subscribed to its topic, without waiting.
    pub fn publish(&self, rec: &Record) {
        let mut clients = self.shared.clients();
        if clients.is_empty() {
            return;
        }
        // Which subscriptions want it; encode only if any.
        let mut encoded: Option<(u32, u64, Vec<u8>)> = None;
        let topic_of = |r: &Record| match r {
            Record::Frame { .. } => crate::record::channels::TOPIC_IMAGE,
            Record::Wrench { .. } => crate::record::channels::TOPIC_WRENCH,
            Record::Pose { .. } => crate::record::channels::TOPIC_POSE,
            Record::Paired(_) => crate::record::channels::TOPIC_PAIRED,
            Record::Stage { .. } => crate::record::channels::TOPIC_STAGE,
            Record::Truth { .. } => crate::record::channels::TOPIC_TRUTH,
        };
        let Some(cid) = channel_id(topic_of(rec)) else {
            return;
        };
        for client in clients.values_mut() {
            for (&sub, &ch) in &client.subs {
                if ch != cid {
                    continue;
                }
                let (_, t_ns, body) = encoded.get_or_insert_with(|| {
                    let (_, t, b) = rec.encode();
                    (cid, t, b)
                });
                let mut frame = Vec::with_capacity(13 + body.len());
                frame.push(0x01);
                frame.extend_from_slice(&sub.to_le_bytes());
                frame.extend_from_slice(&t_ns.to_le_bytes());
                frame.extend_from_slice(body);
                match client.tx.try_send(Message::Binary(frame.into())) {
                    Ok(()) => {
                        self.shared.sent.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(_) => {
                        self.shared.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
    }

    pub fn stats(&self) -> LiveStats {
        LiveStats {
            clients: self.shared.clients().len() as u64,
            sent: self.shared.sent.load(Ordering::Relaxed),
            dropped: self.shared.dropped.load(Ordering::Relaxed),
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

/// One client: handshake with the subprotocol, serverInfo + advertise, then its requests.
async fn serve(stream: TcpStream, peer: SocketAddr, shared: Arc<Shared>) {
    #[allow(clippy::result_large_err)] // the callback's signature is tungstenite's
    let pick = |req: &Request, mut resp: Response| {
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
    };
    let ws = match tokio_tungstenite::accept_hdr_async(stream, pick).await {
        Ok(ws) => ws,
        Err(e) => {
            tracing::debug!("live view: handshake with {peer} failed: {e}");
            return;
        }
    };
    let (mut sink, mut source) = ws.split();
    let (tx, mut rx) = mpsc::channel::<Message>(CLIENT_QUEUE);
    let id = shared.next_client.fetch_add(1, Ordering::Relaxed);
    let info = serde_json::json!({
        "op": "serverInfo",
        "name": "TransForce rig",
        "capabilities": [],
        "supportedEncodings": [],
        "metadata": {},
        "sessionId": format!("{}", std::process::id()),
    })
    .to_string();
    if sink.send(Message::Text(info.into())).await.is_err()
        || sink.send(Message::Text(advertise().into())).await.is_err()
    {
        return;
    }
    shared.clients().insert(
        id,
        Client {
            tx,
            subs: HashMap::new(),
        },
    );
    tracing::info!("live view: {peer} connected");
    let writer = tokio::spawn(async move {
        while let Some(m) = rx.recv().await {
            if sink.send(m).await.is_err() {
                break;
            }
        }
        let _ = sink.close().await;
    });
    while let Some(msg) = source.next().await {
        let text = match msg {
            Ok(Message::Text(t)) => t,
            Ok(Message::Close(_)) | Err(_) => break,
            Ok(_) => continue,
        };
        let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) else {
            tracing::debug!("live view: {peer} sent bad JSON");
            continue;
        };
        let mut clients = shared.clients();
        let Some(client) = clients.get_mut(&id) else {
            break;
        };
        match v["op"].as_str() {
            Some("subscribe") => {
                for s in v["subscriptions"].as_array().into_iter().flatten() {
                    let (Some(sub), Some(ch)) = (s["id"].as_u64(), s["channelId"].as_u64()) else {
                        continue;
                    };
                    if let (Ok(sub), Ok(ch)) = (u32::try_from(sub), u32::try_from(ch))
                        && (1..=CHANNELS.len() as u32).contains(&ch)
                    {
                        client.subs.insert(sub, ch);
                    }
                }
            }
            Some("unsubscribe") => {
                for s in v["subscriptionIds"].as_array().into_iter().flatten() {
                    if let Some(sub) = s.as_u64().and_then(|s| u32::try_from(s).ok()) {
                        client.subs.remove(&sub);
                    }
                }
            }
            other => tracing::debug!("live view: {peer}: unsupported op {other:?}"),
        }
    }
    shared.clients().remove(&id);
    writer.abort();
    tracing::info!("live view: {peer} disconnected");
}
