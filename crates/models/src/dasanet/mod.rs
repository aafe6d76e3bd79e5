//! DASANet (Zhang & Wei, Remote Sensing 2023) in burn, on the Voxel R-CNN blocks:
//!
//! - stage one (Algorithm A1, steps 3–5): two sparse backbones of Voxel R-CNN's shape
//!   with separate weights, over LiDAR voxels and pseudo-point voxels; their last maps
//!   (C4, P4 after the output layer) height-compressed, concatenated → BEV backbone →
//!   anchor head → proposals (decoded and suppressed by the caller);
//! - stage two (steps 6–11): RoI grid features F^S from C3, C4 and F^P from P3, P4 →
//!   [`tdis`] → F^T; the LiDAR and pseudo points cropped in each RoI → [`stca`] → F^A;
//!   F^T and F^A flattened, concatenated → detection head ([`RoiHead`]); two auxiliary
//!   heads on F^T alone and F^A alone while training (Section 3.4.1).
//!
//! The rows of the ablation switch the modules: the +TDIS row's head reads F^T alone, the
//! +STCA row's F^A alone (no RoI grid pooling; see [`config`] for why). The baseline row
//! is Voxel R-CNN itself.

mod bev_buckets;
pub mod checkpoint;
pub mod config;
pub mod giou;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod giou_device;
pub mod loss;
pub mod stca;
pub mod tca;
pub mod tdis;

pub use checkpoint::{
    DasanetShape, load_dasanet, load_dasanet_for_detection, read_dasanet_shape, save_dasanet,
    save_dasanet_for_inference,
};
pub use config::{AblationRow, DasanetModules, DasanetNetConfig, PSEUDO_VOXEL_FEATURES};
pub use giou::{giou_3d_loss, iou_giou_3d};
pub use loss::rcnn_loss;
pub use stca::{RoiPoints, Stca, StcaConfig};
pub use tca::CoordinateAttention3d;
pub use tdis::Tdis;

use crate::info::trainable_params;
use crate::voxel_rcnn::{
    AnchorHead, AnchorPredictions, BackboneOutput, BackbonePlan, BevBackbone, RoiGridIndex,
    RoiGridPool, RoiHead, RoiPredictions, VoxelBackbone, bev_heights, height_compression,
    pooled_maps,
};
use burn::prelude::*;

#[derive(Module, Debug)]
pub struct Dasanet {
    pub lidar_backbone: VoxelBackbone,
    pub pseudo_backbone: VoxelBackbone,
    pub bev: BevBackbone,
    pub anchor_head: AnchorHead,
    /// F^S from C3, C4 and F^P from P3, P4 (with TDIS).
    pub lidar_pool: Option<RoiGridPool>,
    pub pseudo_pool: Option<RoiGridPool>,
    pub tdis: Option<Tdis>,
    pub stca: Option<Stca>,
    pub head: RoiHead,
    /// Auxiliary heads on F^T and on F^A (both modules on; training only).
    pub aux_tdis: Option<RoiHead>,
    pub aux_stca: Option<RoiHead>,
}

/// Stage one's outputs: both branches' maps (kept for RoI pooling) and the anchors.
#[derive(Debug, Clone)]
pub struct DasanetStageOne {
    pub lidar: BackboneOutput,
    pub pseudo: BackboneOutput,
    pub anchors: AnchorPredictions,
}

/// What stage two reads besides the maps: the RoI grid queries of both branches (for
/// TDIS) and the points cropped in the RoIs (for STCA).
#[derive(Debug, Clone)]
pub struct DasanetRoiInputs {
    /// (LiDAR, pseudo) RoI grid queries.
    pub grids: Option<(RoiGridIndex, RoiGridIndex)>,
    /// (LiDAR, pseudo) points per RoI, for STCA.
    pub points: Option<(stca::RoiPoints, stca::RoiPoints)>,
}

