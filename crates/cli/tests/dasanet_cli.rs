//! DASANet from the binary: `info` on the published rows, `gt-database --pseudo`, `train`
//! → `detect` (completing depth itself, or from given maps) → `eval` of the tiny
//! configuration on simulated frames, and frames whose image is missing or of the wrong
//! size.

mod common;

use common::{
    all_output, assert_fails_with, assert_forward_parts_logged, eval_val, repo_root, run, s,
};

#[test]
fn info_counts_the_published_rows_against_table_five() {
    for (file, total, paper) in [
        ("dasanet-tdis-car.toml", "27858396", "26.2 M"),
        ("dasanet-stca-car.toml", "30383992", "30.8 M"),
        ("dasanet-car.toml", "55113048", "55.2 M"),
    ] {
        let config = repo_root().join("configs").join(file);
        let o = run("info", &["--config", s(&config)]);
        let out = all_output(&o);
        assert!(o.status.success(), "{out}");
        let words = out.split_whitespace().collect::<Vec<_>>().join(" ");
        for needle in [
            "LiDAR 3D backbone 711872",
            &format!("total (inference) {total}"),
            &format!("Table 5 for this row: {paper}"),
            "pseudo 3D backbone",
            "Multiply-adds per frame",
        ] {
            assert!(
                words.contains(needle),
                "{file}: missing `{needle}` in\n{out}"
            );
        }
    }
}

