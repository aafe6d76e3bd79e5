//! Why an evaluation could not run. Reader errors keep the kitti crate's
//! file:line:field message and only say which input (labels or results) it came from.

use fusiondet_kitti::FormatError;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A ground-truth label file (or the split file) is unreadable or malformed.
    #[error("ground truth: {0}")]
    GroundTruth(#[source] FormatError),
    /// A detection result file is malformed.
    #[error("results: {0}")]
    Results(#[source] FormatError),
    /// LiDAR or calibration input of the breakdown is unreadable or malformed.
    #[error("breakdown input: {0}")]
    Breakdown(#[source] FormatError),
    /// An I/O problem that is not tied to one file's contents.
    #[error("{}: {message}", path.display())]
    Dir { path: PathBuf, message: String },
    /// In-memory input: the ground-truth and detection frames do not line up.
    #[error(
        "frame {index}: ground truth is frame `{gt_id}` but detections are for `{det_id}` (pass both in the same order)"
    )]
    FrameMismatch {
        index: usize,
        gt_id: String,
        det_id: String,
    },
    /// In-memory input: different numbers of ground-truth and detection frames.
    #[error(
        "{gt} ground-truth frames but {det} detection frames (pass one detection frame per ground-truth frame)"
    )]
    FrameCount { gt: usize, det: usize },
    /// In-memory input: a detection without a score.
    #[error("frame `{frame}`: detection {index} has no score (detections need the 16th column)")]
    MissingScore { frame: String, index: usize },
    /// A class the benchmark does not evaluate, or an unknown class name.
    #[error("{0}")]
    Class(String),
    /// One frame's boxes of one class are piled on each other beyond what fits in memory.
    #[error(
        "frame `{frame}`: its {class} ground truth and detections overlap in more than {pairs} \
         pairs, more than one evaluation holds in memory; are the results of this frame \
         duplicated many times over?"
    )]
    TooManyOverlaps {
        frame: String,
        class: String,
        pairs: usize,
    },
    /// Nothing to evaluate.
    #[error("no frames to evaluate: {0}")]
    NoFrames(String),
}
