//! The constants of the KITTI object benchmark protocol, kept in one place so that the
//! matching code reads like the devkit and nothing is repeated.

use fusiondet_kitti::ObjectClass;

/// Number of recall sample points of the current devkit (0, 1/40, ..., 1).
pub const N_SAMPLE_PTS: usize = 41;

/// The benchmark's three difficulty levels. A ground-truth box that is too small, too
/// occluded or too truncated for a level is *ignored* at that level: neither a miss nor a
/// hit, and a detection matched to it is dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Difficulty {
    Easy,
    Moderate,
    Hard,
}

impl Difficulty {
    pub const ALL: [Difficulty; 3] = [Difficulty::Easy, Difficulty::Moderate, Difficulty::Hard];

    pub fn index(self) -> usize {
        self as usize
    }

    /// Minimum 2D box height in pixels. Ground truth must be strictly taller; a detection
    /// whose height, truncated to whole pixels as the devkit does, is below it is ignored.
    pub fn min_height(self) -> f64 {
        [40.0, 25.0, 25.0][self.index()]
    }

    /// Maximum occlusion level (0 fully visible, 1 partly, 2 largely occluded).
    pub fn max_occlusion(self) -> i32 {
        [0, 1, 2][self.index()]
    }

    /// Maximum truncation fraction.
    pub fn max_truncation(self) -> f64 {
        [0.15, 0.30, 0.50][self.index()]
    }

    pub fn as_str(self) -> &'static str {
        ["easy", "moderate", "hard"][self.index()]
    }
}

/// What is measured: the three overlap measures and the orientation score (AOS), which
/// the devkit computes on the image-box (bbox) matching.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Metric {
    /// 2D image boxes, axis-aligned IoU.
    Bbox,
    /// Bird's-eye-view rotated IoU.
    Bev,
    /// 3D IoU (BEV intersection × height overlap).
    ThreeD,
    /// Average orientation similarity on the bbox matching.
    Aos,
}

impl Metric {
    /// The overlap measures, in the devkit's order (image, ground, 3D).
    pub const OVERLAPS: [Metric; 3] = [Metric::Bbox, Metric::Bev, Metric::ThreeD];
    /// Every reported row kind, in the order the table prints them.
    pub const ALL: [Metric; 4] = [Metric::Bbox, Metric::Bev, Metric::ThreeD, Metric::Aos];

    /// Index of the overlap measure used (AOS uses the bbox matching).
    pub fn overlap_index(self) -> usize {
        match self {
            Metric::Bbox | Metric::Aos => 0,
            Metric::Bev => 1,
            Metric::ThreeD => 2,
        }
    }

    /// The overlap measure whose matching this row uses (AOS: bbox).
    pub fn overlap_metric(self) -> Metric {
        match self {
            Metric::Aos => Metric::Bbox,
            m => m,
        }
    }

    /// The name used in the JSON output and the table: `bbox`, `bev`, `3d`, `aos`.
    pub fn as_str(self) -> &'static str {
        match self {
            Metric::Bbox => "bbox",
            Metric::Bev => "bev",
            Metric::ThreeD => "3d",
            Metric::Aos => "aos",
        }
    }
}

impl std::fmt::Display for Metric {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Minimum overlaps per evaluated class for (bbox, bev, 3d). A match needs an overlap
/// strictly greater than the minimum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OverlapSetting {
    pub car: [f64; 3],
    pub pedestrian: [f64; 3],
    pub cyclist: [f64; 3],
}

impl OverlapSetting {
    /// The official setting: Car 0.7, Pedestrian and Cyclist 0.5 for every measure.
    pub const STRICT: OverlapSetting = OverlapSetting {
        car: [0.7, 0.7, 0.7],
        pedestrian: [0.5, 0.5, 0.5],
        cyclist: [0.5, 0.5, 0.5],
    };

    /// The commonly reported looser setting: Car 0.7/0.5/0.5, Pedestrian and Cyclist
    /// 0.5/0.25/0.25 for bbox/bev/3d.
    pub const LOOSE: OverlapSetting = OverlapSetting {
        car: [0.7, 0.5, 0.5],
        pedestrian: [0.5, 0.25, 0.25],
        cyclist: [0.5, 0.25, 0.25],
    };

    /// The minimum overlap for a class and metric (AOS: the bbox one); `None` for a
    /// class the benchmark does not evaluate.
    pub fn min_overlap(&self, class: ObjectClass, metric: Metric) -> Option<f64> {
        let row = match class {
            ObjectClass::Car => &self.car,
            ObjectClass::Pedestrian => &self.pedestrian,
            ObjectClass::Cyclist => &self.cyclist,
            _ => return None,
        };
        Some(row[metric.overlap_index()])
    }
}

/// The ground-truth class whose boxes are ignored (not missed) when evaluating `class`:
/// Van for Car and Person_sitting for Pedestrian, as in the devkit.
pub fn neighbour_class(class: ObjectClass) -> Option<ObjectClass> {
    match class {
        ObjectClass::Car => Some(ObjectClass::Van),
        ObjectClass::Pedestrian => Some(ObjectClass::PersonSitting),
        _ => None,
    }
}

/// Whether the benchmark evaluates this class (Car, Pedestrian, Cyclist).
pub fn is_evaluated(class: ObjectClass) -> bool {
    ObjectClass::EVALUATED.contains(&class)
}

/// Parses a `--classes` style list (comma separated, KITTI spelling), rejecting
/// unknown names and classes the benchmark does not evaluate.
pub fn parse_classes(list: &str) -> Result<Vec<ObjectClass>, String> {
    let mut out = Vec::new();
    for name in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let class = ObjectClass::parse(name).ok_or_else(|| {
            format!("unknown class `{name}` (the benchmark evaluates Car, Pedestrian, Cyclist)")
        })?;
        if !is_evaluated(class) {
            return Err(format!(
                "class `{name}` is not evaluated by the KITTI benchmark (choose from Car, Pedestrian, Cyclist)"
            ));
        }
        if !out.contains(&class) {
            out.push(class);
        }
    }
    if out.is_empty() {
        return Err("no class given (choose from Car, Pedestrian, Cyclist)".to_string());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_list_parsing() {
        assert_eq!(
            parse_classes("Car, Cyclist,Car").unwrap(),
            [ObjectClass::Car, ObjectClass::Cyclist]
        );
        assert!(
            parse_classes("Car,Bus")
                .unwrap_err()
                .contains("unknown class `Bus`")
        );
        assert!(
            parse_classes("car")
                .unwrap_err()
                .contains("unknown class `car`")
        );
        assert!(parse_classes("Van").unwrap_err().contains("not evaluated"));
        assert!(parse_classes(" , ").is_err());
    }

    #[test]
    fn overlap_settings() {
        let s = OverlapSetting::LOOSE;
        assert_eq!(s.min_overlap(ObjectClass::Car, Metric::Bev), Some(0.5));
        assert_eq!(
            s.min_overlap(ObjectClass::Cyclist, Metric::ThreeD),
            Some(0.25)
        );
        assert_eq!(
            s.min_overlap(ObjectClass::Pedestrian, Metric::Aos),
            Some(0.5)
        );
        assert_eq!(s.min_overlap(ObjectClass::Van, Metric::Bbox), None);
    }
}