/// The detection head's predictions and, when asked for, the auxiliary heads'.
#[derive(Debug, Clone)]
pub struct DasanetRoiOutput {
    pub detection: RoiPredictions,
    pub aux_tdis: Option<RoiPredictions>,
    pub aux_stca: Option<RoiPredictions>,
}

impl Dasanet {
    /// The network for a voxel grid with `grid_z` heights (41 in the published config).
    pub fn new(config: &DasanetNetConfig, grid_z: usize, device: &Device) -> Result<Self, String> {
        config.validate()?;
        let base = &config.voxel_rcnn;
        let mut pseudo_base = base.clone();
        pseudo_base.input_channels = PSEUDO_VOXEL_FEATURES;
        let bev_in = 2 * base.bev_input_channels(bev_heights(grid_z));
        let level_channels: Vec<usize> = base
            .roi
            .levels
            .iter()
            .map(|l| base.stage_channels(l.stage))
            .collect();
        let pool = || RoiGridPool::new(&base.roi, &level_channels, device);
        let (c, n) = (config.roi_channels(), config.grid_locations());
        let grid_width = config.grid_width();
        let stca_width = config.modules.stca_shape.flattened_width();
        let head = |width| RoiHead::new(&base.roi, width, device);
        Ok(Self {
            lidar_backbone: VoxelBackbone::new(base, device),
            pseudo_backbone: VoxelBackbone::new(&pseudo_base, device),
            bev: BevBackbone::new(&base.bev, bev_in, &base.backbone_norm(), device),
            anchor_head: AnchorHead::new(
                BevBackbone::output_channels(&base.bev),
                base.anchors_per_location,
                base.num_classes,
                base.num_direction_bins,
                device,
            ),
            lidar_pool: config.modules.tdis.then(pool),
            pseudo_pool: config.modules.tdis.then(pool),
            tdis: config.modules.tdis.then(|| {
                Tdis::new(
                    c,
                    n,
                    config.modules.tdis_init,
                    config.modules.tdis_form,
                    device,
                )
            }),
            stca: config
                .modules
                .stca
                .then(|| Stca::new(&config.modules.stca_shape, &base.backbone_norm(), device)),
            head: head(config.head_input()),
            aux_tdis: config.has_aux_heads().then(|| head(grid_width)),
            aux_stca: config.has_aux_heads().then(|| head(stca_width)),
        })
    }

    /// The network for detection: the training-only auxiliary heads dropped.
    pub fn without_aux_heads(self) -> Self {
        Self {
            aux_tdis: None,
            aux_stca: None,
            ..self
        }
    }

    /// LiDAR voxel features [voxels, 4] and pseudo voxel features [voxels, 6] on their
    /// plans' sites (one grid) → both branches' maps and the anchor predictions.
    pub fn stage_one(
        &self,
        lidar_features: Tensor<2>,
        lidar_plan: &BackbonePlan,
        pseudo_features: Tensor<2>,
        pseudo_plan: &BackbonePlan,
    ) -> DasanetStageOne {
        let lidar = self.lidar_backbone.forward(lidar_features, lidar_plan);
        let pseudo = self.pseudo_backbone.forward(pseudo_features, pseudo_plan);
        DasanetStageOne {
            anchors: self.bev_and_anchors(&lidar, &pseudo),
            lidar,
            pseudo,
        }
    }

    /// C4 and P4 height-compressed and concatenated → BEV backbone → anchor head.
    pub fn bev_and_anchors(
        &self,
        lidar: &BackboneOutput,
        pseudo: &BackboneOutput,
    ) -> AnchorPredictions {
        let bev = Tensor::cat(
            vec![
                height_compression(&lidar.output),
                height_compression(&pseudo.output),
            ],
            1,
        );
        self.anchor_head.forward(self.bev.forward(bev))
    }

