//! Detection with a trained model of any family: load the checkpoint (its family
//! checked against the configuration's), read the split in the family's form, detect,
//! write one KITTI result file per frame; and the per-stage timing `bench` reports.

use crate::config::ExperimentConfig;
use crate::dasanet::DasanetDetector;
use crate::device::ComputeDevice;
use crate::error::{PipelineError, Result};
use crate::frustum::FrustumDetector;
use crate::voxel_rcnn::VoxelRcnnDetector;
use burn::prelude::*;
use fusiondet_dataset::SensorFrame;
use fusiondet_frustum::{FrameSource, InMemoryFrames, SkipCounts};
use fusiondet_kitti::atomic::DirLock;
use fusiondet_kitti::shard::{self, ShardRecord};
use fusiondet_kitti::{
    DatasetDir, Detection2d, Object, ResultsManifest, Shard, read_detections2d, read_manifest,
    write_manifest, write_objects,
};
use fusiondet_models::DetectorKind;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

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

    /// Everything but loading from disk: what frames/s is measured over.
    pub fn compute(&self) -> Duration {
        self.stages.iter().map(|(_, d)| *d).sum()
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

/// What a family reads beside the frames, read once for a split: the 2D detections (the
/// frustum family) and where completed depth maps are (DASANet).
#[derive(Debug, Clone, Default)]
pub struct SplitSide {
    pub detections: Vec<Detection2d>,
    pub depth_dir: Option<PathBuf>,
}

/// Frames detection holds in memory at once: a split is detected in chunks of this many,
/// so memory stays flat however long the split (about 1 MB a frame; KITTI's val split
/// whole would take 4 GB). Every family gives the same boxes in chunks as whole: the
/// frustum family names each frustum's point-sampling stream by its frame
/// ([`fusiondet_frustum::StreamKey::Frame`]), the voxel families draw nothing.
pub const DETECT_CHUNK_FRAMES: usize = 64;

/// What a family reads beside the frames: 2D detections (the frustum family; `None`
/// reads the data set's own file) and completed depth maps (DASANet; `None` completes).
#[derive(Debug, Clone, Copy, Default)]
pub struct SideInputs<'a> {
    pub detections: Option<&'a Path>,
    pub depth_dir: Option<&'a Path>,
}

/// A trained detector of any family, chosen by the family its checkpoint records.
pub enum Detector {
    Frustum(Box<FrustumDetector>),
    VoxelRcnn(Box<VoxelRcnnDetector>),
    Dasanet(Box<DasanetDetector>),
}

/// A split prepared for one family's detector (the frames in the family's form, and
/// what else it reads).
pub enum SplitInputs {
    /// Frames with their in-image points, and the 2D detections that become frustums.
    Frustum {
        frames: InMemoryFrames,
        detections: Vec<Detection2d>,
    },
    /// Whole frames (the full scan; no 2D detections needed).
    Lidar {
        frames: fusiondet_dataset::InMemoryFrames<SensorFrame>,
    },
    /// Whole frames with their images, and completed depth maps when given.
    Camera {
        frames: fusiondet_dataset::InMemoryFrames<SensorFrame>,
        depth_dir: Option<PathBuf>,
    },
}

impl SplitInputs {
    pub fn frames(&self) -> usize {
        match self {
            SplitInputs::Frustum { frames, .. } => frames.len(),
            SplitInputs::Lidar { frames } | SplitInputs::Camera { frames, .. } => frames.len(),
        }
    }

    /// 2D detections read (0 for a family that needs none).
    pub fn detections_2d(&self) -> usize {
        match self {
            SplitInputs::Frustum { detections, .. } => detections.len(),
            SplitInputs::Lidar { .. } | SplitInputs::Camera { .. } => 0,
        }
    }
}

