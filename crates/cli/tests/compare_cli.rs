//! End-to-end tests of `fusiondet compare`: a demo's pinned results against themselves,
//! against a copy with one box moved 5 cm, and bad input.

mod common;

use common::{all_output, repo_root, s};
use std::path::Path;

fn pinned() -> std::path::PathBuf {
    repo_root().join("crates/cli/tests/data/demo-results-fconvnet/sim")
}

#[test]
fn a_result_directory_equals_itself_and_a_moved_box_is_caught() {
    let o = common::run("compare", &[s(&pinned()), s(&pinned())]);
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("same boxes within 0.01 m"), "{out}");

    // A copy whose first box of the first frame moved 5 cm along x.
    let dir = tempfile::tempdir().unwrap();
    let moved = dir.path().join("moved");
    std::fs::create_dir(&moved).unwrap();
    let mut first = true;
    for entry in std::fs::read_dir(pinned()).unwrap() {
        let path = entry.unwrap().path();
        let mut text = std::fs::read_to_string(&path).unwrap();
        if first && path.file_name().unwrap() == "000000.txt" {
            let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
            let mut f: Vec<String> = lines[0].split(' ').map(str::to_string).collect();
            let x: f64 = f[11].parse().unwrap();
            f[11] = format!("{:.2}", x + 0.05);
            lines[0] = f.join(" ");
            text = lines.join("\n") + "\n";
            first = false;
        }
        std::fs::write(moved.join(path.file_name().unwrap()), text).unwrap();
    }
    assert!(!first, "the pinned results hold frame 000000");
    let o = common::run("compare", &[s(&pinned()), s(&moved)]);
    let out = all_output(&o);
    assert!(!o.status.success(), "{out}");
    assert!(out.contains("largest centre offset  0.05"), "{out}");
    assert!(out.contains("differ beyond the tolerance"), "{out}");
    // A wider tolerance accepts it.
    let o = common::run(
        "compare",
        &[s(&pinned()), s(&moved), "--max-metres", "0.06"],
    );
    assert!(o.status.success(), "{}", all_output(&o));
}

#[test]
fn bad_input_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nothing");
    common::assert_fails_with("compare", &[s(&pinned()), s(&missing)], "no such directory");
    common::assert_fails_with(
        "compare",
        &[s(dir.path()), s(dir.path())],
        "holds a result file",
    );
    common::assert_fails_with(
        "compare",
        &[s(&pinned()), s(&pinned()), "--max-score", "nan"],
        "a tolerance is a finite number",
    );
    std::fs::write(dir.path().join("000000.txt"), "Car 0 0 0 1 2 3\n").unwrap();
    common::assert_fails_with("compare", &[s(&pinned()), s(dir.path())], "000000.txt");
}

/// `scripts/gpu-check.sh` on the CPU as its device, with this build, six simulated frames,
/// the tiny Voxel R-CNN's training of two frames and `out` as its work directory.
fn gpu_check_on_the_cpu(out: &Path) -> std::process::Command {
    let mut command = std::process::Command::new("bash");
    command
        .arg(repo_root().join("scripts/gpu-check.sh"))
        .env("FUSIONDET", env!("CARGO_BIN_EXE_fusiondet"))
        .env("DEVICE", "cpu")
        .env("TRAIN_CONFIGS", "configs/tiny-voxel-rcnn.toml")
        .env("FRAMES", "6")
        .env("REPEATS", "1")
        .env("STEPS_FRAMES", "2")
        .env("CHECK_OUT", out);
    command
}

