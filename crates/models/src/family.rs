//! The detector families, a closed set: what a configuration's `[detector] kind` names
//! and what every checkpoint records, so that a command dispatches on the file it is
//! given rather than on strings scattered around.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DetectorKind {
    /// The frustum family: F-ConvNet (with its refinement stage), FCAM and SAF, as
    /// configurations of one pipeline (2D boxes → frustums → sub-frustum PointNets → FCN).
    Frustum,
    /// Voxel R-CNN (LiDAR only): voxels → sparse 3D backbone → BEV anchor head →
    /// voxel RoI pooling → RoI head.
    VoxelRcnn,
    /// DASANet: Voxel R-CNN with a pseudo-point branch from depth completion, TDIS and
    /// STCA (the rows of its ablation are configurations of this family).
    Dasanet,
}

impl DetectorKind {
    pub const ALL: [DetectorKind; 3] = [
        DetectorKind::Frustum,
        DetectorKind::VoxelRcnn,
        DetectorKind::Dasanet,
    ];

    /// The name in configurations (`[detector] kind`).
    pub fn name(self) -> &'static str {
        match self {
            DetectorKind::Frustum => "frustum",
            DetectorKind::VoxelRcnn => "voxel_rcnn",
            DetectorKind::Dasanet => "dasanet",
        }
    }

    /// The tag stored in a checkpoint's metadata. The frustum family's is "fconvnet",
    /// what every checkpoint written so far carries.
    pub fn checkpoint_tag(self) -> &'static str {
        match self {
            DetectorKind::Frustum => "fconvnet",
            DetectorKind::VoxelRcnn => "voxel_rcnn",
            DetectorKind::Dasanet => "dasanet",
        }
    }

    pub fn from_checkpoint_tag(tag: &str) -> Option<DetectorKind> {
        Self::ALL.into_iter().find(|k| k.checkpoint_tag() == tag)
    }
}

impl std::fmt::Display for DetectorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_tags_round_trip() {
        for k in DetectorKind::ALL {
            assert_eq!(
                DetectorKind::from_checkpoint_tag(k.checkpoint_tag()),
                Some(k)
            );
            let toml = format!("kind = \"{}\"", k.name());
            #[derive(Deserialize)]
            struct T {
                kind: DetectorKind,
            }
            assert_eq!(toml::from_str::<T>(&toml).unwrap().kind, k);
        }
        assert_eq!(DetectorKind::from_checkpoint_tag("voxel"), None);
    }
}
