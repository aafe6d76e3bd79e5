//! Frames as the voxel family feeds them to its network: scene (FOV points, labels in
//! the LiDAR frame) → augmentation (training) → targets kept → voxels; then batches of
//! frames as sparse sites with the backbone's rulebooks and the anchor targets as
//! tensors.

use super::config::VoxelRcnnSection;
use crate::error::{PipelineError, Result};
use burn::prelude::*;
use fusiondet_dataset::SensorFrame;
use fusiondet_dataset::rng::Sampler;
use fusiondet_kitti::ObjectClass;
use fusiondet_models::voxel_rcnn::{AnchorLossTargets, BackbonePlan};
use fusiondet_nn::sparse::SparseSites;
use fusiondet_voxel::{
    AnchorAssigner, GtBox, GtSampler, PseudoPoint, Scene, Voxelizer, Voxels, augment,
};
use std::sync::Arc;

/// One frame ready for the network.
#[derive(Debug, Clone)]
pub struct VoxelSample {
    pub id: String,
    pub voxels: Voxels,
    /// The ground truth the detector learns (its classes, centres in range).
    pub gts: Vec<GtBox>,
}

/// What turns frames into samples: the voxelizer, the anchors and, for training, the
/// ground-truth sampler.
pub struct VoxelData {
    pub section: VoxelRcnnSection,
    pub voxelizer: Voxelizer,
    pub assigner: AnchorAssigner,
    pub classes: Vec<ObjectClass>,
    pub gt_sampler: Option<GtSampler>,
    /// The anchors on the GPU device the proposals are chosen on, uploaded with the first
    /// frame: every frame and step ranks the same anchors.
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    device_anchors: std::sync::OnceLock<Tensor<2>>,
}

/// The anchors [A, 7] (x, y, z, dx, dy, dz, heading) as f32 on `device`: what the device's
/// choice of proposals decodes against.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub fn anchor_tensor(anchors: &fusiondet_voxel::Anchors, device: &Device) -> Tensor<2> {
    let values: Vec<f32> = anchors
        .boxes
        .iter()
        .flat_map(|anchor| anchor.to_array().map(|v| v as f32))
        .collect();
    Tensor::from_data(TensorData::new(values, [anchors.len(), 7]), device).inner()
}

fn voxel_err(e: fusiondet_voxel::VoxelError) -> PipelineError {
    PipelineError::Invalid(e.to_string())
}

impl VoxelData {
    /// [`anchor_tensor`] on `device`, uploaded once (again only for another device).
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    pub fn device_anchors(&self, device: &Device) -> Tensor<2> {
        let device = device.clone().without_autodiff();
        let cached = self
            .device_anchors
            .get_or_init(|| anchor_tensor(self.assigner.anchors(), &device));
        match cached.device() == device {
            true => cached.clone(),
            false => anchor_tensor(self.assigner.anchors(), &device),
        }
    }

    pub fn new(section: &VoxelRcnnSection, gt_sampler: Option<GtSampler>) -> Result<VoxelData> {
        Ok(VoxelData {
            voxelizer: Voxelizer::new(&section.voxels).map_err(voxel_err)?,
            assigner: AnchorAssigner::new(&section.voxels, &section.anchors).map_err(voxel_err)?,
            classes: section.anchors.classes.iter().map(|c| c.class).collect(),
            section: section.clone(),
            gt_sampler,
            #[cfg(any(feature = "wgpu", feature = "cuda"))]
            device_anchors: std::sync::OnceLock::new(),
        })
    }

    /// The frame's sample; `augment_with` draws the training augmentation and the
    /// voxel-cap sampling (detection passes `None`: no augmentation, scan order).
    pub fn sample(
        &self,
        frame: &SensorFrame,
        augment_with: Option<&mut Sampler>,
    ) -> Result<VoxelSample> {
        let mut rng = augment_with;
        let scene = self.scene(frame, Vec::new(), rng.as_deref_mut())?;
        Ok(self.voxelize(&frame.id, &scene, rng))
    }

    /// The frame's scene with `pseudo` points beside its scan (none for Voxel R-CNN),
    /// augmented when `augment_with` is given, its targets kept.
    pub fn scene(
        &self,
        frame: &SensorFrame,
        pseudo: Vec<PseudoPoint>,
        augment_with: Option<&mut Sampler>,
    ) -> Result<Scene> {
        let mut scene = Scene::from_frame(frame, self.section.voxels.fov_only);
        scene.pseudo = pseudo;
        if let Some(rng) = augment_with {
            augment(
                &mut scene,
                &self.section.augment,
                self.gt_sampler.as_ref(),
                rng,
            )
            .map_err(voxel_err)?;
        }
        scene.keep_targets(&self.classes, &self.section.voxels);
        Ok(scene)
    }

    /// The scene's LiDAR voxels (a sampler: training's cap sampling).
    pub fn voxelize(&self, id: &str, scene: &Scene, shuffle: Option<&mut Sampler>) -> VoxelSample {
        let max_voxels = self.section.voxels.max_voxels(shuffle.is_some());
        VoxelSample {
            id: id.to_string(),
            voxels: self.voxelizer.voxelize(&scene.points, max_voxels, shuffle),
            gts: scene.gts.clone(),
        }
    }
}