impl Detector {
    /// Loads a checkpoint onto `device` after checking that it belongs to the family
    /// `config` is for.
    pub fn load(config: ExperimentConfig, checkpoint: &Path, device: &Device) -> Result<Self> {
        let stored = fusiondet_models::read_checkpoint_kind(checkpoint)?;
        if stored != config.kind() {
            return Err(PipelineError::Config {
                path: checkpoint.to_path_buf(),
                message: format!(
                    "a {stored} checkpoint cannot be run with a {} configuration ({}); pass \
                     the configuration it was trained with",
                    config.kind(),
                    config.name
                ),
            });
        }
        Ok(match config.kind() {
            DetectorKind::Frustum => {
                Detector::Frustum(Box::new(FrustumDetector::load(config, checkpoint, device)?))
            }
            DetectorKind::VoxelRcnn => Detector::VoxelRcnn(Box::new(VoxelRcnnDetector::load(
                config, checkpoint, device,
            )?)),
            DetectorKind::Dasanet => {
                Detector::Dasanet(Box::new(DasanetDetector::load(config, checkpoint, device)?))
            }
        })
    }

    pub fn config(&self) -> &ExperimentConfig {
        match self {
            Detector::Frustum(d) => &d.config,
            Detector::VoxelRcnn(d) => &d.config,
            Detector::Dasanet(d) => &d.config,
        }
    }

    /// Reads the first `max_frames` frames of a split (0 = all) in this family's form,
    /// with what else it needs (the frustum family: the 2D detections, `detections` or
    /// the data set's own file for the split; DASANet: completed depth maps in
    /// `depth_dir`, if given). Refuses what the family does not read.
    pub fn load_split(
        &self,
        data_dir: &Path,
        split: &str,
        max_frames: usize,
        side: SideInputs,
    ) -> Result<SplitInputs> {
        let SplitSide {
            detections,
            depth_dir,
        } = self.read_side(data_dir, split, side)?;
        let ids = fusiondet_dataset::split_ids(data_dir, split, max_frames)?;
        self.load_frames(data_dir, &ids, detections, depth_dir.as_deref())
    }

    /// What this family reads beside the frames, read once for a split; refuses what the
    /// family does not read.
    pub fn read_side(&self, data_dir: &Path, split: &str, side: SideInputs) -> Result<SplitSide> {
        let SideInputs {
            detections,
            depth_dir,
        } = side;
        if let (Some(dir), false) = (depth_dir, matches!(self, Detector::Dasanet(_))) {
            return Err(PipelineError::Invalid(format!(
                "--depth-dir {}: only a dasanet detector reads completed depth maps; this is \
                 a {} one",
                dir.display(),
                self.config().kind()
            )));
        }
        let detections = match self {
            Detector::Frustum(_) => {
                let path = detections
                    .map(Path::to_path_buf)
                    .unwrap_or_else(|| DatasetDir::new(data_dir).rgb_detections(split));
                read_detections2d(&path)?
            }
            Detector::VoxelRcnn(_) | Detector::Dasanet(_) => Vec::new(),
        };
        Ok(SplitSide {
            detections,
            depth_dir: depth_dir.map(Path::to_path_buf),
        })
    }

    /// The frames `ids` in this family's form, with `detections` (the frustum family's 2D
    /// boxes for these frames) and `depth_dir` (DASANet's completed maps), as
    /// [`Detector::read_side`] read them.
    pub fn load_frames(
        &self,
        data_dir: &Path,
        ids: &[String],
        detections: Vec<Detection2d>,
        depth_dir: Option<&Path>,
    ) -> Result<SplitInputs> {
        let training = DatasetDir::new(data_dir).training();
        Ok(match self {
            Detector::Frustum(_) => SplitInputs::Frustum {
                frames: InMemoryFrames::load(&training, ids, false)?,
                detections,
            },
            Detector::VoxelRcnn(_) => SplitInputs::Lidar {
                frames: fusiondet_dataset::InMemoryFrames::load(&training, ids, false)?,
            },
            Detector::Dasanet(_) => SplitInputs::Camera {
                frames: fusiondet_dataset::InMemoryFrames::load(&training, ids, false)?,
                depth_dir: depth_dir.map(Path::to_path_buf),
            },
        })
    }

