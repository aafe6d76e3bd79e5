//! End-to-end tests of `fusiondet viz` on a prepared SUN RGB-D directory: the real scene
//! 000017 of the `sunrgbd` fixture, with detections written as SUN RGB-D result lines.

use fusiondet_kitti::image::read_image;
use fusiondet_viz::image::{Rgb, RgbImage};
use fusiondet_viz::style::{DETECTION, GT};
use std::path::PathBuf;

mod common;

use common::{all_output, assert_fails_with, s};

fn fixture() -> PathBuf {
    common::repo_root().join("crates/sunrgbd/tests/data")
}

fn count(img: &RgbImage, rows: std::ops::Range<u32>, c: Rgb<u8>) -> usize {
    rows.map(|y| {
        (0..img.width())
            .filter(|&x| *img.get_pixel(x, y) == c)
            .count()
    })
    .sum()
}

#[test]
fn draws_a_sun_rgbd_scene_with_its_boxes_above_the_room() {
    let tmp = tempfile::tempdir().unwrap();
    // The bed as a detection, 40 cm to the right of its label, and a lamp (not one of
    // the ten classes, drawn all the same).
    let results = tmp.path().join("results");
    std::fs::create_dir(&results).unwrap();
    let labels = std::fs::read_to_string(fixture().join("label/000017.txt")).unwrap();
    let bed = labels.lines().find(|l| l.starts_with("bed ")).unwrap();
    let mut f: Vec<String> = bed.split_whitespace().map(str::to_string).collect();
    f[1] = format!("{}", f[1].parse::<f64>().unwrap() + 0.4);
    std::fs::write(results.join("000017.txt"), format!("{} 0.8\n", f.join(" "))).unwrap();

    let out = tmp.path().join("scene.png");
    let o = common::run(
        "viz",
        &[
            "--data-dir",
            s(&fixture()),
            "--id",
            "17",
            "--result-dir",
            s(&results),
            "--out",
            s(&out),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let picture = read_image(&out).unwrap();
    let image = fusiondet_viz::image::open(fixture().join("image/000017.jpg"))
        .unwrap()
        .to_rgb8();
    let (w, h) = image.dimensions();
    assert_eq!(picture.width(), w);
    // The top view: 0-8 m ahead at w / 10 m pixels a metre, at the bottom; the image
    // 4 rows above it.
    let bev_rows = (8.0 * w as f64 / 10.0).round() as u32;
    assert!(
        picture.height() > bev_rows + 4 + h,
        "{:?}",
        picture.dimensions()
    );
    let bev_top = picture.height() - bev_rows;
    let camera = bev_top - 4 - h..bev_top - 4;
    let bev = bev_top..picture.height();
    for (what, rows) in [("image", camera), ("top view", bev)] {
        let gt = count(&picture, rows.clone(), GT);
        let det = count(&picture, rows, DETECTION);
        assert!(
            gt > 200 && det > 100,
            "{what}: {gt} ground-truth and {det} detection pixels"
        );
    }
    assert!(text_of(&o).contains("wrote"), "{}", all_output(&o));

    // Without results: ground truth only.
    let plain = tmp.path().join("plain.png");
    let o = common::run(
        "viz",
        &[
            "--data-dir",
            s(&fixture()),
            "--id",
            "000017",
            "--out",
            s(&plain),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let plain = read_image(&plain).unwrap();
    assert_eq!(count(&plain, 0..plain.height(), DETECTION), 0);
    assert!(count(&plain, 0..plain.height(), GT) > 400);
}

fn text_of(o: &std::process::Output) -> String {
    common::text(&o.stdout)
}

#[test]
fn kitti_only_inputs_and_missing_scenes_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x.png");
    assert_fails_with(
        "viz",
        &[
            "--data-dir",
            s(&fixture()),
            "--id",
            "000017",
            "--depth-dir",
            s(tmp.path()),
            "--out",
            s(&out),
        ],
        "--depth-dir is for KITTI frames",
    );
    assert_fails_with(
        "viz",
        &[
            "--data-dir",
            s(&fixture()),
            "--id",
            "000018",
            "--out",
            s(&out),
        ],
        "000018",
    );
    assert!(!out.exists());
}