/// Frames of a batch on one set of sparse sites (batch index = position in the batch).
pub struct VoxelBatch {
    pub ids: Vec<String>,
    pub features: Tensor<2>,
    pub plan: BackbonePlan,
    pub gts: Vec<Vec<GtBox>>,
    /// Stage one's targets (training only).
    pub anchor_targets: Option<AnchorLossTargets>,
}

/// Sites and mean features of `samples` as one batch; refuses a batch without a voxel
/// (the network has nothing to run on).
pub fn batch_inputs(
    samples: &[VoxelSample],
    sparse_shape: [usize; 3],
    device: &Device,
) -> Result<(Tensor<2>, BackbonePlan)> {
    let coords: Vec<[i32; 4]> = samples
        .iter()
        .enumerate()
        .flat_map(|(b, s)| s.voxels.coords_with_batch(b as i32))
        .collect();
    if coords.is_empty() {
        let ids: Vec<&str> = samples.iter().map(|s| s.id.as_str()).collect();
        return Err(PipelineError::Invalid(format!(
            "frames {ids:?} have no LiDAR point inside the point range (and the camera's \
             field of view): nothing to detect on"
        )));
    }
    let features: Vec<f32> = samples
        .iter()
        .flat_map(|s| s.voxels.flat_features().iter().copied())
        .collect();
    let n = coords.len();
    let sites = SparseSites::new(coords, sparse_shape, samples.len())
        .map_err(|e| PipelineError::Invalid(format!("voxel sites: {e}")))?;
    let plan = BackbonePlan::new(Arc::new(sites), device);
    Ok((
        Tensor::from_data(TensorData::new(features, [n, 4]), device),
        plan,
    ))
}

/// The anchor targets of a batch as the loss takes them: per frame (its ground truth),
/// each cared anchor weighted by 1 / (the frame's positives, at least 1).
pub fn anchor_targets(data: &VoxelData, frames: &[&[GtBox]], device: &Device) -> AnchorLossTargets {
    let b = frames.len();
    let a = data.assigner.anchors().len();
    let k = data.classes.len();
    let bins = data.section.anchors.num_dir_bins;
    let mut cls_onehot = vec![0f32; b * a * k];
    let mut cls_weights = vec![0f32; b * a];
    let mut reg_weights = vec![0f32; b * a];
    let mut box_targets = vec![0f32; b * a * 7];
    let mut dir_onehot = vec![0f32; b * a * bins];
    for (f, gts) in frames.iter().enumerate() {
        let t = data.assigner.assign(gts);
        let positives = t.labels.iter().filter(|&&l| l > 0).count().max(1) as f32;
        for i in 0..a {
            let row = f * a + i;
            let label = t.labels[i];
            if label >= 0 {
                cls_weights[row] = 1.0 / positives;
            }
            if label > 0 {
                cls_onehot[row * k + (label as usize - 1)] = 1.0;
                reg_weights[row] = 1.0 / positives;
                box_targets[row * 7..row * 7 + 7].copy_from_slice(&t.box_targets[i]);
            }
            dir_onehot[row * bins + t.dir_targets[i] as usize] = 1.0;
        }
    }
    let t3 = |v: Vec<f32>, c: usize| Tensor::<3>::from_data(TensorData::new(v, [b, a, c]), device);
    let t2 = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [b, a]), device);
    AnchorLossTargets {
        cls_onehot: t3(cls_onehot, k),
        cls_weights: t2(cls_weights),
        reg_weights: t2(reg_weights),
        box_targets: t3(box_targets, 7),
        dir_onehot: t3(dir_onehot, bins),
    }
}

/// A training or detection batch of `samples`.
pub fn collate(
    data: &VoxelData,
    samples: Vec<VoxelSample>,
    with_targets: bool,
    device: &Device,
) -> Result<VoxelBatch> {
    let (features, plan) = batch_inputs(&samples, data.section.voxels.sparse_shape(), device)?;
    let gts: Vec<&[GtBox]> = samples.iter().map(|s| s.gts.as_slice()).collect();
    let anchor_targets = with_targets.then(|| anchor_targets(data, &gts, device));
    Ok(VoxelBatch {
        ids: samples.iter().map(|s| s.id.clone()).collect(),
        features,
        plan,
        gts: samples.into_iter().map(|s| s.gts).collect(),
        anchor_targets,
    })
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::*;

    /// The anchors go to the device with the first call only; the next calls on that
    /// device get the same values from the kept tensor.
    #[test]
    fn on_wgpu_the_anchors_are_uploaded_once() {
        let Some(device) = fusiondet_nn::cube::working_wgpu_device("the anchors' upload") else {
            return;
        };
        // A small grid (3,200 anchors, 90 KB): the tests beside it share the device.
        let mut section = VoxelRcnnSection::default();
        section.voxels.point_range = [0.0, -8.0, -3.0, 16.0, 8.0, 1.0];
        let data = VoxelData::new(&section, None).unwrap();
        assert_eq!(data.assigner.anchors().len(), 3_200);
        let first = data.device_anchors(&device);
        let kept = data
            .device_anchors
            .get()
            .expect("kept after the first call");
        assert!(
            kept.device() == device.clone().without_autodiff(),
            "kept for this device"
        );
        let again = data.device_anchors(&device).into_data();
        assert_eq!(again, first.into_data());
        assert_eq!(
            again.shape().to_vec(),
            vec![data.assigner.anchors().len(), 7]
        );
    }
}
