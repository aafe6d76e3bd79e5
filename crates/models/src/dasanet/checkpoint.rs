//! DASANet checkpoints: burnpack weights tagged with the family and the network's shape
//! (configuration, input grid height), refused by a configuration of another shape or
//! family. The auxiliary heads are stored with the rest (training resumes with them).

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
        Dasanet::new(&shape.network, shape.grid_z, device)
    })
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
}
