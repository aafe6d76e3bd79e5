//! Realism statistics of a simulated dataset, against what KITTI shows:
//!
//! * LiDAR points inside unoccluded car boxes by depth, next to KITTI's curve
//!   (measured on the real frames: 680 points at 13 m, ~70 at 34–38 m, 26 at 51 m,
//!   9 at 58 m; interpolated as a piecewise power law);
//! * the labelled class mix and the shares of occluded and truncated cars;
//! * KITTI difficulty counts (easy / moderate / hard as the devkit defines them);
//! * how the simulated 2D detector behaves (recall, IoU, scores, false positives).
//!
//! The JSON holds no timings, so the same seed writes the same file.

use crate::SimFrame;
use crate::math::{exp, ln};
use fusiondet_geometry::{Normalization, iou_2d, overlap_2d};
use fusiondet_kitti::{Object, ObjectClass};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// KITTI's points-on-car curve: (depth in m, points inside the box), measured on
/// the real frames for unoccluded cars.
pub const KITTI_CAR_POINTS: [(f64, f64); 4] =
    [(13.0, 680.0), (36.0, 70.0), (51.0, 26.0), (58.0, 9.0)];

/// KITTI's curve at `depth`: power-law interpolation between the measured cars.
/// Beyond them it is extended with the slope of the whole 36–58 m stretch (the last
/// segment alone, one car at 58 m, is too steep to extrapolate), and below 13 m with
/// the 13–36 m slope. Bins outside 13–58 m compare against an extrapolation.
pub fn kitti_car_points(depth: f64) -> f64 {
    let k = &KITTI_CAR_POINTS;
    let slope = |(d0, n0): (f64, f64), (d1, n1): (f64, f64)| (ln(n1) - ln(n0)) / (ln(d1) - ln(d0));
    let d = depth.max(1.0);
    let (anchor, s) = if d <= k[1].0 {
        (k[0], slope(k[0], k[1]))
    } else if d <= k[2].0 {
        (k[1], slope(k[1], k[2]))
    } else if d <= k[3].0 {
        (k[2], slope(k[2], k[3]))
    } else {
        (k[3], slope(k[1], k[3]))
    };
    exp(ln(anchor.1) + s * (ln(d) - ln(anchor.0)))
}

/// KITTI difficulty of a labelled object (None: ignored by the benchmark).
pub fn difficulty(o: &Object) -> Option<&'static str> {
    let h = o.bbox.y2 - o.bbox.y1;
    if h >= 40.0 && o.occlusion <= 0 && o.truncation <= 0.15 {
        Some("easy")
    } else if h >= 25.0 && o.occlusion <= 1 && o.truncation <= 0.30 {
        Some("moderate")
    } else if h >= 25.0 && o.occlusion <= 2 && o.truncation <= 0.50 {
        Some("hard")
    } else {
        None
    }
}

/// One labelled object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectRecord {
    pub class: String,
    pub depth: f64,
    pub occlusion: i32,
    pub hidden: f64,
    pub truncation: f64,
    pub height_px: f64,
    pub points: usize,
    pub difficulty: Option<String>,
    /// Best IoU of a same-class detection (0 if none).
    pub detection_iou: f64,
    pub detection_score: f64,
}

/// One detection, judged against the labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectionRecord {
    pub class: String,
    pub score: f64,
    /// Overlaps a same-class label with IoU ≥ 0.5.
    pub true_positive: bool,
    /// Lies mostly (≥ 50%) inside a DontCare region.
    pub in_dontcare: bool,
}

/// Per-frame numbers the dataset statistics are built from (also kept by a sharded run's
/// shards until the last one writes the statistics; the JSON round trip is exact).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    pub index: usize,
    pub kind: String,
    pub points: usize,
    pub rays: usize,
    pub objects: Vec<ObjectRecord>,
    pub dontcare: usize,
    pub detections: Vec<DetectionRecord>,
    pub val: bool,
}

