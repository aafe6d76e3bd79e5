//! The experiment configuration: one TOML file naming the detector family
//! (`[detector] kind`, required) and the data (`[dataset]`: format and classes), then
//! the family's sections — for the frustum family the frustum data set (`[frustum]`),
//! the network (`[model]`), its loss (`[loss]`) — and training (`[train]`) and
//! detection (`[detect]`) settings. Every other key has the published F-ConvNet Car
//! value as default; unknown keys are errors, so a typo never goes unnoticed. This is
//! the one parser every command uses.

use crate::dasanet::DasanetSection;
use crate::error::{PipelineError, Result};
use crate::schedule::{OneCycle, StepDecay};
use crate::voxel_rcnn::VoxelRcnnSection;
use fusiondet_dataset::{Class, ClassSet};
use fusiondet_frustum::{BoxCoder, FrustumConfig};
use fusiondet_kitti::ObjectClass;
use fusiondet_models::{DetectorKind, FConvNetConfig, LossConfig, ModelConfig};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExperimentConfig {
    /// A name for logs and result headers.
    pub name: String,
    /// `[detector] kind`: the family. Required: a file that does not say what it
    /// configures is refused rather than read as F-ConvNet Car.
    #[serde(default)]
    pub detector: Option<DetectorSection>,
    /// `[dataset]`: the data's format and the classes the detector learns.
    pub dataset: DatasetSection,
    /// The frustum data set; its `classes` come from `[dataset] classes`.
    pub frustum: FrustumConfig,
    pub model: ModelConfig,
    pub loss: LossConfig,
    pub train: TrainConfig,
    pub detect: DetectConfig,
    /// Set for F-ConvNet's refinement stage (with `frustum.proposal_crop`): the model
    /// whose boxes this one refines.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refine: Option<RefineConfig>,
    /// The voxel family's sections (`kind = "voxel_rcnn"` only; filled with the
    /// published values when the file has none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub voxel_rcnn: Option<VoxelRcnnSection>,
    /// What DASANet adds to Voxel R-CNN (`kind = "dasanet"` only, whose LiDAR branch,
    /// BEV network, anchors, heads and data `[voxel_rcnn]` configures).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dasanet: Option<DasanetSection>,
}

/// `[detector]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorSection {
    pub kind: DetectorKind,
}

/// The on-disk formats a data set can come in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetFormat {
    /// KITTI's object-benchmark layout (`training/{velodyne,calib,image_2,label_2}`,
    /// `ImageSets/`), which the simulator also writes.
    #[default]
    Kitti,
    /// The prepared SUN RGB-D layout (`points/`, `calib/`, `label/`, `det_2d/`,
    /// `splits/`; see `fusiondet_sunrgbd`), which `simulate --indoor` also writes. Frustum
    /// detectors only; results are SUN RGB-D result files in upright depth.
    SunRgbd,
}

impl DatasetFormat {
    /// The classes a detector of this format's data can learn (one-hot slots and size
    /// clusters).
    pub fn class_set(self) -> ClassSet {
        match self {
            DatasetFormat::Kitti => ClassSet::kitti(),
            DatasetFormat::SunRgbd => ClassSet::sun_rgbd(),
        }
    }

    /// A class name as this format spells it.
    pub fn parse_class(self, name: &str) -> std::result::Result<Class, String> {
        match self {
            DatasetFormat::Kitti => name.parse::<ObjectClass>().map(Class::Kitti),
            DatasetFormat::SunRgbd => fusiondet_sunrgbd::SunClass::parse(name)
                .map(Class::SunRgbd)
                .ok_or_else(|| {
                    format!(
                        "unknown class `{name}` (SUN RGB-D's are {})",
                        ClassSet::sun_rgbd().names().join(", ")
                    )
                }),
        }
    }
}

/// `[dataset]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DatasetSection {
    pub format: DatasetFormat,
    /// The classes the detector learns, as the format spells them (KITTI: `["Car"]`,
    /// `["Pedestrian", "Cyclist"]`).
    pub classes: Vec<String>,
}

impl Default for DatasetSection {
    fn default() -> Self {
        DatasetSection {
            format: DatasetFormat::Kitti,
            classes: vec!["Car".into()],
        }
    }
}

/// The first stage of a refinement model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefineConfig {
    /// The first-stage checkpoint; its configuration is found as for `detect`
    /// (`<name>.toml` beside it, else the run's `config.toml`). A relative path is
    /// relative to the directory of the file that names it.
    pub first_stage: PathBuf,
}

/// Training as published for F-ConvNet: Adam, lr 1e-3, weight decay 1e-4, batch 32,
/// lr × 0.1 at epoch 20 of 50.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Seeds weight initialisation, 2D-box jitter, sampling, augmentation and order.
    pub seed: u64,
    pub epochs: usize,
    pub batch_size: usize,
    pub lr: StepDecay,
    pub weight_decay: f64,
    /// The split (an `ImageSets/*.txt` name) to train on.
    pub split: String,
    /// Use at most this many frames of the split (in split order); 0 uses all.
    pub max_frames: usize,
    /// Adam (L2 weight decay, the frustum detectors) or AdamW (decoupled weight decay,
    /// OpenPCDet's `adam_onecycle`).
    pub optimizer: OptimizerKind,
    /// A per-step one-cycle schedule instead of `lr`'s per-epoch steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub one_cycle: Option<OneCycle>,
    /// Clip gradients to this L2 norm, per `grad_clip_scope`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub grad_clip_norm: Option<f64>,
    /// What `grad_clip_norm` bounds: each parameter tensor's gradient (`per_parameter`,
    /// burn's clipping; the default, which the shipped voxel models trained with) or the
    /// norm of all gradients together (`global`, OpenPCDet's `clip_grad_norm_`).
    #[serde(skip_serializing_if = "GradClipScope::is_per_parameter")]
    pub grad_clip_scope: GradClipScope,
}

/// Where gradient clipping applies (`[train] grad_clip_scope`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GradClipScope {
    #[default]
    PerParameter,
    Global,
}

