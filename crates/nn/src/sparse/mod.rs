//! Sparse 3D convolution over voxel grids (Graham & van der Maaten's submanifold and
//! regular sparse convolutions, as spconv runs them): active sites indexed by linear index,
//! a rulebook of (input row, output row) pairs per kernel offset, and each convolution as
//! gather → matrix multiply → scatter-add through burn's autodiff (per offset on the CPU,
//! through one kernel map on GPUs); on the flex CPU device the per-offset form runs as one
//! custom operation with its own backward pass ([`fused`]), and on a CubeCL device the
//! kernel map can run as CubeCL kernels with theirs (`device_kernels`, features `wgpu` /
//! `cuda`), its table then found on the device too (`rulebook_device`) and its inverse made
//! from the table there when a backward pass needs it.
//!
//! Written here because no Rust crate does sparse convolution; the operations it is made
//! of (select, matmul, select_assign with add) are burn's, so gradients and every backend
//! come with them.

pub mod conv;
pub mod dense;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod device_kernels;
pub mod fused;
pub mod rulebook;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod rulebook_device;
pub mod sites;
mod strided_sites;
#[cfg(test)]
mod test_data;

pub use crate::row_pairs::RowPairs;
pub use conv::{SparseConv3d, SparseConvBlock};
pub use dense::to_dense_bev;
pub use rulebook::{ConvGeometry, HostRules, OffsetRule, RuleGather, RuleLayout, Rulebook};
pub use sites::{SitesError, SparseSites};
