//! End-to-end tests of `fusiondet viz` on bundled KITTI frame 000001.

use fusiondet_kitti::image::read_image;
use fusiondet_viz::image::{Rgb, RgbImage};
use fusiondet_viz::style::{DETECTION, GT};
use std::path::PathBuf;
use std::process::Output;

mod common;

fn training_dir() -> PathBuf {
    common::repo_root().join("data/kitti-sample/training")
}

fn viz(args: &[&str]) -> Output {
    common::run("viz", args)
}

/// A result directory holding frame 000001's labels (DontCare dropped) with scores
/// 0.9, 0.8, 0.7, ..., as a detector would write them.
fn result_dir_from_labels() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let labels = std::fs::read_to_string(training_dir().join("label_2/000001.txt")).unwrap();
    let lines: Vec<String> = labels
        .lines()
        .filter(|l| !l.starts_with("DontCare"))
        .enumerate()
        .map(|(i, l)| format!("{l} {:.2}", 0.9 - 0.1 * i as f64))
        .collect();
    assert_eq!(lines.len(), 3);
    std::fs::write(dir.path().join("000001.txt"), lines.join("\n") + "\n").unwrap();
    dir
}

fn count(img: &RgbImage, rows: std::ops::Range<u32>, c: Rgb<u8>) -> usize {
    rows.map(|y| {
        (0..img.width())
            .filter(|&x| *img.get_pixel(x, y) == c)
            .count()
    })
    .sum()
}

/// Row ranges of the camera image and of the bird's-eye view in a 1242-wide picture:
/// the BEV (0-70 m at 1242/80 px/m = 1087 rows) is at the bottom, the 375-row camera
/// image 4 rows above it, the legend on top.
fn regions(img: &RgbImage) -> (std::ops::Range<u32>, std::ops::Range<u32>) {
    let bev_top = img.height() - 1087;
    let camera_top = bev_top - 4 - 375;
    (camera_top..bev_top - 4, bev_top..img.height())
}

#[test]
fn renders_frame_with_ground_truth_and_detections() {
    let results = result_dir_from_labels();
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("frame.png");
    let o = viz(&[
        "--data-dir",
        training_dir().to_str().unwrap(),
        "--id",
        "1",
        "--result-dir",
        results.path().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        o.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let img = read_image(&out).unwrap();
    assert_eq!(img.width(), 1242);
    assert!(
        img.height() > 375 + 1087 && img.height() < 375 + 1087 + 200,
        "{}",
        img.height()
    );
    let (camera, bev) = regions(&img);
    // The camera part is the photo: its first row is not the dark background.
    assert!(
        count(
            &img,
            camera.start..camera.start + 1,
            fusiondet_viz::style::BACKGROUND
        ) < 100
    );
    for (name, rows) in [("camera", camera), ("bev", bev)] {
        assert!(
            count(&img, rows.clone(), GT) > 100,
            "no ground truth in the {name} view"
        );
        assert!(
            count(&img, rows, DETECTION) > 50,
            "no detections in the {name} view"
        );
    }
}

#[test]
fn score_threshold_hides_low_scoring_detections() {
    let results = result_dir_from_labels();
    let out_dir = tempfile::tempdir().unwrap();
    let render = |threshold: &str| {
        let out = out_dir.path().join(format!("t{threshold}.png"));
        let o = viz(&[
            "--data-dir",
            training_dir().to_str().unwrap(),
            "--id",
            "000001",
            "--result-dir",
            results.path().to_str().unwrap(),
            "--score-threshold",
            threshold,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(
            o.status.success(),
            "stderr: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let img = read_image(&out).unwrap();
        let (camera, bev) = regions(&img);
        count(&img, camera, DETECTION) + count(&img, bev, DETECTION)
    };
    let all = render("0.0");
    let best = render("0.85");
    let none = render("0.95");
    assert!(all > best && best > 0, "all {all}, best {best}");
    assert_eq!(none, 0);
}

#[test]
fn result_dir_without_the_frame_draws_ground_truth_and_warns() {
    let results = tempfile::tempdir().unwrap();
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("frame.png");
    let o = viz(&[
        "--data-dir",
        training_dir().to_str().unwrap(),
        "--id",
        "000001",
        "--result-dir",
        results.path().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        o.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("no result file for 000001"), "{stderr}");
    let img = read_image(&out).unwrap();
    let (camera, bev) = regions(&img);
    assert!(count(&img, camera.clone(), GT) > 100);
    assert_eq!(
        count(&img, camera, DETECTION) + count(&img, bev, DETECTION),
        0
    );
}

#[test]
fn bad_input_fails_cleanly_without_output() {
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("frame.png");
    let data = training_dir();
    let data = data.to_str().unwrap();
    let cases: [(&[&str], &str); 5] = [
        (
            &["--data-dir", data, "--id", "999999"],
            "image_2/999999.png",
        ),
        (
            &["--data-dir", "/no/such/dir", "--id", "000001"],
            "/no/such/dir",
        ),
        (&["--data-dir", data, "--id", "abc"], "not a frame id"),
        (
            &[
                "--data-dir",
                data,
                "--id",
                "000001",
                "--result-dir",
                "/no/such/results",
            ],
            "/no/such/results",
        ),
        (
            &[
                "--data-dir",
                data,
                "--id",
                "000001",
                "--score-threshold",
                "NaN",
            ],
            "finite",
        ),
    ];
    for (args, expected) in cases {
        let mut all = args.to_vec();
        all.extend(["--out", out.to_str().unwrap()]);
        let o = viz(&all);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert!(!out.exists(), "{args:?} wrote output");
    }
}

#[test]
fn unwritable_output_is_an_error_naming_it() {
    let o = viz(&[
        "--data-dir",
        training_dir().to_str().unwrap(),
        "--id",
        "000001",
        "--out",
        "/no/such/dir/frame.png",
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("/no/such/dir/frame.png"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn the_frames_own_image_is_never_the_output() {
    // A copy of frame 000001: should the guard fail, only the copy is overwritten.
    let copy = tempfile::tempdir().unwrap();
    for (sub, ext) in [
        ("image_2", "png"),
        ("calib", "txt"),
        ("velodyne", "bin"),
        ("label_2", "txt"),
    ] {
        std::fs::create_dir_all(copy.path().join(sub)).unwrap();
        let name = format!("000001.{ext}");
        std::fs::copy(
            training_dir().join(sub).join(&name),
            copy.path().join(sub).join(&name),
        )
        .unwrap();
    }
    let image = copy.path().join("image_2/000001.png");
    let before = std::fs::read(&image).unwrap();
    let o = viz(&[
        "--data-dir",
        copy.path().to_str().unwrap(),
        "--id",
        "1",
        "--out",
        image.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = common::text(&o.stderr);
    assert!(
        err.contains("would overwrite an input in --data-dir"),
        "{err}"
    );
    assert_eq!(std::fs::read(&image).unwrap(), before);
}
