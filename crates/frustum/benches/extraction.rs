//! Frustum preparation cost per frame: LiDAR projection, extraction of every
//! detection's frustum, sampling and slicing (no disk I/O in the timed loop).
//!
//! `cargo bench -p fusiondet-frustum --bench extraction`

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_frustum::{
    Augmentation, FrustumConfig, ProjectedFrame, SampleSource, build_sample, collate,
    extract_frustum, rng::Sampler,
};
use fusiondet_kitti::{FrameDir, read_calib, read_detections2d, read_velodyne};
use std::hint::black_box;
use std::path::Path;

fn bench(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample");
    let dir = FrameDir::new(root.join("training"));
    let id = "000134";
    let calib = read_calib(&dir.calib(id)).unwrap();
    let lidar = read_velodyne(&dir.velodyne(id)).unwrap();
    let dets: Vec<_> = read_detections2d(&root.join("rgb_detections/rgb_detection_val.txt"))
        .unwrap()
        .into_iter()
        .filter(|d| d.frame_id == id)
        .collect();
    let config = FrustumConfig {
        classes: vec![fusiondet_kitti::ObjectClass::Pedestrian.into()],
        ..FrustumConfig::pedestrian_cyclist()
    };
    let image_size = [1242.0, 375.0];
    eprintln!(
        "frame {id}: {} LiDAR points, {} detections",
        lidar.len(),
        dets.len()
    );

    c.bench_function("project frame", |b| {
        b.iter(|| ProjectedFrame::new(id, &calib, black_box(&lidar), image_size, vec![]).unwrap())
    });

    let frame = ProjectedFrame::new(id, &calib, &lidar, image_size, vec![]).unwrap();
    c.bench_function("extract frustums (all boxes)", |b| {
        b.iter(|| {
            dets.iter()
                .filter_map(|d| {
                    extract_frustum(&frame, black_box(&d.bbox), config.depth_range, 5.0).ok()
                })
                .count()
        })
    });

    let biggest = dets
        .iter()
        .filter_map(|d| extract_frustum(&frame, &d.bbox, config.depth_range, 5.0).ok())
        .max_by_key(|f| f.points.len())
        .unwrap();
    eprintln!("largest frustum: {} points", biggest.points.len());
    c.bench_function("build one sample (sample 1024, slice 4 scales)", |b| {
        let source = SampleSource {
            frame_id: &frame.id,
            class: fusiondet_kitti::ObjectClass::Pedestrian.into(),
            score: Some(1.0),
            focal_v: frame.camera.fv(),
            p2: frame.camera.p2_rows(),
            object: None,
        };
        let mut rng = Sampler::from_path(2, &[]);
        b.iter(|| {
            build_sample(
                &source,
                black_box(&biggest),
                Augmentation::default(),
                &config,
                &mut rng,
            )
        })
    });

    let frame_pipeline = |frame: &ProjectedFrame, boxes: usize| {
        let mut rng = Sampler::from_path(1, &[]);
        let samples: Vec<_> = dets
            .iter()
            .take(boxes)
            .filter_map(|d| {
                let fp = extract_frustum(frame, &d.bbox, config.depth_range, 5.0).ok()?;
                let source = SampleSource {
                    frame_id: &frame.id,
                    class: d.class.into(),
                    score: Some(d.score),
                    focal_v: frame.camera.fv(),
                    p2: frame.camera.p2_rows(),
                    object: None,
                };
                Some(build_sample(
                    &source,
                    &fp,
                    Augmentation::default(),
                    &config,
                    &mut rng,
                ))
            })
            .collect();
        collate(&samples)
    };
    for boxes in [8, dets.len()] {
        let kept = frame_pipeline(&frame, boxes).batch_size;
        eprintln!("first {boxes} detections: {kept} frustums");
        let name = format!(
            "frame end to end, {boxes} boxes (project + extract + sample + slice + collate)"
        );
        c.bench_function(&name, |b| {
            b.iter(|| {
                let frame =
                    ProjectedFrame::new(id, &calib, black_box(&lidar), image_size, vec![]).unwrap();
                frame_pipeline(&frame, boxes)
            })
        });
    }
    c.bench_function(
        "load frame from disk (read calib + velodyne, project)",
        |b| b.iter(|| ProjectedFrame::load(&dir, black_box(id), false).unwrap()),
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
