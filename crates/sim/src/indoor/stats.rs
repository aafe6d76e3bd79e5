//! Statistics of a simulated indoor data set, and the real scene 000017 beside them: points
//! inside each labelled box (as anyone counts them on real labels), object sizes, camera
//! height against the floor the points show (the 1st percentile of z), measured pixels, the
//! 2D detector's recall and precision. Written to `sim_stats.json`, printed after a run.

use super::IndoorFrame;
use fusiondet_geometry::iou_2d;
use fusiondet_sunrgbd::SunClass;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// The real scene 000017 (all 50,000 points of the shared copy): its floor's z (1st
/// percentile), and the points inside its two labelled boxes.
pub const REAL_FLOOR_Z: f64 = -1.24;
pub const REAL_BED_POINTS: usize = 18_117;
pub const REAL_NIGHT_STAND_POINTS: usize = 951;
/// The real scene's mean point colour (r, g, b in [0, 1]).
pub const REAL_MEAN_RGB: [f64; 3] = [0.508, 0.491, 0.483];
/// Horizontal distances of the real bed's and night stand's box centres from the camera, m.
pub const REAL_BED_DISTANCE: f64 = 2.99;
pub const REAL_NIGHT_STAND_DISTANCE: f64 = 3.63;

/// Simulated objects of one class at about a real object's distance (± 0.5 m).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct NearReal {
    pub class: String,
    pub distance: f64,
    pub real_points: usize,
    pub count: usize,
    pub mean_box_points: f64,
}

/// One labelled object.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ObjectRecord {
    pub class: String,
    pub box_points: usize,
    pub own_points: usize,
    pub size: [f64; 3],
    /// Horizontal distance of the box centre from the camera, metres.
    pub distance: f64,
    pub hidden: f64,
}

/// One frame's summary.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameStats {
    pub id: String,
    pub room: String,
    pub camera_height: f64,
    pub pitch_deg: f64,
    /// 1st percentile of the points' z.
    pub floor_z: f64,
    pub measured_fraction: f64,
    pub points: usize,
    /// Mean colour of the points.
    pub mean_rgb: [f64; 3],
    pub objects: Vec<ObjectRecord>,
    pub detections: usize,
    /// Detections with score ≥ 0.5, and those matching a label of their class at IoU ≥ 0.5.
    pub confident: usize,
    pub confident_correct: usize,
    /// Labels matched by any detection of their class at IoU ≥ 0.5.
    pub found: usize,
}

impl FrameStats {
    pub fn from_frame(f: &IndoorFrame) -> FrameStats {
        let mut z: Vec<f64> = f.points.iter().map(|p| f64::from(p[2])).collect();
        z.sort_by(f64::total_cmp);
        let floor_z = z.get(z.len() / 100).copied().unwrap_or(0.0);
        let objects = f
            .views
            .iter()
            .filter(|v| v.labelled)
            .map(|v| ObjectRecord {
                class: v.class.as_str().to_string(),
                box_points: v.box_points,
                own_points: v.own_points,
                size: v.box3d.size,
                distance: v.box3d.centre[0].hypot(v.box3d.centre[1]),
                hidden: v.hidden(),
            })
            .collect();
        let matches = |d: &fusiondet_sunrgbd::Detection2d| {
            f.objects
                .iter()
                .any(|o| o.class == d.class && iou_2d(&o.bbox, &d.bbox) >= 0.5)
        };
        let confident: Vec<_> = f.detections.iter().filter(|d| d.score >= 0.5).collect();
        FrameStats {
            id: f.id.clone(),
            room: f.room.as_str().to_string(),
            camera_height: f.camera.camera_height,
            pitch_deg: f.camera.pitch.to_degrees(),
            floor_z,
            measured_fraction: f.measured as f64 / f.depth.millimetres.len().max(1) as f64,
            points: f.points.len(),
            mean_rgb: std::array::from_fn(|k| mean(f.points.iter().map(|p| f64::from(p[3 + k])))),
            objects,
            detections: f.detections.len(),
            confident: confident.len(),
            confident_correct: confident.iter().filter(|d| matches(d)).count(),
            found: f
                .objects
                .iter()
                .filter(|o| {
                    f.detections
                        .iter()
                        .any(|d| d.class == o.class && iou_2d(&o.bbox, &d.bbox) >= 0.5)
                })
                .count(),
        }
    }
}