impl FrameStats {
    pub fn from_frame(f: &SimFrame) -> FrameStats {
        let mut objects = Vec::new();
        for v in f.views.iter().filter(|v| v.is_labelled()) {
            let o = v.label.as_ref().expect("labelled");
            let (mut best_iou, mut best_score) = (0.0f64, 0.0);
            for d in f.detections.iter().filter(|d| d.class == o.class) {
                let iou = iou_2d(&d.bbox, &o.bbox);
                if iou > best_iou {
                    best_iou = iou;
                    best_score = d.score;
                }
            }
            objects.push(ObjectRecord {
                class: o.class.to_string(),
                depth: o.box3d.z,
                occlusion: o.occlusion,
                hidden: v.hidden,
                truncation: o.truncation,
                height_px: o.bbox.y2 - o.bbox.y1,
                points: v.points_in_box,
                difficulty: difficulty(o).map(str::to_string),
                detection_iou: best_iou,
                detection_score: best_score,
            });
        }
        let dontcares: Vec<&Object> = f
            .objects
            .iter()
            .filter(|o| o.class == ObjectClass::DontCare)
            .collect();
        let detections = f
            .detections
            .iter()
            .map(|d| DetectionRecord {
                class: d.class.to_string(),
                score: d.score,
                true_positive: f
                    .objects
                    .iter()
                    .any(|o| o.class == d.class && iou_2d(&d.bbox, &o.bbox) >= 0.5),
                in_dontcare: dontcares
                    .iter()
                    .any(|o| overlap_2d(&d.bbox, &o.bbox, Normalization::First) >= 0.5),
            })
            .collect();
        FrameStats {
            index: f.index,
            kind: format!("{:?}", f.layout.kind),
            points: f.points.len(),
            rays: f.rays,
            objects,
            dontcare: dontcares.len(),
            detections,
            val: f.split == crate::Split::Val,
        }
    }
}

/// Median points on unoccluded cars in one depth bin, next to KITTI's curve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointsBin {
    pub depth_from: f64,
    pub depth_to: f64,
    pub cars: usize,
    pub median_depth: f64,
    pub median_points: f64,
    /// KITTI's curve at the bin's median depth.
    pub kitti_points: f64,
    /// median_points / kitti_points.
    pub ratio: f64,
    /// Median over all labelled cars in the bin (occluded and truncated too).
    pub median_points_all_cars: f64,
}

/// Summary of the simulated 2D detector.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectorStats {
    pub detections_per_frame: f64,
    pub above_half_per_frame: f64,
    /// Share of detections that match no label (IoU 0.5) and are not in a DontCare region.
    pub false_positive_share: f64,
    /// Recall (same class, IoU ≥ 0.7 for cars, 0.5 otherwise) per class and difficulty.
    pub recall: BTreeMap<String, BTreeMap<String, f64>>,
    pub median_iou_matched: f64,
    /// Share of detections per score bucket (<0.1, 0.1–0.5, 0.5–0.9, 0.9–0.99, ≥ 0.99).
    pub score_buckets: [f64; 5],
}

/// Realism statistics of a set of frames.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DatasetStats {
    pub frames: usize,
    pub points_per_frame_median: f64,
    pub points_per_frame_min: usize,
    pub points_per_frame_max: usize,
    pub returned_ray_share: f64,
    pub scene_kinds: BTreeMap<String, usize>,
    /// Labelled objects per class (DontCare separately).
    pub labels: BTreeMap<String, usize>,
    pub dontcare: usize,
    /// Share of each of Car / Pedestrian / Cyclist among the three.
    pub evaluated_class_share: BTreeMap<String, f64>,
    pub car_occluded_share: f64,
    pub car_truncated_share: f64,
    /// Cars per occlusion level 0..3.
    pub car_occlusion_levels: [usize; 4],
    /// Objects per class and KITTI difficulty (finest level: easy, moderate, hard, ignored).
    pub difficulty: BTreeMap<String, BTreeMap<String, usize>>,
    pub points_per_car: Vec<PointsBin>,
    pub detector: DetectorStats,
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn round(x: f64, digits: u32) -> f64 {
    let s = crate::math::ipow(10.0, digits);
    (x * s).round() / s
}

/// Depth bins of the points-per-car table.
pub const DEPTH_BINS: [(f64, f64); 9] = [
    (5.0, 10.0),
    (10.0, 15.0),
    (15.0, 20.0),
    (20.0, 30.0),
    (30.0, 40.0),
    (40.0, 50.0),
    (50.0, 60.0),
    (60.0, 70.0),
    (70.0, 80.0),
];

