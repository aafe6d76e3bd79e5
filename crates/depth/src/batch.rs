//! Completing many depth maps: every PNG of a directory, or every frame of a KITTI
//! `training/` directory (its scan projected first). Frames run in parallel; each output
//! is written atomically, and nothing is written into an input directory.

use crate::ip_basic::DepthCompleter;
use crate::project::project_scan;
use crate::pseudo::{Thinning, pseudo_points, write_pseudo_points};
use crate::{DepthError, Result};
use fusiondet_dataset::SensorFrame;
use fusiondet_kitti::DepthMap;
use fusiondet_kitti::paths::{Inputs, check_output_dir};
use fusiondet_kitti::{FormatError, FrameDir};
use fusiondet_kitti::{read_depth_png, write_depth_png};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What a batch did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BatchSummary {
    pub maps: usize,
    /// Measured pixels in, filled pixels out (summed over the maps).
    pub sparse_pixels: usize,
    pub dense_pixels: usize,
}

/// Refuses an output directory that is, lies inside or contains one of `inputs` or the
/// data set they belong to ([`fusiondet_kitti::paths`]), then creates it.
fn refuse_input_dir(out_dir: &Path, inputs: &Inputs) -> Result<()> {
    check_output_dir("--out-dir", out_dir, inputs)
        .map_err(|e| DepthError::Mismatch(e.to_string()))?;
    std::fs::create_dir_all(out_dir).map_err(|e| FormatError::io(out_dir, e))?;
    Ok(())
}

/// Refuses a frame whose scan puts no point into its image (an `image_2` of another size
/// than the calibration's camera, or the wrong file): nothing could be completed, and a
/// map or cloud of nothing would pass for a result.
fn refuse_empty_projection(frames: &FrameDir, id: &str, sparse: &DepthMap) -> Result<()> {
    if sparse.valid_count() == 0 {
        return Err(DepthError::Mismatch(format!(
            "{}: no LiDAR point of the frame falls inside this {}×{} image; is it the frame's \
             image, at the calibration's size?",
            frames.image(id).display(),
            sparse.width,
            sparse.height
        )));
    }
    Ok(())
}

fn summarise(results: Vec<Result<(usize, usize)>>) -> Result<BatchSummary> {
    let mut summary = BatchSummary::default();
    for r in results {
        let (sparse, dense) = r?;
        summary.maps += 1;
        summary.sparse_pixels += sparse;
        summary.dense_pixels += dense;
    }
    Ok(summary)
}

