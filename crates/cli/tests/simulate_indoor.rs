//! End-to-end tests of `fusiondet simulate --indoor`: a small data set read back with the
//! SUN RGB-D readers, byte-identical output for the same seed (on one thread or many), another
//! seed differing, and the refusals (a directory it did not write, --shard, bad arguments).

use fusiondet_sim::indoor::sunrgbd::{
    SunClass, SunRgbdDir, depth::read_depth_png, read_detections_2d, read_image,
};
use std::path::{Path, PathBuf};

mod common;
use common::{assert_fails_with, run, s, snapshot, text};

#[test]
fn writes_a_sun_rgbd_data_set_and_repeats_it_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        tmp.path().join("a"),
        tmp.path().join("b"),
        tmp.path().join("c"),
    );
    let args = |dir: &Path, seed: &'static str| {
        vec![
            "--indoor".to_string(),
            "--out".into(),
            s(dir).to_string(),
            "--frames".into(),
            "3".into(),
            "--seed".into(),
            seed.into(),
            "--points".into(),
            "20000".into(),
        ]
    };
    let go = |v: Vec<String>| {
        let refs: Vec<&str> = v.iter().map(String::as_str).collect();
        run("simulate", &refs)
    };
    let out = go(args(&a, "5"));
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("wrote 3 indoor scenes"), "{stdout}");
    assert!(stdout.contains("camera height"), "{stdout}");
    assert!(stdout.contains("real 000017"), "{stdout}");

    let dir = SunRgbdDir::new(&a);
    let train = dir.split_ids("train").unwrap();
    let val = dir.split_ids("val").unwrap();
    let mut all: Vec<String> = train.iter().chain(&val).cloned().collect();
    all.sort();
    assert_eq!(all, ["000000", "000001", "000002"]);
    let mut labels = 0;
    for id in &all {
        let scene = dir.read_scene(id).unwrap();
        assert_eq!(scene.points.len(), 20_000, "{id}");
        for o in &scene.labels {
            assert!(o.sun_class().is_some(), "{}", o.class);
            assert!(o.bbox.x1 >= 1.0 && o.bbox.x2 <= 640.0 && o.bbox.y2 <= 480.0);
        }
        labels += scene.labels.len();
        // Points lie in front of the camera and project into the image.
        for p in scene.points.iter().step_by(97) {
            let [u, v] = scene
                .calib
                .project([p[0], p[1], p[2]].map(f64::from))
                .unwrap();
            assert!(
                (0.5..=640.5).contains(&u) && (0.5..=480.5).contains(&v),
                "{u} {v}"
            );
        }
        let image = read_image(&dir.image(id)).unwrap();
        assert_eq!(image.dimensions(), (640, 480));
        let depth = read_depth_png(&a.join("depth").join(format!("{id}.png"))).unwrap();
        assert_eq!((depth.width, depth.height), (640, 480));
        assert!(depth.millimetres.iter().all(|&mm| mm <= 8000));
        for d in read_detections_2d(&dir.detections_2d(id)).unwrap() {
            assert!(SunClass::parse(&d.class).is_some() && d.score > 0.0 && d.score < 1.0);
        }
    }
    assert!(labels >= 1, "no labelled object in 3 scenes");

    // The second run on one thread: the bytes do not depend on the thread count.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_fusiondet"))
        .arg("simulate")
        .args(args(&b, "5"))
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (sa, sb) = (snapshot(&a), snapshot(&b));
    assert_eq!(sa.keys().collect::<Vec<_>>(), sb.keys().collect::<Vec<_>>());
    for (k, v) in &sa {
        assert!(
            v == &sb[k],
            "{} differs between two runs of one seed",
            k.display()
        );
    }
    let out = go(args(&c, "6"));
    assert!(out.status.success(), "{}", text(&out.stderr));
    let sc = snapshot(&c);
    let p = PathBuf::from("points/000000.bin");
    assert_ne!(sa[&p], sc[&p], "another seed gives another scene");

    // --force replaces the indoor run (same bytes again).
    let mut again = args(&a, "5");
    again.push("--force".into());
    let out = go(again);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(snapshot(&a), sa);
}

#[test]
fn refuses_what_it_did_not_write_and_bad_arguments() {
    let tmp = tempfile::tempdir().unwrap();
    let other = tmp.path().join("other");
    std::fs::create_dir_all(other.join("label")).unwrap();
    std::fs::write(other.join("label/000000.txt"), b"real labels").unwrap();
    let o = s(&other);
    assert_fails_with(
        "simulate",
        &["--indoor", "--out", o, "--frames", "1"],
        "not empty",
    );
    assert_fails_with(
        "simulate",
        &["--indoor", "--out", o, "--frames", "1", "--force"],
        "only an indoor data set",
    );
    assert_eq!(
        std::fs::read(other.join("label/000000.txt")).unwrap(),
        b"real labels"
    );
    let fresh = tmp.path().join("fresh");
    let f = s(&fresh);
    assert_fails_with(
        "simulate",
        &["--indoor", "--out", f, "--frames", "2", "--shard", "0/2"],
        "--shard is not supported with --indoor",
    );
    assert_fails_with(
        "simulate",
        &["--indoor", "--out", f, "--frames", "0"],
        "--frames must be at least 1",
    );
    assert_fails_with(
        "simulate",
        &[
            "--indoor",
            "--out",
            f,
            "--frames",
            "1",
            "--val-fraction",
            "2",
        ],
        "--val-fraction must be between 0 and 1",
    );
    assert_fails_with(
        "simulate",
        &["--out", f, "--frames", "1", "--points", "10"],
        "--points applies to --indoor",
    );
    assert!(!fresh.join("points").exists());
}
