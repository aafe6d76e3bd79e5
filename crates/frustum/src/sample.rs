//! One network input: a frustum's sampled points, its sub-frustums at every scale with
//! their ragged point membership, and (for training) its targets. f64 throughout;
//! [`crate::collate()`] converts to the f32 batch arrays.

use crate::coder::{BoxCoder, BoxEncoding};
use crate::config::{AugmentConfig, FrustumConfig};
use crate::frustum::{FrustumFrame, FrustumPoints};
use crate::rng::Sampler;
use crate::slicing::{SliceContext, SliceInterval, SliceStrategy, depth_order, slice_pairs};
use crate::targets::position_labels;
use fusiondet_dataset::Class;
use fusiondet_geometry::{alpha_from_ry, corners};
use fusiondet_kitti::{Box2d, Box3d, Object, ObjectClass};

/// One scale of sub-frustums of one frustum.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleScale {
    /// Depth intervals along the frustum axis, sorted by centre.
    pub slices: Vec<SliceInterval>,
    /// Sub-frustum centres in the frustum frame: the box-centre ray at each
    /// interval's centre depth ([`FrustumFrame::ray_point`]).
    pub centers: Vec<[f64; 3]>,
    /// For each (point, sub-frustum) pair, the point's index in `FrustumSample::points`.
    pub pair_point: Vec<u32>,
    /// For each pair, the sub-frustum's index; non-decreasing.
    pub pair_slice: Vec<u32>,
    pub max_points_per_slice: usize,
    /// Per sub-frustum, the factor on depths relative to its centre
    /// ([`crate::Slicing::relative_depth_gains`]); empty = 1.
    pub relative_depth_gains: Vec<f64>,
}

/// Training targets of one frustum.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleTarget {
    /// The ground truth in KITTI's camera frame, as labelled.
    pub object: Box3d,
    /// The ground truth in the sample's frustum frame (bottom-centre location,
    /// frustum-frame heading).
    pub in_frustum: Box3d,
    pub encoding: BoxEncoding,
    /// One label per output position (1 positive, 0 negative, −1 ignored).
    pub labels: Vec<i64>,
    /// `geometry::corners` of `in_frustum`, so the model can compute predicted
    /// corners from its decoded parameters the same way.
    pub corners: [[f64; 3]; 8],
}

/// One frustum, ready for batching.
#[derive(Debug, Clone, PartialEq)]
pub struct FrustumSample {
    pub frame_id: String,
    /// The class of the 2D box (ground truth or detection).
    pub class: Class,
    /// The class's one-hot slot (= size cluster) in the coder's class set, and the
    /// set's size (the one-hot's length).
    pub class_slot: usize,
    pub num_class_slots: usize,
    /// The 2D box that made the frustum, clipped to the image.
    pub box2d: Box2d,
    /// The 2D detection score (detection frustums only).
    pub score: Option<f64>,
    /// Map between the camera frame and this sample's coordinates, augmentation included.
    pub frame: FrustumFrame,
    /// Distinct LiDAR points in the frustum before resampling.
    pub num_frustum_points: usize,
    /// Sample coordinates → pixels (row-major 3 × 4; P2 · frustum→camera, augmentation
    /// included), for SAF's projection loss.
    pub image_projection: [f64; 12],
    /// Sampled points in the frustum frame (`points_per_frustum` of them, repeated
    /// when the frustum has fewer), in random order.
    pub points: Vec<[f64; 3]>,
    /// Sub-frustums, finest scale first.
    pub scales: Vec<SampleScale>,
    /// The scale whose sub-frustum centres are the output positions.
    pub output_scale: usize,
    pub target: Option<SampleTarget>,
}

/// Training augmentation of one sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Augmentation {
    pub mirror: bool,
    pub depth_shift: f64,
}

impl Augmentation {
    /// Draws flip and depth shift (F-ConvNet's rule, see [`crate::DepthShift`]) for a
    /// frustum whose ground truth is `gt` (camera frame), in that order from `rng`.
    pub fn draw(
        config: &AugmentConfig,
        depth_range: [f64; 2],
        frame: &FrustumFrame,
        gt: &Box3d,
        rng: &mut Sampler,
    ) -> Self {
        let mirror = config.flip && rng.unit() < 0.5;
        let depth_shift = match config.depth_shift {
            Some(s) => {
                let diag = gt.l.hypot(gt.w);
                let shift = (rng.normal() * s.sigma * diag).clamp(-s.max * diag, s.max * diag);
                let z = frame.base().to_frustum([gt.x, gt.y, gt.z])[2];
                (z + shift).clamp(depth_range[0], depth_range[1]) - z
            }
            None => 0.0,
        };
        Augmentation {
            mirror,
            depth_shift,
        }
    }
}

