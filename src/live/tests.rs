//! The live view's limits over real loopback sockets: the `Origin` check, the client and
//! subscription limits, the handshake timeout and the incoming message size.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use rig_core::wrench::Wrench;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::client_async;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use super::*;
use crate::record::channels::TOPIC_WRENCH;

type Ws = WebSocketStream<TcpStream>;

async fn start(limits: LiveLimits) -> LiveView {
    LiveView::start_with("127.0.0.1:0".parse().unwrap(), limits)
        .await
        .unwrap()
}

/// A WebSocket handshake offering the Foxglove subprotocol, with `origin` as its `Origin`.
async fn handshake(live: &LiveView, origin: Option<&str>) -> Result<Ws, WsError> {
    let mut req = format!("ws://{}/", live.addr()).into_client_request()?;
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static(SUBPROTOCOL),
    );
    if let Some(o) = origin {
        req.headers_mut()
            .insert("Origin", HeaderValue::from_str(o).unwrap());
    }
    let tcp = TcpStream::connect(live.addr()).await?;
    Ok(client_async(req, tcp).await?.0)
}

/// A served client: handshake, serverInfo and advertise read.
async fn connect(live: &LiveView) -> Ws {
    let mut ws = handshake(live, None).await.unwrap();
    assert_eq!(text(&mut ws).await["op"], "serverInfo");
    assert_eq!(text(&mut ws).await["op"], "advertise");
    ws
}

/// The next thing the server sends (None: the connection ended), within 10 s.
async fn next(ws: &mut Ws) -> Option<Result<Message, WsError>> {
    tokio::time::timeout(Duration::from_secs(10), ws.next())
        .await
        .expect("the server answers within 10 s")
}

async fn text(ws: &mut Ws) -> serde_json::Value {
    match next(ws).await {
        Some(Ok(Message::Text(t))) => serde_json::from_str(&t).unwrap(),
        other => panic!("expected a text message, got {other:?}"),
    }
}

/// (subscription id, log time) of a messageData frame.
fn message_data(m: Option<Result<Message, WsError>>) -> (u32, u64) {
    let Some(Ok(Message::Binary(b))) = m else {
        panic!("expected messageData, got {m:?}")
    };
    assert_eq!(b[0], 0x01, "opcode messageData");
    (
        u32::from_le_bytes(b[1..5].try_into().unwrap()),
        u64::from_le_bytes(b[5..13].try_into().unwrap()),
    )
}

async fn subscribe(ws: &mut Ws, subs: &[u32]) {
    let ch = channel_id(TOPIC_WRENCH).unwrap();
    let subs: Vec<_> = subs
        .iter()
        .map(|id| serde_json::json!({"id": id, "channelId": ch}))
        .collect();
    let req = serde_json::json!({"op": "subscribe", "subscriptions": subs});
    ws.send(Message::Text(req.to_string().into()))
        .await
        .unwrap();
}

fn wrench(t_ns: u64) -> Record {
    Record::Wrench {
        t_ns,
        seq: None,
        wrench: Wrench {
            force_n: [0.0, 0.0, -1.0],
            torque_nmm: [0.0; 3],
        },
    }
}

/// Publishes wrenches until `ws` receives one for subscription `sub` (the server has
/// processed that subscription); returns its log time.
async fn publish_until_served(live: &LiveView, ws: &mut Ws, sub: u32) -> u64 {
    for t in 0..500 {
        live.publish(&wrench(t));
        while let Ok(m) = tokio::time::timeout(Duration::from_millis(20), ws.next()).await {
            let (s, time) = message_data(m);
            if s == sub {
                return time;
            }
        }
    }
    panic!("subscription {sub} never served");
}

