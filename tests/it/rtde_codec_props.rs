//! Property tests of the sans-IO RTDE codec (`rig_core::rtde`): every package type in both
//! directions and both protocol versions, and every data type, survive encode → frame (split
//! at arbitrary points) → decode; arbitrary bytes never make the framer or decoders panic.

use bytes::{Bytes, BytesMut};
use proptest::prelude::*;
use rig_core::rtde::{
    ClientPackage, DataType, FieldType, Frame, FrameDecoder, MessageLevel, PROTOCOL_V1,
    PROTOCOL_V2, ServerPackage, TextMessage, Value, decode_values, encode_values,
};

fn version() -> impl Strategy<Value = u16> {
    prop_oneof![Just(PROTOCOL_V1), Just(PROTOCOL_V2)]
}

fn data_type() -> impl Strategy<Value = DataType> {
    proptest::sample::select(DataType::ALL.to_vec())
}

fn value_of(t: DataType) -> BoxedStrategy<Value> {
    match t {
        DataType::Bool => any::<bool>().prop_map(Value::Bool).boxed(),
        DataType::Uint8 => any::<u8>().prop_map(Value::Uint8).boxed(),
        DataType::Uint32 => any::<u32>().prop_map(Value::Uint32).boxed(),
        DataType::Uint64 => any::<u64>().prop_map(Value::Uint64).boxed(),
        DataType::Int32 => any::<i32>().prop_map(Value::Int32).boxed(),
        DataType::Double => any::<f64>().prop_map(Value::Double).boxed(),
        DataType::Vector3d => any::<[f64; 3]>().prop_map(Value::Vector3d).boxed(),
        DataType::Vector6d => any::<[f64; 6]>().prop_map(Value::Vector6d).boxed(),
        DataType::Vector6Int32 => any::<[i32; 6]>().prop_map(Value::Vector6Int32).boxed(),
        DataType::Vector6Uint32 => any::<[u32; 6]>().prop_map(Value::Vector6Uint32).boxed(),
    }
}

fn values() -> impl Strategy<Value = Vec<Value>> {
    proptest::collection::vec(data_type().prop_flat_map(value_of), 0..24)
}

fn names() -> impl Strategy<Value = Vec<String>> {
    proptest::collection::vec("[A-Za-z][A-Za-z0-9_]{0,30}", 0..12)
}

fn field_types() -> impl Strategy<Value = Vec<FieldType>> {
    proptest::collection::vec(
        prop_oneof![
            8 => data_type().prop_map(FieldType::Known),
            1 => Just(FieldType::NotFound),
            1 => Just(FieldType::InUse),
        ],
        0..12,
    )
}

fn text(v: u16) -> BoxedStrategy<TextMessage> {
    let level = any::<u8>().prop_map(MessageLevel::from_u8);
    if v == PROTOCOL_V2 {
        // v2 carries each string behind a u8 length.
        ("\\PC{0,60}", "\\PC{0,20}", level)
            .prop_filter("fits a u8 length", |(m, s, _)| {
                m.len() < 256 && s.len() < 256
            })
            .prop_map(|(message, source, level)| TextMessage {
                message,
                source,
                level,
            })
            .boxed()
    } else {
        ("\\PC{0,200}", level)
            .prop_map(|(message, level)| TextMessage {
                message,
                source: String::new(),
                level,
            })
            .boxed()
    }
}

fn payload() -> impl Strategy<Value = Bytes> {
    proptest::collection::vec(any::<u8>(), 0..200).prop_map(Bytes::from)
}

fn client_package(v: u16) -> BoxedStrategy<ClientPackage> {
    let freq = if v == PROTOCOL_V2 {
        any::<f64>()
            .prop_filter("comparable", |f| !f.is_nan())
            .boxed()
    } else {
        Just(125.0).boxed() // v1 has no frequency field; the decoder reports 125 Hz
    };
    prop_oneof![
        any::<u16>().prop_map(ClientPackage::RequestProtocolVersion),
        Just(ClientPackage::GetUrControlVersion),
        (freq, names()).prop_map(|(frequency_hz, names)| ClientPackage::SetupOutputs {
            frequency_hz,
            names
        }),
        names().prop_map(|names| ClientPackage::SetupInputs { names }),
        Just(ClientPackage::Start),
        Just(ClientPackage::Pause),
        (any::<u8>(), payload())
            .prop_map(|(recipe_id, payload)| ClientPackage::Data { recipe_id, payload }),
        text(v).prop_map(ClientPackage::TextMessage),
    ]
    .boxed()
}

