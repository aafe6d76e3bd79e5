//! Reading a SUN RGB-D label directory and a result directory (`<id>.txt` each). A missing
//! label file is an error; a missing result file is a scene without detections (reported).

use super::ap::IndoorScene;
use crate::error::EvalError;
use fusiondet_kitti::FormatError;
use fusiondet_sunrgbd::{Object, read_labels, read_results};
use rayon::prelude::*;
use std::path::Path;

/// The scenes of a label and a result directory.
#[derive(Debug, Clone, PartialEq)]
pub struct IndoorLoaded {
    pub scenes: Vec<IndoorScene>,
    /// Ids without a result file (evaluated as scenes without detections).
    pub missing_results: Vec<String>,
}

/// A scene's ground truth and its detections (`None` without a result file).
type SceneFiles = (Vec<Object>, Option<Vec<Object>>);

/// Reads a result file: `Ok(None)` if there is none.
fn read_result_file(path: &Path) -> Result<Option<Vec<Object>>, FormatError> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        _ => read_results(path).map(Some),
    }
}

/// Refuses a result directory that a `fusiondet detect` wrote and did not finish, as the
/// KITTI evaluation does: its files may be stale or missing.
fn check_result_dir(result_dir: &Path) -> Result<(), EvalError> {
    let manifest = fusiondet_kitti::read_manifest(result_dir).map_err(EvalError::Results)?;
    let shards = fusiondet_kitti::shard::read_records(result_dir).map_err(EvalError::Results)?;
    let unfinished = match &manifest {
        Some(m) => !m.complete,
        None => shards.iter().any(|r| r.command == "detect"),
    };
    if unfinished {
        return Err(EvalError::Dir {
            path: result_dir.to_path_buf(),
            message: "its `fusiondet detect` did not finish: some results may be stale or \
                      missing; run detect again (or `fusiondet merge` for sharded runs)"
                .into(),
        });
    }
    if let Some(id) = manifest
        .iter()
        .flat_map(|m| &m.frames)
        .find(|id| !result_dir.join(format!("{id}.txt")).is_file())
    {
        return Err(EvalError::Dir {
            path: result_dir.join(format!("{id}.txt")),
            message: "listed as written by detect but missing; run detect again with --force"
                .into(),
        });
    }
    Ok(())
}

/// Loads the ground truth and detections of `ids` (see [`crate::frame_ids`] for choosing
/// them from a split file or the label directory).
pub fn load_indoor_dirs(
    label_dir: &Path,
    result_dir: &Path,
    ids: &[String],
) -> Result<IndoorLoaded, EvalError> {
    for (dir, what) in [(label_dir, "label"), (result_dir, "result")] {
        if !dir.is_dir() {
            return Err(EvalError::Dir {
                path: dir.to_path_buf(),
                message: format!("the {what} directory does not exist or is not a directory"),
            });
        }
    }
    check_result_dir(result_dir)?;
    let loaded: Vec<Result<SceneFiles, EvalError>> = ids
        .par_iter()
        .map(|id| {
            let file = format!("{id}.txt");
            let gt = read_labels(&label_dir.join(&file)).map_err(EvalError::GroundTruth)?;
            let det = read_result_file(&result_dir.join(&file)).map_err(EvalError::Results)?;
            Ok((gt, det))
        })
        .collect();
    let mut out = IndoorLoaded {
        scenes: Vec::with_capacity(ids.len()),
        missing_results: Vec::new(),
    };
    // The first bad scene in split order is reported, whatever the thread timing.
    for (id, item) in ids.iter().zip(loaded) {
        let (gt, det) = item?;
        let det = det.unwrap_or_else(|| {
            out.missing_results.push(id.clone());
            Vec::new()
        });
        out.scenes.push(IndoorScene {
            id: id.clone(),
            gt,
            det,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const BED: &str = "bed 0 2 0 2 1.5 1 0.3 0 0 10 10";

    fn dirs() -> (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
        let tmp = tempfile::tempdir().unwrap();
        let (gt, det) = (tmp.path().join("gt"), tmp.path().join("det"));
        std::fs::create_dir_all(&gt).unwrap();
        std::fs::create_dir_all(&det).unwrap();
        (tmp, gt, det)
    }

    fn ids(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn loads_scenes_in_split_order_and_reports_missing_results() {
        let (_tmp, gt, det) = dirs();
        std::fs::write(gt.join("000002.txt"), format!("# header\n{BED}\n")).unwrap();
        std::fs::write(gt.join("000001.txt"), "").unwrap();
        std::fs::write(det.join("000002.txt"), format!("{BED} 0.5\n")).unwrap();
        let loaded = load_indoor_dirs(&gt, &det, &ids(&["000002", "000001"])).unwrap();
        assert_eq!(loaded.scenes[0].id, "000002");
        assert_eq!(loaded.scenes[0].det[0].score, Some(0.5));
        assert_eq!(loaded.missing_results, ["000001"]);
        assert!(loaded.scenes[1].gt.is_empty() && loaded.scenes[1].det.is_empty());
    }

    #[test]
    fn bad_input_names_the_file_and_line() {
        let (_tmp, gt, det) = dirs();
        std::fs::write(gt.join("000001.txt"), format!("{BED}\n")).unwrap();
        // A label file missing for an id of the split.
        let err = load_indoor_dirs(&gt, &det, &ids(&["000001", "000003"]))
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("ground truth: ") && err.contains("000003.txt"),
            "{err}"
        );
        // A result line without its score.
        std::fs::write(det.join("000001.txt"), format!("{BED} 0.9\n{BED}\n")).unwrap();
        let err = load_indoor_dirs(&gt, &det, &ids(&["000001"]))
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("results: "), "{err}");
        assert!(
            err.contains("000001.txt:2: field `score`: missing"),
            "{err}"
        );
        // A malformed label line.
        std::fs::write(gt.join("000001.txt"), "bed 0 2 0 2 -1.5 1 0.3 0 0 10 10\n").unwrap();
        let err = load_indoor_dirs(&gt, &det, &ids(&["000001"]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("000001.txt:1: field `dy`"), "{err}");
        let err = load_indoor_dirs(&gt, &gt.join("nope"), &ids(&["000001"]))
            .unwrap_err()
            .to_string();
        assert!(err.contains("result directory does not exist"), "{err}");
    }
}
