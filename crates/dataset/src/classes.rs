//! A detector's class vocabulary: the class names in one-hot order with their mean
//! sizes. A data format's own spelling of its classes (KITTI's `Car`, `Van`, …,
//! `DontCare`) is that format's detail; a detector learns the classes of a set.

use fusiondet_kitti::ObjectClass;
use fusiondet_sunrgbd::SunClass;

/// A class as a data format spells it: KITTI's enum or SUN RGB-D's ten. The frustum
/// family carries this (not a format's own type) so one code path serves both formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Class {
    Kitti(ObjectClass),
    SunRgbd(SunClass),
}

impl Class {
    /// The name as the format's files spell it.
    pub fn as_str(self) -> &'static str {
        match self {
            Class::Kitti(c) => c.as_str(),
            Class::SunRgbd(c) => c.as_str(),
        }
    }

    /// The class a name means in either format (KITTI spells its classes capitalised,
    /// SUN RGB-D in lower case: no name is both).
    pub fn parse(name: &str) -> Option<Class> {
        ObjectClass::parse(name)
            .map(Class::Kitti)
            .or_else(|| SunClass::parse(name).map(Class::SunRgbd))
    }

    /// KITTI's class, if this is one.
    pub fn kitti(self) -> Option<ObjectClass> {
        match self {
            Class::Kitti(c) => Some(c),
            Class::SunRgbd(_) => None,
        }
    }
}

impl From<ObjectClass> for Class {
    fn from(c: ObjectClass) -> Class {
        Class::Kitti(c)
    }
}

impl std::fmt::Display for Class {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One class of a set.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassInfo {
    /// The name as the data format spells it.
    pub name: String,
    /// Mean (l, w, h) in metres: F-ConvNet's size cluster of the class.
    pub mean_size: [f64; 3],
}

/// Classes in one-hot order (index = one-hot slot = size cluster).
#[derive(Debug, Clone, PartialEq)]
pub struct ClassSet {
    /// What the set is called in messages ("KITTI").
    pub name: String,
    pub classes: Vec<ClassInfo>,
}

impl ClassSet {
    /// KITTI's three evaluated classes with F-PointNet's / F-ConvNet's mean sizes at
    /// full precision (Car 3.883 / 1.629 / 1.526, Pedestrian 0.844 / 0.661 / 1.763,
    /// Cyclist 1.763 / 0.597 / 1.737 rounded; the reference implementation's
    /// `dataset_info.py`).
    #[allow(clippy::excessive_precision)]
    pub fn kitti() -> ClassSet {
        let class = |name: &str, mean_size| ClassInfo {
            name: name.into(),
            mean_size,
        };
        ClassSet {
            name: "KITTI".into(),
            classes: vec![
                class("Car", [3.88311640418, 1.62856739989, 1.52563191462]),
                class("Pedestrian", [0.84422524, 0.66068622, 1.76255119]),
                class("Cyclist", [1.76282397, 0.59706367, 1.73698127]),
            ],
        }
    }

    /// SUN RGB-D's ten classes in VoteNet's order with VoteNet's mean sizes
    /// ([`SunClass::mean_size`]). VoteNet lists them as (l, w, h) with l
    /// along the heading: the label's (dx, dy, dz), and `Box3d`'s (l, w, h) after
    /// [`crate::indoor::camera_box`] (l = dx, w = dy, h = dz).
    pub fn sun_rgbd() -> ClassSet {
        ClassSet {
            name: "SUN RGB-D".into(),
            classes: SunClass::ALL
                .iter()
                .map(|c| ClassInfo {
                    name: c.as_str().into(),
                    mean_size: c.mean_size(),
                })
                .collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.classes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.classes.is_empty()
    }

    /// The one-hot slot of a class name, if the set has it.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.classes.iter().position(|c| c.name == name)
    }

    pub fn names(&self) -> Vec<&str> {
        self.classes.iter().map(|c| c.name.as_str()).collect()
    }

    pub fn mean_sizes(&self) -> Vec<[f64; 3]> {
        self.classes.iter().map(|c| c.mean_size).collect()
    }
}

impl Default for ClassSet {
    fn default() -> Self {
        ClassSet::kitti()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kitti_slots_are_car_pedestrian_cyclist() {
        let k = ClassSet::kitti();
        assert_eq!(k.names(), ["Car", "Pedestrian", "Cyclist"]);
        assert_eq!(k.index_of("Cyclist"), Some(2));
        assert_eq!(k.index_of("Van"), None);
        assert!(k.mean_sizes()[0][0] > 3.8 && k.mean_sizes()[1][2] > 1.7);
    }

    #[test]
    fn sun_rgbd_slots_follow_votenet_with_l_along_the_heading() {
        let s = ClassSet::sun_rgbd();
        assert_eq!(s.len(), 10);
        for (k, c) in SunClass::ALL.iter().enumerate() {
            assert_eq!(s.index_of(c.as_str()), Some(c.index()));
            assert_eq!(k, c.index());
        }
        // A bed is longer (dx, along its heading) than wide and wide than high; a
        // bookshelf is its tallest extent; a night stand's dx is its depth (0.50 m); VoteNet's table as published.
        let bed = s.mean_sizes()[0];
        assert!(bed[0] > bed[1] && bed[1] > bed[2], "{bed:?}");
        assert_eq!(bed, [2.114256, 1.620300, 0.927272]);
        let shelf = s.mean_sizes()[8];
        assert!(shelf[2] > shelf[1] && shelf[1] > shelf[0], "{shelf:?}");
        assert_eq!(s.mean_sizes()[7], [0.500618, 0.632163, 0.683424]);
        // Desk and dresser, as VoteNet publishes them (an earlier table here had them wrong).
        assert_eq!(s.mean_sizes()[5], [0.695190, 1.346299, 0.736364]);
        assert_eq!(s.mean_sizes()[6], [0.528526, 1.002642, 1.172878]);
    }

    #[test]
    fn class_names_parse_in_either_format() {
        assert_eq!(Class::parse("Car"), Some(Class::Kitti(ObjectClass::Car)));
        assert_eq!(
            Class::parse("night_stand"),
            Some(Class::SunRgbd(SunClass::NightStand))
        );
        assert_eq!(Class::parse("car"), None);
        assert_eq!(Class::parse("Bed"), None);
        assert_eq!(Class::SunRgbd(SunClass::Bed).to_string(), "bed");
        assert_eq!(Class::SunRgbd(SunClass::Bed).kitti(), None);
    }
}
