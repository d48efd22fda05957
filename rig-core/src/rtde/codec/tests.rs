//! Codec tests against the RTDE guide's byte layouts.

use bytes::{BufMut, Bytes, BytesMut};

use super::*;

fn frames_of(bytes: &[u8]) -> Vec<Frame> {
    let mut d = FrameDecoder::new();
    d.push(bytes);
    let mut out = Vec::new();
    while let Some(f) = d.next_frame().unwrap() {
        out.push(f);
    }
    out
}

#[test]
fn protocol_version_request_matches_the_guide_bytes() {
    let mut out = BytesMut::new();
    ClientPackage::RequestProtocolVersion(2)
        .encode(PROTOCOL_V2, &mut out)
        .unwrap();
    // size 5 (header 3 + u16), type 'V' = 86, version 2.
    assert_eq!(&out[..], &[0, 5, 86, 0, 2]);
}

#[test]
fn output_setup_v2_carries_frequency_then_names() {
    let mut out = BytesMut::new();
    ClientPackage::SetupOutputs {
        frequency_hz: 500.0,
        names: vec!["timestamp".into(), "actual_TCP_pose".into()],
    }
    .encode(PROTOCOL_V2, &mut out)
    .unwrap();
    let names = b"timestamp,actual_TCP_pose";
    assert_eq!(out.len(), 3 + 8 + names.len());
    assert_eq!(out[2], b'O');
    assert_eq!(&out[3..11], &500.0f64.to_be_bytes());
    assert_eq!(&out[11..], names);
}

#[test]
fn output_setup_reply_with_not_found_decodes() {
    let mut payload = vec![1u8];
    payload.extend_from_slice(b"DOUBLE,NOT_FOUND,VECTOR6D");
    let f = Frame {
        type_byte: b'O',
        payload: Bytes::from(payload),
    };
    let p = ServerPackage::decode(&f, PROTOCOL_V2).unwrap();
    assert_eq!(
        p,
        ServerPackage::OutputSetup {
            recipe_id: Some(1),
            types: vec![
                FieldType::Known(DataType::Double),
                FieldType::NotFound,
                FieldType::Known(DataType::Vector6d)
            ]
        }
    );
}

#[test]
fn split_and_coalesced_reads_frame_identically() {
    let mut bytes = BytesMut::new();
    let msgs = [
        ServerPackage::ProtocolVersion { accepted: true },
        ServerPackage::TextMessage(TextMessage {
            message: "hello".into(),
            source: "RTDE".into(),
            level: MessageLevel::Info,
        }),
        ServerPackage::StartReply { accepted: true },
    ];
    for m in &msgs {
        m.encode(PROTOCOL_V2, &mut bytes).unwrap();
    }
    let whole = frames_of(&bytes);
    assert_eq!(whole.len(), 3);
    // One byte at a time.
    let mut d = FrameDecoder::new();
    let mut got = Vec::new();
    for b in bytes.iter() {
        d.push(std::slice::from_ref(b));
        while let Some(f) = d.next_frame().unwrap() {
            got.push(f);
        }
    }
    assert_eq!(got, whole);
    let decoded: Vec<_> = got
        .iter()
        .map(|f| ServerPackage::decode(f, PROTOCOL_V2).unwrap())
        .collect();
    assert_eq!(decoded, msgs);
}

#[test]
fn size_below_header_is_an_error_not_a_panic() {
    let mut d = FrameDecoder::new();
    d.push(&[0, 2, b'V']);
    assert_eq!(d.next_frame(), Err(DecodeError::SizeTooSmall(2)));
}

#[test]
fn unknown_type_is_framed_and_reported() {
    let f = frames_of(&[0, 4, b'Z', 9]);
    assert_eq!(f.len(), 1);
    assert_eq!(
        ServerPackage::decode(&f[0], PROTOCOL_V2),
        Err(DecodeError::UnknownType(b'Z'))
    );
}

#[test]
fn truncated_controller_version_reports_need_and_have() {
    let f = Frame {
        type_byte: b'v',
        payload: Bytes::from_static(&[0, 0, 0, 5, 0, 0]),
    };
    assert!(matches!(
        ServerPackage::decode(&f, PROTOCOL_V2),
        Err(DecodeError::Truncated {
            need: 4,
            have: 2,
            ..
        })
    ));
}

#[test]
fn data_values_round_trip_and_reject_wrong_lengths() {
    let values = [
        Value::Double(1.5),
        Value::Int32(-7),
        Value::Vector6d([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
        Value::Bool(true),
    ];
    let types: Vec<_> = values.iter().map(Value::data_type).collect();
    let mut buf = BytesMut::new();
    encode_values(&values, &mut buf);
    assert_eq!(buf.len(), 8 + 4 + 48 + 1);
    assert_eq!(decode_values(&types, &buf).unwrap(), values);
    assert!(matches!(
        decode_values(&types, &buf[..buf.len() - 1]),
        Err(DecodeError::Truncated { .. })
    ));
    let mut longer = buf.to_vec();
    longer.push(0);
    assert!(matches!(
        decode_values(&types, &longer),
        Err(DecodeError::TrailingBytes { extra: 1, .. })
    ));
}

#[test]
fn v1_text_message_has_level_then_text() {
    let m = TextMessage {
        message: "boot".into(),
        source: String::new(),
        level: MessageLevel::Warning,
    };
    let mut out = BytesMut::new();
    ServerPackage::TextMessage(m.clone())
        .encode(PROTOCOL_V1, &mut out)
        .unwrap();
    assert_eq!(&out[..], &[0, 8, b'M', 2, b'b', b'o', b'o', b't']);
    let f = frames_of(&out);
    assert_eq!(
        ServerPackage::decode(&f[0], PROTOCOL_V1).unwrap(),
        ServerPackage::TextMessage(m)
    );
}

#[test]
fn oversize_package_is_refused_and_leaves_output_untouched() {
    let mut out = BytesMut::new();
    out.put_slice(b"keep");
    let names = vec!["x".repeat(70_000)];
    let err = ClientPackage::SetupInputs { names }
        .encode(PROTOCOL_V2, &mut out)
        .unwrap_err();
    assert!(matches!(err, EncodeError::TooLong(_)));
    assert_eq!(&out[..], b"keep");
}