    /// Detects on every frame of `inputs` (in memory; no disk reads).
    pub fn detect(
        &self,
        device: &Device,
        inputs: &SplitInputs,
        timing: &mut StageTimes,
    ) -> Result<FrameResults> {
        match (self, inputs) {
            (Detector::Frustum(d), SplitInputs::Frustum { frames, detections }) => {
                d.detect_frames(device, frames.clone(), detections, timing)
            }
            (Detector::VoxelRcnn(d), SplitInputs::Lidar { frames }) => {
                d.detect_frames(device, frames, timing)
            }
            (Detector::Dasanet(d), SplitInputs::Camera { frames, depth_dir }) => {
                d.detect_frames(device, frames, depth_dir.as_deref(), timing)
            }
            _ => Err(PipelineError::Invalid(
                "the split was read for another detector family".into(),
            )),
        }
    }
}

/// Parameters of a trained model as the papers count them (both stages of a two-stage
/// model).
pub fn trained_parameters(config: &ExperimentConfig) -> Result<usize> {
    match config.kind() {
        DetectorKind::Frustum => crate::frustum::trained_parameters(config),
        DetectorKind::VoxelRcnn => crate::voxel_rcnn::trained_parameters(config),
        DetectorKind::Dasanet => crate::dasanet::trained_parameters(config),
    }
}