impl DatasetStats {
    pub fn from_frames(frames: &[FrameStats]) -> DatasetStats {
        let mut pts: Vec<f64> = frames.iter().map(|f| f.points as f64).collect();
        let rays: usize = frames.iter().map(|f| f.rays).sum();
        let total_pts: usize = frames.iter().map(|f| f.points).sum();
        let mut scene_kinds = BTreeMap::new();
        for f in frames {
            *scene_kinds.entry(f.kind.clone()).or_insert(0) += 1;
        }
        let objs: Vec<&ObjectRecord> = frames.iter().flat_map(|f| &f.objects).collect();
        let mut labels = BTreeMap::new();
        for o in &objs {
            *labels.entry(o.class.clone()).or_insert(0) += 1;
        }
        let evaluated = ["Car", "Pedestrian", "Cyclist"];
        let n_eval: usize = evaluated
            .iter()
            .map(|c| labels.get(*c).copied().unwrap_or(0))
            .sum();
        let evaluated_class_share = evaluated
            .iter()
            .map(|c| {
                let n = labels.get(*c).copied().unwrap_or(0);
                (c.to_string(), round(n as f64 / n_eval.max(1) as f64, 4))
            })
            .collect();
        let cars: Vec<&&ObjectRecord> = objs.iter().filter(|o| o.class == "Car").collect();
        let n_cars = cars.len().max(1) as f64;
        let mut car_occlusion_levels = [0usize; 4];
        for c in &cars {
            car_occlusion_levels[c.occlusion.clamp(0, 3) as usize] += 1;
        }
        let mut difficulty: BTreeMap<String, BTreeMap<String, usize>> = BTreeMap::new();
        for o in &objs {
            *difficulty
                .entry(o.class.clone())
                .or_default()
                .entry(o.difficulty.as_deref().unwrap_or("ignored").to_string())
                .or_insert(0) += 1;
        }
        let points_per_car = DEPTH_BINS
            .iter()
            .map(|&(lo, hi)| {
                let in_bin = |o: &ObjectRecord| o.depth >= lo && o.depth < hi;
                let clear: Vec<&&ObjectRecord> = cars
                    .iter()
                    .filter(|o| in_bin(o) && o.occlusion == 0 && o.truncation <= 0.15)
                    .copied()
                    .collect();
                let mut p: Vec<f64> = clear.iter().map(|o| o.points as f64).collect();
                let mut d: Vec<f64> = clear.iter().map(|o| o.depth).collect();
                let mut all: Vec<f64> = cars
                    .iter()
                    .filter(|o| in_bin(o))
                    .map(|o| o.points as f64)
                    .collect();
                let md = median(&mut d);
                let mp = median(&mut p);
                let reference = if clear.is_empty() {
                    0.0
                } else {
                    kitti_car_points(md)
                };
                PointsBin {
                    depth_from: lo,
                    depth_to: hi,
                    cars: clear.len(),
                    median_depth: round(md, 2),
                    median_points: mp,
                    kitti_points: round(reference, 1),
                    ratio: if reference > 0.0 {
                        round(mp / reference, 3)
                    } else {
                        0.0
                    },
                    median_points_all_cars: median(&mut all),
                }
            })
            .collect();
        DatasetStats {
            frames: frames.len(),
            points_per_frame_median: median(&mut pts),
            points_per_frame_min: frames.iter().map(|f| f.points).min().unwrap_or(0),
            points_per_frame_max: frames.iter().map(|f| f.points).max().unwrap_or(0),
            returned_ray_share: round(total_pts as f64 / rays.max(1) as f64, 4),
            scene_kinds,
            labels,
            dontcare: frames.iter().map(|f| f.dontcare).sum(),
            evaluated_class_share,
            car_occluded_share: round(
                cars.iter().filter(|c| c.occlusion >= 1).count() as f64 / n_cars,
                4,
            ),
            car_truncated_share: round(
                cars.iter().filter(|c| c.truncation > 0.15).count() as f64 / n_cars,
                4,
            ),
            car_occlusion_levels,
            difficulty,
            points_per_car,
            detector: detector_stats(frames),
        }
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("statistics serialise") + "\n"
    }

    /// A human-readable report.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "Simulated dataset: {} frames", self.frames);
        let _ = writeln!(
            s,
            "  points per frame: median {:.0} (min {}, max {}); {:.1}% of rays return   [KITTI: 113k–127k]",
            self.points_per_frame_median,
            self.points_per_frame_min,
            self.points_per_frame_max,
            100.0 * self.returned_ray_share
        );
        let _ = writeln!(s, "  scene kinds: {:?}", self.scene_kinds);
        let _ = writeln!(s, "  labels: {:?}, DontCare {}", self.labels, self.dontcare);
        let share: Vec<String> = self
            .evaluated_class_share
            .iter()
            .map(|(k, v)| format!("{k} {:.1}%", 100.0 * v))
            .collect();
        let _ = writeln!(
            s,
            "  Car/Pedestrian/Cyclist mix: {}   [KITTI: ~82% / 13% / 5%]",
            share.join(", ")
        );
        let _ = writeln!(
            s,
            "  cars occluded (level ≥ 1): {:.1}%   [KITTI: about half]; levels 0–3: {:?}",
            100.0 * self.car_occluded_share,
            self.car_occlusion_levels
        );
        let _ = writeln!(
            s,
            "  cars truncated > 0.15: {:.1}%",
            100.0 * self.car_truncated_share
        );
        for (class, d) in &self.difficulty {
            let _ = writeln!(s, "  {class} by difficulty: {d:?}");
        }
        let _ = writeln!(
            s,
            "  points inside unoccluded car boxes by depth (median) vs KITTI:"
        );
        for b in &self.points_per_car {
            if b.cars == 0 {
                continue;
            }
            let _ = writeln!(
                s,
                "    {:>3.0}–{:<3.0} m: {:>4} cars, median {:>6.1} points at {:>5.1} m; KITTI {:>6.1}; ratio {:.2}  (all cars: {:.0})",
                b.depth_from,
                b.depth_to,
                b.cars,
                b.median_points,
                b.median_depth,
                b.kitti_points,
                b.ratio,
                b.median_points_all_cars
            );
        }
        let d = &self.detector;
        let _ = writeln!(
            s,
            "  2D detector: {:.1} detections/frame ({:.1} with score > 0.5), {:.1}% false positives, median IoU {:.2}",
            d.detections_per_frame,
            d.above_half_per_frame,
            100.0 * d.false_positive_share,
            d.median_iou_matched
        );
        let _ = writeln!(
            s,
            "    score buckets <0.1, 0.1–0.5, 0.5–0.9, 0.9–0.99, ≥0.99: {:?}",
            d.score_buckets
        );
        for (class, r) in &d.recall {
            let _ = writeln!(s, "    {class} recall: {r:?}");
        }
        s
    }
}