    /// F^T [RoIs, N·C] (with TDIS): both branches' RoI grid features through TDIS.
    pub fn supplemented(
        &self,
        config: &DasanetNetConfig,
        stage_one: &DasanetStageOne,
        inputs: &DasanetRoiInputs,
    ) -> Option<Tensor<2>> {
        let (tdis, lidar_pool, pseudo_pool) = (
            self.tdis.as_ref()?,
            self.lidar_pool.as_ref()?,
            self.pseudo_pool.as_ref()?,
        );
        let (lidar_grid, pseudo_grid) = inputs
            .grids
            .as_ref()
            .expect("TDIS needs both branches' RoI grid queries");
        let levels = &config.voxel_rcnn.roi.levels;
        let lidar = lidar_pool.forward(&pooled_maps(&stage_one.lidar, levels), lidar_grid);
        let pseudo = pseudo_pool.forward(&pooled_maps(&stage_one.pseudo, levels), pseudo_grid);
        Some(tdis.forward(lidar, pseudo))
    }

    /// A diagnostic of TDIS's scale (issue 34): RMS(F^T − F^S) / RMS(F^S) over the batch's
    /// RoIs and the largest |weight| of W^Sp, W^Ch, W^Go. Recomputes the pooling, so only
    /// a run that asks for it (`FUSIONDET_TDIS_STATS`) pays for it.
    pub fn tdis_scale(
        &self,
        config: &DasanetNetConfig,
        stage_one: &DasanetStageOne,
        inputs: &DasanetRoiInputs,
    ) -> Option<(f32, f32)> {
        let (tdis, lidar_pool) = (self.tdis.as_ref()?, self.lidar_pool.as_ref()?);
        let supplemented = self.supplemented(config, stage_one, inputs)?;
        let (lidar_grid, _) = inputs.grids.as_ref()?;
        let levels = &config.voxel_rcnn.roi.levels;
        let lidar = lidar_pool.forward(&pooled_maps(&stage_one.lidar, levels), lidar_grid);
        let rms = |t: Tensor<2>| t.powi_scalar(2).mean().sqrt().into_scalar::<f32>();
        let ratio = rms(supplemented - lidar.clone()) / rms(lidar);
        let largest = [&tdis.spatial, &tdis.channel, &tdis.global]
            .iter()
            .map(|w| w.val().abs().max().into_scalar::<f32>())
            .fold(0.0f32, f32::max);
        Some((ratio, largest))
    }

    /// F^A flattened [RoIs, g³·2C] (with STCA).
    pub fn attention(&self, inputs: &DasanetRoiInputs, device: &Device) -> Option<Tensor<2>> {
        let stca = self.stca.as_ref()?;
        let (lidar, pseudo) = inputs
            .points
            .as_ref()
            .expect("STCA needs the points cropped in the RoIs");
        Some(stca.forward(lidar, pseudo, device))
    }

    /// The detection head's input: F^T and F^A, those present, concatenated.
    pub fn head_input(
        supplemented: &Option<Tensor<2>>,
        attention: &Option<Tensor<2>>,
    ) -> Tensor<2> {
        let parts: Vec<Tensor<2>> = supplemented.iter().chain(attention).cloned().collect();
        Tensor::cat(parts, 1)
    }

    /// Stage two over the RoIs of `inputs`; the auxiliary heads run when `auxiliary`. Its
    /// three steps are public so that a caller can queue TDIS ([`Self::supplemented`]) on a
    /// GPU before it crops STCA's points on the host (`inputs.points`), the crops then
    /// running while the device works, and time STCA ([`Self::attention`]) apart from the
    /// heads ([`Self::heads`]); the same operations in the same order either way.
    pub fn stage_two(
        &self,
        config: &DasanetNetConfig,
        stage_one: &DasanetStageOne,
        inputs: &DasanetRoiInputs,
        auxiliary: bool,
    ) -> DasanetRoiOutput {
        let supplemented = self.supplemented(config, stage_one, inputs);
        let attention = self.attention(inputs, &stage_one.anchors.cls.device());
        self.heads(supplemented, attention, auxiliary)
    }

