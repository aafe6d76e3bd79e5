//! Training and inference for the frustum detectors: run directories, schedules,
//! metrics logs, the training loop and detection.

pub mod metrics_log;
pub mod schedule;
