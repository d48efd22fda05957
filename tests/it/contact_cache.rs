//! Simulate once, render per sensor, through `rig run`: a second sensor with the same gel
//! replays the contact tapes the first sensor's run left in the contact cache and renders its
//! own optics; a sensor with another gel solves its own contact.

use std::path::{Path, PathBuf};
use std::process::Command;

use rig::record::reader::{Message, messages};

use crate::common;

/// A shipped simulated config narrowed to the centre point, 0.6 mm and two directions, with
/// `edits` applied, written as `dir/<out_name>.toml`.
fn narrowed(dir: &Path, shipped: &str, out_name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/rig-configs")).join(shipped);
    let mut text = std::fs::read_to_string(path).unwrap();
    let narrow = [
        (
            "contact_points_mm = [[0.0, 0.0], [-3.0, -2.0], [3.0, -2.0], [-3.0, 2.0], [3.0, 2.0]]",
            "contact_points_mm = [[0.0, 0.0]]",
        ),
        ("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.6]"),
        (
            "directions_deg = [0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0, 210.0, 240.0, 270.0, 300.0, 330.0]",
            "directions_deg = [0.0, 90.0]",
        ),
    ];
    for (from, to) in narrow.iter().chain(edits) {
        assert!(text.contains(from), "{shipped} has no {from:?}");
        text = text.replace(from, to);
    }
    let out = dir.join(format!("{out_name}.toml"));
    std::fs::write(&out, text).unwrap();
    out
}

/// The run's contact-cache line: (replayed, of, tapes found, solved, left, new tapes).
fn cache_line(output: &str) -> [u64; 6] {
    let line = output
        .lines()
        .find(|l| l.starts_with("contact cache: "))
        .unwrap_or_else(|| panic!("no contact cache line in:\n{output}"));
    let numbers: Vec<u64> = line
        .split(|c: char| !c.is_ascii_digit())
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    numbers[..6].try_into().unwrap_or_else(|_| panic!("{line}"))
}

/// Runs the plan of `config` with the cone into `out`, with the contact cache `cache`.
fn record(config: &Path, out: &Path, cache: &Path) -> String {
    let _rig = common::one_rig_at_a_time();
    let run = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cone", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .arg("--contact-cache")
        .arg(cache)
        .args(["--speed-factor", "20"])
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", common::output_text(&run));
    // The run's summary (stdout) and its log (stderr).
    format!(
        "{}{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    )
}

/// Per trajectory file: the largest |Fz| of the simulator's true wrench, and the mean of the
/// first frame's pixels (its colour).
fn summary(dir: &Path) -> Vec<(f64, [f64; 3])> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    files
        .iter()
        .map(|path| {
            let bytes = std::fs::read(path).unwrap();
            let (mut fz, mut colour) = (0.0f64, None);
            for m in messages(&bytes).unwrap() {
                match m.unwrap() {
                    Message::Truth(t) => fz = fz.max(t.wrench.force_n[2].abs()),
                    Message::Frame { format, data, .. } if colour.is_none() => {
                        let img = rig::record::png::decode_as(format, &data).unwrap();
                        let mut sum = [0.0; 3];
                        for p in img.pixels() {
                            for k in 0..3 {
                                sum[k] += p[k] as f64;
                            }
                        }
                        let n = (img.width() * img.height()) as f64;
                        colour = Some(sum.map(|s| s / n));
                    }
                    _ => {}
                }
            }
            (fz, colour.expect("a frame"))
        })
        .collect()
}

#[test]
fn a_second_sensor_with_the_same_gel_replays_the_contact_and_renders_its_own_optics() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("contact");
    let source = narrowed(dir.path(), "sim-source.toml", "source", &[]);
    // sim-target's camera, LEDs and markers on sim-source's gel (the same batch).
    let same_gel = narrowed(
        dir.path(),
        "sim-target.toml",
        "target-same-gel",
        &[("youngs_modulus_mpa = 0.29", "youngs_modulus_mpa = 0.275")],
    );
    let other_gel = narrowed(dir.path(), "sim-target.toml", "target", &[]);

    let out_a = dir.path().join("a");
    let first = cache_line(&record(&source, &out_a, &cache));
    let [replayed, steps, found, solved, left, written] = first;
    // The second direction's way down is the first's: it replays that much of the first's
    // fresh tape, leaves it where the slides part, solves its history anew and goes on live.
    assert_eq!((found, left, written), (0, 1, 2), "{first:?}");
    assert!(solved > 100, "{first:?}");
    assert_eq!(replayed + solved, steps);

    let out_b = dir.path().join("b");
    let stderr = record(&same_gel, &out_b, &cache);
    let second = cache_line(&stderr);
    let [replayed, steps, found, _, left, written] = second;
    assert_eq!(found, 2, "{second:?}");
    // Every step replayed (10 of 10 runs here). A pause between two stages that differs from
    // the tape's by more than the slip allowed (a loaded host at ×20) makes an episode leave
    // its tape and go on live, correctly: then that episode is a new tape.
    assert_eq!(written, left, "{stderr}");
    assert!(replayed * 2 >= steps && steps > 100, "{stderr}");

    let out_c = dir.path().join("c");
    let third = cache_line(&record(&other_gel, &out_c, &cache));
    let [_, _, found, _, left, written] = third;
    // Nothing of the first gel's: it solves (and replays only its own way down, as the first).
    assert_eq!(
        (found, left, written),
        (0, 1, 2),
        "another gel solves: {third:?}"
    );

    // The replayed run passes the dataset check: its paired F/T force is the simulator's true
    // force to within the Nano17's noise, as a solved run's is.
    let check = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check"])
        .arg(&out_b)
        .args(["--max-error-pct", "0.5"])
        .output()
        .unwrap();
    assert!(check.status.success(), "{}", common::output_text(&check));

    let (a, b, c) = (summary(&out_a), summary(&out_b), summary(&out_c));
    assert_eq!((a.len(), b.len(), c.len()), (2, 2, 2));
    for k in 0..2 {
        let (fa, fb, fc) = (a[k].0, b[k].0, c[k].0);
        // The same contact: the replayed peak is the solved one to the physics' own grid
        // dependence (about 2 % at the cone's peak, see the mocks' contact_tape tests).
        assert!(
            (fb - fa).abs() <= 0.02 * fa,
            "trajectory {k}: {fa} N against {fb} N"
        );
        // The 5 % stiffer gel presses harder (force scales with E on a layer).
        assert!(
            fc > fa * 1.02,
            "trajectory {k}: {fc} N on the stiffer gel, {fa} N"
        );
        // Another camera: the frames are that sensor's own.
        let d = (0..3)
            .map(|i| (a[k].1[i] - b[k].1[i]).abs())
            .fold(0.0, f64::max);
        assert!(
            d > 5.0,
            "trajectory {k}: the frames' mean colours {:?} {:?}",
            a[k].1,
            b[k].1
        );
    }
}