    /// The heads on TDIS's F^T and STCA's F^A ([`Self::attention`]): the detection head and,
    /// with `auxiliary`, each module's auxiliary head.
    pub fn heads(
        &self,
        supplemented: Option<Tensor<2>>,
        attention: Option<Tensor<2>>,
        auxiliary: bool,
    ) -> DasanetRoiOutput {
        let aux = |head: &Option<RoiHead>, x: &Option<Tensor<2>>| match (head, x) {
            (Some(h), Some(x)) if auxiliary => Some(h.forward(x.clone())),
            _ => None,
        };
        DasanetRoiOutput {
            detection: self
                .head
                .forward(Self::head_input(&supplemented, &attention)),
            aux_tdis: aux(&self.aux_tdis, &supplemented),
            aux_stca: aux(&self.aux_stca, &attention),
        }
    }

    /// Trainable parameters per module, in data-flow order; the auxiliary heads last
    /// (they exist in training only).
    pub fn param_rows(&self) -> Vec<(String, usize)> {
        let mut rows = vec![
            (
                "LiDAR 3D backbone".to_string(),
                trainable_params(&self.lidar_backbone),
            ),
            (
                "pseudo 3D backbone".into(),
                trainable_params(&self.pseudo_backbone),
            ),
            ("BEV backbone (C4 ⊕ P4)".into(), trainable_params(&self.bev)),
            ("anchor head".into(), trainable_params(&self.anchor_head)),
        ];
        if let Some(p) = &self.lidar_pool {
            rows.push(("RoI grid pooling, LiDAR (F^S)".into(), trainable_params(p)));
        }
        if let Some(p) = &self.pseudo_pool {
            rows.push(("RoI grid pooling, pseudo (F^P)".into(), trainable_params(p)));
        }
        if let Some(t) = &self.tdis {
            rows.push(("TDIS (W^Sp, W^Ch, W^Go)".into(), trainable_params(t)));
        }
        if let Some(s) = &self.stca {
            rows.push(("STCA Siamese encoder".into(), trainable_params(&s.encoder)));
            rows.push((
                "STCA coordinate attention".into(),
                trainable_params(&s.attention),
            ));
        }
        rows.push(("detection head".into(), trainable_params(&self.head)));
        rows
    }

