//! Detection dispatched on the checkpoint's family: load the checkpoint (its family
//! checked against the configuration's), read the split in the family's form, run the
//! family's detector chunk by chunk, write one result file per frame through
//! [`crate::result_dir`]. The families sit below this module and import nothing from it.

use crate::config::ExperimentConfig;
use crate::dasanet::DasanetDetector;
use crate::device::ComputeDevice;
use crate::error::{PipelineError, Result};
use crate::frustum::FrustumDetector;
use crate::voxel_rcnn::VoxelRcnnDetector;
use burn::prelude::*;
use fusiondet_dataset::SensorFrame;
use fusiondet_frustum::{FrameSource, InMemoryFrames};
use fusiondet_kitti::shard;
use fusiondet_kitti::{DatasetDir, Detection2d, Object, Shard, read_detections2d};
use fusiondet_models::DetectorKind;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use crate::detection::{DetectOptions, DetectSummary, FrameResults, StageTimes};
pub use crate::result_dir::{ResultWriter, ShardWriter, complete_sharded_results};
use crate::result_dir::{check_result_dir, refuse_input_dir};

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
            Detector::Frustum(_) => match detections {
                Some(path) => read_detections2d(path)?,
                None => {
                    let path = DatasetDir::new(data_dir).rgb_detections(split);
                    if !path.exists() {
                        return Err(PipelineError::Invalid(format!(
                            "a frustum model needs 2D detections, and {} does not exist: pass \
                             --detections FILE (F-PointNet's format, one box a line: `<image \
                             path> <type: 1 Pedestrian, 2 Car, 3 Cyclist> <score> <x1> <y1> \
                             <x2> <y2>`), or put the file there (README, \"Your own KITTI\")",
                            path.display()
                        )));
                    }
                    read_detections2d(&path)?
                }
            },
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
        // The networks run on the compute pool (see `compute_pool`).
        crate::compute_pool::install(|| self.detect_here(device, inputs, timing))
    }

    fn detect_here(
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
    // A bad FUSIONDET_PREPARE_THREADS or FUSIONDET_STAGE_ONE_AHEAD is refused before the
    // result directory is made.
    crate::prefetch::preparers(&device).map_err(PipelineError::Invalid)?;
    crate::prefetch::stage_one_ahead().map_err(PipelineError::Invalid)?;
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

    let progress = frames_bar(ids.len());
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
        progress.inc(chunk.len() as u64);
    }
    progress.finish_and_clear();
    summary.shards = writer.finish()?;
    Ok(summary)
}

/// A bar of frames detected on stderr, drawn only where stderr is a terminal (a log file
/// gets the summary lines alone). Advances a chunk at a time.
pub fn frames_bar(frames: usize) -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    if !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "detect [{bar:30}] {pos}/{len} frames {elapsed}<{eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar.tick();
    bar
}

/// What defines a sharded detect run, so that shards of different runs never share a
/// result directory: the weights, the configuration, the split, what its frames' files
/// are ([`shard::frames_summary`]) and its 2D detections,
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
    let frames_summary = shard::frames_summary(
        &fusiondet_kitti::FrameDir::new(options.data_dir.join("training")),
        split_ids,
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
