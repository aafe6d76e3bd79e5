//! The official KITTI object evaluation (bbox, BEV, 3D and AOS; AP11 and AP_R40), to
//! reproduce the devkit's `evaluate_object.cpp` (41 recall samples) number for number,
//! about two orders of magnitude faster, as a library the training loop can call.
//!
//! * [`evaluate`] works on in-memory frames ([`FrameGt`], [`FrameDet`]) and returns an
//!   [`EvalReport`] with the AP rows and, per class × metric × difficulty, the
//!   precision/recall arrays ([`PrCurve`]) for plots.
//! * [`evaluate_dirs`] / [`load_dirs`] read a `label_2`-style directory and a result
//!   directory (a missing result file is a frame without detections).
//! * [`evaluate_breakdown`] reports AP_R40 by distance, occlusion and LiDAR point count
//!   (our own extension; its filtering rule is documented in [`breakdown`]).
//! * [`ablation_table`] / [`ablation_breakdown_table`] put several configurations'
//!   reports side by side, as papers' ablation tables do.
//!
//! Overlaps come from `fusiondet-geometry`; the protocol constants are in [`protocol`];
//! the devkit's matching rules, including its quirks, are in the (private) engine.
//!
//! ```
//! use fusiondet_eval::{Difficulty, EvalConfig, Metric, evaluate, synthetic};
//! use fusiondet_kitti::ObjectClass;
//!
//! let (gt, det) = synthetic::generate(50, 7);
//! let report = evaluate(&gt, &det, &EvalConfig::default()).unwrap();
//! let car_3d = report.get(ObjectClass::Car, Metric::ThreeD, 0).unwrap();
//! println!("Car 3D AP_R40 moderate: {:.2}", car_3d.ap40[1]);
//! // Precision/recall at each score threshold, e.g. for a plot:
//! let curve = car_3d.curve(Difficulty::Moderate);
//! assert_eq!(curve.recall.len(), curve.thresholds.len());
//! print!("{}", report.table());
//! ```
//!
//! Known, deliberate departures from the devkit: a missing result file is not fatal; a
//! class without detections is still evaluated (AP 0 rather than left out), and so are
//! BEV and 3D when detections carry no 3D location (x = −1000, which the devkit skips);
//! where a threshold has neither true nor false positives the devkit divides 0 by 0, we
//! use 0.

pub mod ablation;
pub mod bootstrap;
pub mod breakdown;
pub mod compare;
#[cfg(test)]
mod edge_cases;
mod engine;
pub mod error;
pub mod errors;
mod evaluate;
pub mod frames;
pub mod indoor;
pub mod load;
pub mod protocol;
#[cfg(test)]
mod reference;
pub mod report;
pub mod saf_tables;
pub mod seeds;
pub mod synthetic;

pub use ablation::{
    AblationRow, ablation_breakdown_table, ablation_table, ablation_to_json, write_ablation_json,
};
pub use bootstrap::{
    DifferenceRow, PairedBootstrap, Resampling, RowDifference, difference_table, paired_bootstrap,
};
pub use breakdown::{
    BreakdownAxis, BreakdownRow, FramePoints, box_centre_range, breakdown_table,
    count_lidar_points, evaluate_breakdown,
};
pub use error::EvalError;
pub use errors::{ErrorRow, errors_table, true_positive_errors};
pub use evaluate::{EvalConfig, evaluate};
pub use frames::{FrameDet, FrameGt};
pub use load::{LoadedFrames, evaluate_dirs, frame_ids, load_dirs, read_result_file};
pub use protocol::{Difficulty, Metric, N_SAMPLE_PTS, OverlapSetting, parse_classes};
pub use report::{EvalReport, MetricResult, PrCurve};
pub use seeds::{SeedGroup, seed_ablation_table, seed_breakdown_table};

use serde::Serialize;
use std::path::Path;

#[derive(Serialize)]
struct JsonDoc<'a> {
    results: Vec<report::JsonRow>,
    #[serde(skip_serializing_if = "Option::is_none")]
    breakdown: Option<Vec<breakdown::JsonBreakdownRow>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    errors: Option<&'a [ErrorRow]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    baseline: Option<&'a PairedBootstrap>,
}

/// What the JSON document holds beside the AP rows.
#[derive(Debug, Clone, Copy, Default)]
pub struct JsonExtras<'a> {
    pub breakdown: Option<&'a [BreakdownRow]>,
    /// True-positive errors ([`true_positive_errors`]).
    pub errors: Option<&'a [ErrorRow]>,
    /// The difference from a baseline's results ([`paired_bootstrap`]).
    pub baseline: Option<&'a PairedBootstrap>,
}

/// The JSON document: `{"results": [{"class", "metric", "min_overlap", "ap11", "ap40"}, ...]}`
/// with AP in percent, plus a `"breakdown"` array, an `"errors"` array and a `"baseline"`
/// object (the paired bootstrap's rows) when given.
pub fn to_json(report: &EvalReport, extras: JsonExtras<'_>) -> String {
    let doc = JsonDoc {
        results: report.results.iter().map(Into::into).collect(),
        breakdown: extras
            .breakdown
            .map(|rows| rows.iter().map(Into::into).collect()),
        errors: extras.errors,
        baseline: extras.baseline,
    };
    let mut text = serde_json::to_string_pretty(&doc).expect("plain data serialises");
    text.push('\n');
    text
}

/// Writes [`to_json`] to `path` atomically (a reader never sees half a file).
pub fn write_json(
    path: &Path,
    report: &EvalReport,
    extras: JsonExtras<'_>,
) -> Result<(), EvalError> {
    fusiondet_kitti::write_atomic(path, to_json(report, extras).as_bytes()).map_err(|e| {
        EvalError::Dir {
            path: path.to_path_buf(),
            message: format!("cannot write the JSON output: {e}"),
        }
    })
}
