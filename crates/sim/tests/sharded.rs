//! `simulate --shard`: n shards, run one after another or at the same time, leave the same
//! data set one unsharded run writes, byte for byte (the shards' own bookkeeping apart).

use fusiondet_kitti::Shard;
use fusiondet_sim::{DatasetOptions, SimConfig, SimError, write_dataset, write_dataset_shard};
use std::collections::BTreeMap;
use std::path::Path;

const FRAMES: usize = 7;

fn opts(out: &Path) -> DatasetOptions {
    DatasetOptions {
        out: out.to_path_buf(),
        frames: FRAMES,
        seed: 3,
        force: false,
        config: SimConfig {
            val_fraction: 0.4,
            ..SimConfig::default()
        },
    }
}

/// Every file under `root` with its bytes, leaving out the bookkeeping that differs by
/// design: the shard records and the unsharded run's lock file.
fn tree(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let path = entry.path();
            let name = path.strip_prefix(root).unwrap().display().to_string();
            if name.starts_with(".fusiondet-shards") || name == ".fusiondet-sim.lock" {
                continue;
            }
            if path.is_dir() {
                stack.push(path);
            } else {
                files.insert(name, std::fs::read(&path).unwrap());
            }
        }
    }
    files
}

fn shard(index: usize, count: usize) -> Shard {
    Shard { index, count }
}

#[test]
fn shards_one_after_another_and_at_once_write_the_unsharded_data_set() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole");
    write_dataset(&opts(&whole), &|_, _| {}).unwrap();
    let expected = tree(&whole);
    assert!(expected.contains_key("ImageSets/val.txt") && expected.contains_key("sim_stats.json"));

    // One after another: the index files appear only with the last shard.
    let serial = dir.path().join("serial");
    for i in 0..3 {
        let outcome = write_dataset_shard(&opts(&serial), shard(i, 3), &|_, _| {}).unwrap();
        assert_eq!(outcome.frames, [3, 2, 2][i]);
        assert_eq!(outcome.stats.is_some(), i == 2, "shard {i}");
        assert_eq!(serial.join("ImageSets/val.txt").exists(), i == 2);
        if i < 2 {
            assert!(
                outcome.progress.describe().contains("shards not started"),
                "{}",
                outcome.progress.describe()
            );
        }
    }
    assert_eq!(tree(&serial), expected);

    // A finished shard run again changes nothing.
    write_dataset_shard(&opts(&serial), shard(1, 3), &|_, _| {}).unwrap();
    assert_eq!(tree(&serial), expected);

    // At the same time (threads standing in for processes).
    let together = dir.path().join("together");
    std::thread::scope(|s| {
        for i in 0..3 {
            let o = opts(&together);
            s.spawn(move || write_dataset_shard(&o, shard(i, 3), &|_, _| {}).unwrap());
        }
    });
    assert_eq!(tree(&together), expected);
}

#[test]
fn a_shard_of_another_data_set_is_refused_and_force_replaces_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim");
    write_dataset_shard(&opts(&out), shard(0, 2), &|_, _| {}).unwrap();
    // Another seed is another data set: its shard must not mix in.
    let mut other = opts(&out);
    other.seed = 4;
    let err = write_dataset_shard(&other, shard(1, 2), &|_, _| {}).unwrap_err();
    assert!(matches!(err, SimError::NotEmpty(_)), "{err}");
    // So is another shard count.
    let err = write_dataset_shard(&opts(&out), shard(1, 3), &|_, _| {}).unwrap_err();
    assert!(matches!(err, SimError::NotEmpty(_)), "{err}");
    // --force replaces the earlier shard's files; the new run then completes alone.
    other.force = true;
    let outcome = write_dataset_shard(&other, Shard::ALL, &|_, _| {}).unwrap();
    assert!(outcome.progress.is_whole() && outcome.stats.is_some());
    let whole = dir.path().join("whole");
    let mut o = opts(&whole);
    o.seed = 4;
    write_dataset(&o, &|_, _| {}).unwrap();
    assert_eq!(tree(&out), tree(&whole));
}