fn detector_stats(frames: &[FrameStats]) -> DetectorStats {
    let n = frames.len().max(1) as f64;
    let dets: Vec<&DetectionRecord> = frames.iter().flat_map(|f| &f.detections).collect();
    let nd = dets.len().max(1) as f64;
    let mut buckets = [0.0; 5];
    for d in &dets {
        let k = match d.score {
            s if s < 0.1 => 0,
            s if s < 0.5 => 1,
            s if s < 0.9 => 2,
            s if s < 0.99 => 3,
            _ => 4,
        };
        buckets[k] += 1.0 / nd;
    }
    let mut recall: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    let mut counts: BTreeMap<(String, String), (usize, usize)> = BTreeMap::new();
    let mut ious = Vec::new();
    for o in frames.iter().flat_map(|f| &f.objects) {
        let Some(diff) = o.difficulty.as_deref() else {
            continue;
        };
        if !matches!(o.class.as_str(), "Car" | "Pedestrian" | "Cyclist") {
            continue;
        }
        let thr = if o.class == "Car" { 0.7 } else { 0.5 };
        let e = counts
            .entry((o.class.clone(), diff.to_string()))
            .or_insert((0, 0));
        e.1 += 1;
        if o.detection_iou >= thr {
            e.0 += 1;
        }
        if o.detection_iou >= 0.5 {
            ious.push(o.detection_iou);
        }
    }
    for ((class, diff), (hit, total)) in counts {
        recall
            .entry(class)
            .or_default()
            .insert(diff, round(hit as f64 / total.max(1) as f64, 3));
    }
    DetectorStats {
        detections_per_frame: round(dets.len() as f64 / n, 2),
        above_half_per_frame: round(dets.iter().filter(|d| d.score > 0.5).count() as f64 / n, 2),
        false_positive_share: round(
            dets.iter()
                .filter(|d| !d.true_positive && !d.in_dontcare)
                .count() as f64
                / nd,
            4,
        ),
        recall,
        median_iou_matched: round(median(&mut ious), 3),
        score_buckets: buckets.map(|b| round(b, 4)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_kitti::{Box2d, Box3d};

    #[test]
    fn reference_curve_passes_through_kitti_cars() {
        for (d, n) in KITTI_CAR_POINTS {
            assert!((kitti_car_points(d) - n).abs() < 1e-6 * n);
        }
        assert!(kitti_car_points(8.0) > 680.0);
        assert!(kitti_car_points(70.0) < 9.0);
        let mid = kitti_car_points(20.0);
        assert!(mid < 680.0 && mid > 70.0);
    }

    #[test]
    fn difficulty_follows_the_devkit() {
        let mut o = Object {
            class: ObjectClass::Car,
            truncation: 0.0,
            occlusion: 0,
            alpha: 0.0,
            bbox: Box2d {
                x1: 0.0,
                y1: 0.0,
                x2: 10.0,
                y2: 45.0,
            },
            box3d: Box3d::default(),
            score: None,
        };
        assert_eq!(difficulty(&o), Some("easy"));
        o.occlusion = 1;
        assert_eq!(difficulty(&o), Some("moderate"));
        o.occlusion = 2;
        assert_eq!(difficulty(&o), Some("hard"));
        o.bbox.y2 = 20.0;
        assert_eq!(difficulty(&o), None);
    }
}
