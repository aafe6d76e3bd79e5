//! Data that ships inside the binary, so that an installed `fusiondet` runs its demo
//! from any directory with the source tree out of reach: the seven bundled KITTI frames
//! (`data/kitti-sample/`, CC BY-NC-SA 3.0, see its README) and the shipped Car
//! models with the configurations they were trained with (`models/`).

use anyhow::Context;
use std::path::Path;

/// Every file of `data/kitti-sample/` but its README, by path relative to it. A test
/// checks that the list and the directory agree.
pub const KITTI_SAMPLE: &[(&str, &[u8])] = &[
    (
        "ImageSets/train.txt",
        include_bytes!("../../../data/kitti-sample/ImageSets/train.txt"),
    ),
    (
        "ImageSets/trainval.txt",
        include_bytes!("../../../data/kitti-sample/ImageSets/trainval.txt"),
    ),
    (
        "ImageSets/val.txt",
        include_bytes!("../../../data/kitti-sample/ImageSets/val.txt"),
    ),
    (
        "rgb_detections/rgb_detection_train.txt",
        include_bytes!("../../../data/kitti-sample/rgb_detections/rgb_detection_train.txt"),
    ),
    (
        "rgb_detections/rgb_detection_val.txt",
        include_bytes!("../../../data/kitti-sample/rgb_detections/rgb_detection_val.txt"),
    ),
    (
        "training/calib/000000.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000000.txt"),
    ),
    (
        "training/calib/000001.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000001.txt"),
    ),
    (
        "training/calib/000002.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000002.txt"),
    ),
    (
        "training/calib/000003.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000003.txt"),
    ),
    (
        "training/calib/000004.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000004.txt"),
    ),
    (
        "training/calib/000005.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000005.txt"),
    ),
    (
        "training/calib/000134.txt",
        include_bytes!("../../../data/kitti-sample/training/calib/000134.txt"),
    ),
    (
        "training/image_2/000000.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000000.png"),
    ),
    (
        "training/image_2/000001.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000001.png"),
    ),
    (
        "training/image_2/000002.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000002.png"),
    ),
    (
        "training/image_2/000003.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000003.png"),
    ),
    (
        "training/image_2/000004.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000004.png"),
    ),
    (
        "training/image_2/000005.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000005.png"),
    ),
    (
        "training/image_2/000134.png",
        include_bytes!("../../../data/kitti-sample/training/image_2/000134.png"),
    ),
    (
        "training/label_2/000000.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000000.txt"),
    ),
    (
        "training/label_2/000001.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000001.txt"),
    ),
    (
        "training/label_2/000002.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000002.txt"),
    ),
    (
        "training/label_2/000003.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000003.txt"),
    ),
    (
        "training/label_2/000004.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000004.txt"),
    ),
    (
        "training/label_2/000005.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000005.txt"),
    ),
    (
        "training/label_2/000134.txt",
        include_bytes!("../../../data/kitti-sample/training/label_2/000134.txt"),
    ),
    (
        "training/velodyne/000000.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000000.bin"),
    ),
    (
        "training/velodyne/000001.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000001.bin"),
    ),
    (
        "training/velodyne/000002.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000002.bin"),
    ),
    (
        "training/velodyne/000003.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000003.bin"),
    ),
    (
        "training/velodyne/000004.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000004.bin"),
    ),
    (
        "training/velodyne/000005.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000005.bin"),
    ),
    (
        "training/velodyne/000134.bin",
        include_bytes!("../../../data/kitti-sample/training/velodyne/000134.bin"),
    ),
];

/// Writes the bundled KITTI frames under `dir` (a KITTI-layout data set root).
pub fn write_kitti_sample(dir: &Path) -> anyhow::Result<()> {
    for (relative, bytes) in KITTI_SAMPLE {
        let path = dir.join(relative);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("{}: cannot create", parent.display()))?;
        }
        fusiondet_kitti::write_atomic(&path, bytes)?;
    }
    Ok(())
}

/// A shipped model: its checkpoint and the configuration it was trained with.
pub struct ShippedFiles {
    pub checkpoint: &'static [u8],
    pub config: &'static str,
}

/// The checkpoint and configuration of `models/<name>.bpk` / `.toml`, built into the binary.
#[cfg(feature = "embedded-models")]
macro_rules! shipped {
    ($name:literal) => {
        ShippedFiles {
            checkpoint: include_bytes!(concat!("../../../models/", $name, ".bpk")),
            config: include_str!(concat!("../../../models/", $name, ".toml")),
        }
    };
}