fn server_package(v: u16) -> BoxedStrategy<ServerPackage> {
    let v2 = v == PROTOCOL_V2;
    let out_id = if v2 {
        any::<u8>().prop_map(Some).boxed()
    } else {
        Just(None).boxed()
    };
    let data_id = if v2 {
        any::<u8>().prop_map(Some).boxed()
    } else {
        Just(None).boxed()
    };
    prop_oneof![
        any::<bool>().prop_map(|accepted| ServerPackage::ProtocolVersion { accepted }),
        any::<[u32; 4]>().prop_map(|[major, minor, bugfix, build]| {
            ServerPackage::UrControlVersion {
                major,
                minor,
                bugfix,
                build,
            }
        }),
        (out_id, field_types())
            .prop_map(|(recipe_id, types)| ServerPackage::OutputSetup { recipe_id, types }),
        (any::<u8>(), field_types())
            .prop_map(|(recipe_id, types)| ServerPackage::InputSetup { recipe_id, types }),
        any::<bool>().prop_map(|accepted| ServerPackage::StartReply { accepted }),
        any::<bool>().prop_map(|accepted| ServerPackage::PauseReply { accepted }),
        (data_id, payload())
            .prop_map(|(recipe_id, payload)| ServerPackage::Data { recipe_id, payload }),
        text(v).prop_map(ServerPackage::TextMessage),
    ]
    .boxed()
}

/// Frame `bytes` fed in chunks cut at `cuts` (fractions of the length).
fn frames_split(bytes: &[u8], cuts: &[f64]) -> Vec<Frame> {
    let mut points: Vec<usize> = cuts
        .iter()
        .map(|c| ((c * bytes.len() as f64) as usize).min(bytes.len()))
        .collect();
    points.push(0);
    points.push(bytes.len());
    points.sort_unstable();
    let mut d = FrameDecoder::new();
    let mut out = Vec::new();
    for w in points.windows(2) {
        d.push(&bytes[w[0]..w[1]]);
        while let Some(f) = d.next_frame().expect("valid stream") {
            out.push(f);
        }
    }
    assert_eq!(d.buffered(), 0);
    out
}

