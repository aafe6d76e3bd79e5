//! Exact f64 geometry: camera/LiDAR transforms, 2D and 3D boxes, overlaps, NMS. The
//! bottom floor: it knows no file format (a `kitti::Calib` builds a [`CameraModel`]).

pub mod box3d;
pub mod boxes;
pub mod camera;
pub mod iou;
pub mod nms;

pub use box3d::{
    BOX_EDGES, NEAR_PLANE, alpha_from_ry, bev_polygon, clip_to_image, corners, count_points_in_box,
    normalize_angle, points_in_box, project_to_image, projected_bounds, ry_from_alpha,
};
pub use boxes::{Box2d, Box3d};
pub use camera::CameraModel;
pub use iou::{Normalization, iou_2d, iou_3d, iou_bev, overlap_2d, overlap_3d, overlap_bev};
pub use nms::{nms_2d, nms_3d, nms_bev, nms_by};
