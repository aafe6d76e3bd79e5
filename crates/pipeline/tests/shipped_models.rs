//! The checkpoints shipped in `models/`: each fits the repository's size budget, has the
//! configuration it was trained with beside it, and loads into a detector of its family
//! (both stages for the refinement model).

use burn::prelude::Device;
use fusiondet_pipeline::{Detector, ExperimentConfig};
use std::path::{Path, PathBuf};

/// Largest shipped checkpoint: keeps a clone small enough to carry every variant.
const MAX_CHECKPOINT_BYTES: u64 = 16 * 1024 * 1024;

fn models_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models")
}

#[test]
fn every_shipped_checkpoint_is_small_configured_and_loads() {
    let device = Device::flex();
    let mut stems = Vec::new();
    for entry in std::fs::read_dir(models_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "bpk") {
            continue;
        }
        let size = std::fs::metadata(&path).unwrap().len();
        assert!(
            size <= MAX_CHECKPOINT_BYTES,
            "{}: {size} bytes",
            path.display()
        );
        let config = ExperimentConfig::for_checkpoint(&path, None)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let stem = path.file_stem().unwrap().to_string_lossy().to_string();
        // The stored configuration is the `-sim` schedule named after the file.
        assert_eq!(config.name, format!("{stem}-sim"), "{}", path.display());
        let detector = Detector::load(config, &path, &device)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        match detector {
            Detector::Frustum(detector) => assert_eq!(
                detector.first_stage.is_some(),
                stem.contains("refine"),
                "{stem}"
            ),
            Detector::VoxelRcnn(_) => assert!(stem.starts_with("voxel-rcnn"), "{stem}"),
            Detector::Dasanet(_) => assert!(stem.starts_with("dasanet"), "{stem}"),
        }
        stems.push(stem);
    }
    stems.sort();
    // The frustum baseline and the seeds' variants (the refinement stage is optional), and
    // the second family's baseline.
    for needed in ["fcam-car", "fconvnet-car", "saf-car", "voxel-rcnn-car"] {
        assert!(
            stems.iter().any(|s| s == needed),
            "models/{needed}.bpk is missing"
        );
    }
}