/// `scripts/gpu-check.sh` as a dry run, the CPU against itself: the script a lent GPU runs
/// must not fail on its own bugs in the few minutes it has.
#[test]
fn the_gpu_check_script_runs_through_against_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let o = gpu_check_on_the_cpu(dir.path())
        .env("MODELS", "fconvnet-car voxel-rcnn-car")
        .output()
        .unwrap();
    let out = all_output(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("fconvnet-car     parity same"), "{out}");
    assert!(out.contains("voxel-rcnn-car   parity same"), "{out}");
    // The RoI query's A/B ran for the voxel model: its check, and its boxes with the kernels
    // against the host query's (on the CPU both are the host query).
    assert!(
        out.contains("voxel-rcnn-car   RoI query kernels on cpu: 0 of "),
        "{out}"
    );
    assert!(
        out.contains("boxes with the RoI query kernels against the host query on cpu: same"),
        "{out}"
    );
    // The sparse convolution's A/B ran for the voxel model: a kernel map of burn's
    // operations, whose boxes on the CPU match the per-offset layout's.
    assert!(
        out.contains(
            "voxel-rcnn-car   sparse convolution as a kernel map on cpu: parity with the cpu same"
        ),
        "{out}"
    );
    // The repeated-row probe from the first bench: the CPU against itself.
    assert!(
        out.contains("repeated-row additions (every gather's backward) on cpu, largest relative difference from the cpu: 0.0e0"),
        "{out}"
    );
    // The sparse gradient probe from the voxel model's bench: the CPU against itself.
    assert!(
        out.contains(
            "voxel-rcnn-car   sparse convolution on this device (20000 sites, 16 → 16, layout \
             per-offset): largest difference from the CPU's, relative to its largest value: \
             output 0.0e0, input gradient 0.0e0, weight gradient 0.0e0"
        ),
        "{out}"
    );
    // The four runs' first-step losses were read (an unread one would also compare as 0):
    // the CPU's, the device's (the CPU again), the device's with the sparse convolution as a
    // kernel map (the same sums in another order) and with the RoI query on the host (on the
    // CPU, its default: the same bits).
    let losses = out
        .split("first-step loss ")
        .nth(1)
        .and_then(|rest| rest.split(';').next())
        .unwrap_or("");
    let runs: Vec<f64> = losses.split('/').filter_map(|v| v.parse().ok()).collect();
    assert!(
        runs.len() == 4
            && runs[0] > 0.0
            && runs[0] == runs[1]
            && (runs[2] - runs[0]).abs() <= 1e-5 * runs[0]
            && runs[3] == runs[0],
        "{out}"
    );
    // The device's loss curve (here the CPU's again) followed the CPU's step by step.
    assert!(
        out.contains(
            "loss curve against the CPU's: first step 0.00e+00, at most 0.00e+00 (step 1 of 2)/"
        ),
        "{out}"
    );
    assert!(out.contains("s/step"), "{out}");
    // Where the time goes: each bench's stages, and the voxel family's training step by part.
    assert!(
        out.contains("fconvnet-car     stages on cpu, ms a frame: "),
        "{out}"
    );
    assert!(
        out.contains("forward: ") && out.contains("roi_query "),
        "{out}"
    );
    // The matrix-product probe was read from both benches: the same CPU figure twice.
    let errors: Vec<f64> = out
        .split("largest relative error: cpu ")
        .nth(1)
        .and_then(|rest| rest.split(" (").next())
        .map(|pair| {
            pair.split(", cpu ")
                .filter_map(|v| v.parse().ok())
                .collect()
        })
        .unwrap_or_default();
    assert!(
        errors.len() == 2 && errors[0] > 0.0 && errors[0] < 1e-5 && errors[0] == errors[1],
        "{out}"
    );
}

/// `scripts/gpu-check.sh` holds a device's loss curve to a CPU curve given on the command line
/// (`TRAIN_CPU=0 CPU_LOSS_CURVES=…`, the lent machine's way): the CPU's own curve passes, the
/// same curve with its second step 1% off is a failed check.
#[test]
fn the_gpu_check_script_holds_a_device_to_the_cpus_loss_curve() {
    let dir = tempfile::tempdir().unwrap();
    let run = |curves: Option<&str>| {
        let mut command = gpu_check_on_the_cpu(dir.path());
        command
            .env("MODELS", " ")
            .env("AB", "0")
            .env("PROFILE", "0");
        if let Some(curves) = curves {
            command.env("TRAIN_CPU", "0").env("CPU_LOSS_CURVES", curves);
        }
        let o = command.output().unwrap();
        (o.status.success(), all_output(&o))
    };
    let (ok, out) = run(None);
    assert!(ok, "{out}");
    let curve = out
        .lines()
        .find_map(|line| line.split("loss curve, cpu: ").nth(1))
        .unwrap_or_else(|| panic!("no curve: {out}"))
        .trim()
        .to_string();
    let steps: Vec<f64> = curve.split(',').map(|v| v.parse().unwrap()).collect();
    assert!(steps.len() == 2 && steps[0] != steps[1], "{out}");

    let (ok, out) = run(Some(&format!("tiny-voxel-rcnn={curve}")));
    assert!(ok, "{out}");
    assert!(
        out.contains("loss curve against the CPU's: first step 0.00e+00, at most 0.00e+00"),
        "{out}"
    );

    let off = format!("tiny-voxel-rcnn={},{}", steps[0], steps[1] * 1.01);
    let (ok, out) = run(Some(&off));
    assert!(!ok, "{out}");
    assert!(
        out.contains("first step 0.00e+00, at most 9.90e-03 (step 2 of 2): outside tolerance"),
        "{out}"
    );
}