    /// Parameters of the auxiliary heads (training only; not in [`param_rows`](Self::param_rows)).
    pub fn aux_params(&self) -> usize {
        self.aux_tdis.as_ref().map_or(0, trainable_params)
            + self.aux_stca.as_ref().map_or(0, trainable_params)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::voxel_rcnn::loss::{RoiLossTargets, VoxelRcnnLossConfig, box_corners};
    use crate::voxel_rcnn::roi_pool::VoxelGeometry;
    use crate::voxel_rcnn::synthetic::unit;
    use burn::module::{ModuleVisitor, Param};
    use fusiondet_nn::sparse::SparseSites;
    use std::sync::Arc;

    /// A tiny network of the given row.
    pub(crate) fn tiny(row: AblationRow) -> DasanetNetConfig {
        let mut config = DasanetNetConfig::published(row);
        let base = &mut config.voxel_rcnn;
        base.backbone_channels = [4, 8, 8, 8];
        base.backbone_out_channels = 4;
        base.bev.num_filters = vec![4, 4];
        base.bev.num_upsample_filters = vec![4, 4];
        base.bev.layer_nums = vec![1, 1];
        base.roi.grid_size = 2;
        for level in &mut base.roi.levels {
            level.mid_channels = 4;
            level.out_channels = 4;
        }
        base.roi.shared_fc = vec![8];
        base.roi.cls_fc = vec![8];
        base.roi.reg_fc = vec![8];
        base.roi.dropout = 0.0;
        config.modules.stca_shape = StcaConfig {
            grid: 4,
            margin: 0.1,
            max_points: 32,
            point_mlp: [8, 8],
            encoder_channels: 8,
            output_channels: 8,
            reduction: 16,
        };
        config
    }

    /// Random voxels of a 41 × 32 × 32 grid (0.1 m) and their mean features.
    fn voxels(seed: u64, channels: usize, d: &Device) -> (BackbonePlan, Tensor<2>) {
        let mut state = seed;
        let mut coords = std::collections::BTreeSet::new();
        while coords.len() < 400 {
            let c = [
                0,
                (unit(&mut state) * 41.0) as i32,
                (unit(&mut state) * 32.0) as i32,
                (unit(&mut state) * 32.0) as i32,
            ];
            coords.insert(c);
        }
        let n = coords.len();
        let sites = SparseSites::new(coords.into_iter().collect(), [41, 32, 32], 1).unwrap();
        let features: Vec<f32> = (0..n * channels).map(|_| unit(&mut state) as f32).collect();
        (
            BackbonePlan::new(Arc::new(sites), d),
            Tensor::from_data(TensorData::new(features, [n, channels]), d),
        )
    }

    /// Names of the parameters that received a gradient.
    fn with_gradients(model: &Dasanet, grads: &burn::tensor::Gradients) -> Vec<String> {
        struct Seen<'a> {
            path: Vec<String>,
            grads: &'a burn::tensor::Gradients,
            names: Vec<String>,
        }
        impl ModuleVisitor for Seen<'_> {
            fn enter_module(&mut self, name: &str, _: &str) {
                self.path.push(name.to_string());
            }
            fn exit_module(&mut self, _: &str, _: &str) {
                self.path.pop();
            }
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                if param.val().grad(self.grads).is_some() {
                    self.names.push(self.path.join("."));
                }
            }
        }
        let mut seen = Seen {
            path: vec![],
            grads,
            names: vec![],
        };
        model.visit(&mut seen);
        seen.names
    }

    /// Each row runs both stages on random voxels and two RoIs — one without pseudo
    /// points — and a backward pass reaches both backbones and every module of the row.
    #[test]
    fn every_row_trains_end_to_end() {
        let ad = Device::flex().autodiff();
        let geometry = VoxelGeometry {
            origin: [0.0, -1.6, -3.0],
            voxel_size: [0.1; 3],
        };
        for row in [AblationRow::Tdis, AblationRow::Stca, AblationRow::Dasanet] {
            let config = tiny(row);
            let model = Dasanet::new(&config, 41, &ad).unwrap();
            let (lidar_plan, lidar_features) = voxels(1, 4, &ad);
            let (pseudo_plan, pseudo_features) = voxels(2, PSEUDO_VOXEL_FEATURES, &ad);
            let one = model.stage_one(lidar_features, &lidar_plan, pseudo_features, &pseudo_plan);
            let rois = vec![
                [1.5, 0.0, -1.0, 1.2, 0.8, 0.8, 0.3],
                [2.8, 1.2, -1.0, 0.6, 0.4, 0.5, 0.0],
            ];
            let levels = &config.voxel_rcnn.roi.levels;
            let grid = |out: &BackboneOutput| {
                let sites: Vec<&SparseSites> = pooled_maps(out, levels)
                    .iter()
                    .map(|m| m.sites.as_ref())
                    .collect();
                RoiGridIndex::new(std::slice::from_ref(&rois), &sites, levels, 2, &geometry)
            };
            let lidar_points: Vec<f32> = (0..60)
                .flat_map(|i| [1.0 + 0.02 * i as f32, 0.1, -1.0, 0.5])
                .collect();
            let pseudo_points: Vec<f32> = (0..80)
                .flat_map(|i| [1.0 + 0.015 * i as f32, -0.1, -0.9])
                .collect();
            let inputs = DasanetRoiInputs {
                grids: config
                    .modules
                    .tdis
                    .then(|| (grid(&one.lidar), grid(&one.pseudo))),
                points: config.modules.stca.then(|| {
                    (
                        RoiPoints::new(
                            &[(&lidar_points, 4)],
                            &rois,
                            &[0, 0],
                            &config.modules.stca_shape,
                        ),
                        RoiPoints::new(
                            &[(&pseudo_points, 3)],
                            &rois,
                            &[0, 0],
                            &config.modules.stca_shape,
                        ),
                    )
                }),
            };
            if let Some((l, p)) = &inputs.points {
                assert!(l.num_points() > 0 && p.num_points() > 0);
                assert!(
                    p.sites.coords().iter().all(|c| c[0] == 0),
                    "RoI 1 holds no pseudo point"
                );
            }
            let out = model.stage_two(&config, &one, &inputs, true);
            assert_eq!(out.detection.boxes.dims(), [2, 7]);
            assert_eq!(out.aux_tdis.is_some(), row == AblationRow::Dasanet);
            let sizes =
                Tensor::<2>::from_data(TensorData::new(vec![1.2f32, 0.8, 0.8], [1, 3]), &ad);
            let gt = box_corners(
                Tensor::zeros([1, 3], &ad),
                sizes.clone(),
                Tensor::zeros([1, 1], &ad),
            );
            let targets = RoiLossTargets {
                cls: Tensor::from_data(TensorData::new(vec![0.8f32, 0.0], [2, 1]), &ad),
                fg_rows: Some(fusiondet_nn::gather::RowGather::new(&[0], 2, &ad)),
                reg: Tensor::zeros([1, 7], &ad),
                roi_sizes: sizes,
                gt_corners: gt.clone(),
                gt_corners_flipped: gt,
            };
            let terms = rcnn_loss(
                &out,
                &targets,
                &VoxelRcnnLossConfig::default(),
                1.0,
                config.modules.aux_weights,
            );
            let total = terms.into_iter().map(|t| t.1).reduce(|a, b| a + b).unwrap()
                + one.anchors.cls.sum().mul_scalar(1e-3);
            let grads = total.backward();
            let names = with_gradients(&model, &grads);
            let reached = |prefix: &str| names.iter().any(|n| n.starts_with(prefix));
            assert!(
                reached("lidar_backbone") && reached("pseudo_backbone") && reached("head"),
                "{row:?}"
            );
            assert_eq!(reached("tdis"), config.modules.tdis, "{row:?}");
            assert_eq!(reached("pseudo_pool"), config.modules.tdis, "{row:?}");
            assert_eq!(reached("stca.encoder"), config.modules.stca, "{row:?}");
            assert_eq!(reached("stca.attention"), config.modules.stca, "{row:?}");
            assert_eq!(reached("aux_stca"), row == AblationRow::Dasanet, "{row:?}");

            // Inference: the auxiliary heads do not run.
            let valid = model.valid();
            let one = valid.stage_one(
                voxels(1, 4, &Device::flex()).1,
                &voxels(1, 4, &Device::flex()).0,
                voxels(2, PSEUDO_VOXEL_FEATURES, &Device::flex()).1,
                &voxels(2, PSEUDO_VOXEL_FEATURES, &Device::flex()).0,
            );
            let out = valid.stage_two(&config, &one, &inputs, false);
            assert!(out.aux_tdis.is_none() && out.aux_stca.is_none());
        }
    }

    /// The published rows' inference parameters land within 10% of the paper's Table 5.
    #[test]
    fn published_rows_count_within_ten_percent_of_table_five() {
        let device = Device::flex();
        for row in [AblationRow::Tdis, AblationRow::Stca, AblationRow::Dasanet] {
            let config = DasanetNetConfig::published(row);
            let model = Dasanet::new(&config, 41, &device).unwrap();
            let total: usize = model.param_rows().iter().map(|r| r.1).sum();
            let (paper, _, _) = row.published_cost();
            let ratio = total as f64 / (paper * 1e6);
            println!(
                "{}: {total} ({:+.1}%) aux {}",
                row.label(),
                100.0 * (ratio - 1.0),
                model.aux_params()
            );
            for (name, n) in model.param_rows() {
                println!("  {name}: {n}");
            }
            assert!(
                (ratio - 1.0).abs() <= 0.10,
                "{}: {total} against {paper} M",
                row.label()
            );
        }
        assert!(
            DasanetNetConfig::published(AblationRow::Baseline)
                .validate()
                .is_err()
        );
    }
}
