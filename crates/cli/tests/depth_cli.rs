//! `fusiondet depth-complete` end to end on the bundled KITTI frames.

mod common;

use common::{all_output, assert_fails_with, repo_root, run, s};

#[test]
fn completes_projected_scans_and_single_maps_and_measures_held_out_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let training = repo_root().join("data/kitti-sample/training");
    let out = dir.path().join("dense");
    let o = run(
        "depth-complete",
        &[
            "--data-dir",
            s(&training),
            "--ids",
            "000001,000003",
            "--out-dir",
            s(&out),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    assert!(
        all_output(&o).contains("2 depth maps"),
        "{}",
        all_output(&o)
    );
    let dense = fusiondet_depth::read_depth_png(&out.join("000001.png")).unwrap();
    assert_eq!((dense.width, dense.height), (1242, 375));
    // The scan covers the lower part of the image: there, nearly every pixel is filled.
    let lower: Vec<f32> = dense.data[300 * 1242..].to_vec();
    let filled = lower.iter().filter(|&&d| d > 0.0).count() as f64 / lower.len() as f64;
    assert!(filled > 0.9, "{filled}");

    // One map in, one map out; then the same map cannot be written over its input.
    let single = dir.path().join("single.png");
    let o = run(
        "depth-complete",
        &[
            "--sparse",
            s(&out.join("000003.png")),
            "--out",
            s(&single),
            "--blur",
            "gaussian",
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    assert!(single.is_file());
    assert_fails_with(
        "depth-complete",
        &["--sparse", s(&single), "--out", s(&single)],
        "is the input",
    );

    // Held-out accuracy: printed per frame and over all.
    let o = run(
        "depth-complete",
        &[
            "--data-dir",
            s(&training),
            "--ids",
            "000001",
            "--holdout",
            "0.1",
        ],
    );
    let t = all_output(&o);
    assert!(o.status.success(), "{t}");
    assert!(
        t.contains("000001:") && t.contains("all 1 frames") && t.contains("RMSE"),
        "{t}"
    );
}

#[test]
fn bad_input_is_named_and_inputs_are_never_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let training = repo_root().join("data/kitti-sample/training");
    // A colour image where depth is expected.
    let o = run(
        "depth-complete",
        &[
            "--sparse",
            s(&training.join("image_2/000001.png")),
            "--out",
            s(&dir.path().join("x.png")),
        ],
    );
    assert!(!o.status.success());
    let t = all_output(&o);
    assert!(t.contains("000001.png") && t.contains("16-bit"), "{t}");
    // The output directory may not be an input directory.
    assert_fails_with(
        "depth-complete",
        &["--data-dir", s(&training), "--out-dir", s(&training)],
        "is an input directory",
    );
    // A missing frame names its file.
    assert_fails_with(
        "depth-complete",
        &[
            "--data-dir",
            s(&training),
            "--ids",
            "999999",
            "--out-dir",
            s(&dir.path().join("o")),
        ],
        "999999",
    );
    assert_fails_with(
        "depth-complete",
        &["--data-dir", s(&training), "--holdout", "1.5"],
        "--holdout",
    );
}

/// A simulated data set carries the dense truth (training/depth_2/), and
/// `--truth-dir` measures the completion against it.
#[test]
fn simulated_frames_carry_their_dense_depth_and_are_measured_against_it() {
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("sim");
    let o = run(
        "simulate",
        &["--out", s(&sim), "--frames", "2", "--seed", "4"],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let training = sim.join("training");
    let truth = fusiondet_depth::read_depth_png(&training.join("depth_2/000000.png")).unwrap();
    assert_eq!((truth.width, truth.height), (1242, 375));
    assert!(truth.valid_count() > 200_000, "{}", truth.valid_count());
    let o = run(
        "depth-complete",
        &[
            "--data-dir",
            s(&training),
            "--truth-dir",
            s(&training.join("depth_2")),
            "--extrapolate",
        ],
    );
    let t = all_output(&o);
    assert!(o.status.success(), "{t}");
    let all = t.lines().find(|l| l.starts_with("all 2 frames")).unwrap();
    // "… MAE <x> mm …": a completion that follows the scan is within a metre on average.
    let mae: f64 = all
        .split("MAE ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .unwrap()
        .parse()
        .unwrap();
    assert!(mae < 1000.0, "{all}");
}
