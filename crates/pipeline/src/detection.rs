//! What detection is asked to do and what it returns, shared by the dispatch
//! ([`crate::detect`]) and the families' detectors, which sit below it: the options of a
//! run, its summary, a pass's results and its time per stage.

use crate::config::ExperimentConfig;
use crate::device::ComputeDevice;
use fusiondet_frustum::SkipCounts;
use fusiondet_kitti::shard;
use fusiondet_kitti::{Object, Shard};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

/// What `fusiondet detect` was asked to do.
#[derive(Debug, Clone)]
pub struct DetectOptions {
    pub config: ExperimentConfig,
    pub checkpoint: PathBuf,
    pub data_dir: PathBuf,
    pub split: String,
    pub out_dir: PathBuf,
    /// 2D detections; `None` reads `DATA/rgb_detections/rgb_detection_<split>.txt`.
    pub detections: Option<PathBuf>,
    /// Completed depth maps (`<id>.png`) for DASANet's pseudo points; `None` completes
    /// each frame's scan.
    pub depth_dir: Option<PathBuf>,
    /// Where the network runs.
    pub device: ComputeDevice,
    /// Replace the results an earlier detect left in `out_dir` (without it such a
    /// directory is refused).
    pub replace: bool,
    /// Detect only this shard's frames of the split (see [`fusiondet_kitti::shard`]);
    /// `None` runs the whole split.
    pub shard: Option<Shard>,
}

impl DetectOptions {
    /// The whole `split` of `data_dir` into a new or empty `out_dir`, on the CPU, with the
    /// data set's own 2D detections (and, for DASANet, each scan completed).
    pub fn new(
        config: ExperimentConfig,
        checkpoint: impl Into<PathBuf>,
        data_dir: impl Into<PathBuf>,
        split: impl Into<String>,
        out_dir: impl Into<PathBuf>,
    ) -> DetectOptions {
        DetectOptions {
            config,
            checkpoint: checkpoint.into(),
            data_dir: data_dir.into(),
            split: split.into(),
            out_dir: out_dir.into(),
            detections: None,
            depth_dir: None,
            device: ComputeDevice::default(),
            replace: false,
            shard: None,
        }
    }
}

/// What a detection run did, with its time per stage.
#[derive(Debug, Clone, Default)]
pub struct DetectSummary {
    pub frames: usize,
    pub detections_2d: usize,
    /// Inputs the network ran on (frustums for the frustum family).
    pub samples: usize,
    pub skipped: SkipCounts,
    pub boxes_written: usize,
    pub timing: StageTimes,
    /// For a sharded run: how far all the run's shards have got once this one finished.
    pub shards: Option<shard::ShardProgress>,
}

/// Wall time per stage of detection, the stages named by the family (in the order they
/// first ran), and the time spent loading from disk apart.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StageTimes {
    pub load: Duration,
    stages: Vec<(&'static str, Duration)>,
    /// Time stages ran side by side (a frame prepared while the network ran on the one
    /// before, see [`crate::prefetch`]): counted in both stages, once in the wall time.
    overlap: Duration,
}

impl StageTimes {
    /// Adds `elapsed` to stage `stage`.
    pub fn add(&mut self, stage: &'static str, elapsed: Duration) {
        match self.stages.iter_mut().find(|(name, _)| *name == stage) {
            Some((_, d)) => *d += elapsed,
            None => self.stages.push((stage, elapsed)),
        }
    }

    /// The time of one stage (zero if it never ran).
    pub fn get(&self, stage: &str) -> Duration {
        self.stages
            .iter()
            .find(|(name, _)| *name == stage)
            .map_or(Duration::ZERO, |(_, d)| *d)
    }

    /// Every stage with its time, in the order they first ran.
    pub fn stages(&self) -> &[(&'static str, Duration)] {
        &self.stages
    }

    /// Everything but loading from disk, in wall time: what frames/s is measured over.
    pub fn compute(&self) -> Duration {
        self.busy().saturating_sub(self.overlap)
    }

    /// The stages' times added up, overlapping ones each in full.
    pub fn busy(&self) -> Duration {
        self.stages.iter().map(|(_, d)| *d).sum()
    }

    /// How much of [`Self::busy`] ran beside other stages.
    pub fn overlap(&self) -> Duration {
        self.overlap
    }

    /// Adds another pass's (or thread's) stages, overlap and load time.
    pub fn absorb(&mut self, other: &StageTimes) {
        for &(stage, d) in &other.stages {
            self.add(stage, d);
        }
        self.overlap += other.overlap;
        self.load += other.load;
    }

    /// Records that the stages added so far (and the overlap already recorded) took `wall`
    /// in all: what they add up to beyond it ran side by side.
    pub fn set_wall(&mut self, wall: Duration) {
        self.overlap = self.busy().saturating_sub(wall);
    }
}

/// What one detection pass over a set of frames produced.
#[derive(Debug, Clone, Default)]
pub struct FrameResults {
    /// Result objects of every frame (empty lists for frames without detections).
    pub objects: BTreeMap<String, Vec<Object>>,
    /// Frustums left out, by reason (both stages' for a refinement model).
    pub skipped: SkipCounts,
    /// Inputs the network ran on (frustums for the frustum family; the last stage's).
    pub samples: usize,
}
