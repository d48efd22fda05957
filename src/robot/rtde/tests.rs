//! Unit tests of the sans-IO [`Session`]: every handshake corner with scripted replies.

use std::collections::VecDeque;

use bytes::{Bytes, BytesMut};
use rig_core::rtde::{
    ClientPackage, DataType, FieldType, Frame, FrameDecoder, MessageLevel, PROTOCOL_V1,
    PROTOCOL_V2, ServerPackage, TextMessage, Value, encode_values,
};

use super::error::RtdeError;
use super::session::{Phase, Session, SessionConfig, SessionEvent, SkipReason};

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

/// The controller's version reply for software `major`.0.0.0.
fn controller_version(major: u32) -> ServerPackage {
    ServerPackage::UrControlVersion {
        major,
        minor: 0,
        bugfix: 0,
        build: 0,
    }
}

/// A v2 output setup reply that accepts [`cfg`]'s outputs.
fn outputs_accepted() -> ServerPackage {
    ServerPackage::OutputSetup {
        recipe_id: Some(1),
        types: types(&[DataType::Double, DataType::Int32]),
    }
}

/// An input setup reply that accepts [`cfg`]'s input recipe.
fn inputs_accepted() -> ServerPackage {
    ServerPackage::InputSetup {
        recipe_id: 2,
        types: types(&[DataType::Int32]),
    }
}

/// Feed v2-framed `replies` to `s`, each of which it must take without an error.
fn feed(s: &mut Session, replies: impl IntoIterator<Item = ServerPackage>) {
    for r in replies {
        s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap();
    }
}

/// A started session of `c` that took `replies` (v2-framed).
fn fed(c: SessionConfig, replies: impl IntoIterator<Item = ServerPackage>) -> Session {
    let mut s = Session::new(c).unwrap();
    s.start();
    feed(&mut s, replies);
    s
}

/// The v2 replies up to the output setup of an e-Series controller, all accepting.
fn through_output_setup() -> [ServerPackage; 3] {
    [
        ServerPackage::ProtocolVersion { accepted: true },
        controller_version(5),
        outputs_accepted(),
    ]
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
        inputs_accepted(),
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
    feed(&mut s, [data(PROTOCOL_V2)]);
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
    let mut s = fed(
        cfg(),
        [
            ServerPackage::ProtocolVersion { accepted: true },
            controller_version(5),
        ],
    );
    let r = ServerPackage::OutputSetup {
        recipe_id: Some(1),
        types: vec![FieldType::Known(DataType::Double), FieldType::NotFound],
    };
    let e = s.handle_frame(&frame_of(&r, PROTOCOL_V2)).unwrap_err();
    assert!(e.to_string().contains("robot_mode"), "{e}");

    let mut s = fed(cfg(), through_output_setup());
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
    feed(
        &mut s,
        [
            ServerPackage::ProtocolVersion { accepted: true },
            controller_version(5),
            text.clone(),
            outputs_accepted(),
            inputs_accepted(),
            data(PROTOCOL_V2),
        ],
    );
    assert!(s.is_streaming());
    assert_eq!(s.early_data(), 1);
    feed(&mut s, [ServerPackage::StartReply { accepted: true }]);
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
    let no_inputs = SessionConfig {
        input_recipes: vec![],
        ..cfg()
    };
    let mut s = fed(no_inputs, through_output_setup());
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
    feed(&mut s, [data(PROTOCOL_V2)]);
    assert!(matches!(s.poll_event(), Some(SessionEvent::Data(_))));
    feed(&mut s, [ServerPackage::PauseReply { accepted: true }]);
    assert_eq!(s.phase(), Phase::Paused);
    // Data while paused is not ours to use.
    feed(&mut s, [data(PROTOCOL_V2)]);
    assert_eq!(
        s.poll_event(),
        Some(SessionEvent::Skipped(SkipReason::UnexpectedData))
    );
    assert!(s.resume());
    assert_eq!(s.poll_transmit(), Some(ClientPackage::Start));
    feed(&mut s, [ServerPackage::StartReply { accepted: true }]);
    assert!(s.is_streaming());
    assert_eq!(s.poll_event(), Some(SessionEvent::Ready));
}

#[test]
fn a_refused_pause_keeps_streaming() {
    let (mut s, _) = handshake(true, 5);
    assert!(s.pause());
    feed(&mut s, [ServerPackage::PauseReply { accepted: false }]);
    assert!(s.is_streaming());
}
