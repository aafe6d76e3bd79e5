//! The tiny Voxel R-CNN overfits four simulated frames: trained on them without
//! augmentation, it finds (nearly) every car in its range at 3D IoU 0.7 with a high
//! refined score, and scores few false positives.

use fusiondet_geometry::iou_3d;
use fusiondet_kitti::{ObjectClass, read_objects};
use fusiondet_pipeline::{
    DetectOptions, ExperimentConfig, TrainOptions, detect, detect_in_chunks, train,
};
use std::path::Path;

#[test]
fn the_tiny_configuration_overfits_four_frames() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("sim");
    fusiondet_sim::write_dataset(&fusiondet_sim::DatasetOptions::new(&data, 8, 3), &|_, _| {})
        .unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/tiny-voxel-rcnn.toml");
    let mut config = ExperimentConfig::from_file(&path).unwrap();
    config.train.epochs = 100;
    config.train.max_frames = 4;
    let section = config.voxel_rcnn.as_mut().unwrap();
    section.augment = fusiondet_voxel::AugmentConfig::none();
    let range = section.voxels.point_range;
    let run = dir.path().join("run");
    let summary = train(&TrainOptions::new(config.clone(), &data, &run)).unwrap();
    assert_eq!(summary.frames, 4);
    let results = dir.path().join("results");
    let options = |out: &Path| {
        DetectOptions::new(
            config.clone(),
            run.join("model.bpk"),
            data.clone(),
            "train",
            out,
        )
    };
    detect(&options(&results)).unwrap();
    // A frame's boxes do not depend on the frames detected beside it: one frame at a time
    // writes the same files.
    let one_by_one = dir.path().join("one-by-one");
    detect_in_chunks(&options(&one_by_one), 1).unwrap();
    for entry in std::fs::read_dir(&results).unwrap().flatten() {
        let name = entry.file_name();
        assert_eq!(
            std::fs::read(entry.path()).unwrap(),
            std::fs::read(one_by_one.join(&name)).unwrap(),
            "{name:?}"
        );
    }

    let ids: Vec<String> = std::fs::read_to_string(data.join("ImageSets/train.txt"))
        .unwrap()
        .lines()
        .take(4)
        .map(str::to_string)
        .collect();
    let (mut cars, mut found, mut confident, mut confident_true) = (0, 0, 0, 0);
    for id in &ids {
        let truth = read_objects(&data.join(format!("training/label_2/{id}.txt"))).unwrap();
        let dets = read_objects(&results.join(format!("{id}.txt"))).unwrap();
        // Cars whose centre lies in the tiny grid (camera x = −LiDAR y, z = LiDAR x).
        let in_range: Vec<_> = truth
            .iter()
            .filter(|o| o.class == ObjectClass::Car)
            .filter(|o| {
                let b = &o.box3d;
                b.z > range[0] + 1.0
                    && b.z < range[3] - 1.0
                    && -b.x > range[1] + 1.0
                    && -b.x < range[4] - 1.0
            })
            .collect();
        for car in &in_range {
            cars += 1;
            if dets
                .iter()
                .any(|d| d.score.unwrap() >= 0.5 && iou_3d(&d.box3d, &car.box3d) >= 0.7)
            {
                found += 1;
            }
        }
        for d in dets.iter().filter(|d| d.score.unwrap() >= 0.5) {
            confident += 1;
            if truth
                .iter()
                .any(|t| t.class == ObjectClass::Car && iou_3d(&d.box3d, &t.box3d) >= 0.5)
            {
                confident_true += 1;
            }
        }
    }
    assert!(cars >= 8, "the frames hold {cars} cars in range");
    assert!(
        found as f64 >= 0.9 * cars as f64,
        "{found} of {cars} cars found at IoU 0.7"
    );
    assert!(
        confident_true as f64 >= 0.9 * confident as f64,
        "{confident_true} of {confident} confident boxes are cars"
    );
}
