//! In-memory evaluation input: one ground-truth frame and one detection frame per image,
//! so that training code can evaluate without writing files.

use fusiondet_kitti::Object;

/// The ground truth of one frame (a `label_2` file), DontCare regions included.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameGt {
    pub id: String,
    pub objects: Vec<Object>,
}

/// The detections of one frame (a result file); every object must carry a score.
/// An empty list is a frame without detections.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameDet {
    pub id: String,
    pub objects: Vec<Object>,
}

impl FrameGt {
    pub fn new(id: impl Into<String>, objects: Vec<Object>) -> Self {
        FrameGt {
            id: id.into(),
            objects,
        }
    }
}

impl FrameDet {
    pub fn new(id: impl Into<String>, objects: Vec<Object>) -> Self {
        FrameDet {
            id: id.into(),
            objects,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests_support {
    //! Compact constructors for hand-made test boxes.
    use fusiondet_kitti::{Box2d, Box3d, Object, ObjectClass};

    /// A fully visible, untruncated ground-truth box with the given image box; the 3D box
    /// is a 4×1.6×1.5 m car-sized box at depth 20 m shifted sideways by x1/100 so that
    /// image-disjoint boxes are also BEV-disjoint.
    pub fn gt(class: ObjectClass, b: [f64; 4]) -> Object {
        Object {
            class,
            truncation: 0.0,
            occlusion: 0,
            alpha: 0.0,
            bbox: Box2d {
                x1: b[0],
                y1: b[1],
                x2: b[2],
                y2: b[3],
            },
            box3d: Box3d {
                h: 1.5,
                w: 1.6,
                l: 4.0,
                x: b[0] / 10.0,
                y: 1.6,
                z: 20.0,
                ry: 0.0,
            },
            score: None,
        }
    }

    pub fn det(class: ObjectClass, b: [f64; 4], score: f64) -> Object {
        Object {
            truncation: -1.0,
            occlusion: -1,
            score: Some(score),
            ..gt(class, b)
        }
    }

    pub fn dontcare(b: [f64; 4]) -> Object {
        Object {
            class: ObjectClass::DontCare,
            truncation: -1.0,
            occlusion: -1,
            alpha: -10.0,
            box3d: Box3d {
                h: -1.0,
                w: -1.0,
                l: -1.0,
                x: -1000.0,
                y: -1000.0,
                z: -1000.0,
                ry: -10.0,
            },
            ..gt(ObjectClass::DontCare, b)
        }
    }
}
