//! Running any detector family: the experiment configuration, run directories,
//! schedules, metrics logs, the generic training loop ([`trainer`]), detection dispatched
//! on the checkpoint's family ([`detect`]) and its speed benchmark ([`bench`]); each
//! family plugs in through a module of its own ([`frustum`]).

pub mod batch_norm_probe;
pub mod bench;
pub mod compute_pool;
pub mod config;
pub mod custom_op_probe;
pub mod dasanet;
pub mod detect;
pub mod detection;
pub mod device;
pub mod error;
pub mod frustum;
pub mod grad_clip;
pub mod kernel_cache;
pub mod linear_probe;
pub mod matmul_precision;
pub mod metrics_log;
pub mod optimizer;
pub mod prefetch;
pub mod result_dir;
pub mod run_dir;
pub mod schedule;
pub mod sparse_gradient_probe;
pub mod trainer;
pub mod voxel_rcnn;

pub use bench::{BenchOptions, DetectBench, bench_detect, frames_per_second};
pub use config::{
    DatasetFormat, DatasetSection, DetectConfig, DetectorSection, ExperimentConfig, GradClipScope,
    OptimizerKind, RefineConfig, TrainConfig,
};
pub use detect::{
    DETECT_CHUNK_FRAMES, DetectOptions, DetectSummary, Detector, FrameResults, ResultWriter,
    ShardWriter, SideInputs, SplitInputs, SplitSide, StageTimes, complete_sharded_results, detect,
    detect_in_chunks, inference_multiply_adds, trained_parameters,
};
pub use device::ComputeDevice;
pub use error::{PipelineError, Result};
pub use trainer::{TrainOptions, TrainSummary, TrainingTask, train};
