//! Interoperability with a client no one here wrote: PyPI `ur-rtde` (1.6.5) against
//! `rig-mock ur5e` on port 30004.
//!
//! Needs:
//! - the mock binary, built with `cargo build -p hardware-mocks --bins` (a test of the root
//!   crate cannot build another package's binary, so it looks for `rig-mock` next to the test
//!   executable's directory, `target/<profile>/rig-mock`);
//! - `pip install ur-rtde==1.6.5` (`.ci/run` installs it).
//!
//! Missing either is a failure with that instruction, never a silent skip.
//!
//! Port 30004 is hard-coded in ur_rtde. This file holds exactly one test, and cargo runs test
//! binaries one after another, so nothing else in the workspace binds 30004 at the same time
//! (every other test of the mock uses ephemeral ports).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use bytes::BytesMut;
use rig_core::rtde::{
    ClientPackage, DataType, FieldType, FrameDecoder, PROTOCOL_V2, ServerPackage, Value,
    decode_values,
};

/// Home pose given to the mock; ur_rtde must read it back exactly.
const HOME: [f64; 6] = [0.4123, -0.1877, 0.2531, 0.0123, 3.1002, -0.0456];

fn rig_mock_path() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/ur_rtde_interop-<hash> → target/<profile>/rig-mock
    let profile_dir = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("test executable lives in target/<profile>/deps");
    let bin = profile_dir.join(format!("rig-mock{}", std::env::consts::EXE_SUFFIX));
    assert!(
        bin.exists(),
        "{} not found: run `cargo build -p hardware-mocks --bins` first (same profile as the tests)",
        bin.display()
    );
    bin
}

/// The mock process and its log lines; SIGTERM (a clean shutdown) on drop, SIGKILL if it
/// lingers.
struct Mock(Child, std::sync::mpsc::Receiver<String>);

impl Mock {
    /// The mock's own count of data packages sent on RTDE connection `conn`, and their rate,
    /// from the line it logs when that connection closes.
    fn packages_sent(&self, conn: u32) -> (u64, f64) {
        let deadline = Instant::now() + Duration::from_secs(10);
        let tag = format!("conn={conn} ");
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            let Ok(line) = self.1.recv_timeout(left) else {
                break;
            };
            let line = strip_ansi(&line);
            if !(line.contains("RTDE client disconnected") && line.contains(&tag)) {
                continue;
            }
            let field = |key: &str| -> Option<String> {
                let rest = &line[line.find(key)? + key.len()..];
                Some(rest.split_whitespace().next()?.trim_matches('"').to_owned())
            };
            let n = field("data_packages=").and_then(|v| v.parse().ok());
            let hz = field("rate_hz=").and_then(|v| v.parse().ok());
            if let (Some(n), Some(hz)) = (n, hz) {
                return (n, hz);
            }
            panic!("cannot read the package count from the mock's line: {line}");
        }
        panic!("the mock never logged the end of RTDE connection {conn}");
    }
}

