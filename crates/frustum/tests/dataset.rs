//! Data sets over the bundled KITTI frames: preparation and skip counting, batches
//! (contract with the networks), determinism across seeds and thread counts.

use fusiondet_frustum::{
    AugmentConfig, BoxCoder, BoxEncoding, DiskFrames, FrameSource, FrustumConfig, FrustumDataset,
    FrustumFrames, InMemoryFrames, PreparedBatch, SkipReason, collate,
};
use fusiondet_geometry::normalize_angle;
use fusiondet_kitti::{Box2d, Detection2d, FrameDir, ObjectClass, read_detections2d};
use std::path::{Path, PathBuf};

const ALL: [&str; 7] = [
    "000000", "000001", "000002", "000003", "000004", "000005", "000134",
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample")
}

fn frames(ids: &[&str]) -> InMemoryFrames {
    let ids: Vec<String> = ids.iter().map(|s| s.to_string()).collect();
    InMemoryFrames::load(&FrameDir::new(root().join("training")), &ids, true).unwrap()
}

fn val_detections() -> Vec<Detection2d> {
    read_detections2d(&root().join("rgb_detections/rgb_detection_val.txt")).unwrap()
}

fn batches<S: FrustumFrames>(
    d: &FrustumDataset<S>,
    seed: u64,
    epoch: u64,
    batch: usize,
) -> Vec<PreparedBatch> {
    d.epoch(seed, epoch, batch)
        .collect::<Result<Vec<_>, _>>()
        .unwrap()
}

#[test]
fn car_training_set_counts_objects_copies_and_skips() {
    let config = FrustumConfig::car();
    let d = FrustumDataset::from_labels(frames(&ALL), config.clone(), 11).unwrap();
    // 8 labelled cars in the sample frames, 5 jittered copies each; the cars of
    // 000001 (21.6 px tall) and the far one of 000004 (20.7 px) are under 25 px.
    let cars = 8 * config.augment.copies;
    assert_eq!(d.len() + d.skips().total(), cars, "{}", d.skips());
    assert_eq!(d.skips().get(SkipReason::TooSmall), 10, "{}", d.skips());
    assert_eq!(d.len(), 30, "{}", d.skips());
    assert!(
        d.specs()
            .iter()
            .all(|s| s.class == ObjectClass::Car.into() && s.object.is_some() && s.score.is_none())
    );
    // Each object's copies have different boxes.
    let copies: Vec<_> = d
        .specs()
        .iter()
        .filter(|s| s.frame == 3)
        .map(|s| s.box2d)
        .collect();
    assert!(copies.len() >= 4 && copies.windows(2).all(|w| w[0] != w[1]));

    // Raising the height threshold drops boxes as too small, and nothing else changes.
    let strict = FrustumConfig {
        min_box_height_train: 40.0,
        ..config.clone()
    };
    let s = FrustumDataset::from_labels(frames(&ALL), strict, 11).unwrap();
    assert!(s.skips().get(SkipReason::TooSmall) > d.skips().get(SkipReason::TooSmall));
    assert_eq!(s.len() + s.skips().total(), cars);
    // Requiring many points on the object drops the far cars for that reason.
    let dense = FrustumConfig {
        min_object_points: 200,
        ..config
    };
    let s = FrustumDataset::from_labels(frames(&ALL), dense, 11).unwrap();
    assert!(
        s.skips().get(SkipReason::NoObjectPoints) > 0,
        "{}",
        s.skips()
    );
}

#[test]
fn jitter_is_seeded_by_frame_id_not_position() {
    let config = FrustumConfig::car();
    let a = FrustumDataset::from_labels(frames(&["000003", "000004"]), config.clone(), 5).unwrap();
    let b = FrustumDataset::from_labels(frames(&["000004", "000003"]), config.clone(), 5).unwrap();
    let boxes = |d: &FrustumDataset<InMemoryFrames>, id: &str| -> Vec<Box2d> {
        d.specs()
            .iter()
            .filter(|s| d.source().frame_id(s.frame) == id)
            .map(|s| s.box2d)
            .collect()
    };
    assert_eq!(boxes(&a, "000003"), boxes(&b, "000003"));
    let c = FrustumDataset::from_labels(frames(&["000003", "000004"]), config, 6).unwrap();
    assert_ne!(boxes(&a, "000003"), boxes(&c, "000003"));
}

