//! `FUSIONDET_CUSTOM_OPS`: `off` trains on burn's generic operations instead of the custom
//! flex ones (`nn::ragged`, `nn::conv2d`): the tiny SAF's loss stays within float tolerance
//! of the custom path's while its weights differ in the last bits (so the variable took
//! effect); a value the variable does not know is named and ignored (the custom path's
//! weights to the bit).

mod common;

use common::{all_output, repo_root, run, s};
use std::path::Path;
use std::process::{Command, Output};

fn train(data: &Path, out: &Path, custom_ops: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_fusiondet"));
    command.env_remove("FUSIONDET_CUSTOM_OPS");
    if let Some(value) = custom_ops {
        command.env("FUSIONDET_CUSTOM_OPS", value);
    }
    let config = repo_root().join("configs/tiny-saf.toml");
    command
        .args([
            "train",
            "--config",
            s(&config),
            "--data",
            s(data),
            "--out",
            s(out),
        ])
        .args(["--epochs", "2"])
        .output()
        .expect("run fusiondet")
}

fn last_loss(run_dir: &Path) -> f64 {
    let metrics = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap();
    let last: serde_json::Value = serde_json::from_str(metrics.lines().last().unwrap()).unwrap();
    last["loss_total"].as_f64().unwrap()
}

#[test]
fn generic_operations_train_alike_and_unknown_values_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let o = run(
        "simulate",
        &["--out", s(&data), "--frames", "6", "--seed", "5"],
    );
    assert!(o.status.success(), "{}", all_output(&o));
    let runs = ["custom", "generic", "unknown"].map(|name| dir.path().join(name));
    for (run_dir, value) in runs.iter().zip([None, Some("off"), Some("fastest")]) {
        let o = train(&data, run_dir, value);
        let text = all_output(&o);
        assert!(o.status.success(), "{text}");
        assert_eq!(
            text.contains("FUSIONDET_CUSTOM_OPS=\"fastest\" is neither"),
            value == Some("fastest"),
            "{text}"
        );
    }
    let model = |run_dir: &Path| std::fs::read(run_dir.join("model.bpk")).unwrap();
    let [custom, generic, unknown] = &runs;
    let (a, b) = (last_loss(custom), last_loss(generic));
    assert!(
        (a - b).abs() <= 1e-2 * a.abs().max(1.0),
        "custom {a} vs generic {b}"
    );
    assert!(model(custom) != model(generic), "`off` took effect");
    assert!(
        model(custom) == model(unknown),
        "an unknown value keeps the custom operations"
    );
}
