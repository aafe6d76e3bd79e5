//! The contract between the frustum dataset and the networks: a batch of frustums as
//! flat, row-major arrays (f32 for values, i64 for indices) that map directly onto tensors.
//!
//! Frames: every coordinate is in the *frustum frame* — the rectified camera frame
//! rotated about its y axis so that the 2D box centre's ray has x = 0 (x right,
//! y down, z = depth along the frustum).
//!
//! Precisely (see `crate::frustum`): before the rotation the origin is moved
//! horizontally to P2's optical centre (≈ 6 cm from the rectified origin in KITTI), so
//! the ray is x = 0 exactly at every depth; y is the rectified y unchanged. Training
//! samples may additionally be mirrored (x → −x) and shifted in depth; the sample's
//! `FrustumFrame` records both, and `decode_box` undoes them.

/// One scale of sub-frustums for the whole batch, with ragged point membership: only
/// the real (point, sub-frustum) pairs are listed, so a PointNet runs on exactly those.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchScale {
    /// Sub-frustums per frustum at this scale (Car: 280, 140, 70, 35).
    pub slices_per_frustum: usize,
    /// Sub-frustum centres, [batch · slices_per_frustum, 3], frustum-major.
    pub slice_centers: Vec<f32>,
    /// For each (point, sub-frustum) pair: the point's row in `FrustumBatch::points`.
    pub pair_point: Vec<i64>,
    /// For each pair: the sub-frustum's row in `slice_centers`. Non-decreasing.
    pub pair_slice: Vec<i64>,
    /// The cap on points per sub-frustum at this scale (Car: 32, 64, 64, 128).
    pub max_points_per_slice: usize,
    /// Per sub-frustum, [batch · slices_per_frustum]: the factor on a point's depth (z)
    /// relative to the sub-frustum's centre; empty = 1 everywhere (the published models).
    pub relative_depth_gains: Vec<f32>,
}

/// Training targets, one object per frustum.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchTargets {
    /// Per output position (the slices of `FrustumBatch::output_scale`),
    /// [batch · positions]: 1 positive, 0 negative, -1 ignored.
    pub labels: Vec<i64>,
    /// Ground-truth box centre (geometric centre, not the bottom face), [batch, 3].
    pub center: Vec<f32>,
    /// Heading bin of the ground truth's rotation in the frustum frame, [batch].
    pub heading_bin: Vec<i64>,
    /// Residual from the bin centre in radians, [batch].
    pub heading_residual: Vec<f32>,
    /// Size cluster (the class's mean size), [batch].
    pub size_cluster: Vec<i64>,
    /// (l, w, h) residual over the cluster's mean size, divided by that mean size, [batch, 3].
    pub size_residual: Vec<f32>,
    /// The ground truth's 8 corners, [batch, 8, 3].
    pub corners: Vec<f32>,
}

/// A batch of frustums.
#[derive(Debug, Clone, PartialEq)]
pub struct FrustumBatch {
    pub batch_size: usize,
    /// Points per frustum (1024 for the first stage).
    pub points_per_frustum: usize,
    /// Point coordinates, [batch · points_per_frustum, 3].
    pub points: Vec<f32>,
    /// One-hot class of each frustum's 2D box (Car, Pedestrian, Cyclist), [batch, 3].
    pub class_one_hot: Vec<f32>,
    /// Frustum frame → homogeneous pixels, row-major 3 × 4 per frustum, [batch, 12]
    /// (SAF's projection loss).
    pub image_projection: Vec<f32>,
    /// The four scales, finest first.
    pub scales: Vec<BatchScale>,
    /// Index into `scales` whose slice centres are the output positions (1: 140 for Car).
    pub output_scale: usize,
    /// Present for training batches.
    pub targets: Option<BatchTargets>,
}