#[test]
fn trains_detects_and_evaluates_the_tiny_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let o = run(
        "simulate",
        &["--out", s(&data), "--frames", "6", "--seed", "5"],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let config = repo_root().join("configs/tiny-dasanet.toml");

    // The database with pseudo points, beside the data.
    let o = run(
        "gt-database",
        &["--data", s(&data), "--pseudo", "--config", s(&config)],
    );
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        data.join("gt_database/train-pseudo/index.json").is_file(),
        "{out}"
    );

    let run_dir = dir.path().join("run");
    let o = run(
        "train",
        &[
            "--config",
            s(&config),
            "--data",
            s(&data),
            "--out",
            s(&run_dir),
        ],
    );
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    let metrics = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap();
    for term in [
        "loss_cls",
        "loss_rcnn_giou",
        "loss_aux_tdis_cls",
        "loss_aux_stca_reg",
    ] {
        assert!(metrics.contains(term), "{term} not logged: {metrics}");
    }
    assert_forward_parts_logged(&metrics, &["stca", "stca_crops"]);

    let val: Vec<String> = std::fs::read_to_string(data.join("ImageSets/val.txt"))
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    let model = run_dir.join("model.bpk");
    let results = dir.path().join("results");
    let o = run(
        "detect",
        &[
            "--checkpoint",
            s(&model),
            "--data",
            s(&data),
            "--out",
            s(&results),
        ],
    );
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains(&format!(
            "{} frames ({} with LiDAR and pseudo points",
            val.len(),
            val.len()
        )),
        "{out}"
    );
    assert!(out.contains("depth completion + pseudo points"), "{out}");
    eval_val(&data, &results);

    // model.bpk leaves out the auxiliary heads; the last epoch checkpoint (which keeps them
    // for resuming) detects the same boxes.
    let mut epochs: Vec<_> = std::fs::read_dir(run_dir.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.to_string_lossy().ends_with(".bpk") && !p.to_string_lossy().ends_with(".optim.bpk")
        })
        .collect();
    epochs.sort();
    let last = epochs.last().expect("an epoch checkpoint");
    let size = |p: &std::path::Path| std::fs::metadata(p).unwrap().len();
    assert!(
        size(&model) < size(last),
        "{} vs {}",
        size(&model),
        size(last)
    );
    let from_epoch = dir.path().join("results-epoch");
    let o = run(
        "detect",
        &[
            "--checkpoint",
            s(last),
            "--config",
            s(&run_dir.join("config.toml")),
            "--data",
            s(&data),
            "--out",
            s(&from_epoch),
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    for id in &val {
        let name = format!("{id}.txt");
        assert_eq!(
            std::fs::read(results.join(&name)).unwrap(),
            std::fs::read(from_epoch.join(&name)).unwrap(),
            "{name}"
        );
    }

    // Given completed maps (as `depth-complete` writes them, IP-Basic's default without
    // extrapolation), detection reads them instead of completing: the same boxes up to the
    // PNG's 1/256 m depth steps. Empty maps leave no pseudo point: nothing is detected.
    let depth = dir.path().join("depth");
    let o = run(
        "depth-complete",
        &[
            "--data-dir",
            s(&data.join("training")),
            "--out-dir",
            s(&depth),
            "--no-extrapolate",
        ],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let detect_with = |maps: &std::path::Path, out: &std::path::Path| {
        run(
            "detect",
            &[
                "--checkpoint",
                s(&model),
                "--data",
                s(&data),
                "--out",
                s(out),
                "--depth-dir",
                s(maps),
            ],
        )
    };
    let given = dir.path().join("given");
    let o = detect_with(&depth, &given);
    assert!(o.status.success(), "{}", all_output(&o));
    let boxes = |dir: &std::path::Path| -> usize {
        val.iter()
            .map(|id| {
                std::fs::read_to_string(dir.join(format!("{id}.txt")))
                    .unwrap()
                    .lines()
                    .count()
            })
            .sum()
    };
    let (own, read) = (boxes(&results), boxes(&given));
    assert!(
        own > 0 && own.abs_diff(read) * 10 <= own,
        "{own} boxes completing, {read} from the maps"
    );
    let empty = dir.path().join("empty-depth");
    std::fs::create_dir_all(&empty).unwrap();
    for id in &val {
        let size =
            image::image_dimensions(data.join(format!("training/image_2/{id}.png"))).unwrap();
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(size.0, size.1)
            .save(empty.join(format!("{id}.png")))
            .unwrap();
    }
    let o = detect_with(&empty, &dir.path().join("none"));
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains(&format!(
            "{} frames (0 with LiDAR and pseudo points",
            val.len()
        )),
        "{out}"
    );

    // The ablation trains the baseline and DASANet with two seeds each and puts the
    // seeds' means, ranges and differences from the baseline beside the per-run rows.
    let ablation = dir.path().join("ablation");
    let baseline = repo_root().join("configs/tiny-voxel-rcnn.toml");
    let o = run(
        "ablation",
        &[
            "--configs",
            s(&baseline),
            s(&config),
            "--data",
            s(&data),
            "--out",
            s(&ablation),
            "--epochs",
            "1",
            "--seeds",
            "1,2",
        ],
    );
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    let table = std::fs::read_to_string(ablation.join("ablation.md")).unwrap();
    for needle in [
        "| tiny-dasanet (seed 2)    |",
        "over 2 seeds",
        "tiny-dasanet (2 seeds)",
        "*vs tiny-voxel-rcnn*",
        "| tiny-dasanet (seed 2) |    2 |",
        "by distance, occlusion and LiDAR points",
        "GMACs",
    ] {
        assert!(table.contains(needle), "missing `{needle}` in\n{table}");
    }
    assert!(
        ablation
            .join("runs/tiny-dasanet/seed-2/model.bpk")
            .is_file()
    );

    // A frame without its image, and one whose image has another size, are named.
    let image = data.join(format!("training/image_2/{}.png", val[0]));
    let saved = std::fs::read(&image).unwrap();
    std::fs::remove_file(&image).unwrap();
    let out = dir.path().join("x");
    let args = [
        "--checkpoint",
        s(&model),
        "--data",
        s(&data),
        "--out",
        s(&out),
    ];
    assert_fails_with("detect", &args, &val[0]);
    let small = image::RgbImage::new(100, 50);
    small.save(&image).unwrap();
    assert_fails_with("detect", &args, "100×50");
    std::fs::write(&image, saved).unwrap();
}