/// Terminal colour codes, in case the log writer adds them despite NO_COLOR.
fn strip_ansi(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

impl Drop for Mock {
    fn drop(&mut self) {
        let pid = self.0.id().to_string();
        let _ = Command::new("kill").args(["-TERM", &pid]).status();
        let deadline = Instant::now() + Duration::from_secs(3);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_mock() -> Mock {
    let pose = HOME.map(|x| x.to_string()).join(",");
    let mut child = Command::new(rig_mock_path())
        .args([
            "ur5e",
            "--rtde-port",
            "30004",
            "--dashboard-port",
            "0",
            "--script-port",
            "0",
            "--robot-mode",
            "running",
            "--home-pose",
            &pose,
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .env("NO_COLOR", "1")
        .spawn()
        .expect("start rig-mock");
    let stdout = child.stdout.take().unwrap();
    let stderr = child.stderr.take().unwrap();
    let (log_tx, log_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            eprintln!("rig-mock: {line}");
            let _ = log_tx.send(line);
        }
    });
    let mock = Mock(child, log_rx);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(line);
    });
    let line = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("rig-mock did not report ready within 20 s");
    assert!(
        line.starts_with("ur5e ready rtde=127.0.0.1:30004 "),
        "unexpected first line from rig-mock: {line:?} (is port 30004 taken?)"
    );
    mock
}

/// The Python with the interop packages: `RIG_PYTHON` (scripts/test points it at the project's
/// .venv), else `python3` on the PATH.
fn python() -> String {
    std::env::var("RIG_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

fn require_ur_rtde() {
    let ok = Command::new(python())
        .args(["-c", "import rtde_receive, rtde_io"])
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    assert!(
        ok,
        "{} cannot import ur_rtde: run the tests with `bash scripts/test` (it installs \
         tests/python/requirements.txt into .venv), or pip install ur-rtde==1.6.5",
        python()
    );
}

/// A few lines of blocking RTDE on the codec: read one data package of `names`.
fn read_outputs_once(names: &[&str]) -> Vec<Value> {
    let mut sock = TcpStream::connect("127.0.0.1:30004").expect("connect to the mock");
    sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut dec = FrameDecoder::new();
    let send = |sock: &mut TcpStream, p: ClientPackage| {
        let mut out = BytesMut::new();
        p.encode(PROTOCOL_V2, &mut out).unwrap();
        sock.write_all(&out).unwrap();
    };
    let mut recv = |sock: &mut TcpStream| -> ServerPackage {
        loop {
            if let Some(f) = dec.next_frame().unwrap() {
                let p = ServerPackage::decode(&f, PROTOCOL_V2).unwrap();
                if !matches!(p, ServerPackage::TextMessage(_)) {
                    return p;
                }
                continue;
            }
            let mut buf = [0u8; 4096];
            let n = sock.read(&mut buf).expect("reply from the mock");
            assert!(n > 0, "mock closed the connection");
            dec.push(&buf[..n]);
        }
    };
    send(
        &mut sock,
        ClientPackage::RequestProtocolVersion(PROTOCOL_V2),
    );
    assert_eq!(
        recv(&mut sock),
        ServerPackage::ProtocolVersion { accepted: true }
    );
    send(
        &mut sock,
        ClientPackage::SetupOutputs {
            frequency_hz: 500.0,
            names: names.iter().map(|s| s.to_string()).collect(),
        },
    );
    let types: Vec<DataType> = match recv(&mut sock) {
        ServerPackage::OutputSetup { types, .. } => types
            .into_iter()
            .map(|t| match t {
                FieldType::Known(t) => t,
                other => panic!("output recipe refused: {other:?}"),
            })
            .collect(),
        other => panic!("{other:?}"),
    };
    send(&mut sock, ClientPackage::Start);
    loop {
        match recv(&mut sock) {
            ServerPackage::StartReply { accepted } => assert!(accepted),
            ServerPackage::Data { payload, .. } => return decode_values(&types, &payload).unwrap(),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn ur_rtde_streams_500_hz_reads_state_and_writes_a_register() {
    require_ur_rtde();
    let mock = start_mock();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python/ur_rtde_check.py");
    let (register, value) = (18, 424242);
    let out = Command::new(python())
        .arg(script)
        .args(["--seconds", "5", "--register", &register.to_string()])
        .args(["--value", &value.to_string()])
        .stderr(Stdio::inherit())
        .output()
        .expect("run the interop Python");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "ur_rtde_check.py failed: {stdout}");
    let r: serde_json::Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("bad JSON from ur_rtde_check.py ({e}): {stdout}"));
    eprintln!("ur_rtde results: {r}");

    // Rate, from the sender: the mock counts every data package it wrote to ur_rtde's
    // connection (the first one) over TCP, which delivers them all or drops the link.
    let (sent, rate_hz) = mock.packages_sent(1);
    assert!(
        sent >= 2475 && (rate_hz - 500.0).abs() <= 5.0,
        "mock sent {sent} data packages at {rate_hz} Hz to ur_rtde in ~5 s: {r}"
    );
    assert_eq!(r["connected_while_streaming"], true, "{r}");
    // And from the receiver: ur_rtde saw controller timestamps on the 2 ms grid spanning the
    // whole 5 s. (A Python poller cannot see every package: several may arrive between two
    // polls when the machine is busy, so count distinct ones only as a floor.)
    let span = r["last_timestamp"].as_f64().unwrap() - r["first_timestamp"].as_f64().unwrap();
    assert!(
        span >= 4.9,
        "ur_rtde saw timestamps over {span} s only: {r}"
    );
    let steps = r["steps"].as_u64().unwrap();
    let on_grid = r["steps_on_2ms_grid"].as_u64().unwrap();
    assert_eq!(on_grid, steps, "timestamp steps off the 2 ms grid: {r}");
    assert!(
        r["distinct_timestamps"].as_u64().unwrap() >= 500,
        "ur_rtde's state barely changed: {r}"
    );
    let pose: Vec<f64> = serde_json::from_value(r["actual_tcp_pose"].clone()).unwrap();
    for (got, want) in pose.iter().zip(HOME) {
        assert!((got - want).abs() < 1e-9, "pose {pose:?} != home {HOME:?}");
    }
    assert_eq!(pose.len(), 6);
    assert_eq!(r["robot_mode"], 7, "{r}");
    assert_eq!(r["safety_mode"], 1, "{r}");
    assert_eq!(r["set_input_int_register"], true, "{r}");

    // The mock now reports what ur_rtde wrote.
    let reg = format!("input_int_register_{register}");
    let vals = read_outputs_once(&[&reg, "robot_mode"]);
    assert_eq!(vals[0], Value::Int32(value));
    assert_eq!(vals[1], Value::Int32(7));
}