fn cuts() -> impl Strategy<Value = Vec<f64>> {
    proptest::collection::vec(0.0..1.0f64, 0..6)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn client_packages_round_trip(
        (v, pkgs) in version().prop_flat_map(|v| (Just(v), proptest::collection::vec(client_package(v), 1..5))),
        cuts in cuts(),
    ) {
        let mut bytes = BytesMut::new();
        for p in &pkgs {
            p.encode(v, &mut bytes).unwrap();
        }
        let frames = frames_split(&bytes, &cuts);
        prop_assert_eq!(frames.len(), pkgs.len());
        for (f, p) in frames.iter().zip(&pkgs) {
            prop_assert_eq!(&ClientPackage::decode(f, v).unwrap(), p);
        }
    }

    #[test]
    fn server_packages_round_trip(
        (v, pkgs) in version().prop_flat_map(|v| (Just(v), proptest::collection::vec(server_package(v), 1..5))),
        cuts in cuts(),
    ) {
        let mut bytes = BytesMut::new();
        for p in &pkgs {
            p.encode(v, &mut bytes).unwrap();
        }
        let frames = frames_split(&bytes, &cuts);
        prop_assert_eq!(frames.len(), pkgs.len());
        for (f, p) in frames.iter().zip(&pkgs) {
            prop_assert_eq!(&ServerPackage::decode(f, v).unwrap(), p);
        }
    }

    /// Every data type, in recipes of any shape, inside data packages in both directions.
    #[test]
    fn data_values_round_trip_in_both_directions(v in version(), vals in values(), id in any::<u8>()) {
        let types: Vec<DataType> = vals.iter().map(Value::data_type).collect();
        let mut enc = BytesMut::new();
        encode_values(&vals, &mut enc);
        prop_assert_eq!(enc.len(), types.iter().map(|t| t.size()).sum::<usize>());
        let same_bits = |got: &[Value]| {
            let mut again = BytesMut::new();
            encode_values(got, &mut again);
            again == enc // bit-exact, so NaNs compare too
        };

        // Controller → client.
        let mut bytes = BytesMut::new();
        ServerPackage::Data { recipe_id: (v == PROTOCOL_V2).then_some(id), payload: enc.clone().freeze() }
            .encode(v, &mut bytes).unwrap();
        let f = frames_split(&bytes, &[]);
        let ServerPackage::Data { payload, .. } = ServerPackage::decode(&f[0], v).unwrap() else {
            panic!("not data")
        };
        let got = decode_values(&types, &payload).unwrap();
        prop_assert!(same_bits(&got));

        // Client → controller.
        let mut bytes = BytesMut::new();
        ClientPackage::Data { recipe_id: id, payload: enc.clone().freeze() }.encode(v, &mut bytes).unwrap();
        let f = frames_split(&bytes, &[]);
        let ClientPackage::Data { payload, recipe_id } = ClientPackage::decode(&f[0], v).unwrap() else {
            panic!("not data")
        };
        prop_assert_eq!(recipe_id, id);
        let got = decode_values(&types, &payload).unwrap();
        prop_assert!(same_bits(&got));
        for (a, b) in got.iter().zip(&vals) {
            prop_assert_eq!(a.data_type(), b.data_type());
        }
    }

    /// Arbitrary bytes, cut anyhow: the framer and every decoder return errors, never panic.
    #[test]
    fn arbitrary_bytes_never_panic(
        bytes in proptest::collection::vec(any::<u8>(), 0..600),
        cuts in cuts(),
        types in proptest::collection::vec(data_type(), 0..8),
    ) {
        let mut d = FrameDecoder::new();
        let mut points: Vec<usize> = cuts.iter().map(|c| (c * bytes.len() as f64) as usize).collect();
        points.extend([0, bytes.len()]);
        points.sort_unstable();
        'outer: for w in points.windows(2) {
            d.push(&bytes[w[0]..w[1]]);
            loop {
                match d.next_frame() {
                    Ok(Some(f)) => {
                        for v in [PROTOCOL_V1, PROTOCOL_V2] {
                            let _ = ServerPackage::decode(&f, v);
                            let _ = ClientPackage::decode(&f, v);
                        }
                        let _ = decode_values(&types, &f.payload);
                    }
                    Ok(None) => break,
                    Err(_) => break 'outer, // size < 3: the stream is unusable, as documented
                }
            }
        }
    }

    /// A frame of any type byte and payload decodes or errors, in both versions.
    #[test]
    fn any_frame_decodes_or_errors(ty in any::<u8>(), payload in payload(), types in proptest::collection::vec(data_type(), 0..8)) {
        let f = Frame { type_byte: ty, payload };
        for v in [PROTOCOL_V1, PROTOCOL_V2] {
            let _ = ServerPackage::decode(&f, v);
            let _ = ClientPackage::decode(&f, v);
        }
        let _ = decode_values(&types, &f.payload);
    }
}

#[test]
fn every_package_type_is_covered_by_the_strategies() {
    // Encoding one of each proves the strategies above reach every variant's code path.
    for v in [PROTOCOL_V1, PROTOCOL_V2] {
        let mut b = BytesMut::new();
        for p in [
            ClientPackage::RequestProtocolVersion(2),
            ClientPackage::GetUrControlVersion,
            ClientPackage::SetupOutputs {
                frequency_hz: 125.0,
                names: vec!["timestamp".into()],
            },
            ClientPackage::SetupInputs {
                names: vec!["input_int_register_24".into()],
            },
            ClientPackage::Start,
            ClientPackage::Pause,
            ClientPackage::Data {
                recipe_id: 1,
                payload: Bytes::from_static(&[0, 0, 0, 1]),
            },
        ] {
            b.clear();
            p.encode(v, &mut b).unwrap();
            let f = frames_split(&b, &[0.5]);
            assert_eq!(ClientPackage::decode(&f[0], v).unwrap(), p);
        }
    }
}