#[test]
fn batches_follow_the_contract() {
    let d = FrustumDataset::from_labels(frames(&ALL), FrustumConfig::car(), 3).unwrap();
    let all = batches(&d, 9, 0, 4);
    assert_eq!(
        all.len(),
        d.len() / 4,
        "fixed batch size, last partial batch dropped"
    );
    for pb in &all {
        let b = &pb.batch;
        assert_eq!(b.batch_size, 4);
        assert_eq!(b.points_per_frustum, 1024);
        assert_eq!(b.points.len(), 4 * 1024 * 3);
        assert_eq!(b.class_one_hot, [1.0, 0.0, 0.0].repeat(4));
        assert_eq!(b.output_scale, 1);
        let counts: Vec<usize> = b.scales.iter().map(|s| s.slices_per_frustum).collect();
        assert_eq!(counts, [280, 140, 70, 35]);
        for s in &b.scales {
            assert_eq!(s.slice_centers.len(), 4 * s.slices_per_frustum * 3);
            assert_eq!(s.pair_point.len(), s.pair_slice.len());
            assert!(
                s.pair_slice.windows(2).all(|w| w[0] <= w[1]),
                "pair_slice non-decreasing"
            );
            let mut per_slice = vec![0usize; 4 * s.slices_per_frustum];
            for (&p, &q) in s.pair_point.iter().zip(&s.pair_slice) {
                let (p, q) = (p as usize, q as usize);
                // The point and the sub-frustum belong to the same frustum.
                assert_eq!(p / 1024, q / s.slices_per_frustum);
                per_slice[q] += 1;
                // The point's depth is within the sub-frustum's interval (centre ± half length;
                // half the stride doubled: the centre spacing).
                let z = b.points[3 * p + 2];
                let c = s.slice_centers[3 * q + 2];
                let stride = s.slice_centers[5] - s.slice_centers[2];
                assert!((z - c).abs() <= stride + 1e-4, "point z {z} vs centre {c}");
            }
            assert!(per_slice.iter().all(|&n| n <= s.max_points_per_slice));
        }
        let t = b.targets.as_ref().unwrap();
        assert_eq!(t.labels.len(), 4 * 140);
        assert_eq!(t.center.len(), 12);
        assert_eq!(t.corners.len(), 4 * 24);
        assert!(t.heading_bin.iter().all(|&h| (0..12).contains(&h)));
        assert!(t.size_cluster.iter().all(|&c| c == 0));
        for i in 0..4 {
            let labels = &t.labels[i * 140..(i + 1) * 140];
            assert!(labels.contains(&1), "every frustum has a positive position");
        }
    }
}

/// Sample `i`'s f32 targets decoded through `decode_box` from its first positive output
/// position's centre.
fn decode_at_first_positive(pb: &PreparedBatch, i: usize) -> fusiondet_kitti::Box3d {
    let b = &pb.batch;
    let t = b.targets.as_ref().unwrap();
    let pos = &b.scales[b.output_scale];
    let n = pos.slices_per_frustum;
    let k = (0..n).find(|&k| t.labels[i * n + k] == 1).unwrap();
    let pc: [f64; 3] = std::array::from_fn(|j| pos.slice_centers[3 * (i * n + k) + j] as f64);
    let off: [f64; 3] = std::array::from_fn(|j| t.center[3 * i + j] as f64 - pc[j]);
    let sr: [f64; 3] = std::array::from_fn(|j| t.size_residual[3 * i + j] as f64);
    let predicted = BoxEncoding {
        center: off,
        heading_bin: t.heading_bin[i] as usize,
        heading_residual: t.heading_residual[i] as f64,
        size_cluster: t.size_cluster[i] as usize,
        size_residual: sr,
    };
    BoxCoder::kitti().decode_box(pc, &predicted, &pb.samples[i].frame)
}

