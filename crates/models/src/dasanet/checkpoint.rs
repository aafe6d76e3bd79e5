//! DASANet checkpoints: burnpack weights tagged with the family and the network's shape
//! (configuration, input grid height), refused by a configuration of another shape or
//! family. A training checkpoint stores the auxiliary heads (training resumes with them);
//! an inference checkpoint (a run's `model.bpk`) leaves them out, since detection never
//! runs them: at the published size they are 37 of 92 M parameters.

use super::{Dasanet, DasanetNetConfig};
use crate::checkpoint::{load_shaped, read_shape, save_shaped};
use crate::error::ModelError;
use crate::family::DetectorKind;
use burn::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What fixes the tensors of a DASANet.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DasanetShape {
    pub network: DasanetNetConfig,
    /// Heights of the input grid (41 for the published one).
    pub grid_z: usize,
    /// Without the auxiliary heads (detection only). Absent in files written before
    /// inference checkpoints existed, which all hold the heads.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub inference_only: bool,
}

impl DasanetShape {
    /// The same network without the training-only auxiliary heads.
    pub fn for_inference(&self) -> Self {
        Self {
            inference_only: true,
            ..self.clone()
        }
    }
}

pub fn save_dasanet(model: &Dasanet, shape: &DasanetShape, path: &Path) -> Result<(), ModelError> {
    save_shaped(model, DetectorKind::Dasanet, shape, path)
}

/// The shape stored in a checkpoint of this family (refuses other families).
pub fn read_dasanet_shape(path: &Path) -> Result<DasanetShape, ModelError> {
    read_shape(path, DetectorKind::Dasanet)
}

/// Loads a checkpoint whose stored shape must equal `shape`.
pub fn load_dasanet(
    shape: &DasanetShape,
    path: &Path,
    device: &Device,
) -> Result<Dasanet, ModelError> {
    load_shaped(shape, DetectorKind::Dasanet, path, || {
        let model = Dasanet::new(&shape.network, shape.grid_z, device)?;
        Ok(match shape.inference_only {
            true => model.without_aux_heads(),
            false => model,
        })
    })
}

/// Loads either kind of file for detection: a training checkpoint of `shape` (its
/// auxiliary heads loaded, never run) or an inference file of `shape.for_inference()`.
pub fn load_dasanet_for_detection(
    shape: &DasanetShape,
    path: &Path,
    device: &Device,
) -> Result<Dasanet, ModelError> {
    match read_dasanet_shape(path)?.inference_only {
        true => load_dasanet(&shape.for_inference(), path, device),
        false => load_dasanet(shape, path, device),
    }
}

/// Writes `model` without its auxiliary heads, as `shape.for_inference()`.
pub fn save_dasanet_for_inference(
    model: &Dasanet,
    shape: &DasanetShape,
    path: &Path,
) -> Result<(), ModelError> {
    save_dasanet(
        &model.clone().without_aux_heads(),
        &shape.for_inference(),
        path,
    )
}

#[cfg(test)]
mod tests {
    use super::super::AblationRow;
    use super::super::tests::tiny;
    use super::*;
    use crate::info::trainable_params;
    use crate::voxel_rcnn::{VoxelRcnn, VoxelRcnnShape, read_voxel_rcnn_shape, save_voxel_rcnn};

    #[test]
    fn round_trips_and_refuses_other_shapes_and_families() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.bpk");
        let device = Device::flex();
        let shape = DasanetShape {
            network: tiny(AblationRow::Dasanet),
            grid_z: 41,
            inference_only: false,
        };
        let model = Dasanet::new(&shape.network, 41, &device).unwrap();
        save_dasanet(&model, &shape, &path).unwrap();
        assert_eq!(
            crate::read_checkpoint_kind(&path).unwrap(),
            DetectorKind::Dasanet
        );
        let back = load_dasanet(&shape, &path, &device).unwrap();
        assert_eq!(trainable_params(&back), trainable_params(&model));
        let w = |m: &Dasanet| {
            m.tdis
                .as_ref()
                .unwrap()
                .global
                .val()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        assert_eq!(w(&back), w(&model));

        // Another row of the ablation is another shape.
        let other = DasanetShape {
            network: tiny(AblationRow::Tdis),
            grid_z: 41,
            inference_only: false,
        };
        let err = load_dasanet(&other, &path, &device)
            .unwrap_err()
            .to_string();
        assert!(err.contains("d.bpk") && err.contains("stca"), "{err}");
        // Voxel R-CNN's reader refuses it, and DASANet's refuses a Voxel R-CNN checkpoint.
        assert!(
            read_voxel_rcnn_shape(&path)
                .unwrap_err()
                .to_string()
                .contains("dasanet")
        );
        let vpath = dir.path().join("v.bpk");
        let vshape = VoxelRcnnShape {
            network: shape.network.voxel_rcnn.clone(),
            grid_z: 41,
        };
        let v = VoxelRcnn::new(&vshape.network, 41, &device).unwrap();
        save_voxel_rcnn(&v, &vshape, &vpath).unwrap();
        assert!(
            read_dasanet_shape(&vpath)
                .unwrap_err()
                .to_string()
                .contains("voxel_rcnn")
        );
    }

    /// An inference checkpoint holds every weight but the auxiliary heads', loads as the
    /// inference shape only, and a training checkpoint's JSON shape is what it was before
    /// the flag existed (so older files still match).
    #[test]
    fn inference_checkpoints_leave_out_the_auxiliary_heads() {
        let dir = tempfile::tempdir().unwrap();
        let (full, lean) = (dir.path().join("full.bpk"), dir.path().join("lean.bpk"));
        let device = Device::flex();
        let shape = DasanetShape {
            network: tiny(AblationRow::Dasanet),
            grid_z: 41,
            inference_only: false,
        };
        assert!(
            !serde_json::to_string(&shape)
                .unwrap()
                .contains("inference_only")
        );
        let model = Dasanet::new(&shape.network, 41, &device).unwrap();
        assert!(model.aux_params() > 0);
        save_dasanet(&model, &shape, &full).unwrap();
        save_dasanet_for_inference(&model, &shape, &lean).unwrap();
        assert_eq!(read_dasanet_shape(&lean).unwrap(), shape.for_inference());
        let back = load_dasanet(&shape.for_inference(), &lean, &device).unwrap();
        assert_eq!(back.aux_params(), 0);
        assert_eq!(
            trainable_params(&back),
            trainable_params(&model) - model.aux_params()
        );
        let head = |m: &Dasanet| {
            m.head
                .cls_out
                .weight
                .val()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        assert_eq!(head(&back), head(&model));
        let size = |p: &std::path::Path| std::fs::metadata(p).unwrap().len();
        assert!(size(&lean) < size(&full));
        // Detection takes both files.
        for path in [&full, &lean] {
            let m = load_dasanet_for_detection(&shape, path, &device).unwrap();
            assert_eq!(head(&m), head(&model));
        }
        // A training configuration refuses the inference file.
        let err = load_dasanet(&shape, &lean, &device)
            .unwrap_err()
            .to_string();
        assert!(err.contains("inference_only"), "{err}");
    }
}
