//! The two box types every layer speaks: image boxes in pixels and 3D boxes in the
//! rectified camera frame (KITTI's convention, which the indoor data is converted to).

/// An axis-aligned image box in pixels, (x1, y1) top-left and (x2, y2) bottom-right.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Box2d {
    pub x1: f64,
    pub y1: f64,
    pub x2: f64,
    pub y2: f64,
}

impl Box2d {
    pub fn width(&self) -> f64 {
        self.x2 - self.x1
    }
    pub fn height(&self) -> f64 {
        self.y2 - self.y1
    }
    pub fn center(&self) -> (f64, f64) {
        ((self.x1 + self.x2) * 0.5, (self.y1 + self.y2) * 0.5)
    }
}

/// A 3D box in KITTI's rectified camera convention: (x, y, z) is the centre of the
/// bottom face (y points down), h/w/l are height/width/length in metres and `ry`
/// the rotation about the camera y axis (0 = facing the camera's x axis).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Box3d {
    pub h: f64,
    pub w: f64,
    pub l: f64,
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub ry: f64,
}
