//! The binary as a user installs it: copied away from the source tree and run from an
//! empty directory, and the demo's results against those of the binary before the
//! crates were reshaped for a second detector family.

mod common;

use common::{all_output, repo_root};
use std::path::Path;
use std::process::Command;

/// Every result file of the demo (16 frames, seed 2026) with each shipped Car model (kept
/// in `tests/data/demo-results-<model>/`). The demo must keep writing exactly these bytes:
/// the same detections from the same checkpoints. They were pinned before the crates were
/// reshaped for a second detector family, and written anew when detection's point sampling
/// came to draw from streams named by frame (so that a split detected in chunks gives what
/// it gives whole) and to put a small frustum's distinct points before its repeats.
/// Voxel R-CNN's and DASANet's were pinned when each joined the demo (DASANet's anew when its
/// third-form model was shipped), SAF's anew when the shipped SAF was retrained on the
/// baseline's budget and again when the gated SAF with ω = 0 replaced it, the two-stage and people models' when
/// they were shipped, SAF people's anew when its gated form replaced it (each the same with 1
/// and 2 threads).
#[test]
fn the_demo_writes_the_same_result_files_as_before_with_every_shipped_model() {
    let dir = tempfile::tempdir().unwrap();
    for model in [
        "fconvnet",
        "fcam",
        "saf",
        "voxel-rcnn",
        "dasanet",
        "fconvnet-refine",
        "fconvnet-people",
        "saf-people",
        "fconvnet-refine-people",
    ] {
        let out = dir.path().join(model);
        let o = Command::new(env!("CARGO_BIN_EXE_fusiondet"))
            .args(["demo", "--model", model, "--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{model}: {}", all_output(&o));
        let expected = repo_root().join(format!("crates/cli/tests/data/demo-results-{model}"));
        let mut compared = 0;
        for split in ["sim", "kitti"] {
            let mut names: Vec<_> = std::fs::read_dir(expected.join(split))
                .unwrap()
                .map(|e| e.unwrap().file_name())
                .collect();
            names.sort();
            // Result files only (detect's manifest beside them is not one).
            let written = std::fs::read_dir(out.join("results").join(split))
                .unwrap()
                .filter(|e| {
                    e.as_ref()
                        .unwrap()
                        .path()
                        .extension()
                        .is_some_and(|x| x == "txt")
                })
                .count();
            assert_eq!(written, names.len(), "{model} {split}: result file count");
            for name in names {
                let want = std::fs::read(expected.join(split).join(&name)).unwrap();
                let got = std::fs::read(out.join("results").join(split).join(&name)).unwrap();
                assert!(
                    want == got,
                    "{model} {split}/{}: differs from the result before the restructuring\nbefore:\n{}\nnow:\n{}",
                    name.to_string_lossy(),
                    String::from_utf8_lossy(&want),
                    String::from_utf8_lossy(&got)
                );
                compared += 1;
            }
        }
        assert_eq!(compared, 13, "{model}");
    }
}

/// `cargo install` puts the binary far from the source tree: the demo (every shipped
/// model) must run from an empty directory with nothing but the binary.
#[test]
fn an_installed_binary_runs_the_demo_from_an_empty_directory() {
    let bin_dir = tempfile::tempdir().unwrap();
    let installed = bin_dir.path().join("fusiondet");
    std::fs::copy(env!("CARGO_BIN_EXE_fusiondet"), &installed).unwrap();
    let work = tempfile::tempdir().unwrap();
    for model in ["fconvnet", "saf", "voxel-rcnn", "dasanet"] {
        let out = format!("demo-{model}");
        let o = Command::new(&installed)
            .current_dir(work.path())
            .args(["demo", "--frames", "4", "--model", model, "--out", &out])
            .output()
            .unwrap();
        let t = all_output(&o);
        assert!(o.status.success(), "--model {model}: {t}");
        assert!(t.contains("bundled KITTI frames"), "{t}");
        let out = work.path().join(out);
        for f in [
            "eval-sim.json",
            "eval-kitti.json",
            "pictures/kitti-000001.png",
        ] {
            assert!(out.join(f).is_file(), "{model}: {f} missing\n{t}");
        }
        assert!(Path::new(&out.join("kitti/training/velodyne/000134.bin")).is_file());
    }
}
