//! A detector's class vocabulary: the class names in one-hot order with their mean
//! sizes. A data format's own spelling of its classes (KITTI's `Car`, `Van`, …,
//! `DontCare`) is that format's detail; a detector learns the classes of a set.

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
}
