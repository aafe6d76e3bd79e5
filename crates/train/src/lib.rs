//! Training and inference for the frustum detectors: the experiment configuration,
//! run directories, schedules, metrics logs, the training loop and detection.

pub mod config;
pub mod error;
pub mod metrics_log;
pub mod run_dir;
pub mod schedule;
pub mod trainer;

pub use config::{DetectConfig, ExperimentConfig, TrainConfig};
pub use error::{Result, TrainError};
pub use trainer::{TrainOptions, TrainSummary, load_split, train};
pub mod detect;

pub use detect::{DetectOptions, DetectSummary, StageTimes, detect, detect_frames, write_results};