/// Indices of `n` points to take from `available`: a random subset in random order when
/// there are enough; otherwise all of them in random order, then the random repeats.
///
/// Distinct points come first because a prefix of the sample is what SAF's LFA keeps (its
/// random halvings keep the first half of a shuffled set, so the 1,024 points it slices are
/// the first quarter of its 4,096): with the repeats mixed in, a frustum of 1,000 points
/// kept only ~655 of them. The draws are those of the earlier mixed order and only the
/// order changes; models that use every sampled point still see other results, because a
/// capped sub-frustum keeps its first points.
pub fn sample_indices(available: usize, n: usize, rng: &mut Sampler) -> Vec<usize> {
    assert!(available > 0, "cannot sample from an empty frustum");
    let mut idx: Vec<usize> = (0..available).collect();
    if available >= n {
        // Partial Fisher–Yates: a uniform random n-subset in random order.
        for i in 0..n {
            let j = i + rng.below(available - i);
            idx.swap(i, j);
        }
        idx.truncate(n);
    } else {
        idx.extend((available..n).map(|_| rng.below(available)));
        rng.shuffle(&mut idx);
        // Each point's first occurrence, in the shuffled order, then the repeats.
        let mut seen = vec![false; available];
        let (first, repeats): (Vec<usize>, Vec<usize>) = idx
            .into_iter()
            .partition(|&i| !std::mem::replace(&mut seen[i], true));
        idx = first;
        idx.extend(repeats);
    }
    idx
}

/// Identity of a sample apart from its points.
#[derive(Debug, Clone)]
pub struct SampleSource<'a> {
    pub frame_id: &'a str,
    pub class: Class,
    pub score: Option<f64>,
    /// Vertical focal length of P2 (for slicing strategies that use it).
    pub focal_v: f64,
    /// P2 (rectified camera → pixels), for the sample's image projection.
    pub p2: [[f64; 4]; 3],
    /// The ground truth (camera frame) for training samples.
    pub object: Option<&'a Box3d>,
}

/// Builds a sample from an extracted frustum: augmentation applied to the points,
/// `points_per_frustum` points sampled from `rng`, sub-frustums laid out by the
/// config's slicing, and targets when `source.object` is given.
pub fn build_sample(
    source: &SampleSource<'_>,
    frustum: &FrustumPoints,
    augmentation: Augmentation,
    config: &FrustumConfig,
    rng: &mut Sampler,
) -> FrustumSample {
    let frame = frustum
        .frame
        .with_augmentation(augmentation.mirror, augmentation.depth_shift);
    let chosen = sample_indices(frustum.points.len(), config.points_per_frustum, rng);
    let points: Vec<[f64; 3]> = chosen
        .iter()
        .map(|&i| frame.augment(frustum.points[i]))
        .collect();
    let layout = config.slicing.layout(&SliceContext {
        depth_range: config.depth_range,
        class: source.class,
        box2d: &frustum.box2d,
        focal_v: source.focal_v,
    });
    let sliced = match config.sliced_points {
        0 => points.len(),
        n => n.min(points.len()),
    };
    let depths: Vec<f64> = points[..sliced].iter().map(|p| p[2]).collect();
    let order = depth_order(&depths);
    let scales = layout
        .into_iter()
        .map(|scale| {
            let (pair_point, pair_slice) =
                slice_pairs(&depths, &order, &scale.slices, scale.max_points);
            SampleScale {
                relative_depth_gains: config.slicing.relative_depth_gains(&scale.slices),
                centers: scale
                    .slices
                    .iter()
                    .map(|s| frame.ray_point(s.center))
                    .collect(),
                slices: scale.slices,
                pair_point,
                pair_slice,
                max_points_per_slice: scale.max_points,
            }
        })
        .collect();
    let class_slot = config
        .coder
        .cluster_of(source.class.as_str())
        .expect("the config only admits classes with a size cluster");
    let mut sample = FrustumSample {
        frame_id: source.frame_id.to_string(),
        class: source.class,
        class_slot,
        num_class_slots: config.coder.num_clusters(),
        box2d: frustum.box2d,
        score: source.score,
        frame,
        image_projection: frame.image_projection(&source.p2),
        num_frustum_points: frustum.points.len(),
        points,
        scales,
        output_scale: config.output_scale,
        target: None,
    };
    if let Some(object) = source.object {
        sample.target = Some(make_target(
            &config.coder,
            object,
            sample.class_slot,
            &sample.frame,
            sample.positions(),
        ));
    }
    sample
}

