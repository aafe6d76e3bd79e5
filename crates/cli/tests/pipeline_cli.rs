//! End-to-end tests of `demo`, `train`, `detect` and `info` through the binary.

mod common;

use common::all_output as text;
use std::path::Path;
use std::process::Output;

/// `fusiondet ARGS...` (the first argument is the subcommand).
fn fusiondet(args: &[&str]) -> Output {
    common::run(args[0], &args[1..])
}

/// Simulates a 6-frame dataset into `dir/sim` with the extra `simulate` arguments.
fn simulate_six_frames(dir: &std::path::Path, extra: &[&str]) -> std::path::PathBuf {
    let data = dir.join("sim");
    let mut args = vec!["simulate", "--out", data.to_str().unwrap(), "--frames", "6"];
    args.extend_from_slice(extra);
    let o = fusiondet(&args);
    assert!(o.status.success(), "{}", text(&o));
    data
}

fn configs() -> std::path::PathBuf {
    common::repo_root().join("configs")
}

/// `fusiondet SUBCOMMAND INPUT_FLAG INPUT --data DATA --out OUT EXTRA…`: what `train` and
/// `detect` take.
fn on_data(
    subcommand: &str,
    input_flag: &str,
    input: &Path,
    data: &Path,
    out: &Path,
    extra: &[&str],
) -> Output {
    let mut args = vec![
        subcommand,
        input_flag,
        input.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    fusiondet(&args)
}

/// `fusiondet train --config CONFIG --data DATA --out OUT EXTRA…`.
fn train(config: &Path, data: &Path, out: &Path, extra: &[&str]) -> Output {
    on_data("train", "--config", config, data, out, extra)
}

/// `fusiondet detect --checkpoint CHECKPOINT --data DATA --out OUT EXTRA…`.
fn detect(checkpoint: &Path, data: &Path, out: &Path, extra: &[&str]) -> Output {
    on_data("detect", "--checkpoint", checkpoint, data, out, extra)
}

/// `fusiondet demo --out OUT --frames FRAMES EXTRA…`.
fn demo(out: &std::path::Path, frames: &str, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["demo", "--out", out.to_str().unwrap(), "--frames", frames];
    args.extend_from_slice(extra);
    fusiondet(&args)
}

#[test]
fn demo_runs_the_shipped_model_and_can_be_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let args = ["demo", "--out", out.to_str().unwrap(), "--frames", "8"];
    let o = fusiondet(&args);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("simulated 8 frames"), "{t}");
    assert!(t.contains("the shipped F-ConvNet Car model"), "{t}");
    assert!(t.contains("Car AP_R40@0.70, 0.70, 0.70"), "{t}");
    // One closing line with the 3D AP of both evaluations, as the indoor demo has.
    let summary = t
        .lines()
        .find(|l| l.starts_with("3D AP_R40 easy / moderate / hard: simulated val Car "))
        .unwrap_or_else(|| panic!("no summary line in\n{t}"));
    assert!(summary.contains("; bundled KITTI frames Car "), "{summary}");
    for f in [
        "model/fconvnet-car.bpk",
        "model/fconvnet-car.toml",
        "eval-sim.json",
        "eval-kitti.json",
        "pictures/kitti-000001.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing\n{t}");
    }
    // The written model is the repository's file, byte for byte.
    assert_eq!(
        std::fs::read(out.join("model/fconvnet-car.bpk")).unwrap(),
        std::fs::read(common::repo_root().join("models/fconvnet-car.bpk")).unwrap()
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval-kitti.json")).unwrap())
            .unwrap();
    assert!(!json["results"].as_array().unwrap().is_empty());
    // A second run replaces the demo's own output.
    let o = fusiondet(&args);
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn demo_runs_each_shipped_variant_from_the_clone() {
    // (--model, file stem, what it says it runs, an evaluated class's line)
    let car = "Car AP_R40@0.70, 0.70, 0.70";
    let people = "Pedestrian AP_R40@0.50, 0.50, 0.50";
    for (model, stem, title, class_line) in [
        ("fcam", "fcam-car", "FCAM Car", car),
        ("saf", "saf-car", "SAF Car", car),
        ("voxel-rcnn", "voxel-rcnn-car", "Voxel R-CNN Car", car),
        ("dasanet", "dasanet-car", "DASANet Car", car),
        (
            "fconvnet-refine",
            "fconvnet-refine-car",
            "two-stage F-ConvNet Car",
            car,
        ),
        (
            "fconvnet-people",
            "fconvnet-people",
            "F-ConvNet Pedestrian + Cyclist",
            people,
        ),
        (
            "saf-people",
            "saf-people",
            "SAF Pedestrian + Cyclist",
            people,
        ),
        (
            "fconvnet-refine-people",
            "fconvnet-refine-people",
            "two-stage F-ConvNet Pedestrian + Cyclist",
            people,
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("demo");
        let o = demo(&out, "6", &["--model", model]);
        let t = text(&o);
        assert!(o.status.success(), "{model}: {t}");
        assert!(t.contains(&format!("the shipped {title} model")), "{t}");
        assert!(t.contains(class_line), "{t}");
        let mut written = vec![stem];
        // A two-stage model runs from the one configuration, its first stage beside it.
        if let Some(first) = stem.strip_prefix("fconvnet-refine-").map(|rest| {
            if rest == "car" {
                "fconvnet-car"
            } else {
                "fconvnet-people"
            }
        }) {
            written.push(first);
        }
        for stem in written {
            assert_eq!(
                std::fs::read(out.join(format!("model/{stem}.bpk"))).unwrap(),
                std::fs::read(common::repo_root().join(format!("models/{stem}.bpk"))).unwrap()
            );
        }
        assert!(out.join("eval-kitti.json").is_file(), "{t}");
        // A people model writes Pedestrian and Cyclist lines, no Car.
        if class_line == people {
            let lines: String = std::fs::read_dir(out.join("results/sim"))
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|x| x == "txt"))
                .map(|p| std::fs::read_to_string(p).unwrap())
                .collect();
            assert!(
                lines.contains("Pedestrian ") || lines.contains("Cyclist "),
                "{model}: no people detected\n{lines}"
            );
            assert!(!lines.contains("Car "), "{model}\n{lines}");
        }
    }
}