#[cfg(feature = "embedded-models")]
pub use embedded::*;

/// The shipped models, present with the `embedded-models` feature.
#[cfg(feature = "embedded-models")]
mod embedded {
    use super::ShippedFiles;

    pub const FCONVNET_CAR: ShippedFiles = shipped!("fconvnet-car");
    pub const FCAM_CAR: ShippedFiles = shipped!("fcam-car");
    pub const SAF_CAR: ShippedFiles = shipped!("saf-car");
    pub const VOXEL_RCNN_CAR: ShippedFiles = shipped!("voxel-rcnn-car");
    pub const DASANET_CAR: ShippedFiles = shipped!("dasanet-car");
    /// The second stage only: its configuration names `fconvnet-car.bpk` as its first stage.
    pub const FCONVNET_REFINE_CAR: ShippedFiles = shipped!("fconvnet-refine-car");
    pub const FCONVNET_PEOPLE: ShippedFiles = shipped!("fconvnet-people");
    pub const SAF_PEOPLE: ShippedFiles = shipped!("saf-people");
    /// The second stage only: its configuration names `fconvnet-people.bpk` as its first
    /// stage.
    pub const FCONVNET_REFINE_PEOPLE: ShippedFiles = shipped!("fconvnet-refine-people");
}

/// The tiny network's configuration, as shipped in `configs/tiny.toml`.
pub const TINY_CONFIG: &str = include_str!("../../../configs/tiny.toml");

/// The tiny network on SUN RGB-D's ten classes, as shipped in `configs/tiny-sunrgbd.toml`.
pub const TINY_SUNRGBD_CONFIG: &str = include_str!("../../../configs/tiny-sunrgbd.toml");

/// The real SUN RGB-D scene of the `sunrgbd` crate's fixture (`crates/sunrgbd/tests/data`,
/// see its README): points (5,000, float32 × 6), image, calibration and labels, by path
/// relative to a prepared directory.
pub const SUNRGBD_SCENE: &[(&str, &[u8])] = &[
    (
        "points/000017.bin",
        include_bytes!("../../sunrgbd/tests/data/points/000017.bin"),
    ),
    (
        "image/000017.jpg",
        include_bytes!("../../sunrgbd/tests/data/image/000017.jpg"),
    ),
    (
        "calib/000017.txt",
        include_bytes!("../../sunrgbd/tests/data/calib/000017.txt"),
    ),
    (
        "label/000017.txt",
        include_bytes!("../../sunrgbd/tests/data/label/000017.txt"),
    ),
];

/// The id of the bundled real scene.
pub const SUNRGBD_SCENE_ID: &str = "000017";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_scene_is_the_fixture_and_the_tiny_config_the_shipped_one() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../sunrgbd/tests/data");
        for (relative, bytes) in SUNRGBD_SCENE {
            assert_eq!(
                &std::fs::read(root.join(relative)).unwrap(),
                bytes,
                "{relative}"
            );
            assert!(relative.contains(SUNRGBD_SCENE_ID), "{relative}");
        }
        // Points, image, calibration, labels: a scene the readers take.
        assert_eq!(SUNRGBD_SCENE[0].1.len(), 5_000 * 24);
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        assert_eq!(
            std::fs::read_to_string(configs.join("tiny-sunrgbd.toml")).unwrap(),
            TINY_SUNRGBD_CONFIG
        );
    }

    #[test]
    fn the_embedded_sample_is_the_whole_directory() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample");
        let mut on_disk = Vec::new();
        let mut stack = vec![root.clone()];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    stack.push(path);
                } else if path.file_name().unwrap() != "README.md" {
                    let relative = path.strip_prefix(&root).unwrap();
                    on_disk.push(relative.to_string_lossy().replace('\\', "/"));
                }
            }
        }
        on_disk.sort();
        let embedded: Vec<String> = KITTI_SAMPLE.iter().map(|(p, _)| p.to_string()).collect();
        assert_eq!(embedded, on_disk);
        for (relative, bytes) in KITTI_SAMPLE {
            assert_eq!(
                &std::fs::read(root.join(relative)).unwrap(),
                bytes,
                "{relative}"
            );
        }
    }
}
