//! Checkpoints: burn's burnpack format with the model configuration stored in the file's
//! metadata (`fusiondet.model_config`, JSON), checked on load.
//!
//! Writing is atomic: burn-pack writes a scratch file beside the destination, fsyncs it and
//! renames it into place (`burn_pack::Writer::write_to_file`), so a crash leaves either the
//! old checkpoint or the new one, never a truncated file.

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::family::DetectorKind;
use crate::model::FConvNet;
use burn::module::{ModuleVisitor, Param};
use burn::prelude::*;
use burn::store::burn_pack::Reader;
use burn::store::burn_pack::Tensor as PackTensor;
use burn::store::{BurnpackStore, ModuleAdapter, ModuleContext, ModuleSnapshot};
use std::path::Path;

/// Metadata key of the checkpoint's family ([`DetectorKind::checkpoint_tag`]).
const KIND_KEY: &str = "fusiondet.model";
const CONFIG_KEY: &str = "fusiondet.model_config";
/// Metadata key of the CRC-32 of every tensor's values (`scan_tensors`), verified on
/// load: a file whose bytes were damaged (say, flipped to NaN) is refused.
const CHECKSUM_KEY: &str = "fusiondet.tensor_crc32";

pub(crate) fn ckpt_err(path: &Path, message: impl Into<String>) -> ModelError {
    ModelError::Checkpoint {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Saves the weights and batch-norm statistics of `model` to `path` (exactly that path; no
/// extension is added), replacing any file there atomically.
pub fn save_checkpoint(model: &FConvNet, path: &Path) -> Result<(), ModelError> {
    let config = serde_json::to_string(model.config()).expect("the model configuration serialises");
    write_tagged(model, DetectorKind::Frustum, config, path)
}

/// Writes `model` with its family and its configuration (JSON) in the metadata: every
/// family's checkpoint is written here.
pub(crate) fn write_tagged<M: ModuleSnapshot>(
    model: &M,
    kind: DetectorKind,
    config_json: String,
    path: &Path,
) -> Result<(), ModelError> {
    // `valid()` first folds the batch-norm running statistics that training threads hold
    // apart (burn keeps them per thread until synchronised) into the stored values.
    let model = model.valid();
    // One read of every tensor gives both the checksum and the NaN check.
    let scan = scan_tensors(&model);
    if let Some(error) = scan.unreadable {
        return Err(ckpt_err(path, format!("not written: {error}")));
    }
    if let Some(name) = scan.non_finite {
        return Err(ckpt_err(
            path,
            format!(
                "not written: parameter `{name}` holds NaN or infinite values (the training \
                 diverged); lower the learning rate or check the configuration"
            ),
        ));
    }
    let mut store = BurnpackStore::from_file(path)
        .auto_extension(false)
        .overwrite(true)
        .metadata(KIND_KEY, kind.checkpoint_tag())
        .metadata(CONFIG_KEY, config_json)
        .metadata(CHECKSUM_KEY, format!("{:08x}", scan.crc32))
        .with_to_adapter(NameIds);
    model
        .save_into(&mut store)
        .map_err(|e| ckpt_err(path, format!("cannot write: {e}")))
}

/// What one pass over a module's float tensors (parameters and batch-norm statistics, in the
/// module's own order) finds.
struct TensorScan {
    /// CRC-32 of all values (little-endian f32).
    crc32: u32,
    /// The path of the first tensor holding a NaN or an infinity.
    non_finite: Option<String>,
    /// Why a tensor could not be read (a GPU run whose device failed: an allocation past what
    /// it binds, say); the scan stops there.
    unreadable: Option<String>,
}

fn scan_tensors<M: Module>(module: &M) -> TensorScan {
    struct Scanner {
        path: Vec<String>,
        hasher: crc32fast::Hasher,
        non_finite: Option<String>,
        unreadable: Option<String>,
    }
    impl ModuleVisitor for Scanner {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if self.unreadable.is_some() {
                return;
            }
            let data = match param.val().try_into_data() {
                Ok(data) => data,
                Err(e) => {
                    self.unreadable = Some(format!(
                        "the weights could not be read back from the device (`{}`): {e:?}",
                        self.path.join(".")
                    ));
                    return;
                }
            };
            let mut finite = true;
            for v in data.iter::<f32>() {
                finite &= v.is_finite();
                self.hasher.update(&v.to_le_bytes());
            }
            if !finite && self.non_finite.is_none() {
                self.non_finite = Some(self.path.join("."));
            }
        }
    }
    let mut scanner = Scanner {
        path: Vec::new(),
        hasher: crc32fast::Hasher::new(),
        non_finite: None,
        unreadable: None,
    };
    module.visit(&mut scanner);
    TensorScan {
        crc32: scanner.hasher.finalize(),
        non_finite: scanner.non_finite,
        unreadable: scanner.unreadable,
    }
}

/// CRC-32 of the values of every float parameter and batch-norm statistic of `module`, in
/// the module's own order (little-endian f32), as [`write_tagged`] stores it.
#[cfg(test)]
pub(crate) fn tensor_checksum<M: Module>(module: &M) -> u32 {
    scan_tensors(module).crc32
}

/// Gives every tensor the id of its name: 64-bit FNV-1a, a fixed, documented hash (std's
/// hashers may change between Rust releases, which would change the files). burn draws
/// parameter ids at random and checkpoints store them, so two runs with one seed wrote
/// different files.
#[derive(Clone)]
struct NameIds;

impl NameIds {
    fn id_of(name: &str) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in name.bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        h
    }
}

impl ModuleAdapter for NameIds {
    fn adapt(&self, mut tensor: PackTensor, _ctx: ModuleContext<'_>) -> PackTensor {
        tensor.param_id = Some(Self::id_of(&tensor.name));
        tensor
    }
    fn clone_box(&self) -> Box<dyn ModuleAdapter> {
        Box::new(self.clone())
    }
}

/// `module` with every parameter's id made from its name, as checkpoints store them: then
/// the same seed writes the same bytes, and the optimizer's state (keyed by these ids) fits
/// a resumed network's ids. Applied when a network is created, before any optimizer state
/// exists, by a round trip through an in-memory checkpoint.
pub fn deterministic_param_ids<M: Module>(mut module: M) -> M {
    let mut out = BurnpackStore::from_bytes(None).with_to_adapter(NameIds);
    module
        .save_into(&mut out)
        .expect("a network writes to memory");
    let bytes = out.get_bytes().expect("the bytes just written");
    let mut back = BurnpackStore::from_bytes(Some(bytes));
    module
        .load_from(&mut back)
        .expect("a network reads back its own bytes");
    module
}

/// The path of the first float parameter (or batch-norm statistic) of `module` that holds
/// a NaN or an infinity: such weights detect nothing and must never reach a checkpoint.
pub fn first_non_finite_parameter<M: Module>(module: &M) -> Option<String> {
    scan_tensors(module).non_finite
}

/// Refuses a checkpoint path that is no regular file within the binary size cap (a pipe or
/// a device would hang or flood the reader), before any reader opens it.
fn check_checkpoint_file(path: &Path) -> Result<(), ModelError> {
    fusiondet_kitti::error::open_regular(path, fusiondet_kitti::error::MAX_BINARY_BYTES)
        .map(drop)
        .map_err(|e| {
            // The message without the path, which `ckpt_err` names once.
            let message = match e {
                fusiondet_kitti::FormatError::Io { source, .. } => source.to_string(),
                fusiondet_kitti::FormatError::File { message, .. } => message,
                other => other.to_string(),
            };
            ckpt_err(path, message)
        })
}

/// The configuration (JSON) stored in a checkpoint of family `kind`; refuses other families.
pub(crate) fn read_tagged_config(path: &Path, kind: DetectorKind) -> Result<String, ModelError> {
    let reader = open_checkpoint(path)?;
    let meta = reader.metadata();
    let found = kind_of(path, meta)?;
    if found != kind {
        return Err(ckpt_err(
            path,
            format!("a {found} checkpoint, not a {kind} one"),
        ));
    }
    meta.get(CONFIG_KEY)
        .cloned()
        .ok_or_else(|| ckpt_err(path, "no model configuration in the metadata"))
}

/// Loads the weights of `path` into `model`, refusing a file with tensors it lacks.
pub(crate) fn load_weights<M: ModuleSnapshot>(mut model: M, path: &Path) -> Result<M, ModelError> {
    check_checkpoint_file(path)?;
    let mut store = BurnpackStore::from_file(path).auto_extension(false);
    let result = model
        .load_from(&mut store)
        .map_err(|e| ckpt_err(path, format!("cannot load the weights: {e}")))?;
    if !result.unused.is_empty() {
        return Err(ckpt_err(
            path,
            format!("tensors the network does not have: {:?}", result.unused),
        ));
    }
    // Files written before checksums were stored (the shipped models among them) carry none.
    let reader =
        Reader::from_file_exact(path).map_err(|e| ckpt_err(path, format!("cannot read: {e}")))?;
    if let Some(stored) = reader.metadata().get(CHECKSUM_KEY) {
        let scan = scan_tensors(&model);
        if let Some(error) = scan.unreadable {
            return Err(ckpt_err(path, format!("cannot check the weights: {error}")));
        }
        let found = format!("{:08x}", scan.crc32);
        if *stored != found {
            return Err(ckpt_err(
                path,
                format!(
                    "the weights are damaged (their checksum is {found}, the file was written \
                     with {stored}); restore the file or train again"
                ),
            ));
        }
    }
    Ok(model)
}

/// Writes a network of family `kind` with the shape that fixes its tensors (JSON).
pub(crate) fn save_shaped<M: ModuleSnapshot, S: serde::Serialize>(
    model: &M,
    kind: DetectorKind,
    shape: &S,
    path: &Path,
) -> Result<(), ModelError> {
    let json = serde_json::to_string(shape).expect("the network shape serialises");
    write_tagged(model, kind, json, path)
}

/// The shape stored in a checkpoint of family `kind` (refuses other families).
pub(crate) fn read_shape<S: serde::de::DeserializeOwned>(
    path: &Path,
    kind: DetectorKind,
) -> Result<S, ModelError> {
    let json = read_tagged_config(path, kind)?;
    serde_json::from_str(&json)
        .map_err(|e| ckpt_err(path, format!("unreadable network shape: {e}")))
}

/// Loads a checkpoint of family `kind` whose stored shape must equal `shape`, into the
/// network `build` makes for it.
pub(crate) fn load_shaped<M, S>(
    shape: &S,
    kind: DetectorKind,
    path: &Path,
    build: impl FnOnce() -> Result<M, String>,
) -> Result<M, ModelError>
where
    M: ModuleSnapshot,
    S: serde::Serialize + serde::de::DeserializeOwned + PartialEq,
{
    let stored: S = read_shape(path, kind)?;
    if stored != *shape {
        return Err(ModelError::ConfigMismatch {
            path: path.to_path_buf(),
            differences: format!(
                "the configuration builds {} but the checkpoint holds {}",
                serde_json::to_string(shape).unwrap_or_default(),
                serde_json::to_string(&stored).unwrap_or_default()
            ),
        });
    }
    load_weights(build().map_err(ModelError::InvalidConfig)?, path)
}

/// The family a checkpoint belongs to, from its metadata.
pub fn read_checkpoint_kind(path: &Path) -> Result<DetectorKind, ModelError> {
    kind_of(path, open_checkpoint(path)?.metadata())
}

/// Opens a checkpoint file, saying plainly when there is none at `path` and when the file
/// is not a burnpack file at all (a user's first mistakes: a typo, the wrong file).
fn open_checkpoint(path: &Path) -> Result<Reader, ModelError> {
    if !path.exists() {
        return Err(ckpt_err(
            path,
            "checkpoint not found (a run's model.bpk, or a shipped models/<name>.bpk)",
        ));
    }
    check_checkpoint_file(path)?;
    Reader::from_file_exact(path).map_err(|e| {
        ckpt_err(
            path,
            format!("not a fusiondet checkpoint (not a burnpack file: {e})"),
        )
    })
}

fn kind_of(
    path: &Path,
    meta: &std::collections::BTreeMap<String, String>,
) -> Result<DetectorKind, ModelError> {
    let tag = meta.get(KIND_KEY).ok_or_else(|| {
        ckpt_err(
            path,
            "not a fusiondet checkpoint (no fusiondet model metadata)",
        )
    })?;
    DetectorKind::from_checkpoint_tag(tag).ok_or_else(|| {
        ckpt_err(
            path,
            format!("a checkpoint of the unknown family `{tag}` (written by a newer fusiondet?)"),
        )
    })
}

/// The frustum model configuration stored in a checkpoint.
pub fn read_checkpoint_config(path: &Path) -> Result<ModelConfig, ModelError> {
    let json = read_tagged_config(path, DetectorKind::Frustum)?;
    serde_json::from_str(&json)
        .map_err(|e| ckpt_err(path, format!("unreadable model configuration: {e}")))
}

/// The fields in which two configurations differ, for error messages.
pub fn config_differences(expected: &ModelConfig, found: &ModelConfig) -> Vec<String> {
    // Destructured so that a new field cannot be forgotten here.
    let ModelConfig {
        num_classes,
        slice_encoder,
        attention,
        lfa,
        pointnet_widths,
        fcn_channels,
        deconv_channels,
        num_heading_bins,
        size_clusters,
        bias_before_norm,
        batch_norm_momentum,
        batch_norm_epsilon,
    } = expected;
    let mut out = Vec::new();
    macro_rules! compare {
        ($($field:ident),*) => {$(
            if *$field != found.$field {
                out.push(format!(
                    "{}: expected {:?}, checkpoint has {:?}",
                    stringify!($field),
                    $field,
                    found.$field
                ));
            }
        )*};
    }
    compare!(
        num_classes,
        slice_encoder,
        attention,
        lfa,
        pointnet_widths,
        fcn_channels,
        deconv_channels,
        num_heading_bins,
        size_clusters,
        bias_before_norm,
        batch_norm_momentum,
        batch_norm_epsilon
    );
    out
}

/// Loads a checkpoint into a network built from `config` on `device`; fails with
/// [`ModelError::ConfigMismatch`] when the checkpoint was written for another configuration.
pub fn load_checkpoint(
    config: &ModelConfig,
    path: &Path,
    device: &Device,
) -> Result<FConvNet, ModelError> {
    let stored = read_checkpoint_config(path)?;
    let differences = config_differences(config, &stored);
    if !differences.is_empty() {
        return Err(ModelError::ConfigMismatch {
            path: path.to_path_buf(),
            differences: differences.join("; "),
        });
    }
    load_weights(FConvNet::new(config, device)?, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;

    /// A network whose weights a failed device cannot give back is refused with a message
    /// saying so, not a panic, and nothing is written. The failure: an allocation one value
    /// past what the adapter binds (lavapipe: 128 MiB), whose result the weights are made of.
    #[cfg(feature = "wgpu")]
    #[test]
    fn on_wgpu_weights_a_failed_device_cannot_give_back_are_an_error() {
        let Some(gpu) = fusiondet_nn::cube::working_wgpu_device("a failed device's checkpoint")
        else {
            return;
        };
        let limit = fusiondet_nn::cube::binding_limit(&gpu).unwrap_or(u64::MAX);
        if limit > 1 << 30 {
            eprintln!("this adapter binds {limit} bytes: no failing allocation to test with");
            return;
        }
        let past_the_limit = (limit / 4 + 1) as usize;
        let failed = Tensor::<1>::ones([past_the_limit], &gpu).mul_scalar(2.0);
        let mut linear = LinearConfig::new(2, 2).init(&gpu);
        linear.weight = Param::from_tensor(failed.slice(0..4).reshape([2, 2]));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.bpk");
        let err = write_tagged(&linear, DetectorKind::Frustum, "{}".into(), &path)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("not written: the weights could not be read back from the device"),
            "{err}"
        );
        assert!(!path.exists());
    }

    /// A burnpack file with `tag` as its family (or none).
    fn pack(path: &Path, tag: Option<&str>) {
        let mut store = BurnpackStore::from_file(path)
            .auto_extension(false)
            .overwrite(true);
        if let Some(tag) = tag {
            store = store.metadata(KIND_KEY, tag);
        }
        LinearConfig::new(2, 2)
            .init(&Device::flex())
            .save_into(&mut store)
            .unwrap();
    }

    #[test]
    fn the_family_is_read_from_the_file_and_unknown_ones_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let ours = dir.path().join("ours.bpk");
        pack(&ours, Some("fconvnet"));
        assert_eq!(read_checkpoint_kind(&ours).unwrap(), DetectorKind::Frustum);
        let newer = dir.path().join("newer.bpk");
        pack(&newer, Some("point_pillars"));
        let err = read_checkpoint_kind(&newer).unwrap_err().to_string();
        assert!(
            err.contains("newer.bpk") && err.contains("point_pillars"),
            "{err}"
        );
        assert!(read_checkpoint_config(&newer).is_err());
        let foreign = dir.path().join("foreign.bpk");
        pack(&foreign, None);
        let err = read_checkpoint_kind(&foreign).unwrap_err().to_string();
        assert!(err.contains("not a fusiondet checkpoint"), "{err}");
    }

    #[test]
    fn weights_holding_nan_are_never_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("diverged.bpk");
        let mut linear = LinearConfig::new(2, 2).init(&Device::flex());
        assert_eq!(first_non_finite_parameter(&linear), None);
        write_tagged(&linear, DetectorKind::Frustum, "{}".into(), &path).unwrap();
        let before = std::fs::read(&path).unwrap();
        linear.bias = linear.bias.map(|b| b.map(|t| t.div_scalar(0.0)));
        assert_eq!(first_non_finite_parameter(&linear).as_deref(), Some("bias"));
        let err = write_tagged(&linear, DetectorKind::Frustum, "{}".into(), &path)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("diverged.bpk") && err.contains("`bias`"),
            "{err}"
        );
        assert_eq!(
            std::fs::read(&path).unwrap(),
            before,
            "the good checkpoint stays"
        );
    }

    /// A Linear holding `weight` and `bias` under freshly drawn parameter ids.
    fn linear_of(weight: &Tensor<2>, bias: &Tensor<1>) -> burn::nn::Linear {
        let mut l = LinearConfig::new(2, 2).init(&Device::flex());
        l.weight = Param::from_tensor(weight.clone());
        l.bias = Some(Param::from_tensor(bias.clone()));
        l
    }

    #[test]
    fn the_same_weights_write_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let l = LinearConfig::new(2, 2).init(&Device::flex());
        let (w, b) = (l.weight.val(), l.bias.as_ref().unwrap().val());
        let write = |model: &burn::nn::Linear, name: &str| {
            let path = dir.path().join(name);
            write_tagged(model, DetectorKind::Frustum, "{}".into(), &path).unwrap();
            std::fs::read(path).unwrap()
        };
        // burn draws parameter ids at random; the files store each tensor's name's id.
        let (a, b_) = (linear_of(&w, &b), linear_of(&w, &b));
        assert_ne!(a.weight.id, b_.weight.id);
        assert_eq!(write(&a, "a.bpk"), write(&b_, "b.bpk"));
        // A network made with those ids keeps them across a save and a load, so an
        // optimizer's state keyed by them fits the resumed network.
        let a = deterministic_param_ids(linear_of(&w, &b));
        let b_ = deterministic_param_ids(linear_of(&w, &b));
        assert_eq!(a.weight.id, b_.weight.id);
        write(&a, "a.bpk");
        let loaded = load_weights(linear_of(&w, &b), &dir.path().join("a.bpk")).unwrap();
        assert_eq!(loaded.weight.id, a.weight.id, "ids come back from the file");
    }

    #[test]
    fn weights_that_do_not_match_their_checksum_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let good = LinearConfig::new(2, 2).init(&Device::flex());
        let path = dir.path().join("model.bpk");
        write_tagged(&good, DetectorKind::Frustum, "{}".into(), &path).unwrap();
        load_weights(good.clone(), &path).unwrap();
        // The same file with other values under the good file's checksum: a damaged file.
        let mut damaged = good.clone();
        damaged.weight = damaged.weight.map(|w| w.mul_scalar(f32::NAN));
        let mut store = BurnpackStore::from_file(&path)
            .auto_extension(false)
            .overwrite(true)
            .metadata(KIND_KEY, "fconvnet")
            .metadata(CHECKSUM_KEY, format!("{:08x}", tensor_checksum(&good)));
        damaged.save_into(&mut store).unwrap();
        let err = load_weights(good, &path).unwrap_err().to_string();
        assert!(
            err.contains("model.bpk") && err.contains("weights are damaged"),
            "{err}"
        );
    }
}