/// Per-class summary.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ClassStats {
    pub class: String,
    pub count: usize,
    pub mean_box_points: f64,
    pub median_box_points: f64,
    pub mean_size: [f64; 3],
    /// SUN RGB-D's mean size of the class (the real data's).
    pub real_mean_size: [f64; 3],
    pub mean_distance: f64,
}

/// The data set's summary.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DatasetStats {
    pub frames: usize,
    pub rooms: BTreeMap<String, usize>,
    pub points_per_scene: f64,
    pub measured_fraction: f64,
    pub mean_rgb: [f64; 3],
    pub camera_height: [f64; 3],
    /// Mean of floor z + camera height (how well the floor shows the height).
    pub floor_offset: f64,
    pub labels_per_scene: f64,
    pub classes: Vec<ClassStats>,
    /// Points in boxes at the real scene's objects' distances.
    pub near_real: Vec<NearReal>,
    pub detections_per_scene: f64,
    pub recall_iou50: f64,
    pub precision_score50: f64,
    pub per_frame: Vec<FrameStats>,
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (mut n, mut s) = (0.0, 0.0);
    for x in v {
        n += 1.0;
        s += x;
    }
    if n > 0.0 { s / n } else { 0.0 }
}

impl DatasetStats {
    pub fn from_frames(frames: Vec<FrameStats>) -> DatasetStats {
        let n = frames.len().max(1) as f64;
        let mut rooms = BTreeMap::new();
        for f in &frames {
            *rooms.entry(f.room.clone()).or_insert(0) += 1;
        }
        let heights: Vec<f64> = frames.iter().map(|f| f.camera_height).collect();
        let classes = SunClass::ALL
            .iter()
            .map(|c| {
                let objs: Vec<&ObjectRecord> = frames
                    .iter()
                    .flat_map(|f| &f.objects)
                    .filter(|o| o.class == c.as_str())
                    .collect();
                let mut pts: Vec<f64> = objs.iter().map(|o| o.box_points as f64).collect();
                pts.sort_by(f64::total_cmp);
                ClassStats {
                    class: c.as_str().to_string(),
                    count: objs.len(),
                    mean_box_points: mean(pts.iter().copied()),
                    median_box_points: pts.get(pts.len() / 2).copied().unwrap_or(0.0),
                    mean_size: std::array::from_fn(|k| mean(objs.iter().map(|o| o.size[k]))),
                    real_mean_size: c.mean_size(),
                    mean_distance: mean(objs.iter().map(|o| o.distance)),
                }
            })
            .collect();
        let near_real = [
            (SunClass::Bed, REAL_BED_DISTANCE, REAL_BED_POINTS),
            (
                SunClass::NightStand,
                REAL_NIGHT_STAND_DISTANCE,
                REAL_NIGHT_STAND_POINTS,
            ),
        ]
        .into_iter()
        .map(|(c, distance, real_points)| {
            let pts: Vec<f64> = frames
                .iter()
                .flat_map(|f| &f.objects)
                .filter(|o| o.class == c.as_str() && (o.distance - distance).abs() <= 0.5)
                .map(|o| o.box_points as f64)
                .collect();
            NearReal {
                class: c.as_str().to_string(),
                distance,
                real_points,
                count: pts.len(),
                mean_box_points: mean(pts.into_iter()),
            }
        })
        .collect();
        let labels: usize = frames.iter().map(|f| f.objects.len()).sum();
        let confident: usize = frames.iter().map(|f| f.confident).sum();
        DatasetStats {
            frames: frames.len(),
            rooms,
            points_per_scene: mean(frames.iter().map(|f| f.points as f64)),
            measured_fraction: mean(frames.iter().map(|f| f.measured_fraction)),
            mean_rgb: std::array::from_fn(|k| mean(frames.iter().map(|f| f.mean_rgb[k]))),
            camera_height: [
                heights.iter().copied().fold(f64::INFINITY, f64::min),
                mean(heights.iter().copied()),
                heights.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            ],
            floor_offset: mean(frames.iter().map(|f| f.floor_z + f.camera_height)),
            labels_per_scene: labels as f64 / n,
            classes,
            near_real,
            detections_per_scene: mean(frames.iter().map(|f| f.detections as f64)),
            recall_iou50: frames.iter().map(|f| f.found).sum::<usize>() as f64
                / labels.max(1) as f64,
            precision_score50: frames.iter().map(|f| f.confident_correct).sum::<usize>() as f64
                / confident.max(1) as f64,
            per_frame: frames,
        }
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("statistics serialise")
    }

