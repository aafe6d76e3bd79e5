//! Training and inference for the frustum detectors: the experiment configuration,
//! run directories, schedules, metrics logs, the training loop, detection and its
//! speed benchmark.

pub mod bench;
pub mod config;
pub mod detect;
pub mod device;
pub mod error;
pub mod metrics_log;
pub mod run_dir;
pub mod schedule;
pub mod trainer;

pub use bench::{BenchOptions, DetectBench, bench_detect, frames_per_second};
pub use config::{DetectConfig, ExperimentConfig, RefineConfig, TrainConfig};
pub use detect::{
    DetectOptions, DetectSummary, Detector, FrameResults, StageTimes, detect, write_results,
};
pub use device::ComputeDevice;
pub use error::{Result, TrainError};
pub use trainer::{TrainOptions, TrainSummary, load_split, train};
