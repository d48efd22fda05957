//! Parse throughput of each F/T front end's core, in samples per second, against the rate the
//! real device delivers (serial controller ≥1 kHz, Net F/T 7 kHz, DAQ 1 kHz).
//!
//! Each case parses a buffer of 10 000 encoded records and converts them to a wrench (counts /
//! CPF for the controller and Net F/T; temperature compensation and F = M·(V − bias) for the
//! DAQ). After criterion's own report, a summary line per front end gives samples/s and the
//! headroom over the real rate.

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, Throughput, criterion_group};
use rig_core::ft::NANO17_SI_25_MAX;
use rig_core::ft::cal::Calibration;
use rig_core::ft::daq::{DaqFrame, DaqParser};
use rig_core::ft::netft::{FACTORY_COUNTS_PER_FORCE, FACTORY_COUNTS_PER_TORQUE, RdtRecord};
use rig_core::ft::sequence::SequenceTracker;
use rig_core::ft::serial::{
    CountsRecord, DEFAULT_COUNTS_PER_FORCE as CPF, DEFAULT_COUNTS_PER_TORQUE as CPT, OutputMode,
    SerialEvent, SerialParser, plausible_counts,
};

const N: usize = 10_000;
const CAL: &str = include_str!("../../tests/data/nano17_useraxis.cal");

fn counts(k: usize) -> [i32; 6] {
    let k = k as i32;
    [
        k % 300,
        -(k % 200),
        -2000 - k % 500,
        k % 4000,
        -(k % 3000),
        50,
    ]
}

fn serial_bytes(mode: OutputMode) -> Vec<u8> {
    let mut b = Vec::new();
    if mode == OutputMode::Binary {
        b.extend(b"QS\r\n");
    }
    for k in 0..N {
        let r = CountsRecord {
            status: 0,
            counts: counts(k),
        };
        match mode {
            OutputMode::Ascii => b.extend(r.encode_ascii()),
            OutputMode::Binary => b.extend(r.encode_binary()),
        }
    }
    b
}

fn parse_serial(bytes: &[u8], mode: OutputMode) -> f64 {
    let mut p = SerialParser::new(mode, plausible_counts(&NANO17_SI_25_MAX, CPF, CPT, 1.5));
    let mut acc = 0.0;
    for c in bytes.chunks(4096) {
        p.push(c);
        while let Some(e) = p.next_event() {
            if let SerialEvent::Record(r) = e {
                acc += r.to_wrench(CPF, CPT)[2];
            }
        }
    }
    acc
}

fn rdt_datagrams() -> Vec<[u8; 36]> {
    (0..N)
        .map(|k| {
            RdtRecord {
                rdt_sequence: k as u32,
                ft_sequence: k as u32,
                status: 0,
                counts: counts(k),
            }
            .encode()
        })
        .collect()
}

fn parse_rdt(d: &[[u8; 36]]) -> f64 {
    let mut t = SequenceTracker::new();
    let mut acc = 0.0;
    for g in d {
        if let Ok(r) = RdtRecord::decode(g) {
            t.observe(r.rdt_sequence);
            acc += r.to_wrench(FACTORY_COUNTS_PER_FORCE, FACTORY_COUNTS_PER_TORQUE)[2];
        }
    }
    acc
}

fn daq_bytes() -> Vec<u8> {
    let mut b = Vec::new();
    for k in 0..N {
        let c = counts(k);
        b.extend(
            DaqFrame {
                sequence: k as u32,
                device_time_us: k as u32 * 1000,
                gauges_uv: c.map(|x| x * 100),
                thermistor_uv: 1_273_400,
                status: 0,
            }
            .encode(),
        );
    }
    b
}

fn parse_daq(bytes: &[u8], cal: &Calibration) -> f64 {
    let mut p = DaqParser::new();
    let bias = [0.1; 6];
    let mut acc = 0.0;
    for c in bytes.chunks(4096) {
        p.push(c);
        while let Some(f) = p.next_frame() {
            let (g, _) = cal.compensate(&f.gauges_v(), f.thermistor_v());
            acc += cal.wrench(&g, &bias)[2];
        }
    }
    acc
}

fn bench(c: &mut Criterion) {
    let ascii = serial_bytes(OutputMode::Ascii);
    let binary = serial_bytes(OutputMode::Binary);
    let rdt = rdt_datagrams();
    let daq = daq_bytes();
    let cal = Calibration::parse(CAL).expect("test calibration parses");
    let mut g = c.benchmark_group("ft_parse");
    g.throughput(Throughput::Elements(N as u64));
    g.bench_function("serial_ascii", |b| {
        b.iter(|| parse_serial(black_box(&ascii), OutputMode::Ascii))
    });
    g.bench_function("serial_binary", |b| {
        b.iter(|| parse_serial(black_box(&binary), OutputMode::Binary))
    });
    g.bench_function("netft_rdt", |b| b.iter(|| parse_rdt(black_box(&rdt))));
    g.bench_function("daq_calibrated", |b| {
        b.iter(|| parse_daq(black_box(&daq), &cal))
    });
    g.finish();
}

/// Samples per second of `f` over `reps` passes of N samples.
fn rate(mut f: impl FnMut() -> f64) -> f64 {
    let reps = 50;
    let t = Instant::now();
    for _ in 0..reps {
        black_box(f());
    }
    (reps * N) as f64 / t.elapsed().as_secs_f64()
}

pub fn summary() {
    let ascii = serial_bytes(OutputMode::Ascii);
    let binary = serial_bytes(OutputMode::Binary);
    let rdt = rdt_datagrams();
    let daq = daq_bytes();
    let cal = Calibration::parse(CAL).expect("test calibration parses");
    println!("\nF/T parse throughput against the real device rate:");
    for (name, real_hz, r) in [
        (
            "serial ASCII (controller)",
            1000.0,
            rate(|| parse_serial(&ascii, OutputMode::Ascii)),
        ),
        (
            "serial binary (controller)",
            1000.0,
            rate(|| parse_serial(&binary, OutputMode::Binary)),
        ),
        ("Net F/T RDT", 7000.0, rate(|| parse_rdt(&rdt))),
        (
            "DAQ gauges + calibration",
            1000.0,
            rate(|| parse_daq(&daq, &cal)),
        ),
    ] {
        println!(
            "  {name:<28} {:>12.0} samples/s  = {:>8.0} × the real {real_hz:.0} Hz",
            r,
            r / real_hz
        );
    }
}

criterion_group!(benches, bench);
