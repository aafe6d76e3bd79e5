//! Loading a label directory and a result directory (in parallel). A missing result
//! file means "no detections in this frame" and is reported back, not an error; a
//! malformed line is an error naming file, line and field.

use crate::error::EvalError;
use crate::evaluate::{EvalConfig, evaluate};
use crate::frames::{FrameDet, FrameGt};
use crate::report::EvalReport;
use fusiondet_kitti::label::parse_objects;
use fusiondet_kitti::layout::list_frame_ids;
use fusiondet_kitti::{FormatError, read_objects, read_split};
use rayon::prelude::*;
use std::path::Path;

/// Ground truth and detections of a set of frames, paired by index.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedFrames {
    pub gt: Vec<FrameGt>,
    pub det: Vec<FrameDet>,
    /// Ids of frames without a result file (evaluated as frames without detections).
    pub missing_results: Vec<String>,
}

/// The frames to evaluate: the ids of a split file, or else every `NNNNNN.txt` in the
/// label directory, sorted.
pub fn frame_ids(label_dir: &Path, split: Option<&Path>) -> Result<Vec<String>, EvalError> {
    let ids = match split {
        Some(path) => read_split(path).map_err(EvalError::GroundTruth)?,
        None => list_frame_ids(label_dir, "txt").map_err(|e| EvalError::Dir {
            path: label_dir.to_path_buf(),
            message: format!("cannot list the label directory: {e}"),
        })?,
    };
    if ids.is_empty() {
        let what = match split {
            Some(p) => format!("the split file {} lists no frame", p.display()),
            None => format!("no label files (NNNNNN.txt) in {}", label_dir.display()),
        };
        return Err(EvalError::NoFrames(what));
    }
    Ok(ids)
}

/// Reads a result file: `Ok(None)` if it does not exist; every line must have a score.
pub fn read_result_file(path: &Path) -> Result<Option<Vec<fusiondet_kitti::Object>>, FormatError> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        _ => {}
    }
    // Read as every reader reads: a pipe or a device in a result's place is refused.
    let text = fusiondet_kitti::error::read_text(path)?;
    let objects = parse_objects(&text, path)?;
    if let Some(k) = objects.iter().position(|o| o.score.is_none()) {
        // parse_objects skips blank lines: object k is the k-th non-blank line.
        let line = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .nth(k)
            .map_or(0, |(i, _)| i + 1);
        return Err(FormatError::field(
            path,
            line,
            "score",
            "missing: a result line needs 16 columns, the last one the detection score",
        ));
    }
    Ok(Some(objects))
}

/// Loads the ground truth and the detections of `ids`.
pub fn load_dirs(
    label_dir: &Path,
    result_dir: &Path,
    ids: &[String],
) -> Result<LoadedFrames, EvalError> {
    for (dir, what) in [(label_dir, "label"), (result_dir, "result")] {
        if !dir.is_dir() {
            return Err(EvalError::Dir {
                path: dir.to_path_buf(),
                message: format!("the {what} directory does not exist or is not a directory"),
            });
        }
    }
    // A result directory that `fusiondet detect` wrote says whether it finished and which
    // frames it holds: an interrupted one, or one missing a frame it lists, is refused
    // rather than scored as if complete.
    let manifest = fusiondet_kitti::read_manifest(result_dir).map_err(EvalError::Results)?;
    // A sharded detect writes the manifest when its last shard finishes: without it the
    // directory holds only some shards' results.
    let shards = fusiondet_kitti::shard::read_records(result_dir).map_err(EvalError::Results)?;
    if manifest.is_none() && shards.iter().any(|r| r.command == "detect") {
        return Err(EvalError::Dir {
            path: result_dir.to_path_buf(),
            message: "holds a sharded `fusiondet detect` that has not finished (its manifest \
                      is written when every shard has): `fusiondet merge --dir DIR` says \
                      which shards or frames are missing"
                .into(),
        });
    }
    if let Some(m) = &manifest {
        if !m.complete {
            return Err(EvalError::Dir {
                path: result_dir.to_path_buf(),
                message: "its `fusiondet detect` did not finish (killed, or a write failed): \
                          some results may be stale or missing; run detect again with --force"
                    .into(),
            });
        }
        if let Some(id) = m
            .frames
            .iter()
            .find(|id| !result_dir.join(format!("{id}.txt")).is_file())
        {
            return Err(EvalError::Dir {
                path: result_dir.join(format!("{id}.txt")),
                message: "listed as written by detect but missing; run detect again with --force"
                    .into(),
            });
        }
    }
    let loaded: Vec<Result<(FrameGt, Option<FrameDet>), EvalError>> = ids
        .par_iter()
        .map(|id| {
            let file = format!("{id}.txt");
            let gt = read_objects(&label_dir.join(&file)).map_err(EvalError::GroundTruth)?;
            let det = read_result_file(&result_dir.join(&file)).map_err(EvalError::Results)?;
            Ok((
                FrameGt::new(id.clone(), gt),
                det.map(|d| FrameDet::new(id.clone(), d)),
            ))
        })
        .collect();
    let mut out = LoadedFrames {
        gt: Vec::with_capacity(ids.len()),
        det: Vec::with_capacity(ids.len()),
        missing_results: Vec::new(),
    };
    // Errors are reported for the first bad frame in split order, whatever the thread timing.
    for item in loaded {
        let (gt, det) = item?;
        let det = det.unwrap_or_else(|| {
            out.missing_results.push(gt.id.clone());
            FrameDet::new(gt.id.clone(), Vec::new())
        });
        out.gt.push(gt);
        out.det.push(det);
    }
    Ok(out)
}

/// Loads and evaluates: `split` chooses the frames (default: every label file).
pub fn evaluate_dirs(
    label_dir: &Path,
    result_dir: &Path,
    split: Option<&Path>,
    cfg: &EvalConfig,
) -> Result<(EvalReport, LoadedFrames), EvalError> {
    let ids = frame_ids(label_dir, split)?;
    let frames = load_dirs(label_dir, result_dir, &ids)?;
    let report = evaluate(&frames.gt, &frames.det, cfg)?;
    Ok((report, frames))
}