impl GradClipScope {
    fn is_per_parameter(&self) -> bool {
        *self == GradClipScope::PerParameter
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OptimizerKind {
    #[default]
    Adam,
    AdamW,
}

impl TrainConfig {
    /// The rate of step `step` (0-based) of epoch `epoch`, of `steps_per_epoch`.
    pub fn lr_at(&self, epoch: usize, step: usize, steps_per_epoch: usize) -> f64 {
        match &self.one_cycle {
            Some(c) => c.lr_at(
                epoch * steps_per_epoch + step,
                self.epochs * steps_per_epoch,
            ),
            None => self.lr.lr_at(epoch),
        }
    }

    /// OpenPCDet's Voxel R-CNN training: AdamW with one-cycle (max 0.01), weight decay
    /// 0.01, batch 2, 80 epochs, gradient clipping at 10.
    pub fn voxel_rcnn() -> TrainConfig {
        TrainConfig {
            epochs: 80,
            batch_size: 2,
            weight_decay: 0.01,
            optimizer: OptimizerKind::AdamW,
            one_cycle: Some(OneCycle::voxel_rcnn()),
            grad_clip_norm: Some(10.0),
            ..TrainConfig::default()
        }
    }
}

/// Test-time settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectConfig {
    /// 3D NMS IoU threshold across a frame's frustums (F-ConvNet: 0.1).
    pub nms_iou: f64,
    /// Frustums per forward pass.
    pub batch_size: usize,
    /// Seeds the point sampling of test frustums.
    pub seed: u64,
    /// Points sampled per test frustum when not `frustum.points_per_frustum` (a speed /
    /// accuracy knob: the PointNets' work is proportional to it). Not for LFA models,
    /// whose point count is part of the architecture.
    pub points_per_frustum: Option<usize>,
}

impl Default for ExperimentConfig {
    fn default() -> Self {
        ExperimentConfig {
            name: "fconvnet-car".into(),
            detector: Some(DetectorSection {
                kind: DetectorKind::Frustum,
            }),
            dataset: DatasetSection::default(),
            frustum: FrustumConfig::car(),
            model: ModelConfig::car(),
            loss: LossConfig::default(),
            train: TrainConfig::default(),
            detect: DetectConfig::default(),
            refine: None,
            voxel_rcnn: None,
            dasanet: None,
        }
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            seed: 1,
            epochs: 50,
            batch_size: 32,
            lr: StepDecay {
                base_lr: 1e-3,
                factor: 0.1,
                milestones: vec![20],
                every: None,
            },
            weight_decay: 1e-4,
            split: "train".into(),
            max_frames: 0,
            optimizer: OptimizerKind::Adam,
            one_cycle: None,
            grad_clip_norm: None,
            grad_clip_scope: GradClipScope::PerParameter,
        }
    }
}

impl Default for DetectConfig {
    fn default() -> Self {
        DetectConfig {
            nms_iou: 0.1,
            batch_size: 32,
            seed: 7,
            points_per_frustum: None,
        }
    }
}

impl ExperimentConfig {
    /// Parses and validates `text`, read from `path` (relative paths in it are
    /// resolved against `path`'s directory).
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self> {
        let config_err = |message: String| PipelineError::Config {
            path: path.to_path_buf(),
            message,
        };
        let mut config: ExperimentConfig =
            toml::from_str(text).map_err(|e| config_err(e.to_string()))?;
        let raw: toml::Table = toml::from_str(text).map_err(|e| config_err(e.to_string()))?;
        let kind = config.kind();
        if kind != DetectorKind::Dasanet && raw.contains_key("dasanet") {
            return Err(config_err(format!(
                "[dasanet] configures a dasanet detector, but [detector] kind is \"{kind}\""
            )));
        }
        match kind {
            DetectorKind::VoxelRcnn | DetectorKind::Dasanet => {
                for section in ["frustum", "model", "loss", "refine"] {
                    if raw.contains_key(section) {
                        return Err(config_err(format!(
                            "[{section}] configures the frustum family; a {kind} \
                             detector is configured in [voxel_rcnn] (remove [{section}])"
                        )));
                    }
                }
                if kind == DetectorKind::Dasanet {
                    config.dasanet.get_or_insert_with(DasanetSection::default);
                }
                // The family's own training defaults, overlaid with the file's keys.
                let mut train = toml::Table::try_from(TrainConfig::voxel_rcnn())
                    .expect("the training configuration serialises");
                if let Some(given) = raw.get("train").and_then(|t| t.as_table()) {
                    train.extend(given.clone());
                }
                config.train = train
                    .try_into()
                    .map_err(|e: toml::de::Error| config_err(format!("[train] {e}")))?;
                config
                    .voxel_rcnn
                    .get_or_insert_with(VoxelRcnnSection::default);
            }
            DetectorKind::Frustum => {
                if raw.contains_key("voxel_rcnn") {
                    return Err(config_err(
                        "[voxel_rcnn] configures a voxel_rcnn detector, but [detector] kind is \
                         \"frustum\""
                            .into(),
                    ));
                }
            }
        }
        if config.detector.is_none() {
            return Err(config_err(
                "no [detector] table: name the family, e.g. `[detector]` then \
                 `kind = \"frustum\"` (configurations written before families existed: \
                 also move `[frustum] classes` to `[dataset] classes`)"
                    .into(),
            ));
        }
        // The classes live in [dataset]; the frustum data set takes them from there.
        if raw
            .get("frustum")
            .and_then(|f| f.as_table())
            .is_some_and(|f| f.contains_key("classes"))
        {
            return Err(config_err(
                "[frustum] classes: the classes are a property of the data; write them as \
                 `[dataset] classes = [...]`"
                    .into(),
            ));
        }
        config.frustum.classes = config
            .dataset
            .classes
            .iter()
            .map(|name| config.dataset.format.parse_class(name))
            .collect::<std::result::Result<_, _>>()
            .map_err(|m| config_err(format!("[dataset] classes: {m}")))?;
        // One box coder for targets, loss and decoding: the network's heading bins and
        // the format's class set.
        config.frustum.coder = BoxCoder::new(
            config.model.num_heading_bins,
            config.dataset.format.class_set(),
        )
        .map_err(|m| config_err(format!("[model] num_heading_bins: {m}")))?;
        // Another format's network takes its one-hot length and size clusters from the
        // class set unless the file gives them (KITTI's defaults are F-ConvNet's own).
        if config.dataset.format != DatasetFormat::Kitti {
            let model = raw.get("model").and_then(|m| m.as_table());
            let given = |key: &str| model.is_some_and(|m| m.contains_key(key));
            if !given("num_classes") {
                config.model.num_classes = config.frustum.coder.num_clusters();
            }
            if !given("size_clusters") {
                config.model.size_clusters = config.frustum.coder.mean_sizes_f32();
            }
        }
        if let Some(r) = &mut config.refine
            && r.first_stage.is_relative()
        {
            let dir = path.parent().unwrap_or(Path::new(""));
            r.first_stage = dir.join(&r.first_stage);
        }
        config.validate(path).map_err(|e| at_line(e, text))?;
        Ok(config)
    }