    /// The printed report, with the real scene's numbers beside.
    pub fn report(&self) -> String {
        let mut o = String::new();
        let rooms: Vec<String> = self.rooms.iter().map(|(k, v)| format!("{k} {v}")).collect();
        let _ = writeln!(
            o,
            "indoor data set: {} scenes ({})",
            self.frames,
            rooms.join(", ")
        );
        let _ = writeln!(
            o,
            "  points per scene {:.0} (real prepared scenes: 50000); measured pixels {:.0}%",
            self.points_per_scene,
            100.0 * self.measured_fraction
        );
        let [r, g, b] = self.mean_rgb;
        let [rr, rg, rb] = REAL_MEAN_RGB;
        let _ = writeln!(
            o,
            "  mean point colour {r:.2} {g:.2} {b:.2} (real 000017: {rr:.2} {rg:.2} {rb:.2})"
        );
        let _ = writeln!(
            o,
            "  camera height {:.2}–{:.2} m, mean {:.2} (real 000017: floor at z = {REAL_FLOOR_Z:.2}, i.e. 1.24 m); \
             floor z + height = {:+.3} m on average",
            self.camera_height[0], self.camera_height[2], self.camera_height[1], self.floor_offset
        );
        let _ = writeln!(o, "  labels per scene {:.2}", self.labels_per_scene);
        let _ = writeln!(
            o,
            "  {:<12} {:>5} {:>10} {:>10} {:>20} {:>20} {:>6}",
            "class", "count", "pts mean", "pts median", "size dx×dy×dz", "SUN RGB-D mean", "dist"
        );
        for c in &self.classes {
            let f = |s: [f64; 3]| format!("{:.2}×{:.2}×{:.2}", s[0], s[1], s[2]);
            let _ = writeln!(
                o,
                "  {:<12} {:>5} {:>10.0} {:>10.0} {:>20} {:>20} {:>6.2}",
                c.class,
                c.count,
                c.mean_box_points,
                c.median_box_points,
                if c.count > 0 {
                    f(c.mean_size)
                } else {
                    "-".into()
                },
                f(c.real_mean_size),
                c.mean_distance
            );
        }
        for n in &self.near_real {
            let _ = writeln!(
                o,
                "  {} at {:.1}±0.5 m: {} simulated, {:.0} points in the box on average; real 000017's at {:.1} m: {}",
                n.class, n.distance, n.count, n.mean_box_points, n.distance, n.real_points
            );
        }
        let _ = writeln!(
            o,
            "  2D detector: {:.1} detections per scene, recall {:.0}% (IoU 0.5, any score), precision {:.0}% (score ≥ 0.5)",
            self.detections_per_scene,
            100.0 * self.recall_iou50,
            100.0 * self.precision_score50
        );
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(class: &str, box_points: usize, distance: f64) -> ObjectRecord {
        ObjectRecord {
            class: class.into(),
            box_points,
            own_points: box_points,
            size: [2.0, 1.5, 1.0],
            distance,
            hidden: 0.0,
        }
    }

    #[test]
    fn summaries_count_what_they_say() {
        let frame = |objects, found, confident, correct| FrameStats {
            id: "000000".into(),
            room: "bedroom".into(),
            camera_height: 1.3,
            pitch_deg: 10.0,
            floor_z: -1.28,
            measured_fraction: 0.9,
            points: 50_000,
            mean_rgb: [0.5; 3],
            objects,
            detections: 3,
            confident,
            confident_correct: correct,
            found,
        };
        let stats = DatasetStats::from_frames(vec![
            frame(
                vec![object("bed", 10_000, 3.2), object("chair", 500, 2.0)],
                2,
                2,
                2,
            ),
            frame(vec![object("bed", 2_000, 4.0)], 0, 2, 1),
        ]);
        assert_eq!(stats.frames, 2);
        assert!((stats.labels_per_scene - 1.5).abs() < 1e-12);
        assert!((stats.recall_iou50 - 2.0 / 3.0).abs() < 1e-12);
        assert!((stats.precision_score50 - 0.75).abs() < 1e-12);
        assert!((stats.floor_offset - 0.02).abs() < 1e-9);
        let bed = &stats.classes[SunClass::Bed.index()];
        assert_eq!((bed.count, bed.mean_box_points), (2, 6_000.0));
        // Only the bed within 0.5 m of the real bed's 2.99 m is compared with it.
        assert_eq!(stats.near_real[0].count, 1);
        assert_eq!(stats.near_real[0].mean_box_points, 10_000.0);
        assert!(stats.report().contains("real 000017's at 3.0 m: 18117"));
    }
}
