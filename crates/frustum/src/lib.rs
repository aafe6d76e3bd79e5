//! Frustum datasets for the frustum detectors (F-ConvNet and its variants):
//! frustum extraction from 2D boxes, point sampling, sub-frustum slicing,
//! training targets and batching into flat arrays the networks consume.

pub mod batch;

pub use batch::{BatchScale, BatchTargets, FrustumBatch};