/// Decoding the batch's own f32 targets through `decode_box`, from each positive
/// position's centre, gives back the KITTI label (within f32 precision), whatever
/// flip and depth shift the sample received.
#[test]
fn batch_targets_decode_to_the_labels() {
    let d = FrustumDataset::from_labels(frames(&ALL), FrustumConfig::car(), 4).unwrap();
    let mut flipped = 0;
    for pb in batches(&d, 21, 2, 5) {
        assert_eq!(
            pb.batch.scales[pb.batch.output_scale].slices_per_frustum,
            140
        );
        for (i, s) in pb.samples.iter().enumerate() {
            flipped += s.frame.mirrored as usize;
            let gt = s.target.as_ref().unwrap().object;
            let out = decode_at_first_positive(&pb, i);
            for (a, g) in [
                (out.x, gt.x),
                (out.y, gt.y),
                (out.z, gt.z),
                (out.l, gt.l),
                (out.w, gt.w),
                (out.h, gt.h),
            ] {
                assert!((a - g).abs() < 1e-4, "{out:?} vs {gt:?}");
            }
            assert!(normalize_angle(out.ry - gt.ry).abs() < 1e-5);
        }
    }
    assert!(flipped > 0, "some samples were flipped");
}

#[test]
fn same_seed_same_batches_other_seed_or_epoch_differs() {
    let d = FrustumDataset::from_labels(frames(&ALL), FrustumConfig::car(), 3).unwrap();
    let a = batches(&d, 42, 0, 4);
    let b = batches(&d, 42, 0, 4);
    assert_eq!(
        a.iter().map(|x| &x.batch).collect::<Vec<_>>(),
        b.iter().map(|x| &x.batch).collect::<Vec<_>>()
    );
    assert_eq!(a[0].indices, b[0].indices);
    let c = batches(&d, 43, 0, 4);
    assert_ne!(a[0].batch, c[0].batch);
    let e = batches(&d, 42, 1, 4);
    assert_ne!(a[0].indices, e[0].indices);
    // A sample's content depends on (seed, epoch, index), not on its batch.
    let one = d.sample(a[1].indices[2], 42, 0).unwrap();
    assert_eq!(one, a[1].samples[2]);
    // And a data set prepared again from the same seed is the same.
    let d2 = FrustumDataset::from_labels(frames(&ALL), FrustumConfig::car(), 3).unwrap();
    assert_eq!(d2.specs(), d.specs());
    assert_eq!(batches(&d2, 42, 0, 4)[0].batch, a[0].batch);
}

#[test]
fn thread_count_does_not_change_anything() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let d = FrustumDataset::from_labels(frames(&ALL), FrustumConfig::car(), 8).unwrap();
            let specs = d.specs().to_vec();
            let batches: Vec<_> = batches(&d, 77, 3, 8).into_iter().map(|b| b.batch).collect();
            (specs, batches)
        })
    };
    let one = run(1);
    assert_eq!(run(2), one);
    assert_eq!(run(5), one);
}

