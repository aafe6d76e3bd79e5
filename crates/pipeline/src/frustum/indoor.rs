//! `detect` on a prepared SUN RGB-D directory: each scene's 2D detections
//! (`det_2d/<id>.txt`, or `<id>.txt` in the `--detections` directory) → frustums → one
//! box per frustum → 3D NMS per class → `<id>.txt` result lines in upright depth, under
//! detect's manifest (so `eval --dataset sunrgbd` reads them).

use crate::detection::{DetectOptions, DetectSummary};
use crate::error::{PipelineError, Result};
use crate::frustum::FrustumDetector;
use crate::result_dir::{ResultWriter, check_result_dir, refuse_input_dir};
use fusiondet_dataset::Class;
use fusiondet_dataset::indoor::{load_scenes, scene_ids};
use fusiondet_frustum::{FrameDetection, InMemoryFrames};
use fusiondet_sunrgbd::{SunClass, SunRgbdDir, read_detections_2d};
use std::path::Path;
use std::time::Instant;

/// The 2D detections of scene `id` as frustum prompts: from `dir/<id>.txt` when a
/// directory is given, else the data set's `det_2d/<id>.txt`. Classes other than the
/// ten are not detected (as labels of other classes are not learnt).
fn scene_detections(
    data: &SunRgbdDir,
    dir: Option<&Path>,
    id: &str,
) -> Result<Vec<FrameDetection>> {
    let path = match dir {
        Some(d) => d.join(format!("{id}.txt")),
        None => data.detections_2d(id),
    };
    Ok(read_detections_2d(&path)?
        .into_iter()
        .filter_map(|d| {
            Some(FrameDetection {
                frame_id: id.to_string(),
                class: Class::SunRgbd(SunClass::parse(&d.class)?),
                bbox: d.bbox,
                score: d.score,
            })
        })
        .collect())
}

/// `crate::detect::detect_in_chunks` for SUN RGB-D data (whole splits only).
pub fn detect_scenes(options: &DetectOptions, chunk_frames: usize) -> Result<DetectSummary> {
    refuse_input_dir(options)?;
    if options.shard.is_some() {
        return Err(PipelineError::Invalid(
            "--shard: sharded detection reads KITTI data only for now; run SUN RGB-D splits \
             whole"
                .into(),
        ));
    }
    if options.depth_dir.is_some() {
        return Err(PipelineError::Invalid(
            "--depth-dir: only a dasanet detector reads completed depth maps".into(),
        ));
    }
    if let Some(d) = &options.detections
        && !d.is_dir()
    {
        return Err(PipelineError::Invalid(format!(
            "--detections {}: for SUN RGB-D data this is a directory of per-scene files \
             (`<id>.txt`, lines `class x1 y1 x2 y2 score`, as in det_2d/)",
            d.display()
        )));
    }
    check_result_dir(&options.out_dir, options.replace)?;
    let mut summary = DetectSummary::default();
    let t = Instant::now();
    let device = options.device.device();
    let stored = fusiondet_models::read_checkpoint_kind(&options.checkpoint)?;
    if stored != fusiondet_models::DetectorKind::Frustum {
        return Err(PipelineError::Invalid(format!(
            "SUN RGB-D data is detected by frustum models only; {} is a {stored} checkpoint",
            options.checkpoint.display()
        )));
    }
    let detector = FrustumDetector::load(options.config.clone(), &options.checkpoint, &device)?;
    let data = SunRgbdDir::new(&options.data_dir);
    let ids = scene_ids(&options.data_dir, &options.split, 0)?;
    // Every scene's detections are read before anything is written: a missing file
    // fails the run with the results directory untouched.
    let mut detections = Vec::with_capacity(ids.len());
    for id in &ids {
        detections.push(scene_detections(&data, options.detections.as_deref(), id)?);
    }
    let mut writer = ResultWriter::begin(&options.out_dir, &ids, options.replace)?;
    summary.timing.load += t.elapsed();
    for (chunk, dets) in ids
        .chunks(chunk_frames.max(1))
        .zip(detections.chunks(chunk_frames.max(1)))
    {
        let t = Instant::now();
        let frames: InMemoryFrames = load_scenes(&options.data_dir, chunk, false)?;
        summary.timing.load += t.elapsed();
        let dets: Vec<FrameDetection> = dets.iter().flatten().cloned().collect();
        let found = detector.detect_scenes(&device, frames, &dets, &mut summary.timing)?;
        summary.frames += chunk.len();
        summary.detections_2d += dets.len();
        summary.samples += found.samples;
        summary.skipped.merge(&found.skipped);
        for id in chunk {
            let lines = found.objects.get(id).map_or(&[][..], Vec::as_slice);
            summary.boxes_written += lines.len();
            writer.write_scene(id, lines)?;
        }
    }
    writer.finish()?;
    Ok(summary)
}