    /// The configuration that belongs to a checkpoint: `explicit` if given, else
    /// `<checkpoint>.toml` (a shipped model), else `config.toml` beside it (a run).
    pub fn for_checkpoint(checkpoint: &Path, explicit: Option<&Path>) -> Result<Self> {
        // The checkpoint first: a missing or foreign file is the mistake to name, not the
        // configuration that would be looked for beside it.
        fusiondet_models::read_checkpoint_kind(checkpoint)?;
        if let Some(path) = explicit {
            return Self::from_file(path);
        }
        let beside = checkpoint.with_extension("toml");
        let run_config = checkpoint.parent().map(|d| d.join("config.toml"));
        for candidate in [Some(beside), run_config].into_iter().flatten() {
            if candidate.is_file() {
                return Self::from_file(&candidate);
            }
        }
        Err(PipelineError::Config {
            path: checkpoint.with_extension("toml"),
            message: format!(
                "no configuration found for {}: pass --config, or keep the run's config.toml \
                 (or <name>.toml) beside it",
                checkpoint.display()
            ),
        })
    }

    pub fn from_file(path: &Path) -> Result<Self> {
        // Read as every reader reads (a pipe or device is refused, not waited on); the
        // error names the file.
        let text = fusiondet_kitti::error::read_text(path)?;
        Self::from_toml_str(&text, path)
    }

    /// The file form: what [`ExperimentConfig::from_toml_str`] reads back (the classes
    /// in `[dataset]` only).
    pub fn to_toml_string(&self) -> String {
        let mut table =
            toml::Table::try_from(self).expect("the experiment configuration serialises");
        if let Some(frustum) = table.get_mut("frustum").and_then(|f| f.as_table_mut()) {
            frustum.remove("classes");
        }
        if self.kind() != DetectorKind::Frustum {
            // The frustum family's sections do not apply (and are refused on reading).
            for section in ["frustum", "model", "loss"] {
                table.remove(section);
            }
        }
        toml::to_string_pretty(&table).expect("the experiment configuration serialises")
    }

    /// The family this configuration is for.
    pub fn kind(&self) -> DetectorKind {
        self.detector
            .as_ref()
            .map_or(DetectorKind::Frustum, |d| d.kind)
    }

    /// The same configuration with another test-time point count, validated.
    pub fn with_test_points(mut self, points: Option<usize>) -> Result<Self> {
        self.detect.points_per_frustum = points;
        self.validate(Path::new("--points"))?;
        Ok(self)
    }

    /// The frustum settings detection uses (the training ones, with the test point count).
    pub fn detect_frustum(&self) -> FrustumConfig {
        FrustumConfig {
            points_per_frustum: self
                .detect
                .points_per_frustum
                .unwrap_or(self.frustum.points_per_frustum),
            ..self.frustum.clone()
        }
    }

    /// The network + loss part, as the models crate takes it.
    pub fn network(&self) -> FConvNetConfig {
        FConvNetConfig {
            model: self.model.clone(),
            loss: self.loss.clone(),
        }
    }