fn make_target(
    coder: &BoxCoder,
    object: &Box3d,
    cluster: usize,
    frame: &FrustumFrame,
    positions: &[[f64; 3]],
) -> SampleTarget {
    let in_frustum = frame.box_to_frustum(object);
    SampleTarget {
        object: *object,
        in_frustum,
        encoding: coder.encode_box(object, cluster, frame),
        labels: position_labels(positions, &in_frustum),
        corners: corners(&in_frustum),
    }
}

impl FrustumSample {
    /// Centres of the output positions.
    pub fn positions(&self) -> &[[f64; 3]] {
        &self.scales[self.output_scale].centers
    }

    /// A KITTI result line for a camera-frame box decoded from this sample (see
    /// [`crate::decode_box`]): the frustum's class and (clipped) 2D box, alpha from the
    /// box, truncation and occlusion −1 (results carry none), and `score`. A class of
    /// another format becomes `Misc` (its writer reads [`FrustumSample::class`]).
    pub fn to_kitti_object(&self, box3d: Box3d, score: f64) -> Object {
        Object {
            class: self.class.kitti().unwrap_or(ObjectClass::Misc),
            truncation: -1.0,
            occlusion: -1,
            alpha: alpha_from_ry(box3d.ry, box3d.x, box3d.z),
            bbox: self.box2d,
            box3d,
            score: Some(score),
        }
    }