#[test]
fn detection_frustums_carry_scores_and_count_skips() {
    let mut dets = val_detections();
    // A detection too short, one outside the image, one in a frame the set lacks.
    let mk = |frame: &str, b: Box2d| Detection2d {
        frame_id: frame.into(),
        class: ObjectClass::Car,
        score: 0.5,
        bbox: b,
    };
    dets.push(mk(
        "000004",
        Box2d {
            x1: 600.0,
            y1: 190.0,
            x2: 640.0,
            y2: 194.0,
        },
    ));
    dets.push(mk(
        "000004",
        Box2d {
            x1: 1300.0,
            y1: 190.0,
            x2: 1400.0,
            y2: 250.0,
        },
    ));
    dets.push(mk(
        "000999",
        Box2d {
            x1: 600.0,
            y1: 190.0,
            x2: 640.0,
            y2: 250.0,
        },
    ));
    let cars_in_file = dets.iter().filter(|d| d.class == ObjectClass::Car).count();
    let val = ["000001", "000002", "000004", "000005", "000134"];
    let d = FrustumDataset::from_detections(frames(&val), &dets, FrustumConfig::car()).unwrap();
    let k = d.skips();
    assert_eq!(k.get(SkipReason::TooSmall), 1, "{k}");
    assert_eq!(k.get(SkipReason::OutsideImage), 1, "{k}");
    assert_eq!(k.get(SkipReason::UnknownFrame), 1, "{k}");
    assert_eq!(d.len() + k.total(), cars_in_file);
    assert!(
        d.specs()
            .iter()
            .all(|s| s.score.is_some() && s.object.is_none())
    );
    // Four far detections have LiDAR points only beyond 70 m.
    assert_eq!(k.get(SkipReason::NoPoints), 4, "{k}");
    // File order is kept (scores are unique in the file).
    let file_pos: Vec<usize> = d
        .specs()
        .iter()
        .map(|s| {
            dets.iter()
                .position(|x| x.score == s.score.unwrap())
                .unwrap()
        })
        .collect();
    assert!(file_pos.windows(2).all(|w| w[0] < w[1]), "{file_pos:?}");

    // Inference batches: in order, last partial batch kept, no targets.
    let all: Vec<_> = d.in_order(0, 4).collect::<Result<Vec<_>, _>>().unwrap();
    assert_eq!(all.len(), d.len().div_ceil(4));
    assert_eq!(
        all.iter().map(|b| b.batch.batch_size).sum::<usize>(),
        d.len()
    );
    assert!(all.iter().all(|b| b.batch.targets.is_none()));
    let order: Vec<usize> = all.iter().flat_map(|b| b.indices.clone()).collect();
    assert_eq!(order, (0..d.len()).collect::<Vec<_>>());
    assert_eq!(all[0].samples[0].score, Some(dets[0].score));
    assert_eq!(all[0].samples[0].frame_id, "000001");
}

#[test]
fn people_config_and_disk_frames() {
    let dir = FrameDir::new(root().join("training"));
    let source = DiskFrames::new(dir, vec!["000134".into(), "000000".into()], true);
    let config = FrustumConfig {
        augment: AugmentConfig::none(),
        ..FrustumConfig::pedestrian_cyclist()
    };
    let d = FrustumDataset::from_labels(source, config, 0).unwrap();
    // 000134: 7 pedestrians + 5 cyclists; 000000: 1 pedestrian. One copy each, no jitter.
    assert_eq!(d.len() + d.skips().total(), 13, "{}", d.skips());
    let b = d.in_order(0, 16).next().unwrap().unwrap();
    let counts: Vec<usize> = b
        .batch
        .scales
        .iter()
        .map(|s| s.slices_per_frustum)
        .collect();
    assert_eq!(counts, [280, 140, 70, 35]);
    // One-hot and size cluster follow the class.
    let t = b.batch.targets.as_ref().unwrap();
    for (i, s) in b.samples.iter().enumerate() {
        let slot = if s.class == ObjectClass::Pedestrian.into() {
            1
        } else {
            2
        };
        assert_eq!(b.batch.class_one_hot[3 * i + slot], 1.0);
        assert_eq!(t.size_cluster[i], slot as i64);
        assert!(
            !s.frame.mirrored && s.frame.depth_shift == 0.0,
            "no augmentation"
        );
        assert_eq!(
            s.box2d,
            d.source().frame(d.specs()[i].frame).unwrap().objects[d.specs()[i].object.unwrap()]
                .bbox
        );
    }
}

#[test]
fn collate_of_nothing_and_mixed_targets() {
    assert_eq!(collate(&[]).batch_size, 0);
    let d = FrustumDataset::from_labels(frames(&["000003"]), FrustumConfig::car(), 1).unwrap();
    let mut s = vec![d.sample(0, 0, 0).unwrap(), d.sample(1, 0, 0).unwrap()];
    s[1].target = None;
    let r = std::panic::catch_unwind(|| collate(&s));
    assert!(
        r.is_err(),
        "mixing samples with and without targets is refused"
    );
}