    /// Checks every constraint across sections; `path` names the source in errors.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let bad = |message: String| {
            Err(PipelineError::Config {
                path: path.to_path_buf(),
                message,
            })
        };
        self.frustum.validate().map_err(|e| PipelineError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        self.model.validate().map_err(|e| PipelineError::Config {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        self.loss.validate().map_err(|e| PipelineError::Config {
            path: path.to_path_buf(),
            message: format!("[loss] {e}"),
        })?;
        if self.train.epochs == 0 {
            return bad(
                "train.epochs (--epochs) must be at least 1 (0 would train nothing and name a \
                 model that was never written)"
                    .into(),
            );
        }
        if self.train.batch_size == 0 {
            return bad("train.batch_size must be at least 1".into());
        }
        if self.detect.batch_size == 0 {
            return bad("detect.batch_size must be at least 1".into());
        }
        // NaN fails every range test below, so it is refused with the key's range.
        let lr = &self.train.lr;
        if !(lr.base_lr > 0.0 && lr.base_lr <= 10.0) {
            return bad(format!(
                "train.lr.base_lr must be in (0, 10], not {}",
                lr.base_lr
            ));
        }
        if !(lr.factor > 0.0 && lr.factor <= 1.0) {
            return bad(format!(
                "train.lr.factor must be in (0, 1], not {}",
                lr.factor
            ));
        }
        if !(0.0..=1.0).contains(&self.train.weight_decay) {
            return bad(format!(
                "train.weight_decay must be in [0, 1], not {}",
                self.train.weight_decay
            ));
        }
        if let Some(c) = &self.train.one_cycle {
            c.validate().map_err(|m| PipelineError::Config {
                path: path.to_path_buf(),
                message: m,
            })?;
        }
        if self
            .train
            .grad_clip_norm
            .is_some_and(|n| n.is_nan() || n <= 0.0)
        {
            return bad("train.grad_clip_norm must be positive".into());
        }
        if let Some(d) = &self.dasanet {
            d.validate().map_err(|m| PipelineError::Config {
                path: path.to_path_buf(),
                message: m,
            })?;
        }
        if let Some(v) = &self.voxel_rcnn {
            v.validate().map_err(|m| PipelineError::Config {
                path: path.to_path_buf(),
                message: m,
            })?;
            if self.dataset.classes.len() != v.anchors.classes.len()
                || self
                    .dataset
                    .classes
                    .iter()
                    .zip(&v.anchors.classes)
                    .any(|(name, a)| *name != a.class.to_string())
            {
                return bad(format!(
                    "[dataset] classes {:?} must be the classes of [voxel_rcnn.anchors], in order",
                    self.dataset.classes
                ));
            }
        }
        if self.dataset.format == DatasetFormat::SunRgbd {
            if self.kind() != DetectorKind::Frustum {
                return bad(format!(
                    "[dataset] format = \"sun_rgbd\" is read by frustum detectors only, not {}",
                    self.kind()
                ));
            }
            if self.refine.is_some() {
                return bad(
                    "[refine]: a refinement stage is KITTI-only for now; SUN RGB-D models are \
                     one stage"
                        .into(),
                );
            }
        }
        if self.train.lr.base_lr.is_nan() || self.train.lr.base_lr <= 0.0 {
            return bad("train.lr.base_lr must be positive".into());
        }
        if !(0.0..1.0).contains(&self.detect.nms_iou) {
            return bad("detect.nms_iou must be in [0, 1)".into());
        }
        if let Some(n) = self.detect.points_per_frustum {
            if n == 0 {
                return bad("detect.points_per_frustum must be at least 1".into());
            }
            if self.model.lfa.is_some() {
                return bad(
                    "detect.points_per_frustum cannot change the point count of an LFA model \
                     (its halvings fix it); remove it"
                        .into(),
                );
            }
        }
        let coder = &self.frustum.coder;
        if coder.heading_bins() != self.model.num_heading_bins {
            return bad(format!(
                "the frustum targets' box coder has {} heading bins, model.num_heading_bins {}; \
                 build the coder from the model (configurations read from files always are)",
                coder.heading_bins(),
                self.model.num_heading_bins
            ));
        }
        if self.model.num_classes != coder.num_clusters() {
            return bad(format!(
                "model.num_classes is {}, but the {} class set has {} classes ({}); remove the \
                 key or make it {}",
                self.model.num_classes,
                coder.classes().name,
                coder.num_clusters(),
                coder.classes().names().join(", "),
                coder.num_clusters()
            ));
        }
        // The network's f32 clusters must be the coder's means to f32 precision (the
        // shipped models store F-ConvNet's own rounding, within 1e-6 of them).
        let agree = self.model.size_clusters.len() == coder.num_clusters()
            && (0..coder.num_clusters()).all(|k| {
                (0..3).all(|d| {
                    let mean = coder.mean_size(k)[d];
                    (self.model.size_clusters[k][d] as f64 - mean).abs() <= 1e-6 * mean
                })
            });
        if !agree {
            return bad(format!(
                "model.size_clusters {:?} differ from the mean sizes of the {} class set \
                 ({:?}), which the targets and the decoding use; remove the key",
                self.model.size_clusters,
                coder.classes().name,
                coder.mean_sizes_f32()
            ));
        }
        match (&self.refine, &self.frustum.proposal_crop) {
            (Some(_), None) => {
                return bad(
                    "[refine] needs [frustum.proposal_crop]: a refinement stage cuts its \
                     frustums around the first stage's boxes"
                        .into(),
                );
            }
            (None, Some(_)) => {
                return bad(
                    "[frustum.proposal_crop] needs [refine] first_stage = \"<checkpoint>\": \
                     the model whose boxes are refined"
                        .into(),
                );
            }
            _ => {}
        }
        if let Some(lfa) = &self.model.lfa {
            let n = self.frustum.points_per_frustum;
            let survivors = n >> lfa.stages.len();
            if !n.is_multiple_of(1 << lfa.stages.len()) || self.frustum.sliced_points != survivors {
                return bad(format!(
                    "model.lfa halves the frustum's points {} times: frustum.points_per_frustum \
                     ({n}) must be divisible by {} and frustum.sliced_points ({}) must equal the \
                     survivors, {survivors}",
                    lfa.stages.len(),
                    1 << lfa.stages.len(),
                    self.frustum.sliced_points
                ));
            }
        }
        Ok(())
    }
}

/// `text` with the `[detector]` table every configuration needs, for tests.
/// A validation error of a configuration file pointed at the line that sets the key it
/// names (the first key named in the message that the file sets), when there is one.
fn at_line(err: PipelineError, text: &str) -> PipelineError {
    let PipelineError::Config { path, message } = err else {
        return err;
    };
    match key_line(text, &message) {
        Some(line) => PipelineError::ConfigAt {
            path,
            line,
            message,
        },
        None => PipelineError::Config { path, message },
    }
}

/// The 1-based line of `text` that sets the first key `message` names: the words of the
/// message made of letters, digits, `_` and `.` (`train.epochs`, `depth_range`) are tried
/// in order, each by its last dotted part, against `key =` at the start of a line or inside
/// an inline table.
fn key_line(text: &str, message: &str) -> Option<usize> {
    let words = message
        .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '.'))
        .filter(|w| w.contains('_') || w.contains('.'));
    for word in words {
        let key = word.trim_matches('.').rsplit('.').next().unwrap_or(word);
        if key.is_empty() || !key.contains('_') && !word.contains('.') {
            continue;
        }
        let sets = |line: &str| {
            let code = line.split('#').next().unwrap_or("");
            code.match_indices(key).any(|(i, _)| {
                let before = code[..i].trim_end();
                let after = code[i + key.len()..].trim_start();
                (before.is_empty() || before.ends_with('{') || before.ends_with(','))
                    && after.starts_with('=')
            })
        };
        if let Some(i) = text.lines().position(sets) {
            return Some(i + 1);
        }
    }
    None
}

