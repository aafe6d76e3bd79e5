//! Samples → one [`FrustumBatch`] of flat arrays.

use crate::batch::{BatchScale, BatchTargets, FrustumBatch};
use crate::sample::FrustumSample;

/// Stacks samples into a batch. Row `i` of every per-frustum array is `samples[i]`;
/// pair indices are offset by `i · points_per_frustum` (points) and
/// `i · slices_per_frustum` (sub-frustums), so `pair_slice` stays non-decreasing.
/// Targets are present when every sample has them.
///
/// Panics when the samples disagree in points per frustum, scales, sub-frustum counts,
/// caps or output scale, or when only some have targets: samples of one data set
/// never do, so this is a programming error.
pub fn collate(samples: &[FrustumSample]) -> FrustumBatch {
    let Some(first) = samples.first() else {
        return FrustumBatch {
            batch_size: 0,
            points_per_frustum: 0,
            points: Vec::new(),
            class_one_hot: Vec::new(),
            image_projection: Vec::new(),
            scales: Vec::new(),
            output_scale: 0,
            targets: None,
        };
    };
    let n_points = first.points.len();
    let n = samples.len();
    for (i, s) in samples.iter().enumerate() {
        assert_eq!(
            s.points.len(),
            n_points,
            "sample {i}: points per frustum differ"
        );
        assert_eq!(
            s.scales.len(),
            first.scales.len(),
            "sample {i}: number of scales differs"
        );
        assert_eq!(
            s.output_scale, first.output_scale,
            "sample {i}: output scale differs"
        );
        for (a, b) in s.scales.iter().zip(&first.scales) {
            assert_eq!(
                a.centers.len(),
                b.centers.len(),
                "sample {i}: sub-frustums per scale differ"
            );
            assert_eq!(
                a.max_points_per_slice, b.max_points_per_slice,
                "sample {i}: caps differ"
            );
        }
    }

    let mut points = Vec::with_capacity(n * n_points * 3);
    let slots = first.num_class_slots;
    let mut class_one_hot = vec![0.0f32; n * slots];
    let mut image_projection = Vec::with_capacity(n * 12);
    for (i, s) in samples.iter().enumerate() {
        points.extend(s.points.iter().flat_map(|p| p.map(|v| v as f32)));
        image_projection.extend(s.image_projection.map(|v| v as f32));
        assert_eq!(s.num_class_slots, slots, "sample {i}: class set differs");
        class_one_hot[i * slots + s.class_slot] = 1.0;
    }

    let scales = (0..first.scales.len())
        .map(|k| {
            let per = first.scales[k].centers.len();
            let pairs: usize = samples.iter().map(|s| s.scales[k].pair_point.len()).sum();
            let mut scale = BatchScale {
                slices_per_frustum: per,
                slice_centers: Vec::with_capacity(n * per * 3),
                pair_point: Vec::with_capacity(pairs),
                pair_slice: Vec::with_capacity(pairs),
                max_points_per_slice: first.scales[k].max_points_per_slice,
                relative_depth_gains: Vec::new(),
            };
            let with_gains = samples
                .iter()
                .any(|s| !s.scales[k].relative_depth_gains.is_empty());
            for (i, s) in samples.iter().enumerate() {
                let sc = &s.scales[k];
                scale
                    .slice_centers
                    .extend(sc.centers.iter().flat_map(|c| c.map(|v| v as f32)));
                let (po, so) = ((i * n_points) as i64, (i * per) as i64);
                scale
                    .pair_point
                    .extend(sc.pair_point.iter().map(|&p| p as i64 + po));
                scale
                    .pair_slice
                    .extend(sc.pair_slice.iter().map(|&q| q as i64 + so));
                if with_gains {
                    match sc.relative_depth_gains.len() {
                        0 => scale
                            .relative_depth_gains
                            .extend(std::iter::repeat_n(1.0, per)),
                        _ => scale
                            .relative_depth_gains
                            .extend(sc.relative_depth_gains.iter().map(|&g| g as f32)),
                    }
                }
            }
            scale
        })
        .collect();

    let with_targets = samples.iter().filter(|s| s.target.is_some()).count();
    assert!(
        with_targets == 0 || with_targets == n,
        "only {with_targets} of {n} samples have targets; do not mix training and detection frustums"
    );
    let targets = (with_targets == n).then(|| {
        let mut t = BatchTargets {
            labels: Vec::with_capacity(n * first.positions().len()),
            center: Vec::with_capacity(n * 3),
            heading_bin: Vec::with_capacity(n),
            heading_residual: Vec::with_capacity(n),
            size_cluster: Vec::with_capacity(n),
            size_residual: Vec::with_capacity(n * 3),
            corners: Vec::with_capacity(n * 24),
        };
        for s in samples {
            let st = s.target.as_ref().expect("checked above");
            let e = &st.encoding;
            t.labels.extend_from_slice(&st.labels);
            t.center.extend(e.center.map(|v| v as f32));
            t.heading_bin.push(e.heading_bin as i64);
            t.heading_residual.push(e.heading_residual as f32);
            t.size_cluster.push(e.size_cluster as i64);
            t.size_residual.extend(e.size_residual.map(|v| v as f32));
            t.corners
                .extend(st.corners.iter().flat_map(|c| c.map(|v| v as f32)));
        }
        t
    });

    FrustumBatch {
        batch_size: n,
        points_per_frustum: n_points,
        points,
        class_one_hot,
        image_projection,
        scales,
        output_scale: first.output_scale,
        targets,
    }
}
