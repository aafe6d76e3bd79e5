//! Frames as DASANet reads them: the Voxel R-CNN scene (FOV points, labels) with the
//! frame's pseudo cloud beside it, both augmented together (pasted objects bring their
//! pseudo points), then both voxelized on one grid; the points themselves are kept for
//! STCA's RoI crops.

use super::config::DasanetSection;
use super::pseudo::PseudoCloudMaker;
use crate::error::{PipelineError, Result};
use crate::voxel_rcnn::data::{VoxelData, VoxelSample, anchor_targets};
use burn::prelude::*;
use fusiondet_dataset::SensorFrame;
use fusiondet_dataset::rng::Sampler;
use fusiondet_models::dasanet::PSEUDO_VOXEL_FEATURES;
use fusiondet_models::voxel_rcnn::{AnchorLossTargets, BackbonePlan};
use fusiondet_nn::sparse::SparseSites;
use fusiondet_voxel::{GtBox, Voxels};
use std::sync::Arc;

/// One frame ready for the network.
#[derive(Debug, Clone)]
pub struct DasanetSample {
    pub lidar: VoxelSample,
    pub pseudo_voxels: Voxels,
    /// The scene's LiDAR points (x, y, z, intensity) and pseudo points (x, y, z, r, g, b),
    /// flat, after augmentation.
    pub lidar_points: Vec<f32>,
    pub pseudo_points: Vec<f32>,
}

impl DasanetSample {
    /// Whether both branches have a voxel to run on.
    pub fn has_voxels(&self) -> bool {
        !self.lidar.voxels.is_empty() && !self.pseudo_voxels.is_empty()
    }
}

/// What turns frames into samples: Voxel R-CNN's data side and the pseudo clouds.
pub struct DasanetData {
    pub voxel: VoxelData,
    pub section: DasanetSection,
    pub pseudo: PseudoCloudMaker,
}

impl DasanetData {
    /// Refuses a ground-truth sampler whose database has no pseudo points (pasted objects
    /// would arrive without them).
    pub fn new(
        voxel: VoxelData,
        section: &DasanetSection,
        pseudo: PseudoCloudMaker,
    ) -> Result<Self> {
        if voxel.gt_sampler.as_ref().is_some_and(|s| !s.has_pseudo()) {
            return Err(PipelineError::Invalid(
                "the ground-truth database was built without pseudo points; DASANet pastes \
                 objects with theirs (rebuild it with `fusiondet gt-database --pseudo`)"
                    .into(),
            ));
        }
        Ok(Self {
            voxel,
            section: section.clone(),
            pseudo,
        })
    }

    /// The frame's sample; `augment_with` draws the training augmentation and the
    /// voxel-cap sampling of both clouds (detection passes `None`).
    pub fn sample(
        &self,
        frame: &SensorFrame,
        augment_with: Option<&mut Sampler>,
    ) -> Result<DasanetSample> {
        self.sample_with_cloud(frame, self.pseudo.cloud(frame, None)?, augment_with)
    }

    /// The sample of a frame whose pseudo cloud is given.
    pub fn sample_with_cloud(
        &self,
        frame: &SensorFrame,
        pseudo: Vec<fusiondet_voxel::PseudoPoint>,
        augment_with: Option<&mut Sampler>,
    ) -> Result<DasanetSample> {
        let mut rng = augment_with;
        let training = rng.is_some();
        let scene = self.voxel.scene(frame, pseudo, rng.as_deref_mut())?;
        let lidar = self.voxel.voxelize(&frame.id, &scene, rng.as_deref_mut());
        let p = &self.section.pseudo;
        let pseudo_voxels = self.voxel.voxelizer.voxelize_pseudo(
            &scene.pseudo,
            p.max_points_per_voxel,
            p.max_voxels(training),
            rng.filter(|_| p.shuffles(training)),
        );
        Ok(DasanetSample {
            lidar,
            pseudo_voxels,
            lidar_points: scene.points.iter().flatten().copied().collect(),
            pseudo_points: scene.pseudo.iter().flatten().copied().collect(),
        })
    }
}

/// Frames of a batch: both branches' sites, features and rulebooks.
pub struct DasanetBatch {
    pub ids: Vec<String>,
    pub lidar_features: Tensor<2>,
    pub lidar_plan: BackbonePlan,
    pub pseudo_features: Tensor<2>,
    pub pseudo_plan: BackbonePlan,
    pub gts: Vec<Vec<GtBox>>,
    /// Per frame: LiDAR points (stride 4) and pseudo points (stride 6), for STCA.
    pub clouds: Vec<(Vec<f32>, Vec<f32>)>,
    /// Stage one's targets (training only).
    pub anchor_targets: Option<AnchorLossTargets>,
}

/// One branch's voxels of a batch as sites, features and the backbone's rulebooks.
fn branch_inputs(
    voxels: &[&Voxels],
    channels: usize,
    sparse_shape: [usize; 3],
    device: &Device,
) -> Result<(Tensor<2>, BackbonePlan)> {
    let coords: Vec<[i32; 4]> = voxels
        .iter()
        .enumerate()
        .flat_map(|(b, v)| v.coords_with_batch(b as i32))
        .collect();
    let features: Vec<f32> = voxels
        .iter()
        .flat_map(|v| v.flat_features().iter().copied())
        .collect();
    let n = coords.len();
    let sites = SparseSites::new(coords, sparse_shape, voxels.len())
        .map_err(|e| PipelineError::Invalid(format!("voxel sites: {e}")))?;
    Ok((
        Tensor::from_data(TensorData::new(features, [n, channels]), device),
        BackbonePlan::new(Arc::new(sites), device),
    ))
}

/// A training or detection batch; refuses frames without a voxel in either branch.
pub fn collate(
    data: &DasanetData,
    samples: Vec<DasanetSample>,
    with_targets: bool,
    device: &Device,
) -> Result<DasanetBatch> {
    if let Some(s) = samples.iter().find(|s| !s.has_voxels()) {
        return Err(PipelineError::Invalid(format!(
            "frame {} has no LiDAR or no pseudo point inside the point range and the \
             camera's field of view: nothing to detect on",
            s.lidar.id
        )));
    }
    let shape = data.voxel.section.voxels.sparse_shape();
    let lidar: Vec<&Voxels> = samples.iter().map(|s| &s.lidar.voxels).collect();
    let (lidar_features, lidar_plan) = branch_inputs(&lidar, 4, shape, device)?;
    let pseudo: Vec<&Voxels> = samples.iter().map(|s| &s.pseudo_voxels).collect();
    let (pseudo_features, pseudo_plan) =
        branch_inputs(&pseudo, PSEUDO_VOXEL_FEATURES, shape, device)?;
    let gts: Vec<&[GtBox]> = samples.iter().map(|s| s.lidar.gts.as_slice()).collect();
    let anchor_targets = with_targets.then(|| anchor_targets(&data.voxel, &gts, device));
    // The samples are consumed here: ids, boxes and clouds move into the batch.
    let mut ids = Vec::with_capacity(samples.len());
    let mut gts = Vec::with_capacity(samples.len());
    let mut clouds = Vec::with_capacity(samples.len());
    for s in samples {
        ids.push(s.lidar.id);
        gts.push(s.lidar.gts);
        clouds.push((s.lidar_points, s.pseudo_points));
    }
    Ok(DasanetBatch {
        ids,
        lidar_features,
        lidar_plan,
        pseudo_features,
        pseudo_plan,
        gts,
        clouds,
        anchor_targets,
    })
}