#[cfg(test)]
fn with_kind(text: &str) -> String {
    format!("[detector]\nkind = \"frustum\"\n{text}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_must_name_its_family_and_keep_classes_in_dataset() {
        let err = ExperimentConfig::from_toml_str("", Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("x.toml") && err.contains("[detector]"),
            "{err}"
        );
        let err =
            ExperimentConfig::from_toml_str("[detector]\nkind = \"voxel\"\n", Path::new("x.toml"))
                .unwrap_err()
                .to_string();
        assert!(err.contains("voxel") && err.contains("frustum"), "{err}");
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[frustum]\nclasses = [\"Car\"]\n"),
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("[dataset] classes"), "{err}");
        let c = ExperimentConfig::from_toml_str(
            &with_kind("[dataset]\nclasses = [\"Pedestrian\", \"Cyclist\"]\n"),
            Path::new("x.toml"),
        )
        .unwrap();
        assert_eq!(
            c.frustum.classes,
            [ObjectClass::Pedestrian.into(), ObjectClass::Cyclist.into()]
        );
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[dataset]\nclasses = [\"Bus\"]\n"),
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("[dataset] classes") && err.contains("Bus"),
            "{err}"
        );
    }

    #[test]
    fn the_box_coder_follows_the_network_and_the_class_set() {
        let c = ExperimentConfig::from_toml_str(
            &with_kind("[model]\nnum_heading_bins = 8\n"),
            Path::new("x.toml"),
        )
        .unwrap();
        assert_eq!(c.frustum.coder.heading_bins(), 8);
        assert_eq!(
            c.frustum.coder.classes().names(),
            ["Car", "Pedestrian", "Cyclist"]
        );
        let err = ExperimentConfig::from_toml_str(
            &with_kind(
                "[model]\nsize_clusters = [[4.0, 1.6, 1.5], [0.8, 0.7, 1.8], [1.8, 0.6, 1.7]]\n",
            ),
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("size_clusters") && err.contains("KITTI"),
            "{err}"
        );
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[model]\nnum_classes = 4\n"),
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("num_classes") && err.contains("Cyclist"),
            "{err}"
        );
        // A configuration built in code must keep the two in step.
        let mut c = ExperimentConfig::default();
        c.model.num_heading_bins = 8;
        let err = c.validate(Path::new("built")).unwrap_err().to_string();
        assert!(err.contains("heading bins"), "{err}");
    }

    #[test]
    fn a_bare_frustum_detector_is_the_published_car_configuration() {
        let c = ExperimentConfig::from_toml_str(
            "[detector]\nkind = \"frustum\"\n",
            Path::new("x.toml"),
        )
        .unwrap();
        assert_eq!(c, ExperimentConfig::default());
        assert_eq!(c.train.batch_size, 32);
        assert_eq!(c.detect.nms_iou, 0.1);
    }

    #[test]
    fn round_trips_through_toml() {
        let c = ExperimentConfig::default();
        let back =
            ExperimentConfig::from_toml_str(&c.to_toml_string(), Path::new("x.toml")).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn typos_and_bad_values_are_named() {
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[train]\nepochz = 3\n"),
            Path::new("c.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("c.toml") && err.contains("epochz"), "{err}");
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[model.lfa]\nfeature_gate = \"one\"\n"),
            Path::new("c.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("c.toml") && err.contains("feature_gate") && err.contains("zero"),
            "{err}"
        );
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[train]\nbatch_size = 0\n"),
            Path::new("c.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("batch_size"), "{err}");
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[train]\nepochs = 0\n"),
            Path::new("c.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("train.epochs (--epochs) must be at least 1"),
            "{err}"
        );
        for (key, value, says) in [
            (
                "weight_decay",
                "nan",
                "train.weight_decay must be in [0, 1], not NaN",
            ),
            (
                "weight_decay",
                "-0.1",
                "train.weight_decay must be in [0, 1]",
            ),
        ] {
            let err = ExperimentConfig::from_toml_str(
                &with_kind(&format!("[train]\n{key} = {value}\n")),
                Path::new("c.toml"),
            )
            .unwrap_err()
            .to_string();
            assert!(err.contains(says), "{err}");
        }
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[train.lr]\nbase_lr = inf\nfactor = 0.1\n"),
            Path::new("c.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("train.lr.base_lr must be in (0, 10], not inf"),
            "{err}"
        );
        // Values no real model uses, at the line that sets them.
        for (toml, says) in [
            (
                "[loss]\nfocal_gamma = 1e19\n",
                "c.toml:4: [loss] focal_gamma must be in [0, 10]",
            ),
            (
                "[frustum]\ndepth_range = [0.0, 1e300]\n",
                "c.toml:4: frustum config: `depth_range` [0e0, 1e300] must lie within ±500 m",
            ),
            (
                "[frustum]\npoints_per_frustum = 100000000\n",
                "c.toml:4: frustum config: `points_per_frustum` must be in [1, 65536]",
            ),
            (
                "[frustum.augment]\ncopies = 1000000\n",
                "c.toml:4: frustum config: `augment.copies` must be in [1, 1000]",
            ),
            (
                "[model]\ndeconv_channels = 10000000\n",
                "c.toml:4: invalid model configuration: deconv_channels: at most 4096 channels a layer",
            ),
            (
                "[train]\nepochs = 0\n",
                "c.toml:4: train.epochs (--epochs) must be at least 1",
            ),
        ] {
            let err = ExperimentConfig::from_toml_str(&with_kind(toml), Path::new("c.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(says), "{toml}: {err}");
        }
    }
}

#[cfg(test)]
mod size_ranges {
    use super::*;

    /// Sizes that would make an allocation fail (the process aborting) or a value no
    /// schedule can use are refused with their key, before anything is allocated.
    #[test]
    fn voxel_family_sizes_are_bounded_before_allocation() {
        let level = |samples: &str, radius: &str| {
            format!(
                "[[voxel_rcnn.network.roi.levels]]\nstage = 2\nmid_channels = 32\n\
                 out_channels = 32\nquery_range = [4, 4, 4]\nradius = {radius}\n\
                 samples = {samples}\n"
            )
        };
        for (kind, toml, says) in [
            (
                "voxel_rcnn",
                "[voxel_rcnn.network.roi]\ngrid_size = 100000\n".to_string(),
                "grid_size 100000 must be at most 32",
            ),
            (
                "voxel_rcnn",
                "[voxel_rcnn.roi_targets]\nrois_per_frame = 1000000000\n".to_string(),
                "`rois_per_frame` 1000000000 must be in 1..=4096",
            ),
            (
                "voxel_rcnn",
                "[voxel_rcnn.voxels]\nvoxel_size = [1e-4, 1e-4, 1e-4]\n".to_string(),
                "at most 8192 are allowed",
            ),
            (
                "voxel_rcnn",
                level("1000000000", "0.4"),
                "samples at most 1024",
            ),
            ("voxel_rcnn", level("16", "nan"), "radius NaN"),
            (
                "dasanet",
                "[dasanet.modules.stca_shape]\ngrid = 100000\n".to_string(),
                "grid must be in 2..=32",
            ),
            (
                "voxel_rcnn",
                "[train]\none_cycle = { max_lr = 1e30, div_factor = 10.0, pct_start = 0.4 }\n"
                    .to_string(),
                "max_lr in (0, 10]",
            ),
        ] {
            let text = format!("[detector]\nkind = \"{kind}\"\n{toml}");
            let err = ExperimentConfig::from_toml_str(&text, Path::new("c.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(says), "{toml}: {err}");
        }
    }
}

#[cfg(test)]
mod shipped_configs {
    use super::with_kind;
    use super::*;
    use fusiondet_models::ModelConfig;

    fn load(name: &str) -> ExperimentConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs")
            .join(name);
        ExperimentConfig::from_file(&path).unwrap()
    }

    /// SAF's module rows at full size (docs/frustum.md): each row is the shipped
    /// baseline's file with only its modules' keys changed (slicing: `[frustum.slicing]`
    /// and the depth range it divides; LFA: `[model.lfa]` at the paper's size and the
    /// 4,096 points it halves to the 1,024 sliced; PL: `loss.projection_weight`), so the
    /// rows share the baseline's data, schedule and budget. The full row is the shipped
    /// SAF's recipe with only LFA's widths changed, and the twice-budget pair is the
    /// baseline and the full row with the copies per object doubled.
    #[test]
    fn the_saf_module_rows_differ_only_in_the_modules() {
        use fusiondet_frustum::Slicing;
        use fusiondet_models::{CoordinateInit, LfaConfig, LfaFeatureGate};
        let base = load("fconvnet-car-sim.toml");
        // `row` with its modules' keys set back to the baseline's.
        let without_modules = |row: &ExperimentConfig, slicing: bool, lfa: bool, pl: bool| {
            let name = &row.name;
            assert_eq!(
                matches!(row.frustum.slicing, Slicing::DepthGuided(_)),
                slicing,
                "{name}"
            );
            assert_eq!(row.loss.projection_weight > 0.0, pl, "{name}");
            let mut r = row.clone();
            r.name = base.name.clone();
            if slicing {
                assert_eq!(r.frustum.depth_range, [0.0, 75.0], "{name}");
                r.frustum.slicing = base.frustum.slicing.clone();
                r.frustum.depth_range = base.frustum.depth_range;
            }
            if lfa {
                assert_eq!(r.model.lfa, Some(LfaConfig::paper()), "{name}");
                assert_eq!(
                    (r.frustum.points_per_frustum, r.frustum.sliced_points),
                    (4096, 1024),
                    "{name}"
                );
                r.model.lfa = None;
                r.frustum.points_per_frustum = base.frustum.points_per_frustum;
                r.frustum.sliced_points = base.frustum.sliced_points;
            } else {
                assert_eq!(r.model.lfa, None, "{name}");
            }
            r.loss.projection_weight = base.loss.projection_weight;
            r
        };
        for (file, slicing, lfa, pl) in [
            ("saf-slicing-car-sim.toml", true, false, false),
            ("saf-lfa-car-sim.toml", false, true, false),
            ("saf-pl-car-sim.toml", false, false, true),
            ("saf-car-sim.toml", true, true, true),
        ] {
            let row = load(file);
            assert_eq!(without_modules(&row, slicing, lfa, pl), base, "{file}");
        }
        // Each derived row is its parent with only its own keys changed: `undo` checks
        // them and sets them back to the parent's.
        let derived_from = |file: &str, parent: &str, undo: &dyn Fn(&mut ExperimentConfig)| {
            let mut row = load(file);
            undo(&mut row);
            row.name = parent.trim_end_matches(".toml").into();
            assert_eq!(row, load(parent), "{file} against {parent}");
        };
        fn lfa(c: &mut ExperimentConfig) -> &mut LfaConfig {
            c.model.lfa.as_mut().unwrap()
        }
        let gate = |c: &mut ExperimentConfig| {
            assert_eq!(lfa(c).feature_gate, LfaFeatureGate::Zero);
            lfa(c).feature_gate = LfaFeatureGate::None;
        };
        let own_init = |c: &mut ExperimentConfig| {
            assert_eq!(lfa(c).coordinate_init, CoordinateInit::Own);
            lfa(c).coordinate_init = CoordinateInit::Shared;
        };
        // ω = 0 in the row, `parent_omega` in its parent.
        let no_near_region_of = |parent_omega: f64| {
            move |c: &mut ExperimentConfig| {
                let Slicing::DepthGuided(guided) = &mut c.frustum.slicing else {
                    panic!("{}: depth-guided slicing expected", c.name);
                };
                assert_eq!(guided.omega, 0.0);
                guided.omega = parent_omega;
            }
        };
        let no_near_region = no_near_region_of(0.55);
        derived_from("saf-lfa-norm-car-sim.toml", "saf-lfa-car-sim.toml", &|c| {
            let l = lfa(c);
            assert_eq!((l.position_scale_m, l.offset_scale_m), (5.0, 1.0));
            (l.position_scale_m, l.offset_scale_m) = (1.0, 1.0);
        });
        derived_from("saf-lfa-gate-car-sim.toml", "saf-lfa-car-sim.toml", &gate);
        derived_from(
            "saf-lfa-own-car-sim.toml",
            "saf-lfa-car-sim.toml",
            &own_init,
        );
        derived_from(
            "saf-lfa-gate-own-car-sim.toml",
            "saf-lfa-gate-car-sim.toml",
            &own_init,
        );
        derived_from(
            "saf-slicing-w0-car-sim.toml",
            "saf-slicing-car-sim.toml",
            &no_near_region,
        );
        derived_from("saf-gate-w0-car-sim.toml", "saf-car-sim.toml", &|c| {
            gate(c);
            own_init(c);
            no_near_region(c);
        });
        derived_from(
            "saf-slicing-lfa-gate-w0-car-sim.toml",
            "saf-gate-w0-car-sim.toml",
            &|c| {
                assert_eq!(c.loss.projection_weight, 0.0);
                c.loss.projection_weight = 0.1;
            },
        );
        derived_from("saf-gate-w0-people-sim.toml", "saf-people-sim.toml", &|c| {
            gate(c);
            own_init(c);
            no_near_region_of(0.85)(c);
        });
        // The shipped SAF models are the gated full rows with omega 0, under the shipped names.
        for (model, row) in [
            ("saf-car", "saf-gate-w0-car-sim"),
            ("saf-people", "saf-gate-w0-people-sim"),
        ] {
            let mut shipped = ExperimentConfig::from_file(
                &Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../models/{model}.toml")),
            )
            .unwrap();
            assert_eq!(shipped.name, format!("{model}-sim"));
            shipped.name = row.into();
            assert_eq!(shipped, load(&format!("{row}.toml")), "models/{model}.toml");
        }
        // The pairs at twice the budget.
        for (file, row) in [
            ("fconvnet-car-sim-2x.toml", base.clone()),
            ("saf-car-sim-2x.toml", load("saf-car-sim.toml")),
            (
                "saf-gate-w0-car-sim-2x.toml",
                load("saf-gate-w0-car-sim.toml"),
            ),
        ] {
            let mut twice = load(file);
            assert_eq!(
                twice.frustum.augment.copies,
                2 * row.frustum.augment.copies,
                "{file}"
            );
            twice.frustum.augment.copies = row.frustum.augment.copies;
            twice.name = row.name.clone();
            assert_eq!(twice, row, "{file}");
        }
    }

    #[test]
    fn the_car_config_is_the_published_one() {
        assert_eq!(load("fconvnet-car.toml"), ExperimentConfig::default());
    }

    /// The CPU-sized DASANet ablation rows differ only in their modules, and the baseline
    /// row (Voxel R-CNN) shares their data, augmentation, voxel grid, stage one and schedule.
    #[test]
    fn the_cpu_ablation_rows_differ_only_in_the_network() {
        let base = load("voxel-rcnn-local-aug-car-sim.toml");
        assert_eq!(base.kind(), DetectorKind::VoxelRcnn);
        let shipped = load("voxel-rcnn-car-sim.toml");
        let (b, s) = (
            base.voxel_rcnn.as_ref().unwrap(),
            shipped.voxel_rcnn.as_ref().unwrap(),
        );
        assert_eq!(b.network, s.network);
        assert_ne!(b.augment, s.augment);
        for (name, tdis, stca) in [
            ("dasanet-tdis-car-sim.toml", true, false),
            ("dasanet-stca-car-sim.toml", false, true),
            ("dasanet-car-sim.toml", true, true),
        ] {
            let row = load(name);
            assert_eq!(row.kind(), DetectorKind::Dasanet, "{name}");
            let v = row.voxel_rcnn.as_ref().unwrap();
            let m = &row.dasanet.as_ref().unwrap().modules;
            assert_eq!((m.tdis, m.stca), (tdis, stca), "{name}");
            assert_eq!(v.augment, b.augment, "{name}");
            assert_eq!(v.voxels, b.voxels, "{name}");
            assert_eq!(v.anchors, b.anchors, "{name}");
            assert_eq!(v.roi_targets, b.roi_targets, "{name}");
            assert_eq!(v.proposals, b.proposals, "{name}");
            assert_eq!(v.post, b.post, "{name}");
            assert_eq!(
                v.network.backbone_channels, b.network.backbone_channels,
                "{name}"
            );
            assert_eq!(v.network.bev, b.network.bev, "{name}");
            assert_eq!(row.train, base.train, "{name}");
            assert_eq!(row.dataset, base.dataset, "{name}");
        }
    }

    /// Gradient clipping bounds each parameter unless `grad_clip_scope = "global"`; the
    /// default is not written out (stored configurations stay as they were), an unknown
    /// scope is an error naming the file.
    #[test]
    fn grad_clip_scope_reads_back_and_refuses_unknown_values() {
        use crate::config::GradClipScope;
        let text = |scope: &str| {
            format!("[detector]\nkind = \"voxel_rcnn\"\n[train]\ngrad_clip_norm = 10.0\n{scope}")
        };
        let read = |t: String| ExperimentConfig::from_toml_str(&t, Path::new("v.toml"));
        let plain = read(text("")).unwrap();
        assert_eq!(plain.train.grad_clip_scope, GradClipScope::PerParameter);
        assert!(!plain.to_toml_string().contains("grad_clip_scope"));
        let global = read(text("grad_clip_scope = \"global\"\n")).unwrap();
        assert_eq!(global.train.grad_clip_scope, GradClipScope::Global);
        let back = read(global.to_toml_string()).unwrap();
        assert_eq!(back.train.grad_clip_scope, GradClipScope::Global);
        let e = read(text("grad_clip_scope = \"layer\"\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("v.toml") && e.contains("grad_clip_scope"), "{e}");
    }

    /// TDIS starts like a linear layer unless `tdis_init = "zero"`; an unknown value is an
    /// error naming the file.
    #[test]
    fn tdis_init_reads_back_and_refuses_unknown_values() {
        use fusiondet_models::dasanet::config::TdisInit;
        let text = |init: &str| {
            format!("[detector]\nkind = \"dasanet\"\n[dasanet.modules]\nstca = false\n{init}")
        };
        let read = |t: String| ExperimentConfig::from_toml_str(&t, Path::new("d.toml"));
        let init = |c: &ExperimentConfig| c.dasanet.as_ref().unwrap().modules.tdis_init;
        assert_eq!(init(&read(text("")).unwrap()), TdisInit::FanIn);
        let zero = read(text("tdis_init = \"zero\"\n")).unwrap();
        assert_eq!(init(&zero), TdisInit::Zero);
        let back = read(zero.to_toml_string()).unwrap();
        assert_eq!(init(&back), TdisInit::Zero);
        let e = read(text("tdis_init = \"ones\"\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("d.toml") && e.contains("tdis_init"), "{e}");
    }

    #[test]
    fn a_voxel_rcnn_file_takes_the_families_published_defaults() {
        let c = load("voxel-rcnn-car.toml");
        assert_eq!(c.kind(), DetectorKind::VoxelRcnn);
        assert_eq!(c.voxel_rcnn, Some(VoxelRcnnSection::default()));
        assert_eq!(c.train, TrainConfig::voxel_rcnn());
        assert_eq!(c.train.optimizer, OptimizerKind::AdamW);
        assert_eq!((c.train.batch_size, c.train.epochs), (2, 80));
        // A [train] key overrides only itself.
        let text = "[detector]\nkind = \"voxel_rcnn\"\n[train]\nepochs = 3\n";
        let c = ExperimentConfig::from_toml_str(text, Path::new("t.toml")).unwrap();
        assert_eq!(c.train.epochs, 3);
        assert_eq!(c.train.one_cycle, Some(OneCycle::voxel_rcnn()));
        // What a run stores reads back to the same configuration.
        let back =
            ExperimentConfig::from_toml_str(&c.to_toml_string(), Path::new("r.toml")).unwrap();
        assert_eq!(back, c);
        assert!(!c.to_toml_string().contains("[frustum]"));
    }

    #[test]
    fn families_refuse_each_others_sections_and_bad_voxel_keys() {
        let err = |text: &str| {
            ExperimentConfig::from_toml_str(text, Path::new("x.toml"))
                .unwrap_err()
                .to_string()
        };
        let e = err("[detector]\nkind = \"voxel_rcnn\"\n[frustum]\npoints_per_frustum = 8\n");
        assert!(
            e.contains("x.toml") && e.contains("[frustum] configures the frustum family"),
            "{e}"
        );
        let e = err(
            "[detector]\nkind = \"frustum\"\n[voxel_rcnn.voxels]\nvoxel_size = [0.1, 0.1, 0.1]\n",
        );
        assert!(
            e.contains("[voxel_rcnn] configures a voxel_rcnn detector"),
            "{e}"
        );
        let e = err(
            "[detector]\nkind = \"voxel_rcnn\"\n[voxel_rcnn.network]\nanchors_per_location = 3\n",
        );
        assert!(
            e.contains("anchors_per_location is 3") && e.contains("make it 2"),
            "{e}"
        );
        let e = err(
            "[detector]\nkind = \"voxel_rcnn\"\n[voxel_rcnn.network]\nbackbon_channels = [1, 1, 1, 1]\n",
        );
        assert!(e.contains("backbon_channels"), "{e}");
        let e = err("[detector]\nkind = \"voxel_rcnn\"\n[dataset]\nclasses = [\"Pedestrian\"]\n");
        assert!(e.contains("classes of [voxel_rcnn.anchors]"), "{e}");
        let e = err(
            "[detector]\nkind = \"voxel_rcnn\"\n[train]\none_cycle = { max_lr = 0.01, div_factor = 10.0, pct_start = 1.5 }\n",
        );
        assert!(e.contains("pct_start"), "{e}");
    }

    #[test]
    fn every_shipped_config_loads_and_says_what_it_is() {
        use fusiondet_models::SliceEncoderKind;
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut names = Vec::new();
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                let c = ExperimentConfig::from_file(&path).unwrap();
                let file_stem = path.file_stem().unwrap().to_string_lossy().to_string();
                assert_eq!(c.name, file_stem, "{}: name", path.display());
                if c.kind() == DetectorKind::VoxelRcnn {
                    assert!(file_stem.contains("voxel-rcnn"), "{file_stem}");
                    names.push(file_stem);
                    continue;
                }
                // The name states the variant (tiny-* are the tiny network's variants):
                // check that the file holds it.
                let stem = file_stem.strip_prefix("tiny-").unwrap_or(&file_stem);
                // `-half`, `-2x`: a `-sim` schedule on another budget.
                let stem = ["-half", "-2x"]
                    .iter()
                    .find_map(|b| stem.strip_suffix(b))
                    .unwrap_or(stem);
                let stem = stem.strip_suffix("-sim").unwrap_or(stem);
                let variant = stem
                    .strip_suffix("-car")
                    .or_else(|| stem.strip_suffix("-people"))
                    .or_else(|| stem.strip_suffix("-sunrgbd"))
                    .unwrap_or(stem);
                let parts: Vec<&str> = variant.split('-').collect();
                let saf = parts[0] == "saf";
                // A SAF name without a module's word is the full SAF (`saf-gate-w0`: all
                // three modules, with its own keys).
                let all_three = saf && !parts.iter().any(|p| ["slicing", "lfa", "pl"].contains(p));
                let slicing = all_three || (saf && parts.contains(&"slicing"));
                let lfa = all_three || (saf && parts.contains(&"lfa"));
                let pl = all_three || (saf && parts.contains(&"pl"));
                assert_eq!(
                    matches!(
                        c.frustum.slicing,
                        fusiondet_frustum::Slicing::DepthGuided(_)
                    ),
                    slicing,
                    "{stem}: slicing"
                );
                assert_eq!(c.model.lfa.is_some(), lfa, "{stem}: lfa");
                assert_eq!(c.loss.projection_weight > 0.0, pl, "{stem}: pl");
                let encoder = match (parts[0], parts.get(1)) {
                    ("fcam", Some(&"cbam")) => SliceEncoderKind::Cbam,
                    ("fcam", _) => SliceEncoderKind::ImprovedCbam,
                    _ => SliceEncoderKind::PointNet,
                };
                assert_eq!(c.model.slice_encoder, encoder, "{stem}: encoder");
                // `-r<N>`: both channel MLPs at reduction N.
                if let Some(r) = parts.iter().find_map(|p| p.strip_prefix('r')?.parse().ok()) {
                    let a = &c.model.attention;
                    assert_eq!((a.channel_reduction, a.tanh_reduction), (r, r), "{stem}");
                }
                let refine = parts.contains(&"refine");
                assert_eq!(c.refine.is_some(), refine, "{stem}: refine");
                assert_eq!(c.frustum.proposal_crop.is_some(), refine, "{stem}: crop");
                let indoor = stem.ends_with("sunrgbd");
                assert_eq!(
                    c.dataset.format == DatasetFormat::SunRgbd,
                    indoor,
                    "{stem}: format"
                );
                if indoor {
                    assert_eq!(c.frustum.classes.len(), 10, "{stem}");
                    assert_eq!(c.frustum.depth_range, [0.0, 8.0], "{stem}");
                }
                if stem.ends_with("-people") {
                    use fusiondet_kitti::ObjectClass::{Cyclist, Pedestrian};
                    assert_eq!(
                        c.frustum.classes,
                        [Pedestrian.into(), Cyclist.into()],
                        "{stem}"
                    );
                }
                names.push(file_stem);
            }
        }
        names.sort();
        // Every row of the seeds' tables, for Car and for Pedestrian + Cyclist.
        for row in [
            "fconvnet",
            "fconvnet-refine",
            "fcam-cbam",
            "fcam",
            "saf",
            "saf-slicing",
            "saf-lfa",
            "saf-pl",
            "saf-slicing-lfa",
            "saf-slicing-pl",
            "saf-lfa-pl",
        ] {
            for class in ["car", "people"] {
                let name = format!("{row}-{class}");
                assert!(names.contains(&name), "configs/{name}.toml is missing");
            }
        }
    }

    #[test]
    fn test_points_override_the_detection_frustums_only() {
        let c = load("fconvnet-car.toml")
            .with_test_points(Some(512))
            .unwrap();
        assert_eq!(c.detect_frustum().points_per_frustum, 512);
        assert_eq!(c.frustum.points_per_frustum, 1024);
        assert!(load("fconvnet-car.toml").with_test_points(Some(0)).is_err());
        let err = load("saf-car.toml")
            .with_test_points(Some(512))
            .unwrap_err()
            .to_string();
        assert!(err.contains("LFA"), "{err}");
    }

    #[test]
    fn lfa_needs_the_survivors_to_be_the_sliced_points() {
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[frustum]\npoints_per_frustum = 4096\n[model.lfa]\n"),
            Path::new("s.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("sliced_points") && err.contains("1024"),
            "{err}"
        );
    }

    #[test]
    fn a_refinement_config_names_its_first_stage_relative_to_itself() {
        let c = load("fconvnet-refine-car.toml");
        let first = &c.refine.as_ref().unwrap().first_stage;
        assert!(
            first.ends_with("configs/../models/fconvnet-car.bpk"),
            "{first:?}"
        );
        assert!(first.is_file(), "the shipped first stage {first:?}");
        assert_eq!(c.frustum.points_per_frustum, 512);
        // The crop and [refine] come together.
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[frustum]\ndepth_range = [-2.0, 2.0]\n[frustum.proposal_crop]\n"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("[refine]"), "{err}");
        let err = ExperimentConfig::from_toml_str(
            &with_kind("[refine]\nfirst_stage = \"a.bpk\"\n"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("proposal_crop"), "{err}");
    }

    #[test]
    fn the_tiny_config_uses_the_tiny_network() {
        let c = load("tiny.toml");
        assert_eq!(c.model, ModelConfig::tiny());
        assert_eq!(c.frustum.points_per_frustum, 256);
    }
}
