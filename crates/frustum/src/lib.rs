//! Frustum datasets for the frustum detectors (F-ConvNet and its variants):
//! frustum extraction from 2D boxes, point sampling, sub-frustum slicing,
//! training targets and batching into flat arrays the networks consume.
//!
//! Pipeline: [`Frame`] (LiDAR projected once) → [`extract_frustum`] per 2D box
//! ([`FrustumPoints`] in the box's [`FrustumFrame`], or a [`SkipReason`]) →
//! [`build_sample`] (augmentation, 1024-point sampling, sub-frustums of every scale
//! by the configured [`Slicing`]: F-ConvNet's uniform or SAF's depth-guided, whose ω
//! [`omega_study()`] helps choose; [`BoxEncoding`] targets by the [`BoxCoder`]) → [`collate()`] into a
//! [`FrustumBatch`]. [`FrustumDataset`] ties these together over a [`FrameSource`]
//! with seeded, parallel, thread-count-independent epochs. [`BoxCoder::decode_box`]
//! turns network outputs back into KITTI camera-frame boxes.
//!
//! Geometry is f64; only the batch arrays handed to the network are f32.

pub mod batch;
pub mod coder;
pub mod collate;
pub mod config;
pub mod dataset;
pub mod error;
pub mod frame;
pub mod frustum;
pub mod omega_study;
pub mod proposal;
pub mod rng;
pub mod sample;
pub mod slicing;
pub mod targets;

pub use batch::{BatchScale, BatchTargets, FrustumBatch};
pub use coder::{BoxCoder, BoxEncoding};
pub use collate::collate;
pub use config::{AugmentConfig, DepthShift, FrustumConfig};
pub use dataset::{
    Batches, BoxDetection, FrameDetection, FrustumDataset, FrustumSpec, PreparedBatch, StreamKey,
    jitter_box,
};
pub use error::{FrustumError, Result, SkipCounts, SkipReason};
pub use frame::{
    DiskFrames, FrameSource, FrustumFrames, InMemoryFrames, ProjectedCloud, ProjectedFrame,
    load_split,
};
pub use frustum::{FrustumFrame, FrustumPoints, clip_box, extract_frustum};
pub use fusiondet_dataset::Class;
pub use omega_study::{
    DEFAULT_OMEGAS, MAX_OBJECT_LOSS, OmegaRow, OmegaStudy, omega_study, omega_study_from_labels,
};
pub use proposal::{
    ProposalCrop, enlarged, extract_proposal_frustum, match_proposal, proposal_frame,
};
pub use sample::{
    Augmentation, FrustumSample, SampleScale, SampleSource, SampleTarget, build_sample,
};
pub use slicing::{
    DEFAULT_OMEGA, DepthGuidedSlicing, MAX_NEAR_FRACTION, MeanHeights, ScaleLayout, SliceContext,
    SliceInterval, SliceStrategy, Slicing, UniformSlicing, coarse_depth,
};
pub use targets::position_labels;

/// The bundled KITTI sample frames, for tests.
#[cfg(test)]
pub(crate) mod test_data {
    use crate::frame::ProjectedFrame;
    use fusiondet_geometry::CameraModel;
    use fusiondet_kitti::{FrameDir, read_calib};
    use std::path::Path;

    pub fn sample_dir() -> FrameDir {
        FrameDir::new(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training"),
        )
    }

    pub fn sample_frame(id: &str) -> ProjectedFrame {
        ProjectedFrame::load(&sample_dir(), id, true).unwrap()
    }

    pub fn sample_camera() -> CameraModel {
        read_calib(&sample_dir().calib("000003"))
            .unwrap()
            .camera_model()
            .unwrap()
    }
}
