//! RTDE benchmarks.
//!
//! 1. Decode time of one 500 Hz data package of the rig's output recipe: framing
//!    (`FrameDecoder`), package decode (`ServerPackage::decode`) and typed state
//!    (`StateDecoder::decode`), measured by criterion.
//! 2. End-to-end latency from the simulated controller's sample to the client's typed state,
//!    over loopback TCP: the mock and the client share one system clock, the mock stamps each
//!    sample with its tick time (`timestamp_s` since the mock's start), the client stamps
//!    `t_host_ns` when it has decoded the package. The difference over 2000 samples is printed
//!    as a table (p50, p90, p99, max). It includes the mock's timer wake-up delay (tokio's
//!    timers have 1 ms resolution, so the mock's tick runs up to ~1 ms after its nominal
//!    time, which dominates the p50), the RTDE server's encode and the loopback hop. Decode
//!    itself is the sub-microsecond part measured in (1).

use std::hint::black_box;
use std::time::Duration;

use bytes::BytesMut;
use criterion::{Criterion, criterion_group};
use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use rig::robot::rtde::{RtdeClient, RtdeConfig};
use rig::robot::state::{StateDecoder, output_recipe};
use rig_core::clock::Clock;
use rig_core::rtde::{
    DataType, FrameDecoder, PROTOCOL_V2, ServerPackage, Value, encode_values, fields,
};

fn recipe() -> (Vec<String>, Vec<DataType>) {
    let names = output_recipe();
    let types = names
        .iter()
        .map(|n| fields::output_type(n).expect("rig recipe is valid"))
        .collect();
    (names, types)
}

fn package_bytes(types: &[DataType]) -> BytesMut {
    let values: Vec<Value> = types
        .iter()
        .enumerate()
        .map(|(i, t)| match Value::zero(*t) {
            Value::Double(_) => Value::Double(i as f64 * 0.5),
            Value::Vector6d(_) => Value::Vector6d([0.4, 0.01, 0.2, 3.0, 0.01, 0.0]),
            v => v,
        })
        .collect();
    let mut payload = BytesMut::new();
    encode_values(&values, &mut payload);
    let mut out = BytesMut::new();
    ServerPackage::Data {
        recipe_id: Some(1),
        payload: payload.freeze(),
    }
    .encode(PROTOCOL_V2, &mut out)
    .expect("encodes");
    out
}

fn decode_bench(c: &mut Criterion) {
    let (names, types) = recipe();
    let bytes = package_bytes(&types);
    let dec = StateDecoder::new(&names, &types).expect("decoder");
    let mut g = c.benchmark_group("rtde_decode");
    g.throughput(criterion::Throughput::Bytes(bytes.len() as u64));
    g.bench_function("frame+package+state (rig output recipe)", |b| {
        let mut fd = FrameDecoder::new();
        b.iter(|| {
            fd.push(black_box(&bytes));
            let f = fd.next_frame().expect("frame").expect("whole");
            let ServerPackage::Data { payload, .. } =
                ServerPackage::decode(&f, PROTOCOL_V2).expect("data")
            else {
                unreachable!()
            };
            black_box(dec.decode(&payload, 0).expect("state"))
        })
    });
    let payload = bytes.clone().freeze().slice(4..); // after header and recipe id
    g.bench_function("state only", |b| {
        b.iter(|| black_box(dec.decode(black_box(&payload), 0).expect("state")))
    });
    g.finish();
}

criterion_group!(benches, decode_bench);

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

pub fn latency_table(samples: usize) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(4)
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let clock = Clock::system();
        let mock = Ur5e::start(Ur5eConfig::default(), clock.clone())
            .await
            .expect("mock");
        let snap = mock.snapshot();
        // The mock's time origin on the shared clock.
        let t0_ns = snap.t_ns as f64 - snap.timestamp_s * 1e9;
        let client = RtdeClient::connect(RtdeConfig::new(mock.rtde_addr()), clock.clone())
            .await
            .expect("client");
        let mut rx = client.samples();
        // Skip the first packages (connection warm-up).
        for _ in 0..50 {
            let _ = rx.recv().await;
        }
        let mut lat_us = Vec::with_capacity(samples);
        while lat_us.len() < samples {
            match tokio::time::timeout(Duration::from_secs(2), rx.recv()).await {
                Ok(Ok(s)) => {
                    let sampled_ns = t0_ns + s.timestamp_s * 1e9;
                    lat_us.push((s.t_host_ns as f64 - sampled_ns) * 1e-3);
                }
                Ok(Err(_)) => continue, // lagged: skip
                Err(_) => panic!("stream stopped"),
            }
        }
        lat_us.sort_by(|a, b| a.total_cmp(b));
        let stats = client.stats();
        println!();
        println!("RTDE end-to-end latency, mock sample -> typed RobotState (loopback, 500 Hz)");
        println!("  samples   p50 µs   p90 µs   p99 µs   max µs");
        println!(
            "  {:7}  {:7.1}  {:7.1}  {:7.1}  {:7.1}",
            lat_us.len(),
            percentile(&lat_us, 0.5),
            percentile(&lat_us, 0.9),
            percentile(&lat_us, 0.99),
            lat_us[lat_us.len() - 1]
        );
        println!(
            "  (data packages {}, malformed {}, connections {})",
            stats.data_packages, stats.malformed, stats.connections
        );
        println!();
        client.shutdown().await;
        mock.shutdown().await;
    });
}
