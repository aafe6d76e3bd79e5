//! Generic network layers that know no detector: point-wise MLP layers with their own
//! norm settings, batch norm over a subset of rows, and pooling over ragged groups
//! (sub-frustums of points today; points of a voxel for a voxel feature encoder, and
//! the sparse convolutions of the voxel family, belong here too).
//!
//! Backend-agnostic: every layer takes the [`burn::tensor::Device`] it is built on. On the
//! flex CPU device the hot ragged operations take faster paths of their own: the host in
//! inference ([`host_max`]), custom operations with their own backward passes in training
//! ([`ragged`]).

pub mod adam;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod adam_device;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod batch_norm_device;
pub mod batch_norm_ops;
pub mod buffers;
pub mod conv2d;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod cube;
pub mod deconv;
pub mod gather;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod gather_device;
pub mod host_max;
pub mod inner_split;
pub mod linear;
pub mod linear_chunked;
pub mod matmul;
pub mod mlp;
pub mod norm;
pub mod place;
pub mod ragged;
pub mod reduce;
pub mod row_pairs;
pub mod segment;
pub mod sparse;

pub use mlp::{MlpLayer, mlp_stack};
pub use norm::{
    NormConfig, batch_norm, masked_batch_norm, norm_maps, norm_maps_relu, norm_rows, norm_rows_relu,
};
pub use segment::{SegmentPool, segment_mean};
