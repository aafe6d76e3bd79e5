//! Voxel R-CNN checkpoints: burnpack weights with the family tag and the network's shape
//! (its configuration and the voxel grid's height) in the metadata, so a checkpoint is
//! refused by a configuration of another shape or family instead of failing on a tensor.

use super::{VoxelRcnn, VoxelRcnnNetConfig};
use crate::checkpoint::{load_shaped, read_shape, save_shaped};
use crate::error::ModelError;
use crate::family::DetectorKind;
use burn::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What fixes the tensors of a Voxel R-CNN.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VoxelRcnnShape {
    pub network: VoxelRcnnNetConfig,
    /// Heights of the input grid (OpenPCDet's sparse shape, 41 for the published one).
    pub grid_z: usize,
}

pub fn save_voxel_rcnn(
    model: &VoxelRcnn,
    shape: &VoxelRcnnShape,
    path: &Path,
) -> Result<(), ModelError> {
    save_shaped(model, DetectorKind::VoxelRcnn, shape, path)
}

/// The shape stored in a checkpoint of this family (refuses other families).
pub fn read_voxel_rcnn_shape(path: &Path) -> Result<VoxelRcnnShape, ModelError> {
    read_shape(path, DetectorKind::VoxelRcnn)
}

/// Loads a checkpoint whose stored shape must equal `shape`.
pub fn load_voxel_rcnn(
    shape: &VoxelRcnnShape,
    path: &Path,
    device: &Device,
) -> Result<VoxelRcnn, ModelError> {
    load_shaped(shape, DetectorKind::VoxelRcnn, path, || {
        VoxelRcnn::new(&shape.network, shape.grid_z, device)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::info::trainable_params;

    fn tiny() -> VoxelRcnnShape {
        let mut network = VoxelRcnnNetConfig {
            backbone_channels: [4, 4, 4, 4],
            backbone_out_channels: 4,
            ..Default::default()
        };
        network.bev.num_filters = vec![4, 4];
        network.bev.num_upsample_filters = vec![4, 4];
        network.bev.layer_nums = vec![1, 1];
        network.roi.grid_size = 2;
        network.roi.shared_fc = vec![8];
        network.roi.cls_fc = vec![8];
        network.roi.reg_fc = vec![8];
        VoxelRcnnShape {
            network,
            grid_z: 41,
        }
    }

    #[test]
    fn round_trips_and_refuses_other_shapes_and_families() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("v.bpk");
        let device = Device::flex();
        let shape = tiny();
        let model = VoxelRcnn::new(&shape.network, shape.grid_z, &device).unwrap();
        save_voxel_rcnn(&model, &shape, &path).unwrap();
        assert_eq!(
            crate::read_checkpoint_kind(&path).unwrap(),
            DetectorKind::VoxelRcnn
        );
        let back = load_voxel_rcnn(&shape, &path, &device).unwrap();
        assert_eq!(trainable_params(&back), trainable_params(&model));
        let w = |m: &VoxelRcnn| {
            m.roi_head
                .reg_out
                .weight
                .val()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        assert_eq!(w(&back), w(&model));

        let mut other = shape.clone();
        other.network.roi.grid_size = 3;
        let err = load_voxel_rcnn(&other, &path, &device)
            .unwrap_err()
            .to_string();
        assert!(err.contains("v.bpk") && err.contains("grid_size"), "{err}");
        // A frustum-family reader refuses it, and it refuses a frustum checkpoint.
        assert!(
            crate::read_checkpoint_config(&path)
                .unwrap_err()
                .to_string()
                .contains("voxel_rcnn")
        );
    }
}