/// SAF's depth-guided slicing through the whole pipeline: fixed counts per scale,
/// uneven per-frustum centres, pairs within their own intervals, a positive
/// per frustum, and targets that decode to the labels.
#[test]
fn depth_guided_batches_follow_the_contract_and_decode() {
    let d = FrustumDataset::from_labels(frames(&ALL), FrustumConfig::saf_car(), 3).unwrap();
    assert_eq!(d.len(), 30, "{}", d.skips());
    let all = batches(&d, 9, 1, 5);
    let mut near_ends = Vec::new();
    for pb in &all {
        let b = &pb.batch;
        let counts: Vec<usize> = b.scales.iter().map(|s| s.slices_per_frustum).collect();
        assert_eq!(counts, [240, 120, 60, 30]);
        for (k, s) in b.scales.iter().enumerate() {
            assert_eq!(s.slice_centers.len(), 5 * s.slices_per_frustum * 3);
            assert!(s.pair_slice.windows(2).all(|w| w[0] <= w[1]));
            for (&p, &q) in s.pair_point.iter().zip(&s.pair_slice) {
                let (p, q) = (p as usize, q as usize);
                let (i, j) = (q / s.slices_per_frustum, q % s.slices_per_frustum);
                assert_eq!(p / 1024, i);
                // The sample's own interval, not a common stride.
                let iv = pb.samples[i].scales[k].slices[j];
                let z = b.points[3 * p + 2] as f64;
                assert!((z - iv.center).abs() <= iv.half_length + 1e-4);
                assert!((s.slice_centers[3 * q + 2] as f64 - iv.center).abs() < 1e-4);
            }
        }
        for s in &pb.samples {
            let near = s.scales[0].slices[0];
            near_ends.push(near.center + near.half_length);
        }
        assert_eq!(b.targets.as_ref().unwrap().labels.len(), 5 * 120);
        for (i, s) in pb.samples.iter().enumerate() {
            let gt = s.target.as_ref().unwrap().object;
            let out = decode_at_first_positive(pb, i);
            for (a, g) in [(out.x, gt.x), (out.y, gt.y), (out.z, gt.z), (out.l, gt.l)] {
                assert!((a - g).abs() < 1e-4, "{out:?} vs {gt:?}");
            }
            assert!(normalize_angle(out.ry - gt.ry).abs() < 1e-5);
        }
    }
    // The near region follows each frustum's 2D box.
    near_ends.sort_by(f64::total_cmp);
    near_ends.dedup();
    assert!(near_ends.len() > 10, "{near_ends:?}");
}

/// The labelled cars of the bundled frames as first-stage results, one of them moved
/// 6 m sideways (it overlaps nothing).
fn car_proposals(
    frames: &InMemoryFrames,
) -> std::collections::BTreeMap<String, Vec<fusiondet_kitti::Object>> {
    let mut out = std::collections::BTreeMap::new();
    for i in 0..frames.len() {
        let f = frames.frame(i).unwrap();
        let cars: Vec<_> = f
            .objects
            .iter()
            .filter(|o| o.class == ObjectClass::Car)
            .map(|o| fusiondet_kitti::Object {
                score: Some(0.9),
                ..o.clone()
            })
            .collect();
        out.insert(f.id.clone(), cars);
    }
    let first = out.values_mut().find(|v| !v.is_empty()).unwrap();
    first[0].box3d.x += 6.0;
    out
}

