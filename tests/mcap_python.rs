//! A reader no one here wrote: the PyPI `mcap` package reads recorded trajectory files and finds
//! every channel with the expected message count. Runs `$RIG_PYTHON` (default `python3`);
//! `bash scripts/test` creates `.venv` with the package and sets it. Fails (never skips) when the
//! package is missing.

use std::collections::BTreeMap;
use std::process::Command;

use rig::record::synthetic::{SyntheticSpec, record_dataset};
use rig::record::{CHANNELS, final_name, read_file};

#[test]
fn python_mcap_reads_every_channel_with_the_expected_counts() {
    let dir = tempfile::tempdir().unwrap();
    let ids: Vec<String> = vec!["p0-d0-a0".into(), "p0-d0-a30".into()];
    let spec = SyntheticSpec {
        drop_frames: vec![2],
        ..Default::default()
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(record_dataset(dir.path(), &ids, &spec))
        .unwrap();

    let mut expected = BTreeMap::new();
    for id in &ids {
        let c = read_file(&dir.path().join(final_name(id))).unwrap();
        let per_topic: BTreeMap<&str, u64> = CHANNELS
            .iter()
            .map(|(topic, _, _)| (*topic, c.counts.of_topic(topic)))
            // A synthetic dataset has no simulator truth: that channel holds nothing.
            .filter(|(topic, n)| *n > 0 || *topic != rig::record::channels::TOPIC_TRUTH)
            .collect();
        // The real numbers, so a reader that sees nothing cannot pass.
        assert_eq!(per_topic["/camera/image"], 12);
        assert_eq!(per_topic["/ft/wrench"], 401);
        expected.insert(final_name(id), per_topic);
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
    assert_eq!(stdout.lines().count(), 2, "{stdout}");
}
