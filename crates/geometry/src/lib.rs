//! Exact f64 geometry for KITTI: camera/LiDAR transforms, 3D boxes, overlaps, NMS.

pub mod box3d;
pub mod camera;
pub mod iou;
pub mod nms;

pub use box3d::{
    BOX_EDGES, NEAR_PLANE, alpha_from_ry, bev_polygon, clip_to_image, corners, count_points_in_box,
    normalize_angle, points_in_box, project_to_image, projected_bounds, ry_from_alpha,
};
pub use camera::CameraModel;
pub use iou::{Normalization, iou_2d, iou_3d, iou_bev, overlap_2d, overlap_3d, overlap_bev};
pub use nms::{nms_2d, nms_3d, nms_bev, nms_by};