/// Completes every `*.png` of `sparse_dir` into `out_dir` (same file names).
/// `frame_done` is called once per map written, here and in the other batch functions (a
/// progress bar's tick).
pub fn complete_dir(
    sparse_dir: &Path,
    out_dir: &Path,
    completer: &(dyn DepthCompleter + Sync),
    frame_done: &(dyn Fn() + Sync),
) -> Result<BatchSummary> {
    let mut inputs: Vec<PathBuf> = std::fs::read_dir(sparse_dir)
        .map_err(|e| FormatError::io(sparse_dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    inputs.sort();
    if inputs.is_empty() {
        return Err(DepthError::Mismatch(format!(
            "{}: no .png depth maps here",
            sparse_dir.display()
        )));
    }
    refuse_input_dir(
        out_dir,
        &Inputs::new().with("--sparse-dir", Some(sparse_dir)),
    )?;
    let results = inputs
        .par_iter()
        .map(|input| {
            let sparse = read_depth_png(input)?;
            let dense = completer.complete(&sparse);
            write_depth_png(&out_dir.join(input.file_name().expect("a file")), &dense)?;
            frame_done();
            Ok((sparse.valid_count(), dense.valid_count()))
        })
        .collect();
    summarise(results)
}

/// Projects each frame's scan into its `image_2` and completes it into
/// `out_dir/<id>.png`; `ids` empty = every frame with a `velodyne/*.bin`.
pub fn complete_frames(
    frames: &FrameDir,
    ids: &[String],
    out_dir: &Path,
    completer: &(dyn DepthCompleter + Sync),
    frame_done: &(dyn Fn() + Sync),
) -> Result<BatchSummary> {
    let ids = frame_ids(frames, ids)?;
    refuse_input_dir(
        out_dir,
        &Inputs::new().with("--data-dir", Some(&frames.root)),
    )?;
    let results = ids
        .par_iter()
        .map(|id| {
            let frame = SensorFrame::load(frames, id, false)?;
            let sparse = project_scan(&frame);
            refuse_empty_projection(frames, id, &sparse)?;
            let dense = completer.complete(&sparse);
            write_depth_png(&out_dir.join(format!("{id}.png")), &dense)?;
            frame_done();
            Ok((sparse.valid_count(), dense.valid_count()))
        })
        .collect();
    summarise(results)
}

/// What a pseudo-point run did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PseudoSummary {
    pub frames: usize,
    pub points: usize,
}

/// Writes `out_dir/<id>.bin` for each frame: its completed depth (read from
/// `depth_dir/<id>.png`, else the projected scan completed by `completer`) back-projected
/// with the colours of `image_2`.
pub fn pseudo_frames(
    frames: &FrameDir,
    ids: &[String],
    depth_dir: Option<&Path>,
    out_dir: &Path,
    completer: &(dyn DepthCompleter + Sync),
    thinning: Option<Thinning>,
    frame_done: &(dyn Fn() + Sync),
) -> Result<PseudoSummary> {
    let ids = frame_ids(frames, ids)?;
    let inputs = Inputs::new()
        .with("--data-dir", Some(&frames.root))
        .with("--depth-dir", depth_dir);
    refuse_input_dir(out_dir, &inputs)?;
    let counts: Vec<Result<usize>> = ids
        .par_iter()
        .map(|id| {
            let frame = SensorFrame::load(frames, id, false)?;
            let image = frame.image()?;
            let (depth, source) = match depth_dir {
                Some(dir) => {
                    let path = dir.join(format!("{id}.png"));
                    (read_depth_png(&path)?, Some(path))
                }
                None => {
                    let sparse = project_scan(&frame);
                    refuse_empty_projection(frames, id, &sparse)?;
                    (completer.complete(&sparse), None)
                }
            };
            // A given map of another size than image_2 is refused naming its file.
            let points =
                pseudo_points(&depth, &image, &frame.camera, thinning).map_err(
                    |e| match &source {
                        Some(path) => DepthError::Mismatch(format!("{}: {e}", path.display())),
                        None => e,
                    },
                )?;
            write_pseudo_points(&out_dir.join(format!("{id}.bin")), &points)?;
            frame_done();
            Ok(points.len())
        })
        .collect();
    let mut summary = PseudoSummary::default();
    for c in counts {
        summary.points += c?;
        summary.frames += 1;
    }
    Ok(summary)
}

/// The ids given (each checked to be a frame id and padded to six digits, so that none can
/// lead outside the folders), or every frame with a `velodyne/*.bin`; none is an error.
pub fn frame_ids(frames: &FrameDir, ids: &[String]) -> Result<Vec<String>> {
    let ids = if ids.is_empty() {
        let velodyne = frames.root.join("velodyne");
        fusiondet_kitti::layout::list_frame_ids(&velodyne, "bin")
            .map_err(|e| FormatError::io(&velodyne, e))?
    } else {
        ids.iter()
            .map(|id| {
                fusiondet_kitti::parse_frame_id(id)
                    .map_err(|e| DepthError::Mismatch(format!("--ids: {e}")))
            })
            .collect::<Result<Vec<_>>>()?
    };
    if ids.is_empty() {
        return Err(DepthError::Mismatch(format!(
            "{}: no frames (velodyne/*.bin) here",
            frames.root.display()
        )));
    }
    Ok(ids)
}