#[test]
fn refinement_frustums_are_cut_around_proposals_and_matched_for_training() {
    let source = frames(&ALL);
    let proposals = car_proposals(&source);
    let total: usize = proposals.values().map(Vec::len).sum();
    let config = FrustumConfig::car_refinement();
    let train =
        FrustumDataset::from_proposals(source.clone(), &proposals, config.clone(), true).unwrap();
    // Every proposal but the moved one matches its own ground truth; none is lost
    // otherwise (a distant car may have no points and be skipped as such).
    let skips = train.skips();
    assert_eq!(skips.get(SkipReason::Unmatched), 1, "{skips}");
    assert_eq!(train.len() + skips.total(), total);
    assert!(
        train.len() >= total - 3,
        "{} of {total}: {skips}",
        train.len()
    );
    for (i, spec) in train.specs().iter().enumerate() {
        assert!(spec.proposal.is_some() && spec.object.is_some());
        let s = train.sample(i, 3, 0).unwrap();
        assert_eq!(s.points.len(), 512);
        let shift = s.frame.depth_shift;
        assert!(s.points.iter().all(|p| (p[2] - shift).abs() <= 3.2 + 1e-9));
        // The proposal is the ground truth: its centre is the origin of the sample
        // (up to the training depth shift), and some output position is positive.
        let t = s.target.as_ref().unwrap();
        assert!(t.in_frustum.x.abs() < 1e-9, "{}", t.in_frustum.x);
        assert!(
            (t.in_frustum.z - s.frame.depth_shift).abs() < 1e-9,
            "{} vs shift {}",
            t.in_frustum.z,
            s.frame.depth_shift
        );
        assert!(t.labels.contains(&1));
        let back = s.frame.box_to_rect(&t.in_frustum);
        assert!((back.x - t.object.x).abs() < 1e-9 && (back.z - t.object.z).abs() < 1e-9);
    }
    // At test time nothing is matched: the moved proposal is kept if it holds points.
    let test = FrustumDataset::from_proposals(source.clone(), &proposals, config, false).unwrap();
    assert_eq!(test.skips().get(SkipReason::Unmatched), 0);
    assert_eq!(test.len() + test.skips().total(), total);
    assert!(test.len() >= train.len());
    assert!(test.specs().iter().all(|s| s.object.is_none()));
    assert_eq!(test.specs()[0].score, Some(0.9));
    // A first-stage configuration cannot cut around proposals.
    let err = FrustumDataset::from_proposals(source, &proposals, FrustumConfig::car(), false)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("proposal_crop"), "{err}");
}

#[test]
fn refinement_configs_need_a_relative_depth_range_and_uniform_slicing() {
    let mut c = FrustumConfig::car_refinement();
    c.depth_range = [0.0, 3.2];
    assert!(
        c.validate()
            .unwrap_err()
            .to_string()
            .contains("min < 0 < max")
    );
    let mut c = FrustumConfig::car_refinement();
    c.slicing = FrustumConfig::saf_car().slicing;
    assert!(c.validate().unwrap_err().to_string().contains("uniform"));
    let mut c = FrustumConfig::car();
    c.depth_range = [-1.0, 70.0];
    assert!(c.validate().is_err());
}

/// Inference names each frustum's stream by its frame: the samples of a frame are the same
/// whether the data set holds the whole split or that frame alone (so a split can be
/// detected in chunks), while training streams follow the frustum's place in the set.
#[test]
fn inference_samples_of_a_frame_do_not_depend_on_the_other_frames() {
    let val = ["000001", "000002", "000004", "000005", "000134"];
    let dets = val_detections();
    let whole = FrustumDataset::from_detections(frames(&val), &dets, FrustumConfig::car()).unwrap();
    let points_of = |d: &FrustumDataset<InMemoryFrames>, frame: &str| -> Vec<Vec<[f64; 3]>> {
        d.in_order(7, 3)
            .flat_map(|b| b.unwrap().samples)
            .filter(|s| s.frame_id == frame)
            .map(|s| s.points)
            .collect()
    };
    let with_frustums: Vec<&str> = val
        .iter()
        .copied()
        .filter(|id| !points_of(&whole, id).is_empty())
        .collect();
    assert!(with_frustums.len() >= 2, "{with_frustums:?}");
    for id in &with_frustums {
        let alone =
            FrustumDataset::from_detections(frames(&[id]), &dets, FrustumConfig::car()).unwrap();
        assert_eq!(points_of(&whole, id), points_of(&alone, id), "{id}");
    }
    // Training samples (index-keyed) differ once the frame's place in the set moves.
    let first_of = |d: &FrustumDataset<InMemoryFrames>, frame: &str| {
        let i = d
            .specs()
            .iter()
            .position(|s| d.source().frame_id(s.frame) == frame)
            .unwrap();
        d.sample(i, 7, 0).unwrap().points
    };
    let last = with_frustums[with_frustums.len() - 1];
    let alone =
        FrustumDataset::from_detections(frames(&[last]), &dets, FrustumConfig::car()).unwrap();
    assert_ne!(first_of(&whole, last), first_of(&alone, last));
}
