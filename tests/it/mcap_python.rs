//! A reader no one here wrote: the PyPI `mcap` package (with `mcap-protobuf-support`) reads
//! recorded trajectory files through their summary and index (chunk indexes, statistics, CRCs
//! validated), decodes every message with the file's own protobuf descriptors, and finds every
//! channel with the expected message count and schema name, including the simulator's
//! true wrench (`/sim/true_wrench`, `rig.TrueWrench`, one message per frame) in a trajectory
//! recorded as the simulated rig does, and no such messages in one recorded as a lab rig does.
//! Runs `$RIG_PYTHON` (default `python3`); `bash scripts/test` creates `.venv` with the package
//! and sets it. Fails (never skips) when the package is missing.

use std::collections::BTreeMap;
use std::process::Command;

use rig::record::channels::TOPIC_TRUTH;
use rig::record::synthetic::{SyntheticSpec, record_one};
use rig::record::{
    CHANNELS, Manifest, Recorder, RecorderConfig, SensorInfo, final_name, read_file,
};

#[test]
fn python_mcap_reads_every_channel_with_the_expected_counts() {
    let dir = tempfile::tempdir().unwrap();
    // (trajectory, with simulator truth)
    let trajs = [("p0-d0-a0", false), ("p0-d0-a30", true)];
    let ids: Vec<String> = trajs.iter().map(|(id, _)| (*id).to_owned()).collect();
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let manifest = Manifest::new(
            "synthetic",
            SensorInfo {
                id: "sim-source".into(),
                role: "source".into(),
            },
            serde_json::json!({"synthetic": true}),
            serde_json::json!({"max_loads": [25.0, 25.0, 35.0, 250.0, 250.0, 250.0]}),
            &ids,
        );
        let rec = Recorder::start(dir.path(), manifest, RecorderConfig::default()).unwrap();
        for (id, truth) in trajs {
            let spec = SyntheticSpec {
                drop_frames: vec![2],
                truth,
                ..Default::default()
            };
            record_one(&rec, id, &spec).await.unwrap();
        }
        rec.close().await.unwrap();
    });

    let mut expected = BTreeMap::new();
    for (id, truth) in trajs {
        let c = read_file(&dir.path().join(final_name(id))).unwrap();
        // Readers list only the topics that hold messages: a lab recording's truth channel is
        // declared but empty.
        let counts: BTreeMap<&str, u64> = CHANNELS
            .iter()
            .map(|(topic, _)| (*topic, c.counts.of_topic(topic)))
            .filter(|(_, n)| *n > 0)
            .collect();
        let schemas: BTreeMap<&str, &str> = CHANNELS
            .iter()
            .filter(|(topic, _)| counts.contains_key(topic))
            .map(|(topic, schema)| (*topic, *schema))
            .collect();
        // The real numbers, so a reader that sees nothing cannot pass.
        assert_eq!(counts["/camera/image"], 12);
        assert_eq!(counts["/ft/wrench"], 401);
        if truth {
            assert_eq!(
                counts[TOPIC_TRUTH], 12,
                "one true wrench per recorded frame"
            );
            assert_eq!(schemas[TOPIC_TRUTH], "rig.TrueWrench");
        } else {
            assert!(!counts.contains_key(TOPIC_TRUTH));
        }
        expected.insert(
            final_name(id),
            serde_json::json!({ "counts": counts, "schemas": schemas }),
        );
    }
    let python = std::env::var("RIG_PYTHON").unwrap_or_else(|_| "python3".into());
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python/mcap_check.py");
    let out = Command::new(&python)
        .arg(script)
        .arg(dir.path())
        .arg(serde_json::to_string(&expected).unwrap())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}; run `bash scripts/test`"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "python mcap reader failed (interpreter {python}; if the `mcap` package is missing, run \
         `bash scripts/test`, which installs tests/python/requirements.txt into .venv):\n{stdout}\n{stderr}"
    );
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 2, "{stdout}");
    // What the Python reader itself counted on the truth channel.
    assert!(
        lines[1].starts_with("p0-d0-a30.mcap:") && lines[1].contains("\"/sim/true_wrench\": 12"),
        "{stdout}"
    );
    assert!(!lines[0].contains("/sim/true_wrench"), "{stdout}");
}
