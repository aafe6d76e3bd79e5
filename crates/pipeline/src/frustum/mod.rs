//! The frustum family (F-ConvNet with its refinement stage, FCAM, SAF) plugged into the
//! generic pipeline: its training task ([`FrustumTask`]) and its detector
//! ([`FrustumDetector`]).

mod detector;
pub mod indoor;
mod task;

pub use detector::{FrustumDetector, STAGE_DECODE, STAGE_FRUSTUMS, STAGE_NETWORK, SceneResults};
pub use task::{FIRST_STAGE_FILE, FrustumTask, seeded_network, train, trained_parameters};
