//! The live view speaks the Foxglove WebSocket protocol over real loopback TCP: serverInfo and
//! advertise on connect, messageData frames only for subscribed channels, nothing after an
//! unsubscribe, localhost only, and a client that never reads does not slow `publish`.

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use rig::live::{LiveView, SUBPROTOCOL};
use rig::plan::StageName;
use rig::record::Record;
use rig_core::wrench::Wrench;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::{WebSocketStream, client_async};

type Ws = WebSocketStream<TcpStream>;

async fn connect(live: &LiveView) -> (Ws, serde_json::Value) {
    let mut req = format!("ws://{}/", live.addr())
        .into_client_request()
        .unwrap();
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static(SUBPROTOCOL),
    );
    let tcp = TcpStream::connect(live.addr()).await.unwrap();
    let (mut ws, resp) = client_async(req, tcp).await.unwrap();
    assert_eq!(
        resp.headers().get("Sec-WebSocket-Protocol").unwrap(),
        SUBPROTOCOL
    );
    let info = text(&mut ws).await;
    assert_eq!(info["op"], "serverInfo", "{info}");
    let adv = text(&mut ws).await;
    assert_eq!(adv["op"], "advertise", "{adv}");
    (ws, adv)
}

async fn next(ws: &mut Ws) -> Message {
    tokio::time::timeout(Duration::from_secs(5), ws.next())
        .await
        .expect("a message within 5 s")
        .unwrap()
        .unwrap()
}

async fn text(ws: &mut Ws) -> serde_json::Value {
    match next(ws).await {
        Message::Text(t) => serde_json::from_str(&t).unwrap(),
        other => panic!("expected text, got {other:?}"),
    }
}