/// Multiply-adds of one frame's inference on the synthetic KITTI-like scene `info` uses,
/// for the families that count them (Voxel R-CNN, DASANet); `None` for the frustum family,
/// whose work depends on the 2D detections.
pub fn inference_multiply_adds(config: &ExperimentConfig) -> Result<Option<u64>> {
    let device = Device::flex();
    let total = |rows: &[(&'static str, u64)]| rows.iter().map(|r| r.1).sum::<u64>();
    match config.kind() {
        DetectorKind::Frustum => Ok(None),
        DetectorKind::VoxelRcnn => {
            let section = VoxelRcnnDetector::section(config)?;
            let shape = section.shape();
            let model =
                fusiondet_models::voxel_rcnn::VoxelRcnn::new(&shape.network, shape.grid_z, &device)
                    .map_err(PipelineError::Invalid)?;
            Ok(Some(total(
                &crate::voxel_rcnn::info::stage_costs(section, &model).rows,
            )))
        }
        DetectorKind::Dasanet => {
            let (voxel, dasanet) = crate::dasanet::detector::sections(config)?;
            let shape = dasanet.shape(voxel);
            let model =
                fusiondet_models::dasanet::Dasanet::new(&shape.network, shape.grid_z, &device)
                    .map_err(PipelineError::Invalid)?;
            Ok(Some(total(
                &crate::dasanet::info::stage_costs(voxel, dasanet, &model).rows,
            )))
        }
    }
}

/// What detection runs on: the detector on its device, and the split's inputs.
pub(crate) struct DetectInputs {
    pub detector: Detector,
    pub device: Device,
    pub inputs: SplitInputs,
}

/// Loads a checkpoint (with its first stage for a refinement model) and the first
/// `max_frames` frames of a split (0 = all) with what its family reads besides.
pub(crate) fn load_detect_inputs(
    config: &ExperimentConfig,
    checkpoint: &Path,
    data_dir: &Path,
    split: &str,
    side: SideInputs,
    max_frames: usize,
    device: ComputeDevice,
) -> Result<DetectInputs> {
    let device = device.device();
    let detector = Detector::load(config.clone(), checkpoint, &device)?;
    let inputs = detector.load_split(data_dir, split, max_frames, side)?;
    Ok(DetectInputs {
        detector,
        device,
        inputs,
    })
}

/// Runs detection over the split, [`DETECT_CHUNK_FRAMES`] frames at a time, and writes one
/// KITTI result file per frame of the split (empty when nothing was detected), atomically,
/// under the result directory's manifest.
pub fn detect(options: &DetectOptions) -> Result<DetectSummary> {
    detect_in_chunks(options, DETECT_CHUNK_FRAMES)
}

/// [`detect`] holding at most `chunk_frames` frames in memory at once (see
/// [`DETECT_CHUNK_FRAMES`]).
pub fn detect_in_chunks(options: &DetectOptions, chunk_frames: usize) -> Result<DetectSummary> {
    if options.config.dataset.format == crate::config::DatasetFormat::SunRgbd {
        return crate::frustum::indoor::detect_scenes(options, chunk_frames);
    }
    // Before anything is loaded: a refused --out should not cost a model load.
    refuse_input_dir(options)?;
    if options.shard.is_none() {
        check_result_dir(&options.out_dir, options.replace)?;
    }
    let mut summary = DetectSummary::default();
    let t = Instant::now();
    let device = options.device.device();
    let detector = Detector::load(options.config.clone(), &options.checkpoint, &device)?;
    let SplitSide {
        detections,
        depth_dir,
    } = detector.read_side(
        &options.data_dir,
        &options.split,
        SideInputs {
            detections: options.detections.as_deref(),
            depth_dir: options.depth_dir.as_deref(),
        },
    )?;
    let split_ids = fusiondet_dataset::split_ids(&options.data_dir, &options.split, 0)?;
    // 2D detections of frames outside the split are counted as such once, not per chunk.
    let in_split: std::collections::HashSet<&str> = split_ids.iter().map(String::as_str).collect();
    let (detections, outside): (Vec<Detection2d>, Vec<Detection2d>) = detections
        .into_iter()
        .partition(|d| in_split.contains(d.frame_id.as_str()));
    summary.detections_2d += outside.len();
    summary.skipped.unknown_frame += outside.len();
    let mut writer = match options.shard {
        None => FrameWriter::Whole(ResultWriter::begin(
            &options.out_dir,
            &split_ids,
            options.replace,
        )?),
        Some(shard) => {
            let run = run_fingerprint(options, &split_ids, &detections, shard)?;
            FrameWriter::Shard(ShardWriter::begin(
                &options.out_dir,
                shard,
                run,
                shard.select(&split_ids),
                options.replace,
            )?)
        }
    };
    let ids = writer.frames().to_vec();
    // Another shard's frames are not this run's to count.
    let mine: std::collections::HashSet<&str> = ids.iter().map(String::as_str).collect();
    let mut detections: Vec<Detection2d> = detections
        .into_iter()
        .filter(|d| mine.contains(d.frame_id.as_str()))
        .collect();
    summary.timing.load += t.elapsed();

    for chunk in ids.chunks(chunk_frames.max(1)) {
        let t = Instant::now();
        let chunk_ids: std::collections::HashSet<&str> = chunk.iter().map(String::as_str).collect();
        let (mine, rest) = detections
            .into_iter()
            .partition(|d| chunk_ids.contains(d.frame_id.as_str()));
        detections = rest;
        let inputs = detector.load_frames(&options.data_dir, chunk, mine, depth_dir.as_deref())?;
        summary.timing.load += t.elapsed();
        let results = detector.detect(&device, &inputs, &mut summary.timing)?;
        summary.frames += inputs.frames();
        summary.detections_2d += inputs.detections_2d();
        summary.samples += results.samples;
        summary.skipped.merge(&results.skipped);
        for id in chunk {
            let objects = results.objects.get(id).map_or(&[][..], Vec::as_slice);
            summary.boxes_written += objects.len();
            writer.write(id, objects)?;
        }
    }
    summary.shards = writer.finish()?;
    Ok(summary)
}

/// What defines a sharded detect run, so that shards of different runs never share a
/// result directory: the weights, the configuration, the split, what its frames' files
/// are ([`shard::frame_inputs_summary`]) and its 2D detections,
/// the completed depth maps' folder and the shard count.
fn run_fingerprint(
    options: &DetectOptions,
    split_ids: &[String],
    detections: &[Detection2d],
    shard: Shard,
) -> Result<String> {
    let weights = fusiondet_kitti::error::read_regular(
        &options.checkpoint,
        fusiondet_kitti::error::MAX_BINARY_BYTES,
    )?;
    let frames = fusiondet_kitti::FrameDir::new(options.data_dir.join("training"));
    let frames_summary = shard::frame_inputs_summary(
        split_ids
            .iter()
            .flat_map(|id| [frames.velodyne(id), frames.image(id), frames.calib(id)]),
    );
    let depth_dir = options
        .depth_dir
        .as_ref()
        .map(|d| d.canonicalize().unwrap_or_else(|_| d.clone()))
        .map(|d| d.display().to_string())
        .unwrap_or_default();
    Ok(shard::fingerprint(&[
        &weights,
        options.config.to_toml_string().as_bytes(),
        split_ids.join("\n").as_bytes(),
        &frames_summary,
        format!("{detections:?}").as_bytes(),
        depth_dir.as_bytes(),
        shard.count.to_string().as_bytes(),
    ]))
}

/// Where a detect run's frames go: the whole split under the directory's manifest, or one
/// shard's frames under its shard record.
enum FrameWriter {
    Whole(ResultWriter),
    Shard(ShardWriter),
}

impl FrameWriter {
    fn frames(&self) -> &[String] {
        match self {
            FrameWriter::Whole(w) => &w.manifest.frames,
            FrameWriter::Shard(w) => &w.record.frames,
        }
    }

    fn write(&mut self, id: &str, objects: &[Object]) -> Result<()> {
        match self {
            FrameWriter::Whole(w) => w.write(id, objects),
            FrameWriter::Shard(w) => w.write(id, objects),
        }
    }

    fn finish(self) -> Result<Option<shard::ShardProgress>> {
        match self {
            FrameWriter::Whole(w) => w.finish().map(|()| None),
            FrameWriter::Shard(w) => w.finish().map(Some),
        }
    }
}

fn out_err(path: &Path, message: impl Into<String>) -> PipelineError {
    PipelineError::RunDir {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Refuses a result directory that is, lies inside or contains anything detect reads: the
/// data set (`--out DATA/training/label_2` would overwrite its labels), the checkpoint, the
/// 2D detections, the completed depth maps (see [`fusiondet_kitti::paths`]).
pub(crate) fn refuse_input_dir(options: &DetectOptions) -> Result<()> {
    use fusiondet_kitti::paths::{Inputs, check_output_dir};
    let inputs = Inputs::new()
        .with("--data", Some(&options.data_dir))
        .with("--checkpoint", Some(&options.checkpoint))
        .with("--detections", options.detections.as_deref())
        .with("--depth-dir", options.depth_dir.as_deref());
    check_output_dir("--out", &options.out_dir, &inputs)
        .map_err(|e| PipelineError::Invalid(e.to_string()))
}

/// A result directory must be new, empty, or an earlier detect's: one that finished only
/// with `replace`, one that did not (killed, or stopped by an error; its results are
/// unusable, and eval refuses them) always. Files another program or the user put there are
/// never overwritten.
pub fn check_result_dir(out_dir: &Path, replace: bool) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(out_dir) else {
        return if out_dir.exists() {
            Err(out_err(out_dir, "exists and is not a directory"))
        } else {
            Ok(())
        };
    };
    let sharded = shard::read_records(out_dir)?
        .iter()
        .any(|r| r.command == DETECT);
    // The records folder and the writer lock alone are what a shard starting here makes
    // first.
    let others = entries.flatten().any(|e| {
        e.file_name() != shard::SHARDS_DIR
            && e.file_name() != fusiondet_kitti::atomic::WRITER_LOCK_FILE
    });
    if !others && !sharded {
        return Ok(());
    }
    match read_manifest(out_dir)? {
        None if sharded && !replace => Err(out_err(
            out_dir,
            "holds a sharded detect's results (its shards may still be running; `fusiondet \
             merge` tells); pass --force to replace them, or choose another --out",
        )),
        None if sharded => Ok(()),
        None => Err(out_err(
            out_dir,
            "holds files that `fusiondet detect` did not write; choose a new or empty --out",
        )),
        Some(earlier) if earlier.complete && !replace => Err(out_err(
            out_dir,
            "holds the results of an earlier detect; pass --force to replace them, or choose \
             another --out",
        )),
        Some(_) => Ok(()),
    }
}

/// Removes an earlier detect's files from `out_dir`: the frames its manifest and its shard
/// records list, then the records and the manifest (nothing else). The manifest is first
/// marked unfinished, so a kill while removing leaves a directory eval refuses.
fn remove_earlier_results(out_dir: &Path) -> Result<()> {
    let manifest = read_manifest(out_dir)?;
    let records = shard::read_records(out_dir)?;
    if let Some(old) = &manifest {
        write_manifest(
            out_dir,
            &ResultsManifest {
                complete: false,
                ..old.clone()
            },
        )?;
    }
    let listed = manifest
        .iter()
        .flat_map(|m| m.frames.iter())
        .chain(records.iter().flat_map(|r| r.frames.iter()));
    for id in listed {
        remove_if_present(&out_dir.join(format!("{id}.txt")))?;
    }
    for r in &records {
        remove_if_present(&shard::record_path(out_dir, &r.command, r.shard))?;
    }
    if manifest.is_some() {
        remove_if_present(&fusiondet_kitti::results::manifest_path(out_dir))?;
    }
    Ok(())
}

fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(out_err(
            path,
            format!("cannot remove the earlier result: {e}"),
        )),
        _ => Ok(()),
    }
}

/// Writes a result directory frame by frame under its manifest: it lists the frames
/// first (marked incomplete), then each frame's file is written, then the manifest is
/// marked complete (see [`fusiondet_kitti::results`]).
pub struct ResultWriter {
    out_dir: PathBuf,
    manifest: ResultsManifest,
    /// Held until the writer is dropped: a second detect into the same directory is refused.
    _lock: DirLock,
}

impl ResultWriter {
    /// Opens `out_dir` for the frames `ids`. With `replace`, an earlier detect's files are
    /// removed first (those its manifest lists, nothing else).
    pub fn begin(out_dir: &Path, ids: &[String], replace: bool) -> Result<ResultWriter> {
        check_result_dir(out_dir, replace)?;
        std::fs::create_dir_all(out_dir)
            .map_err(|e| out_err(out_dir, format!("cannot create the result directory: {e}")))?;
        let lock = lock_results(out_dir, false)?;
        // Again under the lock: another detect may have begun since the first look.
        check_result_dir(out_dir, replace)?;
        // Temporary files that killed writes of detect's own files left behind.
        fusiondet_kitti::atomic::remove_temp_files(out_dir, is_result_file);
        remove_earlier_results(out_dir)?;
        let manifest = ResultsManifest {
            complete: false,
            frames: ids.to_vec(),
        };
        write_manifest(out_dir, &manifest)?;
        Ok(ResultWriter {
            out_dir: out_dir.to_path_buf(),
            manifest,
            _lock: lock,
        })
    }

    /// Writes frame `id`'s results.
    pub fn write(&mut self, id: &str, objects: &[Object]) -> Result<()> {
        write_objects(&self.out_dir.join(format!("{id}.txt")), objects)?;
        Ok(())
    }

    /// Writes scene `id`'s SUN RGB-D result lines.
    pub fn write_scene(&mut self, id: &str, objects: &[fusiondet_sunrgbd::Object]) -> Result<()> {
        fusiondet_sunrgbd::write_objects(&self.out_dir.join(format!("{id}.txt")), objects)?;
        Ok(())
    }

    /// Marks the directory complete.
    pub fn finish(mut self) -> Result<()> {
        self.manifest.complete = true;
        write_manifest(&self.out_dir, &self.manifest)?;
        Ok(())
    }
}

/// Takes the result directory's writer lock ([`fusiondet_kitti::atomic::lock_dir`]).
fn lock_results(out_dir: &Path, shared: bool) -> Result<DirLock> {
    fusiondet_kitti::atomic::lock_dir(out_dir, shared)
        .map_err(|e| out_err(out_dir, format!("cannot lock the result directory: {e}")))?
        .ok_or_else(|| {
            out_err(
                out_dir,
                "another detect is writing into this directory now; wait for it to end, or \
                 choose another --out",
            )
        })
}

/// The command name in a result directory's shard records.
const DETECT: &str = "detect";

/// Writes one shard's frames of a result directory under its shard record; the shard that
/// finds every shard finished writes the directory's manifest, as an unsharded run's end
/// does, so the directory is then the same as one detect over the whole split would leave.
pub struct ShardWriter {
    out_dir: PathBuf,
    record: ShardRecord,
    /// Shared with the other shards of the run, held until the writer is dropped: an
    /// unsharded detect into the same directory meanwhile is refused.
    _lock: DirLock,
}

impl ShardWriter {
    /// Opens `out_dir` for shard `shard` of run `run`, writing `frames`. The directory may
    /// be new, empty, or hold other shards of the same run (also a re-run of this shard);
    /// anything else of detect's is replaced only with `replace`, anything not detect's
    /// never.
    pub fn begin(
        out_dir: &Path,
        shard: Shard,
        run: String,
        frames: Vec<String>,
        replace: bool,
    ) -> Result<ShardWriter> {
        std::fs::create_dir_all(out_dir)
            .map_err(|e| out_err(out_dir, format!("cannot create the result directory: {e}")))?;
        let writer_lock = lock_results(out_dir, true)?;
        // Shards starting together take turns to look at and prepare the directory.
        let _lock = shard::lock_records(out_dir)?;
        let earlier = shard::run_records(out_dir, DETECT);
        let same_run = matches!(&earlier, Ok(Some(records)) if records[0].run == run);
        if !same_run {
            match earlier {
                Err(e) if !replace => return Err(e.into()),
                Ok(Some(_)) if !replace => {
                    return Err(out_err(
                        out_dir,
                        "holds the shards of another detect run (another model, \
                         configuration, split or shard count); pass --force to replace them, \
                         or choose another --out",
                    ));
                }
                _ => {}
            }
            check_result_dir(out_dir, replace)?;
            fusiondet_kitti::atomic::remove_temp_files(out_dir, is_result_file);
            remove_earlier_results(out_dir)?;
        }
        let record = ShardRecord {
            command: DETECT.to_string(),
            shard,
            run,
            complete: false,
            frames,
        };
        shard::write_record(out_dir, &record)?;
        Ok(ShardWriter {
            out_dir: out_dir.to_path_buf(),
            record,
            _lock: writer_lock,
        })
    }

    /// Writes frame `id`'s results.
    pub fn write(&mut self, id: &str, objects: &[Object]) -> Result<()> {
        write_objects(&self.out_dir.join(format!("{id}.txt")), objects)?;
        Ok(())
    }

    /// Marks this shard finished; if every shard now is, writes the directory's manifest.
    pub fn finish(mut self) -> Result<shard::ShardProgress> {
        self.record.complete = true;
        shard::write_record(&self.out_dir, &self.record)?;
        let _lock = shard::lock_records(&self.out_dir)?;
        complete_sharded_results(&self.out_dir)
    }
}

/// Checks a sharded detect's result directory and, when every shard finished and every
/// listed frame's file is there, writes its manifest (complete, the split's frames in
/// order). Returns how far the shards have got. `fusiondet merge` runs this too.
pub fn complete_sharded_results(out_dir: &Path) -> Result<shard::ShardProgress> {
    let Some(records) = shard::run_records(out_dir, DETECT)? else {
        return Err(out_err(
            out_dir,
            "holds no shard records of `fusiondet detect --shard`",
        ));
    };
    let progress = shard::progress(out_dir, &records, &|id| PathBuf::from(format!("{id}.txt")));
    if progress.is_whole() {
        let frames = shard::interleave(&records).ok_or_else(|| {
            out_err(
                out_dir,
                "its shard records do not split one list (a record was edited?); run the \
                 shards again with --force",
            )
        })?;
        let manifest = ResultsManifest {
            complete: true,
            frames,
        };
        if read_manifest(out_dir)?.as_ref() != Some(&manifest) {
            write_manifest(out_dir, &manifest)?;
        }
    }
    Ok(progress)
}

/// Whether `name` is one of detect's own files in a result directory: a frame's result
/// (`NNNNNN.txt`) or the manifest.
fn is_result_file(name: &str) -> bool {
    let frame = name
        .strip_suffix(".txt")
        .is_some_and(|id| id.len() == 6 && id.bytes().all(|b| b.is_ascii_digit()));
    frame || name == fusiondet_kitti::results::MANIFEST_FILE
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn shards_share_a_directory_only_with_their_own_run() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("results");
        let split = ids(&["000001", "000002", "000003"]);
        let shard = |i| Shard { index: i, count: 2 };
        let mut w = ShardWriter::begin(
            &out,
            shard(0),
            "run-a".into(),
            shard(0).select(&split),
            false,
        )
        .unwrap();
        w.write("000001", &[]).unwrap();
        w.write("000003", &[]).unwrap();
        let p = w.finish().unwrap();
        assert_eq!(p.missing_shards, vec![1]);
        assert!(
            read_manifest(&out).unwrap().is_none(),
            "no manifest before the last shard"
        );
        // Another run's shard, or an unsharded detect, is refused without --force ...
        let err = ShardWriter::begin(&out, shard(1), "run-b".into(), vec![], false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("shards of another detect run"), "{err}");
        let err = ResultWriter::begin(&out, &split, false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("sharded detect"), "{err}");
        // ... the run's own second shard completes the directory ...
        let mut w = ShardWriter::begin(
            &out,
            shard(1),
            "run-a".into(),
            shard(1).select(&split),
            false,
        )
        .unwrap();
        w.write("000002", &[]).unwrap();
        assert!(w.finish().unwrap().is_whole());
        let manifest = read_manifest(&out).unwrap().unwrap();
        assert!(manifest.complete);
        assert_eq!(manifest.frames, split);
        // ... and --force replaces all of it: files, records and manifest.
        let mut w =
            ShardWriter::begin(&out, Shard::ALL, "run-b".into(), ids(&["000009"]), true).unwrap();
        assert!(!out.join("000001.txt").exists() && read_manifest(&out).unwrap().is_none());
        assert_eq!(shard::read_records(&out).unwrap().len(), 1);
        w.write("000009", &[]).unwrap();
        assert!(w.finish().unwrap().is_whole());
    }

    #[test]
    fn a_result_directory_is_replaced_only_where_it_is_detects_own() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("results");
        let mut w = ResultWriter::begin(&out, &ids(&["000001", "000002"]), false).unwrap();
        w.write("000001", &[]).unwrap();
        // Killed here: the directory is unfinished, with a temporary file left behind.
        drop(w);
        let stale = out.join(".000002.txt.k3Jx9a.tmp");
        std::fs::write(&stale, "partial").unwrap();
        let users = out.join("notes.md");
        std::fs::write(&users, "mine").unwrap();
        // An unfinished detect's directory is replaced without being told.
        let mut w = ResultWriter::begin(&out, &ids(&["000003"]), false).unwrap();
        assert!(!stale.exists() && !out.join("000001.txt").exists());
        assert!(users.is_file(), "only detect's own files are removed");
        w.write("000003", &[]).unwrap();
        w.finish().unwrap();
        let manifest = read_manifest(&out).unwrap().unwrap();
        assert!(manifest.complete);
        assert_eq!(manifest.frames, ids(&["000003"]));
        // A finished one only with `replace`.
        let err = ResultWriter::begin(&out, &ids(&["000004"]), false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("pass --force"), "{err}");
        assert!(ResultWriter::begin(&out, &ids(&["000004"]), true).is_ok());
        assert!(!out.join("000003.txt").exists());
    }
}
