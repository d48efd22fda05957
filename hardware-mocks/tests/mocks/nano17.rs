//! The simulated Nano17 front ends, spoken to at the byte level (no rig code).

use std::io::{BufRead, Read, Write};
use std::sync::Arc;
use std::time::Duration;

use hardware_mocks::nano17::netft::{NetFtMock, NetFtMockConfig};
use hardware_mocks::nano17::serial::{SerialControllerMock, SerialMockConfig};
use hardware_mocks::nano17::{SIM_BIAS_V, SensorModel};
use rig_core::clock::Clock;
use rig_core::ft::netft::{RdtCommand, RdtRecord, RdtRequest};
use rig_core::ft::serial::{OutputMode, SerialEvent, SerialParser};
use rig_core::wrench::Wrench;

const LOAD: [f64; 6] = [1.0, -2.0, -8.0, 10.0, -20.0, 5.0];

#[test]
fn nano17_model_goes_through_the_inverse_calibration() {
    let mut m = SensorModel::nano17(1);
    m.noise_std = [0.0; 6];
    let meas = m.measure(&LOAD, false);
    assert_eq!(meas.saturated_gauges, 0);
    // Resolving the gauges gives the load plus the offset's wrench, M · bias.
    let offset = m.calibration.wrench(&SIM_BIAS_V, &[0.0; 6]);
    let w = m.resolve(&meas);
    for i in 0..6 {
        assert!((w[i] - LOAD[i] - offset[i]).abs() < 1e-9, "{w:?}");
    }
    // The gauges themselves are not the compensated ones (the thermistor is off T0).
    let clean = m.calibration.gauges_for(&LOAD);
    assert!((meas.gauges_v[0] - clean[0] - SIM_BIAS_V[0]).abs() > 1e-6);
    let sat = m.measure(&LOAD, true);
    assert_eq!(sat.saturated_gauges, 0x3f);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nano17_serial_controller_answers_commands_on_its_pty() {
    let clock = Clock::system();
    let mock = SerialControllerMock::start(
        SerialMockConfig::default(),
        SensorModel::nano17(2),
        Arc::new(|_t| Wrench::from_array(LOAD)),
        clock,
    )
    .unwrap();
    let path = mock.path().to_owned();
    let events = tokio::task::spawn_blocking(move || {
        let mut f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .unwrap();
        let mut p = SerialParser::new(OutputMode::Ascii, [32767; 6]);
        let mut out = Vec::new();
        for cmd in [&b"CD A\r"[..], b"CD R\r", b"SB\r", b"QR\r", b"FOO\r"] {
            f.write_all(cmd).unwrap();
            let mut buf = [0u8; 256];
            loop {
                let n = f.read(&mut buf).unwrap();
                p.push(&buf[..n]);
                let mut prompt = false;
                while let Some(e) = p.next_event() {
                    if e == SerialEvent::Prompt {
                        prompt = true;
                    } else {
                        out.push(e);
                    }
                }
                if prompt {
                    break;
                }
            }
        }
        out
    })
    .await
    .unwrap();
    let texts: Vec<String> = events
        .iter()
        .filter_map(|e| {
            if let SerialEvent::Text(t) = e {
                Some(t.clone())
            } else {
                None
            }
        })
        .collect();
    assert_eq!(texts, ["CD A", "CD R", "SB", "QR", "FOO", "Error"]);
    let recs: Vec<_> = events
        .iter()
        .filter_map(|e| {
            if let SerialEvent::Record(r) = e {
                Some(*r)
            } else {
                None
            }
        })
        .collect();
    assert_eq!(recs.len(), 1);
    // After SB the constant load reads as zero, within noise (σ = 1/160 N = 2 counts).
    assert!(recs[0].counts.iter().all(|c| c.abs() < 20), "{recs:?}");
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nano17_netft_streams_the_requested_count_from_sequence_one() {
    let clock = Clock::system();
    let mock = NetFtMock::start(
        NetFtMockConfig {
            rate_hz: 7000.0,
            ..NetFtMockConfig::default()
        },
        SensorModel::nano17(3),
        Arc::new(|_t| Wrench::from_array(LOAD)),
        clock,
    )
    .await
    .unwrap();
    let sock = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    sock.connect(mock.addr()).await.unwrap();
    sock.send(&[0x43, 0x21, 0, 2, 0, 0, 0, 5]).await.unwrap(); // bad header: ignored
    let req = RdtRequest {
        command: RdtCommand::StartRealtime,
        sample_count: 10,
    };
    sock.send(&req.encode()).await.unwrap();
    let mut seqs = Vec::new();
    let mut buf = [0u8; 128];
    while seqs.len() < 10 {
        let n = tokio::time::timeout(Duration::from_secs(1), sock.recv(&mut buf))
            .await
            .unwrap()
            .unwrap();
        let r = RdtRecord::decode(&buf[..n]).unwrap();
        let w = r.to_wrench(1e6, 1e3);
        // Untared: load plus the simulated offset (Fz offset about +1.4 N), within noise.
        assert!((w[2] - (LOAD[2] + 1.42)).abs() < 0.1, "{w:?}");
        seqs.push(r.rdt_sequence);
    }
    assert_eq!(seqs, (1..=10).collect::<Vec<u32>>());
    assert!(
        tokio::time::timeout(Duration::from_millis(50), sock.recv(&mut buf))
            .await
            .is_err(),
        "more than 10 records"
    );
    mock.shutdown().await;
}

#[test]
fn nano17_rig_mock_binary_prints_the_pty_path() {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_rig-mock"))
        .args(["nano17-serial", "--rate-hz", "1000"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let _ = child.kill();
    let _ = child.wait();
    let path = line
        .trim()
        .strip_prefix("nano17-serial ready pty=")
        .unwrap_or_else(|| panic!("{line:?}"));
    assert!(path.starts_with("/dev/"), "{path}");
}