fn channel(adv: &serde_json::Value, topic: &str) -> u64 {
    adv["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == topic)
        .unwrap_or_else(|| panic!("{topic} not advertised: {adv}"))["id"]
        .as_u64()
        .unwrap()
}

/// (subscription id, log time, body) of a messageData frame; the body (a `rig.Wrench` in
/// protobuf) as JSON `{force_n, torque_nmm}`.
fn message_data(m: Message) -> (u32, u64, serde_json::Value) {
    let Message::Binary(b) = m else {
        panic!("expected binary, got {m:?}")
    };
    assert_eq!(b[0], 0x01, "opcode messageData");
    let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
    let t = u64::from_le_bytes(b[5..13].try_into().unwrap());
    let mut body = serde_json::json!({});
    for f in rig::record::proto::fields(&b[13..]) {
        match f.unwrap() {
            (2, v) => body["force_n"] = serde_json::json!(v.vector3().unwrap()),
            (3, v) => body["torque_nmm"] = serde_json::json!(v.vector3().unwrap()),
            _ => {}
        }
    }
    (sub, t, body)
}

fn wrench(t_ns: u64, fz: f64) -> Record {
    Record::Wrench {
        t_ns,
        seq: Some(t_ns as i64),
        wrench: Wrench {
            force_n: [0.1, -0.2, fz],
            torque_nmm: [1.0, 2.0, 3.0],
        },
    }
}

async fn eventually(f: impl Fn() -> bool) {
    for _ in 0..500 {
        if f() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("condition not met within 5 s");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscribed_channels_get_message_data_and_nothing_else() {
    let live = LiveView::start("127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let (mut ws, adv) = connect(&live).await;
    let names: Vec<(&str, &str)> = adv["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["topic"].as_str().unwrap(),
                c["schemaName"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(names.len(), 6, "{names:?}");
    assert!(names.contains(&("/ft/wrench", "rig.Wrench")));
    assert!(names.contains(&("/camera/image", "foxglove.CompressedImage")));
    assert!(names.contains(&("/sim/true_wrench", "rig.TrueWrench")));
    for c in adv["channels"].as_array().unwrap() {
        // The recording's encodings: protobuf, each schema a base64 FileDescriptorSet.
        assert_eq!(c["encoding"], "protobuf");
        assert_eq!(c["schemaEncoding"], "protobuf");
        let schema = rig::record::legacy::base64_decode(c["schema"].as_str().unwrap()).unwrap();
        let name = c["schemaName"].as_str().unwrap();
        assert_eq!(schema, rig::record::channels::schema_data(name), "{name}");
        assert!(!schema.is_empty());
    }

    let ft = channel(&adv, "/ft/wrench");
    ws.send(Message::Text(
        serde_json::json!({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": ft}]})
            .to_string()
            .into(),
    ))
    .await
    .unwrap();
    // Bad input first: it must be ignored, not end the connection.
    ws.send(Message::Text("{not json".into())).await.unwrap();
    ws.send(Message::Text(r#"{"op":"advertiseServices"}"#.into()))
        .await
        .unwrap();
    ws.send(Message::Text(
        r#"{"op":"unsubscribe","subscriptionIds":[99]}"#.into(),
    ))
    .await
    .unwrap();
    // The subscription is registered once a publish reaches the client.
    let mut t = 1_000;
    let (sub, time, body) = loop {
        live.publish(&Record::Stage {
            t_ns: t,
            stage: StageName::Down,
        });
        live.publish(&wrench(t, -1.5));
        if let Ok(Some(Ok(m))) = tokio::time::timeout(Duration::from_millis(50), ws.next()).await {
            break message_data(m);
        }
        t += 1;
    };
    assert_eq!(sub, 7);
    assert_eq!(time, t);
    assert_eq!(body["force_n"], serde_json::json!([0.1, -0.2, -1.5]));
    assert_eq!(body["torque_nmm"], serde_json::json!([1.0, 2.0, 3.0]));
    // The stage record (not subscribed) never came: the next message is the next wrench.
    live.publish(&Record::Stage {
        t_ns: 5_000_000,
        stage: StageName::Shear,
    });
    live.publish(&wrench(6_000_000, -2.0));
    let (sub, time, body) = message_data(next(&mut ws).await);
    assert_eq!((sub, time), (7, 6_000_000));
    assert_eq!(body["force_n"][2], -2.0);

    ws.send(Message::Text(
        r#"{"op":"unsubscribe","subscriptionIds":[7]}"#.into(),
    ))
    .await
    .unwrap();
    // Once the unsubscribe is processed, a publish sends nothing more.
    eventually(|| {
        let before = live.stats().sent;
        live.publish(&wrench(7_000_000, -3.0));
        live.stats().sent == before
    })
    .await;
    let before = live.stats().sent;
    for k in 0..20 {
        live.publish(&wrench(8_000_000 + k, -3.0));
    }
    assert_eq!(live.stats().sent, before);
    live.shutdown().await;
}

#[tokio::test]
async fn only_loopback_addresses_are_served() {
    let e = LiveView::start("0.0.0.0:0".parse().unwrap())
        .await
        .err()
        .expect("refused");
    assert!(e.to_string().contains("localhost only"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_loses_messages_not_the_run() {
    let live = LiveView::start("127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    let (mut stalled, adv) = connect(&live).await;
    let img = channel(&adv, "/camera/image");
    stalled
        .send(Message::Text(
            serde_json::json!({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": img}]})
                .to_string()
                .into(),
        ))
        .await
        .unwrap();
    let (mut reader, _) = connect(&live).await;
    let ft = channel(&adv, "/ft/wrench");
    reader
        .send(Message::Text(
            serde_json::json!({"op": "subscribe", "subscriptions": [{"id": 2, "channelId": ft}]})
                .to_string()
                .into(),
        ))
        .await
        .unwrap();
    let png = vec![0u8; 50_000];
    eventually(|| {
        live.publish(&Record::Frame {
            seq: 0,
            t_ns: 1,
            format: rig::record::ImageFormat::Png,
            data: png.clone(),
        });
        live.stats().sent > 0
    })
    .await;
    // More frames (600 × 50 kB) than the queue (256) and socket buffers hold: `publish` never waits, the
    // stalled client's queue overflows and the overflow is counted.
    for k in 0..600 {
        live.publish(&Record::Frame {
            seq: k,
            t_ns: k as u64,
            format: rig::record::ImageFormat::Png,
            data: png.clone(),
        });
    }
    assert!(live.stats().dropped > 0, "{:?}", live.stats());
    // The other client still gets its messages.
    let (sub, time) = loop {
        live.publish(&wrench(42, -1.0));
        if let Ok(Some(Ok(m))) =
            tokio::time::timeout(Duration::from_millis(50), reader.next()).await
        {
            let (sub, time, _) = message_data(m);
            break (sub, time);
        }
    };
    assert_eq!((sub, time), (2, 42));
    assert_eq!(live.stats().clients, 2);
    drop(stalled);
    live.shutdown().await;
}