#[test]
fn demo_can_train_the_tiny_network_instead() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let o = demo(&out, "8", &["--train-tiny", "--epochs", "1"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("trained the tiny F-ConvNet"), "{t}");
    assert!(out.join("run/model.bpk").is_file(), "{t}");
    assert!(!out.join("model").exists(), "{t}");
}

#[test]
fn demo_refuses_a_directory_it_did_not_write() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("precious.txt"), b"keep me").unwrap();
    let o = fusiondet(&["demo", "--out", dir.path().to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("not written by `fusiondet demo`"),
        "{}",
        text(&o)
    );
    assert_eq!(
        std::fs::read(dir.path().join("precious.txt")).unwrap(),
        b"keep me"
    );
}

/// `fusiondet info` on a shipped config: must succeed; returns its output.
fn info_of(config: &str) -> String {
    let path = configs().join(config);
    let o = fusiondet(&["info", "--config", path.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{config}: {t}");
    t
}

/// Fails unless `text` contains every one of `parts`.
fn assert_mentions(text: &str, parts: &[&str]) {
    for part in parts {
        assert!(text.contains(part), "no {part:?} in:\n{text}");
    }
}

#[test]
fn info_prints_the_published_parameter_count() {
    let t = info_of("fconvnet-car.toml");
    assert!(t.contains("\nparameters: 3316777\n"), "{t}");
}

#[test]
fn info_counts_both_stages_of_the_refinement_model() {
    let t = info_of("fconvnet-refine-car.toml");
    assert_mentions(&t, &["First stage", "Refinement stage"]);
    assert!(
        t.contains("\nBoth stages: 6633554 parameters (3316777 + 3316777)\npaper: 6633554 ("),
        "{t}"
    );
}

/// The number after `prefix` on the line that starts with it.
fn number_after(text: &str, prefix: &str) -> i64 {
    let line = text
        .lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no line {prefix:?} in:\n{text}"));
    line[prefix.len()..]
        .split_whitespace()
        .next()
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no number after {prefix:?} in {line:?}"))
}

/// `info`'s table by block: the block rows (not indented) sum to the total, each block to
/// its modules, and the paper's line gives the difference the total makes.
fn check_block_table(t: &str) -> (i64, i64, f64) {
    let lines: Vec<&str> = t.lines().collect();
    let start = lines
        .iter()
        .position(|l| l.starts_with("block / module"))
        .unwrap_or_else(|| panic!("no table in:\n{t}"));
    let end = lines
        .iter()
        .position(|l| l.starts_with("batch-norm running statistics"))
        .unwrap();
    let count = |l: &str| -> i64 {
        let name_end = l.trim_start().find("  ").unwrap() + (l.len() - l.trim_start().len());
        l[name_end..]
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let (mut blocks, mut modules, mut current) = (0, 0, None::<(i64, i64)>);
    for l in &lines[start + 1..end] {
        if l.starts_with("  ") {
            modules += count(l);
            current.as_mut().unwrap().1 += count(l);
        } else {
            if let Some((b, m)) = current {
                assert_eq!(b, m, "a block is the sum of its modules:\n{t}");
            }
            blocks += count(l);
            current = Some((count(l), 0));
        }
    }
    let (b, m) = current.unwrap();
    assert_eq!(b, m, "{t}");
    let total = number_after(t, "parameters: ");
    assert_eq!((blocks, modules), (total, total), "{t}");
    let paper = number_after(t, "paper: ");
    let paper_line = lines.iter().find(|l| l.starts_with("paper: ")).unwrap();
    let ours = paper_line.rsplit("ours ").next().unwrap();
    let diff: i64 = ours.split_whitespace().next().unwrap().parse().unwrap();
    let pct: f64 = ours.split(['(', '%']).nth(1).unwrap().parse().unwrap();
    assert_eq!(diff, total - paper, "{t}");
    assert!(
        (pct - 100.0 * diff as f64 / paper as f64).abs() < 0.006,
        "{t}"
    );
    (total, paper, pct)
}

/// SAF's published configurations at the paper's size: the table by block beside
/// F-ConvNet's, the paper's count beside ours and within 5% of it, for Car and for
/// Pedestrian + Cyclist (the paper's Tables 4-6 give one count); the shipped SAF's own
/// configuration too, with LFA's gate.
#[test]
fn info_puts_saf_beside_the_papers_count() {
    for config in ["saf-car.toml", "saf-people.toml", "saf-car-sim.toml"] {
        let t = info_of(config);
        assert_mentions(
            &t,
            &[
                "over F-ConvNet",
                "LFA",
                "PointNets",
                "FCN",
                "heads",
                "(SAF, He et al.",
            ],
        );
        let (_, paper, pct) = check_block_table(&t);
        assert_eq!(paper, 3_724_013, "{config}");
        assert!(pct.abs() < 5.0, "{config}: {pct}%\n{t}");
    }
    let shipped = common::repo_root().join("models/saf-car.toml");
    let o = fusiondet(&["info", "--config", shipped.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let (total, paper, pct) = check_block_table(&t);
    assert_eq!(
        total, 3_717_033,
        "the shipped SAF: the paper-size network and LFA's 512 gate scales:\n{t}"
    );
    assert_eq!(paper, 3_724_013, "{t}");
    assert!(pct.abs() < 5.0, "{t}");
    // F-ConvNet's own table has no comparison column and matches its paper's count.
    let t = info_of("fconvnet-car.toml");
    assert!(!t.contains("over F-ConvNet"), "{t}");
    assert_eq!(check_block_table(&t).2, 0.0, "{t}");
}

/// The gated SAF rows count the gate's 512 scales in LFA's block, and stay within 5% of
/// the paper's count; the coordinates' own init adds nothing.
#[test]
fn info_counts_lfas_feature_gate() {
    let plain = check_block_table(&info_of("saf-lfa-car-sim.toml")).0;
    for config in [
        "saf-lfa-gate-car-sim.toml",
        "saf-lfa-gate-own-car-sim.toml",
        "saf-gate-w0-car-sim.toml",
    ] {
        let t = info_of(config);
        assert!(
            t.lines()
                .any(|l| l.trim_start().starts_with("lfa feature gate") && l.contains(" 512 ")),
            "{config}: {t}"
        );
        let (total, paper, pct) = check_block_table(&t);
        assert_eq!(total, plain + 512, "{config}");
        assert_eq!(paper, 3_724_013);
        assert!(pct.abs() < 5.0, "{config}: {pct}%");
    }
    let own = check_block_table(&info_of("saf-lfa-own-car-sim.toml")).0;
    assert_eq!(own, plain);
}

#[test]
fn info_counts_the_refinement_stage_alone_before_its_first_stage_is_trained() {
    // fconvnet-refine-people.toml names runs/fconvnet-people/model.bpk, made by training.
    let t = info_of("fconvnet-refine-people.toml");
    assert_mentions(
        &t,
        &[
            "Refinement stage",
            "parameters: 3316777",
            "First stage not counted",
            "fconvnet-people",
        ],
    );
    assert!(!t.contains("Both stages"), "{t}");
}

#[test]
fn train_and_detect_report_bad_input_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[train]\nbatch_size = \"many\"\n").unwrap();
    let o = fusiondet(&[
        "train",
        "--config",
        bad.to_str().unwrap(),
        "--data",
        "x",
        "--out",
        "y",
    ]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("bad.toml") && text(&o).contains("batch_size"),
        "{}",
        text(&o)
    );

    let tiny = configs().join("tiny.toml");
    let o = fusiondet(&[
        "train",
        "--config",
        tiny.to_str().unwrap(),
        "--data",
        "/no/such/data",
        "--out",
        dir.path().join("run").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("/no/such/data"), "{}", text(&o));

    let o = fusiondet(&[
        "detect",
        "--checkpoint",
        "/no/model.bpk",
        "--data",
        "x",
        "--out",
        "y",
    ]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("checkpoint /no/model.bpk: checkpoint not found"),
        "{}",
        text(&o)
    );
}

/// A SAF network with LFA's gate and the coordinates' own init trains, resumes its config
/// from the checkpoint and detects from the command line (the keys reach the binary).
#[test]
fn a_gated_lfa_network_trains_and_detects_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate_six_frames(dir.path(), &["--seed", "4"]);
    let text_of = std::fs::read_to_string(configs().join("tiny-saf-lfa.toml")).unwrap();
    assert!(text_of.contains("[model.lfa]\n"));
    let gated = text_of.replace(
        "[model.lfa]\n",
        "[model.lfa]\nfeature_gate = \"zero\"\ncoordinate_init = \"own\"\n",
    );
    let config = dir.path().join("tiny-saf-lfa-gated.toml");
    std::fs::write(&config, gated).unwrap();
    let run = dir.path().join("run");
    let o = train(
        &config,
        &data,
        &run,
        &["--epochs", "1", "--max-frames", "6"],
    );
    assert!(o.status.success(), "{}", text(&o));
    let stored = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(
        stored.contains("feature_gate = \"zero\"") && stored.contains("coordinate_init = \"own\""),
        "{stored}"
    );
    let results = dir.path().join("results");
    let o = detect(&run.join("model.bpk"), &data, &results, &["--split", "val"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(results.join(".fusiondet-results").is_file());
}

#[test]
fn train_then_detect_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate_six_frames(dir.path(), &["--seed", "3"]);
    let run = dir.path().join("run");
    let tiny = configs().join("tiny.toml");
    let train_into = |out: &Path| train(&tiny, &data, out, &["--epochs", "1", "--max-frames", "6"]);
    let o = train_into(&run);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("1 epoch(s) run"), "{}", text(&o));
    // The same seed writes the same checkpoint, byte for byte.
    let again = dir.path().join("run-again");
    let o = train_into(&again);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        std::fs::read(run.join("model.bpk")).unwrap()
            == std::fs::read(again.join("model.bpk")).unwrap(),
        "two runs with one seed wrote different checkpoints"
    );
    let results = dir.path().join("results");
    let detect_into = |out: &Path, force: bool| {
        let extra: &[&str] = if force {
            &["--split", "val", "--force"]
        } else {
            &["--split", "val"]
        };
        detect(&run.join("model.bpk"), &data, out, extra)
    };
    let labels = data.join("training/label_2");
    let eval_results = || {
        fusiondet(&[
            "eval",
            "--label-dir",
            labels.to_str().unwrap(),
            "--result-dir",
            results.to_str().unwrap(),
            "--split",
            data.join("ImageSets/val.txt").to_str().unwrap(),
            "--classes",
            "Car",
        ])
    };
    let o = detect_into(&results, false);
    assert!(o.status.success(), "{}", text(&o));
    let ids = std::fs::read_to_string(data.join("ImageSets/val.txt")).unwrap();
    for id in ids.lines() {
        assert!(
            results.join(format!("{id}.txt")).is_file(),
            "no result for {id}"
        );
    }
    let o = eval_results();
    assert!(o.status.success(), "{}", text(&o));

    // What detect writes is its own; nothing else is overwritten.
    let before = std::fs::read(labels.join(format!("{}.txt", ids.lines().next().unwrap())));
    let o = detect_into(&labels, true);
    assert!(!o.status.success());
    assert!(text(&o).contains("lies inside --data"), "{}", text(&o));
    let after = std::fs::read(labels.join(format!("{}.txt", ids.lines().next().unwrap())));
    assert_eq!(before.unwrap(), after.unwrap());
    let users = dir.path().join("users");
    std::fs::create_dir_all(&users).unwrap();
    std::fs::write(users.join("notes.txt"), "mine").unwrap();
    let o = detect_into(&users, true);
    assert!(!o.status.success());
    assert!(text(&o).contains("did not write"), "{}", text(&o));
    let o = detect_into(&results, false);
    assert!(!o.status.success());
    assert!(text(&o).contains("pass --force"), "{}", text(&o));
    let o = detect_into(&results, true);
    assert!(o.status.success(), "{}", text(&o));

    // An interrupted detect, or a result it lists gone missing, is not scored.
    let manifest = results.join(".fusiondet-results");
    let complete = std::fs::read_to_string(&manifest).unwrap();
    std::fs::write(&manifest, complete.replace("complete: yes", "complete: no")).unwrap();
    let o = eval_results();
    assert!(!o.status.success());
    assert!(text(&o).contains("did not finish"), "{}", text(&o));
    std::fs::write(&manifest, &complete).unwrap();
    let first = results.join(format!("{}.txt", ids.lines().next().unwrap()));
    std::fs::remove_file(&first).unwrap();
    let o = eval_results();
    assert!(!o.status.success());
    assert!(
        text(&o).contains("listed as written by detect but missing"),
        "{}",
        text(&o)
    );
    let o = detect_into(&results, true);
    assert!(o.status.success(), "{}", text(&o));
    assert!(eval_results().status.success());

    // `fusiondet bench` of the run's model on the frames, with EXTRA… after.
    let model = run.join("model.bpk");
    let bench = |extra: &[&str]| {
        let common = [
            "bench",
            "--checkpoint",
            model.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
        ];
        fusiondet(&[&common[..], extra].concat())
    };
    let o = bench(&["--repeats", "2"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("2 timed runs") && t.contains("frames/s"), "{t}");
    assert!(t.contains("f32 matrix product on this device"), "{t}");
    // The speed alone: no probe after it.
    let o = bench(&["--repeats", "1", "--no-probes"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("frames/s"), "{t}");
    assert!(
        !t.contains("on this device") && !t.contains("repeated-row"),
        "{t}"
    );
    let o = bench(&["--repeats", "0"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--repeats"), "{}", text(&o));
    // No 2D detection, no frustum: nothing to time (it reported millions of frames/s).
    let empty = dir.path().join("no_detections.txt");
    std::fs::write(&empty, "").unwrap();
    let o = bench(&["--detections", empty.to_str().unwrap()]);
    assert!(!o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("no speed to measure"), "{}", text(&o));
}

#[test]
fn ablation_trains_detects_evaluates_and_plots_every_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate_six_frames(dir.path(), &["--seed", "4", "--traffic-scale", "2"]);
    let out = dir.path().join("ablation");
    let c = configs();
    // The tiny refinement stage (refining the `tiny` row) with generous matching, as the
    // 1-epoch first stage places its boxes roughly.
    let refine = dir.path().join("tiny-fconvnet-refine.toml");
    let shipped = std::fs::read_to_string(c.join("tiny-fconvnet-refine.toml")).unwrap();
    std::fs::write(
        &refine,
        shipped
            .replace("match_iou = 0.1", "match_iou = 0.02")
            .replace("batch_size = 8", "batch_size = 2"),
    )
    .unwrap();
    let args = [
        "ablation",
        "--configs",
        c.join("tiny.toml").to_str().unwrap(),
        refine.to_str().unwrap(),
        c.join("tiny-fcam.toml").to_str().unwrap(),
        c.join("tiny-saf.toml").to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--epochs",
        "1",
    ]
    .map(str::to_string);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = fusiondet(&args);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    for name in ["tiny", "tiny-fconvnet-refine", "tiny-fcam", "tiny-saf"] {
        assert!(t.contains(&format!("| {name} ")), "{name} row missing\n{t}");
        assert!(out.join("runs").join(name).join("model.bpk").is_file());
    }
    // The refinement row refined the `tiny` row's model and counts both stages.
    let first = std::fs::read(out.join("runs/tiny/model.bpk")).unwrap();
    let copy = std::fs::read(out.join("runs/tiny-fconvnet-refine/first-stage.bpk")).unwrap();
    assert!(
        first == copy,
        "the refinement stage used another first stage"
    );
    assert!(t.contains("3D Easy") && t.contains("Occl. 1"), "{t}");
    // The frustum rows beside SAF's Table 4: the refinement row has two stages.
    assert!(t.contains("Car: beside the SAF paper"), "{t}");
    let row_of = |name: &str| {
        t.lines()
            .find(|l| l.starts_with(&format!("| {name} ")) && l.contains(" ours "))
            .unwrap_or_else(|| panic!("no Table 4 row of {name}\n{t}"))
            .to_string()
    };
    assert!(row_of("tiny-fconvnet-refine").contains(" two "), "{t}");
    assert!(row_of("tiny-saf").contains(" one "), "{t}");
    // Each row after the baseline against it, with a frame-bootstrap interval (3D and BEV).
    let intervals = t
        .split("Car: differences from the baseline beyond the frames drawn")
        .nth(1)
        .unwrap_or_else(|| panic!("no interval tables\n{t}"));
    let intervals = intervals.split("###").next().unwrap();
    assert!(
        intervals.contains("1000 resamples of the 3 val frames"),
        "{intervals}"
    );
    for name in ["tiny-fconvnet-refine", "tiny-fcam", "tiny-saf"] {
        assert_eq!(
            intervals.matches(&format!("| {name} ")).count(),
            2,
            "{name}: a 3D and a BEV line\n{intervals}"
        );
    }
    assert!(
        !intervals.contains("| tiny "),
        "the baseline has no line\n{intervals}"
    );
    assert!(
        t.contains("3,724,013") && t.contains("79.91"),
        "the paper's SAF row\n{t}"
    );
    for f in [
        "ablation.md",
        "ablation.json",
        "pr-car-3d.png",
        "pr-car-bev.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("ablation.json")).unwrap()).unwrap();
    let rows = json["configurations"].as_array().unwrap();
    assert_eq!(rows.len(), 4);
    let against = json["against_baseline"].as_array().unwrap();
    let names: Vec<&str> = against
        .iter()
        .map(|d| d["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["tiny-fconvnet-refine", "tiny-fcam", "tiny-saf"]);
    assert_eq!(against[2]["resamples"], 1000, "{json}");
    assert!(against[2]["rows"].as_array().unwrap().len() >= 3, "{json}");
    assert_eq!(
        rows[1]["params"].as_u64().unwrap(),
        2 * rows[0]["params"].as_u64().unwrap(),
        "{json}"
    );
    // A re-run resumes the finished trainings instead of repeating them, and a row stopped
    // before its first epoch was committed (config.toml written, no state yet) starts over.
    let saf = out.join("runs/tiny-saf");
    std::fs::remove_dir_all(&saf).unwrap();
    std::fs::create_dir_all(&saf).unwrap();
    std::fs::write(
        saf.join("config.toml"),
        std::fs::read_to_string(c.join("tiny-saf.toml")).unwrap(),
    )
    .unwrap();
    let o = fusiondet(&args);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("0 epoch(s) run"), "{}", text(&o));
    assert!(saf.join("model.bpk").is_file());
    // Each row's detections are kept where its checkpoint is byte for byte the one they
    // came from (SAF's retraining from the same seed wrote the same bytes), with the
    // same scores.
    assert_eq!(
        text(&o)
            .matches("detections of this checkpoint kept")
            .count(),
        4,
        "{}",
        text(&o)
    );
    let rerun: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("ablation.json")).unwrap()).unwrap();
    for (a, b) in rows.iter().zip(rerun["configurations"].as_array().unwrap()) {
        assert_eq!(a["results"], b["results"], "{}: the same AP", a["name"]);
    }

    // The same trained models as rows without training (`--models`): each finds its
    // configuration in its run (the refinement its own first stage) and scores what the
    // training ablation scored.
    let again = dir.path().join("from-models");
    let o = fusiondet(&[
        "ablation",
        "--models",
        out.join("runs/tiny/model.bpk").to_str().unwrap(),
        out.join("runs/tiny-fconvnet-refine/model.bpk")
            .to_str()
            .unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
        "--resamples",
        "0",
    ]);
    let t2 = text(&o);
    assert!(o.status.success(), "{t2}");
    assert!(!t2.contains("training"), "nothing is trained\n{t2}");
    assert!(
        !t2.contains("beyond the frames drawn"),
        "--resamples 0\n{t2}"
    );
    assert!(!again.join("runs").exists());
    let two_stage = t2
        .lines()
        .find(|l| l.starts_with("| tiny-fconvnet-refine ") && l.contains(" ours "))
        .unwrap_or_else(|| panic!("no Table 4 row of the refinement\n{t2}"));
    assert!(two_stage.contains(" two "), "{t2}");
    let json2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(again.join("ablation.json")).unwrap())
            .unwrap();
    let rows2 = json2["configurations"].as_array().unwrap();
    assert_eq!(rows2.len(), 2);
    assert!(json2.get("against_baseline").is_none(), "--resamples 0");
    for (a, b) in rows.iter().zip(rows2) {
        assert_eq!(a["name"], b["name"]);
        assert_eq!(a["params"], b["params"]);
        assert_eq!(a["results"], b["results"], "{}: the same AP", a["name"]);
        assert_eq!(a["breakdown"], b["breakdown"], "{}", a["name"]);
    }
}

#[test]
fn ablation_and_omega_study_reject_bad_input() {
    let c = configs();
    let o = fusiondet(&[
        "ablation",
        "--configs",
        c.join("tiny.toml").to_str().unwrap(),
        c.join("fconvnet-people.toml").to_str().unwrap(),
        "--data",
        "/nonexistent",
        "--out",
        "/tmp/unused-ablation",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("same classes"), "{}", text(&o));
    let o = fusiondet(&[
        "ablation",
        "--configs",
        c.join("tiny-fconvnet-refine.toml").to_str().unwrap(),
        c.join("tiny.toml").to_str().unwrap(),
        "--data",
        "/nonexistent",
        "--out",
        "/tmp/unused-ablation",
    ]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("first stage listed before it"),
        "{}",
        text(&o)
    );
    // Trained checkpoints are compared as they are: training flags are refused, and one
    // of --configs and --models is needed.
    let shipped = common::repo_root().join("models/fconvnet-car.bpk");
    for (extra, says) in [
        (vec!["--epochs", "2"], "cannot be given with it"),
        (vec!["--seeds", "1,2"], "cannot be used with"),
    ] {
        let mut args = vec![
            "ablation",
            "--models",
            shipped.to_str().unwrap(),
            "--data",
            "/nonexistent",
            "--out",
            "/tmp/unused-ablation",
        ];
        args.extend(extra);
        let o = fusiondet(&args);
        assert!(!o.status.success());
        assert!(text(&o).contains(says), "{}", text(&o));
    }
    let o = fusiondet(&[
        "ablation",
        "--data",
        "/nonexistent",
        "--out",
        "/tmp/unused-ablation",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--configs"), "{}", text(&o));
    let o = fusiondet(&[
        "omega-study",
        "--config",
        c.join("tiny.toml").to_str().unwrap(),
        "--data",
        "/nonexistent",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("depth_guided"), "{}", text(&o));
    let o = fusiondet(&[
        "simulate",
        "--out",
        "/tmp/x",
        "--frames",
        "1",
        "--traffic-scale=0",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--traffic-scale"), "{}", text(&o));
}

#[test]
fn omega_study_runs_on_the_bundled_frames() {
    let kitti = common::repo_root().join("data/kitti-sample");
    let o = fusiondet(&[
        "omega-study",
        "--config",
        configs().join("saf-car.toml").to_str().unwrap(),
        "--data",
        kitti.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("0.85"), "{}", text(&o));
}

#[test]
fn a_refinement_stage_trains_and_detects_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate_six_frames(dir.path(), &["--seed", "4"]);
    let first = dir.path().join("first");
    let train_on_sim = |config: &Path, out: &Path, extra: &[&str]| train(config, &data, out, extra);
    let o = train_on_sim(&configs().join("tiny.toml"), &first, &["--epochs", "2"]);
    assert!(o.status.success(), "{}", text(&o));
    // The shipped tiny refinement config, with this first stage and generous matching
    // (a config of the test's own, beside the first stage it names relatively).
    let shipped = std::fs::read_to_string(configs().join("tiny-fconvnet-refine.toml")).unwrap();
    let config = dir.path().join("tiny-fconvnet-refine.toml");
    std::fs::write(
        &config,
        shipped
            .replace("../runs/tiny/model.bpk", "first/model.bpk")
            .replace("match_iou = 0.1", "match_iou = 0.02")
            .replace("batch_size = 8", "batch_size = 2"),
    )
    .unwrap();
    let refine = dir.path().join("refine");
    let o = train_on_sim(&config, &refine, &["--epochs", "1"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(refine.join("first-stage.bpk").is_file());
    // --first-stage overrides the config; a first-stage config refuses it.
    let o = train_on_sim(
        &config,
        &dir.path().join("r2"),
        &["--epochs", "1", "--first-stage", "/no/first.bpk"],
    );
    assert!(!o.status.success());
    assert!(text(&o).contains("/no/first"), "{}", text(&o));
    let o = train_on_sim(
        &configs().join("tiny.toml"),
        &dir.path().join("r3"),
        &["--first-stage", "x.bpk"],
    );
    assert!(!o.status.success());
    assert!(text(&o).contains("no [refine] table"), "{}", text(&o));
    // Detection runs both stages from the self-contained run directory.
    std::fs::remove_dir_all(&first).unwrap();
    let results = dir.path().join("results");
    let o = detect(&refine.join("model.bpk"), &data, &results, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let ids = std::fs::read_to_string(data.join("ImageSets/val.txt")).unwrap();
    for id in ids.lines() {
        assert!(results.join(format!("{id}.txt")).is_file(), "{id}");
    }
    let o = fusiondet(&[
        "bench",
        "--checkpoint",
        refine.join("model.bpk").to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--repeats",
        "1",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("frames/s"), "{}", text(&o));
}

/// The process ids whose parent is `parent` (from /proc).
#[cfg(target_os = "linux")]
fn children_of(parent: u32) -> Vec<u32> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else {
            continue;
        };
        // `pid (comm) state ppid ...`; comm may hold spaces, so read after the last ')'.
        let after = &stat[stat.rfind(')').unwrap() + 1..];
        let fields: Vec<&str> = after.split_whitespace().collect();
        if fields.get(1).and_then(|p| p.parse::<u32>().ok()) == Some(parent) {
            out.push(pid);
        }
    }
    out
}

/// Whether `pid` is running (not gone, not a zombie).
#[cfg(target_os = "linux")]
fn running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| {
        let after = &stat[stat.rfind(')').unwrap() + 1..];
        !after.trim_start().starts_with('Z')
    })
}

/// `BINARY ablation` of the tiny configuration on `data` into `out` for `epochs` epochs.
#[cfg(target_os = "linux")]
fn tiny_ablation(binary: &Path, data: &Path, out: &Path, epochs: &str) -> std::process::Command {
    let mut command = std::process::Command::new(binary);
    command.args([
        "ablation",
        "--configs",
        configs().join("tiny.toml").to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--epochs",
        epochs,
    ]);
    command
}

#[cfg(target_os = "linux")]
#[test]
fn a_killed_ablation_takes_its_training_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate_six_frames(dir.path(), &["--seed", "6"]);
    let binary = Path::new(env!("CARGO_BIN_EXE_fusiondet"));
    let mut ablation = tiny_ablation(binary, &data, &dir.path().join("ablation"), "1000")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    let train = loop {
        if let Some(&pid) = children_of(ablation.id()).first() {
            break pid;
        }
        assert!(started.elapsed().as_secs() < 60, "no training started");
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    ablation.kill().unwrap();
    ablation.wait().unwrap();
    let killed = std::time::Instant::now();
    while running(train) {
        assert!(
            killed.elapsed().as_secs() < 30,
            "the training {train} outlived its ablation"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// The binary an ablation was started from is removed (a rebuild or an upgrade while it
/// runs) before its first training starts: the trainings still run, in the ablation's own
/// image.
#[cfg(target_os = "linux")]
#[test]
fn an_ablation_outlives_the_removal_of_its_binary() {
    let dir = tempfile::tempdir().unwrap();
    let data = simulate_six_frames(dir.path(), &["--seed", "6"]);
    let copy = dir.path().join("fusiondet-copy");
    std::fs::copy(env!("CARGO_BIN_EXE_fusiondet"), &copy).unwrap();
    let out = dir.path().join("ablation");
    let ablation = tiny_ablation(&copy, &data, &out, "1")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // `spawn` returns once the new process runs the copy, so the file can go now.
    std::fs::remove_file(&copy).unwrap();
    let o = ablation.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(out.join("runs/tiny/model.bpk").is_file(), "{}", text(&o));
    assert!(text(&o).contains("| tiny "), "{}", text(&o));
}