async fn eventually(what: &str, f: impl Fn() -> bool) {
    for _ in 0..1000 {
        if f() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("{what}: not within 10 s");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_foreign_origin_gets_403_and_local_or_absent_origins_are_served() {
    let live = start(LiveLimits::default()).await;
    for origin in ["http://evil.example", "http://localhost.evil.com", "null"] {
        match handshake(&live, Some(origin)).await {
            Err(WsError::Http(resp)) => {
                assert_eq!(resp.status(), StatusCode::FORBIDDEN, "{origin}");
                let body = String::from_utf8(resp.body().clone().unwrap_or_default()).unwrap();
                assert!(
                    body.contains("localhost") && body.contains(origin),
                    "{body}"
                );
            }
            other => panic!("{origin}: expected HTTP 403, got {other:?}"),
        }
    }
    assert_eq!(live.stats().clients, 0);
    let mut served = Vec::new();
    for origin in [None, Some("http://localhost:8080"), Some("https://[::1]")] {
        let mut ws = handshake(&live, origin)
            .await
            .unwrap_or_else(|e| panic!("{origin:?} refused: {e}"));
        assert_eq!(text(&mut ws).await["op"], "serverInfo", "{origin:?}");
        served.push(ws);
    }
    assert_eq!(live.stats().clients, 3);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_past_the_limit_gets_an_error_status_and_a_close() {
    let live = start(LiveLimits {
        max_clients: 2,
        ..LiveLimits::default()
    })
    .await;
    let first = connect(&live).await;
    let _second = connect(&live).await;
    assert_eq!(live.stats().clients, 2);

    let mut third = handshake(&live, None).await.unwrap();
    let st = text(&mut third).await;
    assert_eq!(st["op"], "status", "{st}");
    assert_eq!(st["level"], 2, "{st}");
    let msg = st["message"].as_str().unwrap();
    assert!(msg.contains("at most 2 clients"), "{msg}");
    match next(&mut third).await {
        Some(Ok(Message::Close(Some(f)))) => assert_eq!(f.code, CloseCode::Again),
        other => panic!("expected a close frame, got {other:?}"),
    }
    assert!(
        !matches!(next(&mut third).await, Some(Ok(_))),
        "nothing after the close"
    );
    assert_eq!(live.stats().clients, 2);

    // A client leaving frees its place for the next one.
    drop(first);
    eventually("the first client removed", || live.stats().clients == 1).await;
    let _fourth = connect(&live).await;
    assert_eq!(live.stats().clients, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connection_that_stalls_in_the_handshake_is_closed() {
    let live = start(LiveLimits {
        handshake_timeout: Duration::from_millis(200),
        ..LiveLimits::default()
    })
    .await;
    let silent = TcpStream::connect(live.addr()).await.unwrap();
    let mut half = TcpStream::connect(live.addr()).await.unwrap();
    half.write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n")
        .await
        .unwrap();
    for (name, mut s) in [("silent", silent), ("half a handshake", half)] {
        let mut buf = [0u8; 256];
        let n = tokio::time::timeout(Duration::from_secs(30), s.read(&mut buf))
            .await
            .unwrap_or_else(|_| panic!("{name}: the server never closed it"))
            .unwrap();
        assert_eq!(n, 0, "{name}: got {:?}", String::from_utf8_lossy(&buf[..n]));
    }
    // Whoever completes the handshake is served as before.
    let _ws = connect(&live).await;
    assert_eq!(live.stats().clients, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscriptions_past_the_limit_get_an_error_status_and_are_not_served() {
    let live = start(LiveLimits {
        max_subscriptions: 2,
        ..LiveLimits::default()
    })
    .await;
    let mut ws = connect(&live).await;
    subscribe(&mut ws, &[1, 2, 3]).await;
    let st = text(&mut ws).await;
    assert_eq!(
        (st["op"].as_str(), st["level"].as_u64()),
        (Some("status"), Some(2))
    );
    let msg = st["message"].as_str().unwrap();
    assert!(
        msg.contains("at most 2 subscriptions") && msg.contains("[3]"),
        "{msg}"
    );

    // One record: one frame for each of subscriptions 1 and 2, none for 3.
    let sent = live.stats().sent;
    live.publish(&wrench(42));
    assert_eq!(live.stats().sent, sent + 2);
    let mut subs = [
        message_data(next(&mut ws).await),
        message_data(next(&mut ws).await),
    ];
    subs.sort();
    assert_eq!(subs, [(1, 42), (2, 42)]);
    live.publish(&wrench(43));
    assert!(matches!(message_data(next(&mut ws).await), (1 | 2, 43)));
    assert!(matches!(message_data(next(&mut ws).await), (1 | 2, 43)));

    // Unsubscribing makes room again.
    ws.send(Message::Text(
        r#"{"op":"unsubscribe","subscriptionIds":[1]}"#.into(),
    ))
    .await
    .unwrap();
    subscribe(&mut ws, &[3]).await;
    publish_until_served(&live, &mut ws, 3).await;
    let sent = live.stats().sent;
    live.publish(&wrench(1_000));
    assert_eq!(live.stats().sent, sent + 2, "subscriptions 2 and 3");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_message_closes_that_client_only() {
    let live = start(LiveLimits {
        max_message_bytes: 1024,
        ..LiveLimits::default()
    })
    .await;
    let mut big = connect(&live).await;
    let mut other = connect(&live).await;
    subscribe(&mut other, &[5]).await;
    publish_until_served(&live, &mut other, 5).await;

    // Within the limit: served as usual (bad JSON is ignored).
    big.send(Message::Text("x".repeat(1000).into()))
        .await
        .unwrap();
    big.send(Message::Text("x".repeat(4096).into()))
        .await
        .unwrap();
    match next(&mut big).await {
        Some(Ok(Message::Close(Some(f)))) => assert_eq!(f.code, CloseCode::Size),
        other => panic!("expected a close frame, got {other:?}"),
    }
    eventually("the big client removed", || live.stats().clients == 1).await;

    // The other client is still served.
    live.publish(&wrench(7_777));
    loop {
        let (sub, t) = message_data(next(&mut other).await);
        assert_eq!(sub, 5);
        if t == 7_777 {
            break;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_allowed_foreign_origin_is_served_and_every_other_one_still_gets_403() {
    // By default Foxglove's web app is a foreign origin like any other.
    let closed = start(LiveLimits::default()).await;
    match handshake(&closed, Some("https://app.foxglove.dev")).await {
        Err(WsError::Http(resp)) => assert_eq!(resp.status(), StatusCode::FORBIDDEN),
        other => panic!("expected HTTP 403 by default, got {other:?}"),
    }
    let live = LiveView::start_with_options(
        "127.0.0.1:0".parse().unwrap(),
        LiveOptions {
            allowed_origins: vec!["https://app.foxglove.dev".parse().unwrap()],
            ..LiveOptions::default()
        },
    )
    .await
    .unwrap();
    for origin in ["https://app.foxglove.dev", "https://APP.foxglove.dev:443"] {
        let mut ws = handshake(&live, Some(origin))
            .await
            .unwrap_or_else(|e| panic!("{origin} refused: {e}"));
        assert_eq!(text(&mut ws).await["op"], "serverInfo", "{origin}");
        assert_eq!(text(&mut ws).await["op"], "advertise", "{origin}");
    }
    for origin in [
        "https://app.foxglove.dev.evil.com",
        "http://app.foxglove.dev",
        "https://app.foxglove.dev:8443",
        "https://evil.example",
    ] {
        match handshake(&live, Some(origin)).await {
            Err(WsError::Http(resp)) => {
                assert_eq!(resp.status(), StatusCode::FORBIDDEN, "{origin}");
                let body = String::from_utf8(resp.body().clone().unwrap_or_default()).unwrap();
                assert!(
                    body.contains(origin) && body.contains("https://app.foxglove.dev"),
                    "{body}"
                );
            }
            other => panic!("{origin}: expected HTTP 403, got {other:?}"),
        }
    }
    // This machine's pages are still served beside the allowed origin.
    let mut local = handshake(&live, Some("http://localhost:8080"))
        .await
        .unwrap();
    assert_eq!(text(&mut local).await["op"], "serverInfo");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_does_not_read_is_closed_after_the_idle_time_and_a_reading_one_stays() {
    let idle = Duration::from_secs(1);
    let live = start(LiveLimits {
        idle_timeout: idle,
        ..LiveLimits::default()
    })
    .await;
    // Neither subscribes to anything; one reads its socket (and so answers the pings), the
    // other never reads again after the advertise.
    let mut asleep = connect(&live).await;
    let mut awake = connect(&live).await;
    assert_eq!(live.stats().clients, 2);
    let mut pings = 0;
    let watch = async {
        while let Some(m) = awake.next().await {
            if matches!(m, Ok(Message::Ping(_))) {
                pings += 1;
            }
        }
    };
    // Three idle periods of reading.
    let ended = tokio::time::timeout(3 * idle, watch).await;
    assert!(ended.is_err(), "the reading client's connection ended");
    assert!(pings >= 3, "{pings} pings in three idle periods");
    let stats = live.stats();
    assert_eq!(
        (stats.idle_closed, stats.clients),
        (1, 1),
        "the sleeping client closed, the reading one kept: {stats:?}"
    );
    // What the sleeping client finds when it reads at last: the pings it never answered, then
    // a close frame saying why, or the end of the connection (its late answer to a ping can
    // meet the closed socket before it reads the close frame).
    loop {
        match next(&mut asleep).await {
            Some(Ok(Message::Ping(_))) => continue,
            Some(Ok(Message::Close(Some(f)))) => {
                assert_eq!(f.code, CloseCode::Policy);
                assert_eq!(f.reason.as_str(), "not reading");
                break;
            }
            None | Some(Err(_)) => break,
            other => panic!("expected pings then the close, got {other:?}"),
        }
    }
    // Its place is free again.
    let _next = connect(&live).await;
    assert_eq!(live.stats().clients, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_past_the_pending_handshake_cap_are_closed_unread() {
    // A handshake time far longer than the test: only the cap can close the third connection.
    let live = start(LiveLimits {
        max_pending_handshakes: 2,
        handshake_timeout: Duration::from_secs(600),
        ..LiveLimits::default()
    })
    .await;
    let first = TcpStream::connect(live.addr()).await.unwrap();
    let second = TcpStream::connect(live.addr()).await.unwrap();
    let mut third = TcpStream::connect(live.addr()).await.unwrap();
    let mut buf = [0u8; 64];
    let n = tokio::time::timeout(Duration::from_secs(30), third.read(&mut buf))
        .await
        .expect("the connection past the cap was not closed")
        .unwrap_or(0);
    assert_eq!(n, 0, "got {:?}", String::from_utf8_lossy(&buf[..n]));
    assert_eq!(live.stats().handshakes_refused, 1);
    // The two pending ones are still open (nothing to read, no end of stream).
    for (name, s) in [("first", &first), ("second", &second)] {
        match s.try_read(&mut buf) {
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            other => panic!("{name}: expected an open, silent connection, got {other:?}"),
        }
    }
    // One of them going away frees its place: a handshake is served again.
    drop(first);
    let mut served = None;
    for _ in 0..200 {
        if let Ok(ws) = handshake(&live, None).await {
            served = Some(ws);
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mut ws = served.expect("no handshake served after a pending one went away");
    assert_eq!(text(&mut ws).await["op"], "serverInfo");
    drop(second);
}