    /// The sample mirrored about the frustum axis (x → −x, heading → π − heading), the
    /// frame's mirror flag toggled and the targets recomputed through it. Membership is
    /// unchanged (depths are), so flipping twice returns the original exactly.
    pub fn flipped(&self, coder: &BoxCoder) -> FrustumSample {
        let frame = self
            .frame
            .with_augmentation(!self.frame.mirrored, self.frame.depth_shift);
        let mut out = FrustumSample {
            frame,
            points: self.points.iter().map(|p| [-p[0], p[1], p[2]]).collect(),
            target: None,
            ..self.clone()
        };
        for s in &mut out.scales {
            for c in &mut s.centers {
                c[0] = -c[0];
            }
        }
        // The mirror negates x before the projection: its first column changes sign.
        for row in 0..3 {
            out.image_projection[4 * row] = -out.image_projection[4 * row];
        }
        if let Some(t) = &self.target {
            out.target = Some(make_target(
                coder,
                &t.object,
                out.class_slot,
                &out.frame,
                out.positions(),
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::SkipReason;
    use crate::frustum::extract_frustum;
    use crate::rng::Sampler;
    use crate::slicing::{DepthGuidedSlicing, Slicing};
    use crate::targets::LABEL_POSITIVE;
    use crate::test_data::sample_frame;
    use fusiondet_geometry::points_in_box;

    fn car_sample(aug: Augmentation, seed: u64) -> FrustumSample {
        sample_of_000003(&FrustumConfig::car(), aug, seed)
    }

    /// The training sample of the first object of bundled frame 000003.
    fn sample_of_000003(config: &FrustumConfig, aug: Augmentation, seed: u64) -> FrustumSample {
        let frame = sample_frame("000003");
        let obj = &frame.objects[0];
        let fp = extract_frustum(&frame, &obj.bbox, config.depth_range, 25.0).unwrap();
        let source = SampleSource {
            frame_id: &frame.id,
            class: frame.classes[0],
            score: None,
            focal_v: frame.camera.fv(),
            p2: frame.camera.p2_rows(),
            object: Some(&obj.box3d),
        };
        build_sample(
            &source,
            &fp,
            aug,
            config,
            &mut Sampler::from_path(seed, &[]),
        )
    }

    #[test]
    fn only_the_first_sliced_points_are_cut_into_sub_frustums() {
        let config = FrustumConfig {
            points_per_frustum: 4096,
            sliced_points: 1024,
            ..FrustumConfig::car()
        };
        config.validate().unwrap();
        let s = sample_of_000003(&config, Augmentation::default(), 1);
        assert_eq!(s.points.len(), 4096);
        let used: Vec<u32> = s
            .scales
            .iter()
            .flat_map(|sc| sc.pair_point.clone())
            .collect();
        assert!(used.iter().all(|&p| p < 1024));
        assert!(used.iter().any(|&p| p >= 1000), "the whole prefix is used");
        let too_many = FrustumConfig {
            sliced_points: 5000,
            ..config
        };
        assert!(
            too_many
                .validate()
                .unwrap_err()
                .to_string()
                .contains("sliced_points")
        );
    }

    #[test]
    fn depth_guided_car_sample_on_frame_000003() {
        let frame = sample_frame("000003");
        let obj = &frame.objects[0];
        let s = sample_of_000003(
            &FrustumConfig::saf_car(),
            Augmentation {
                mirror: true,
                depth_shift: 0.6,
            },
            7,
        );
        let counts: Vec<usize> = s.scales.iter().map(|sc| sc.centers.len()).collect();
        assert_eq!(counts, [240, 120, 60, 30]);
        // The 103 px tall box gives L_depth = 721.54 · 1.56 / 102.99 ≈ 10.9 m for a car
        // at 13.3 m (its box is taller than a mean car's would be).
        let l_depth = frame.camera.fv() * 1.56 / obj.bbox.height();
        let near = crate::DEFAULT_OMEGA * l_depth;
        for sc in &s.scales {
            assert!((sc.slices[0].center - 0.5 * near).abs() < 1e-9);
            // Centres are the ray points at the interval centres, even if uneven.
            for (iv, c) in sc.slices.iter().zip(&sc.centers) {
                assert_eq!(*c, s.frame.ray_point(iv.center));
            }
        }
        let t = s.target.as_ref().unwrap();
        assert_eq!(t.labels.len(), 120);
        // Positives are exactly the output centres inside the shrunk footprint.
        for (p, l) in s.positions().iter().zip(&t.labels) {
            let inside = crate::targets::in_footprint(&t.in_frustum, p[0], p[2], 0.5);
            assert_eq!(*l == LABEL_POSITIVE, inside, "position at {}", p[2]);
        }
        let positives: Vec<f64> = s
            .positions()
            .iter()
            .zip(&t.labels)
            .filter(|(_, l)| **l == LABEL_POSITIVE)
            .map(|(p, _)| p[2])
            .collect();
        // Shifted by 0.6 m: about 13.9 m along the frustum.
        assert!(positives.len() >= 2, "{positives:?}");
        assert!(
            positives.iter().all(|z| (z - 13.9).abs() < 1.2),
            "{positives:?}"
        );
        // The decoded target is the label.
        let back = BoxCoder::kitti().decode_encoding(&t.encoding, &s.frame);
        assert!((back.x - obj.box3d.x).abs() < 1e-9 && (back.z - obj.box3d.z).abs() < 1e-9);
    }

    /// `compress_near_depth` reaches the sample's scales and the collated batch: the
    /// near sub-frustum's gain, 1 for the rest, and no gains without it.
    #[test]
    fn compressed_near_depth_reaches_the_batch() {
        let none = Augmentation {
            mirror: false,
            depth_shift: 0.0,
        };
        let plain = sample_of_000003(&FrustumConfig::saf_car(), none, 7);
        assert!(
            plain
                .scales
                .iter()
                .all(|sc| sc.relative_depth_gains.is_empty())
        );
        assert!(
            crate::collate(std::slice::from_ref(&plain))
                .scales
                .iter()
                .all(|sc| sc.relative_depth_gains.is_empty())
        );
        let config = FrustumConfig {
            slicing: Slicing::DepthGuided(DepthGuidedSlicing {
                omega: 0.85,
                compress_near_depth: true,
                ..DepthGuidedSlicing::saf_car()
            }),
            ..FrustumConfig::saf_car()
        };
        let s = sample_of_000003(&config, none, 7);
        let batch = crate::collate(&[s.clone(), s.clone()]);
        for (sc, bs) in s.scales.iter().zip(&batch.scales) {
            let g = &sc.relative_depth_gains;
            assert_eq!(g.len(), sc.slices.len());
            let regular = sc.slices.last().unwrap().half_length;
            assert_eq!(g[0], regular / sc.slices[0].half_length);
            assert!(g[0] < 1.0 && g[1..].iter().all(|&x| x == 1.0));
            let expected: Vec<f32> = g.iter().chain(g).map(|&x| x as f32).collect();
            assert_eq!(bs.relative_depth_gains, expected);
        }
    }

    #[test]
    fn sampling_repeats_only_when_needed() {
        let mut rng = Sampler::from_path(5, &[]);
        let few = sample_indices(10, 1024, &mut rng);
        assert_eq!(few.len(), 1024);
        for i in 0..10 {
            assert!(few.contains(&i), "every real point is kept");
        }
        let many = sample_indices(5000, 1024, &mut rng);
        let mut sorted = many.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(
            sorted.len(),
            1024,
            "no repeats when there are enough points"
        );
        assert!(many.iter().all(|&i| i < 5000));
    }

    /// The defect this guards against: with repeats shuffled in, the first 1,024 of 4,096
    /// samples from a 1,000-point frustum held only ~655 distinct points.
    #[test]
    fn distinct_points_come_before_the_repeats() {
        for available in [800, 1000, 1500, 2000, 4095] {
            let mut rng = Sampler::from_path(9, &[available as u64]);
            let idx = sample_indices(available, 4096, &mut rng);
            assert_eq!(idx.len(), 4096);
            let mut head: Vec<usize> = idx[..available].to_vec();
            head.sort_unstable();
            assert_eq!(head, (0..available).collect::<Vec<_>>(), "{available}");
            let prefix: std::collections::HashSet<usize> = idx[..1024].iter().copied().collect();
            assert_eq!(prefix.len(), available.min(1024), "{available}");
            // Still in random order, not sorted.
            assert_ne!(&idx[..8], &[0, 1, 2, 3, 4, 5, 6, 7]);
        }
    }

    #[test]
    fn real_frame_000003_car() {
        let s = car_sample(Augmentation::default(), 1);
        assert!(s.num_frustum_points > 300, "{}", s.num_frustum_points);
        assert_eq!(s.points.len(), 1024);
        let counts: Vec<usize> = s.scales.iter().map(|sc| sc.centers.len()).collect();
        assert_eq!(counts, [280, 140, 70, 35]);
        let t = s.target.as_ref().unwrap();
        let positives: Vec<f64> = s
            .positions()
            .iter()
            .zip(&t.labels)
            .filter(|(_, l)| **l == LABEL_POSITIVE)
            .map(|(p, _)| p[2])
            .collect();
        assert!(!positives.is_empty());
        // The car is at z 13.22 m, x 1.0 m: about 13.3 m along its frustum, and the
        // positives are no more than half the (shrunk) length away.
        assert!(
            positives.iter().all(|z| (z - 13.3).abs() < 1.2),
            "{positives:?}"
        );
        assert!(
            positives.iter().any(|z| (z - 13.3).abs() < 0.5),
            "{positives:?}"
        );
        // Many of the sampled points hit the car.
        let hit = points_in_box(&t.in_frustum, &s.points)
            .iter()
            .filter(|&&b| b)
            .count();
        assert!(hit > 300, "{hit}");
    }

    #[test]
    fn every_pair_is_real_within_its_interval_and_capped() {
        let s = car_sample(
            Augmentation {
                mirror: true,
                depth_shift: 1.3,
            },
            2,
        );
        for sc in &s.scales {
            assert_eq!(sc.pair_point.len(), sc.pair_slice.len());
            assert!(sc.pair_slice.windows(2).all(|w| w[0] <= w[1]));
            let mut per_slice = vec![0usize; sc.slices.len()];
            for (&p, &k) in sc.pair_point.iter().zip(&sc.pair_slice) {
                let z = s.points[p as usize][2];
                let iv = sc.slices[k as usize];
                assert!(iv.contains(z), "point depth {z} outside {iv:?}");
                per_slice[k as usize] += 1;
            }
            assert!(per_slice.iter().all(|&n| n <= sc.max_points_per_slice));
            // Slices not at their cap hold every point of their interval.
            for (k, iv) in sc.slices.iter().enumerate() {
                let inside = s.points.iter().filter(|p| iv.contains(p[2])).count();
                assert_eq!(
                    per_slice[k],
                    inside.min(sc.max_points_per_slice),
                    "slice {k}"
                );
            }
            assert!(
                per_slice.contains(&sc.max_points_per_slice),
                "the car fills some slice to its cap"
            );
        }
        assert_eq!(
            s.scales
                .iter()
                .map(|sc| sc.max_points_per_slice)
                .collect::<Vec<_>>(),
            [32, 64, 64, 128]
        );
    }

    #[test]
    fn flipping_twice_is_the_identity_and_flip_is_consistent() {
        let s = car_sample(
            Augmentation {
                mirror: false,
                depth_shift: 0.7,
            },
            3,
        );
        let f = s.flipped(&BoxCoder::kitti());
        assert_ne!(f, s);
        assert_eq!(f.flipped(&BoxCoder::kitti()), s);
        // The flipped target decodes to the same camera box, and the same points are inside it.
        let t = s.target.as_ref().unwrap();
        let ft = f.target.as_ref().unwrap();
        let back = BoxCoder::kitti().decode_encoding(&ft.encoding, &f.frame);
        for (a, b) in [
            (back.x, t.object.x),
            (back.z, t.object.z),
            (back.y, t.object.y),
        ] {
            assert!((a - b).abs() < 1e-9);
        }
        assert!(fusiondet_geometry::normalize_angle(back.ry - t.object.ry).abs() < 1e-9);
        assert_eq!(
            points_in_box(&t.in_frustum, &s.points),
            points_in_box(&ft.in_frustum, &f.points)
        );
        assert_eq!(t.labels, ft.labels);
        assert!((ft.in_frustum.x + t.in_frustum.x).abs() < 1e-12);
        // And building with the mirror on gives the flipped sample.
        let built = car_sample(
            Augmentation {
                mirror: true,
                depth_shift: 0.7,
            },
            3,
        );
        assert_eq!(built, f);
    }

    #[test]
    fn depth_shift_moves_points_and_ground_truth_together() {
        let a = car_sample(Augmentation::default(), 4);
        let b = car_sample(
            Augmentation {
                mirror: false,
                depth_shift: 2.5,
            },
            4,
        );
        for (p, q) in a.points.iter().zip(&b.points) {
            assert_eq!((p[0], p[1]), (q[0], q[1]));
            assert!((q[2] - p[2] - 2.5).abs() < 1e-12);
        }
        let (ta, tb) = (a.target.unwrap(), b.target.unwrap());
        assert!((tb.encoding.center[2] - ta.encoding.center[2] - 2.5).abs() < 1e-12);
        assert_eq!(tb.object, ta.object);
        // The positive positions follow the shifted object.
        let first_pos = |s: &[i64]| s.iter().position(|&l| l == 1).unwrap();
        assert_eq!(first_pos(&tb.labels), first_pos(&ta.labels) + 5);
    }

    #[test]
    fn ground_truth_target_decodes_to_a_kitti_line_like_the_label() {
        let frame = sample_frame("000003");
        let label = &frame.objects[0];
        let s = car_sample(
            Augmentation {
                mirror: true,
                depth_shift: -0.4,
            },
            6,
        );
        let t = s.target.as_ref().unwrap();
        let o = s.to_kitti_object(
            BoxCoder::kitti().decode_encoding(&t.encoding, &s.frame),
            0.9,
        );
        assert_eq!(
            (o.class, o.bbox, o.score),
            (label.class, label.bbox, Some(0.9))
        );
        // The label's alpha is reproduced from the decoded box to its two decimals
        // (1.62 − atan2(1.00, 13.22) = 1.5445 against the labelled 1.55).
        assert!(
            (o.alpha - label.alpha).abs() < 0.006,
            "{} vs {}",
            o.alpha,
            label.alpha
        );
        let text = fusiondet_kitti::label::format_objects(&[o]);
        assert!(text.starts_with("Car -1.00 -1 1.54 614.24 181.78 727.31 284.77 1.57 1.73 4.15 1.00 1.75 13.22 1.62 0.9000"), "{text}");
    }

    #[test]
    fn skip_reason_is_typed() {
        let frame = sample_frame("000003");
        let b = Box2d {
            x1: 2000.0,
            y1: 0.0,
            x2: 2100.0,
            y2: 50.0,
        };
        assert_eq!(
            extract_frustum(&frame, &b, [0.0, 70.0], 0.0).err(),
            Some(SkipReason::OutsideImage)
        );
    }
}
