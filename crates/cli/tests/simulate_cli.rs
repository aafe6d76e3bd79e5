//! End-to-end tests of `fusiondet simulate`: a small dataset read back with the KITTI
//! readers, byte-identical output for the same seed, and bad arguments.

use fusiondet_kitti::{
    DatasetDir, ObjectClass, read_calib, read_detections2d, read_objects, read_split, read_velodyne,
};
use std::path::Path;
use std::process::Output;

mod common;
use common::{s, snapshot, text};

fn simulate(args: &[&str]) -> Output {
    common::run("simulate", args)
}

#[test]
fn writes_a_dataset_the_kitti_readers_accept_and_repeats_it_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        tmp.path().join("a"),
        tmp.path().join("b"),
        tmp.path().join("c"),
    );
    let out = simulate(&["--out", s(&a), "--frames", "3", "--seed", "5", "--stats"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("wrote 3 frames"), "{stdout}");
    assert!(
        stdout.contains("points inside unoccluded car boxes"),
        "{stdout}"
    );

    let ds = DatasetDir::new(&a);
    let train = read_split(&ds.split("train")).unwrap();
    let val = read_split(&ds.split("val")).unwrap();
    let all = read_split(&ds.split("trainval")).unwrap();
    assert_eq!(all, ["000000", "000001", "000002"]);
    assert_eq!(train.len() + val.len(), 3);
    assert!(!val.is_empty() && !train.is_empty());
    let t = ds.training();
    let mut labelled = 0;
    for id in &all {
        let points = read_velodyne(&t.velodyne(id)).unwrap();
        assert!(points.len() > 80_000, "{id}: {} points", points.len());
        assert!(points.iter().all(|p| (0.0..=1.0).contains(&p[3])));
        read_calib(&t.calib(id)).unwrap();
        let objects = read_objects(&t.label(id)).unwrap();
        labelled += objects
            .iter()
            .filter(|o| o.class != ObjectClass::DontCare)
            .count();
        let image = fusiondet_kitti::image::read_image(&t.image(id)).unwrap();
        assert_eq!(image.dimensions(), (1242, 375));
    }
    assert!(labelled > 0);
    for (split, ids) in [("train", &train), ("val", &val)] {
        let dets = read_detections2d(&ds.rgb_detections(split)).unwrap();
        assert!(dets.iter().all(|d| ids.contains(&d.frame_id)), "{split}");
        assert!(dets.iter().all(|d| d.score >= 0.01 && d.score <= 1.0));
    }
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(a.join("sim_stats.json")).unwrap()).unwrap();
    assert_eq!(stats["frames"], 3);

    // Same seed: byte-identical, even with nobody reading stdout (`… | head -0`); another
    // seed: another world.
    let out = common::run_into_closed_pipe(
        "simulate",
        &["--out", s(&b), "--frames", "3", "--seed", "5", "--stats"],
    );
    common::assert_quiet_on_closed_pipe(&out);
    let (sa, sb) = (snapshot(&a), snapshot(&b));
    assert_eq!(sa.keys().collect::<Vec<_>>(), sb.keys().collect::<Vec<_>>());
    for (path, bytes) in &sa {
        assert!(
            bytes == &sb[path],
            "{} differs between runs with the same seed",
            path.display()
        );
    }
    let out = simulate(&["--out", s(&c), "--frames", "1", "--seed", "6"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let v = Path::new("training/velodyne/000000.bin");
    assert_ne!(snapshot(&c)[v], sa[v]);

    // --force replaces the dataset: a shorter run leaves no stale frames behind.
    let out = simulate(&["--out", s(&a), "--frames", "1", "--seed", "5", "--force"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(!t.velodyne("000002").exists());
    assert_eq!(read_split(&ds.split("trainval")).unwrap(), ["000000"]);
    assert_eq!(std::fs::read(t.velodyne("000000")).unwrap(), sa[v]);
}

#[test]
fn bad_arguments_fail_with_a_clear_message() {
    let tmp = tempfile::tempdir().unwrap();
    let out = simulate(&["--out", s(&tmp.path().join("x")), "--frames", "0"]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("--frames must be at least 1"),
        "{}",
        text(&out.stderr)
    );

    let full = tmp.path().join("full");
    std::fs::create_dir_all(&full).unwrap();
    std::fs::write(full.join("notes.txt"), "mine").unwrap();
    let out = simulate(&["--out", s(&full), "--frames", "1"]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("not empty") && err.contains("--force"),
        "{err}"
    );
    assert!(full.join("notes.txt").exists());

    // A path below a regular file cannot be created.
    let file = tmp.path().join("file");
    std::fs::write(&file, "x").unwrap();
    let out = simulate(&["--out", s(&file.join("ds")), "--frames", "1"]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("cannot create or use the output directory"),
        "{err}"
    );

    let out = simulate(&[
        "--out",
        s(&tmp.path().join("y")),
        "--frames",
        "1",
        "--val-fraction",
        "1.5",
    ]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("--val-fraction"),
        "{}",
        text(&out.stderr)
    );

    let out = simulate(&["--out", s(&tmp.path().join("z")), "--frames", "lots"]);
    assert!(!out.status.success());
}
