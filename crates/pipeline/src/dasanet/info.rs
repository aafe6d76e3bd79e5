//! `fusiondet info` for a DASANet configuration: parameters per module (the auxiliary
//! heads apart: they exist in training only) and the multiply-adds of each stage on a
//! typical frame — the KITTI-like synthetic scene of `models::voxel_rcnn::synthetic`, its
//! LiDAR sweep for the LiDAR branch and the same scene through the camera for the pseudo
//! branch; the RoI stages at the test-time proposal count, STCA's RoIs the scene's cars
//! repeated.

use super::config::DasanetSection;
use crate::error::{PipelineError, Result};
use crate::voxel_rcnn::VoxelRcnnSection;
use burn::prelude::*;
use fusiondet_models::dasanet::{AblationRow, Dasanet, RoiPoints};
use fusiondet_models::voxel_rcnn::synthetic::{synthetic_pseudo_cloud, synthetic_sweep};
use fusiondet_models::voxel_rcnn::{BackbonePlan, BevBackbone, bev_heights};
use fusiondet_nn::sparse::SparseSites;
use std::fmt::Write;
use std::sync::Arc;

/// Multiply-adds per stage of one frame, with the voxels of both branches.
#[derive(Debug, Clone, PartialEq)]
pub struct DasanetCosts {
    pub lidar_voxels: usize,
    pub pseudo_voxels: usize,
    pub rows: Vec<(&'static str, u64)>,
}

/// The costs of the configured network on the synthetic frame.
pub fn stage_costs(
    voxel: &VoxelRcnnSection,
    dasanet: &DasanetSection,
    model: &Dasanet,
) -> DasanetCosts {
    let v = &voxel.voxels;
    let device = Device::flex();
    let sweep = synthetic_sweep(1, v.point_range, v.voxel_size);
    let pseudo = synthetic_pseudo_cloud(1, v.point_range, v.voxel_size);
    // The detector keeps the first `max_voxels_test` pseudo voxels in scan order.
    let cap = dasanet.pseudo.max_voxels_test.min(pseudo.sites.len());
    let pseudo_sites = SparseSites::new(
        pseudo.sites.coords()[..cap].to_vec(),
        pseudo.sites.spatial_shape(),
        1,
    )
    .expect("a prefix of valid sites");
    let (lidar_voxels, pseudo_voxels) = (sweep.sites.len(), cap);
    let lidar_plan = BackbonePlan::new(Arc::new(sweep.sites), &device);
    let pseudo_plan = BackbonePlan::new(Arc::new(pseudo_sites), &device);
    let net = &voxel.network;
    let mut pseudo_net = net.clone();
    pseudo_net.input_channels = fusiondet_models::dasanet::PSEUDO_VOXEL_FEATURES;
    let [nx, ny, _] = v.grid_size();
    let bev_in = 2 * net.bev_input_channels(bev_heights(v.sparse_shape()[0]));
    let map = [ny / 8, nx / 8];
    let bev_out = BevBackbone::output_channels(&net.bev);
    let anchor_cells = (map[0] * net.bev.upsample_strides[0] / net.bev.layer_strides[0])
        * (map[1] * net.bev.upsample_strides[0] / net.bev.layer_strides[0]);
    let rois = voxel.proposals.test.post_max;
    let grid_points = rois * net.roi.grid_size.pow(3);
    let level_voxels = |plan: &BackbonePlan| -> Vec<usize> {
        net.roi
            .levels
            .iter()
            .map(|l| plan.site_counts()[l.stage - 1])
            .collect()
    };
    let mut rows = vec![
        ("LiDAR 3D backbone", lidar_plan.multiply_adds(net)),
        ("pseudo 3D backbone", pseudo_plan.multiply_adds(&pseudo_net)),
        (
            "BEV backbone",
            BevBackbone::multiply_adds(&net.bev, bev_in, map),
        ),
        (
            "anchor head",
            model.anchor_head.multiply_adds(bev_out, anchor_cells),
        ),
    ];
    if let (Some(lp), Some(pp), Some(tdis)) = (&model.lidar_pool, &model.pseudo_pool, &model.tdis) {
        rows.push((
            "RoI grid pooling (both)",
            lp.multiply_adds(&level_voxels(&lidar_plan), grid_points)
                + pp.multiply_adds(&level_voxels(&pseudo_plan), grid_points),
        ));
        rows.push(("TDIS", tdis.multiply_adds_per_roi() * rois as u64));
    }
    if let Some(stca) = &model.stca {
        let boxes: Vec<[f64; 7]> = (0..rois)
            .map(|k| sweep.cars[k % sweep.cars.len()])
            .collect();
        let shape = &dasanet.modules.stca_shape;
        let batch = vec![0; rois];
        let l = RoiPoints::new(&[(&sweep.cloud, 4)], &boxes, &batch, shape);
        let p = RoiPoints::new(&[(&pseudo.cloud, 6)], &boxes, &batch, shape);
        rows.push(("STCA", stca.multiply_adds(&l, &p, &device)));
    }
    rows.push((
        "detection head",
        model.head.multiply_adds_per_roi() * rois as u64,
    ));
    DasanetCosts {
        lidar_voxels,
        pseudo_voxels,
        rows,
    }
}

pub fn render_info(
    name: &str,
    voxel: &VoxelRcnnSection,
    dasanet: &DasanetSection,
) -> Result<String> {
    let shape = dasanet.shape(voxel);
    let model = Dasanet::new(&shape.network, shape.grid_z, &Device::flex())
        .map_err(PipelineError::Invalid)?;
    let row = shape.network.row();
    let (paper_params, paper_gflops, paper_fps) = row.published_cost();
    let m = &dasanet.modules;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "DASANet, ablation row {} ({name}): Voxel R-CNN's grid {:?} m voxels over {:?} m for both \
         clouds (≤ {} LiDAR / {} pseudo points per voxel); RoI grid {}³ over stages {:?}; STCA \
         grid {}³ → {}³ × {} channels per cloud; λ1, λ2 = {:?}",
        row.label(),
        voxel.voxels.voxel_size,
        voxel.voxels.point_range,
        voxel.voxels.max_points_per_voxel,
        dasanet.pseudo.max_points_per_voxel,
        voxel.network.roi.grid_size,
        voxel
            .network
            .roi
            .levels
            .iter()
            .map(|l| l.stage)
            .collect::<Vec<_>>(),
        m.stca_shape.grid,
        m.stca_shape.output_grid(),
        m.stca_shape.output_channels,
        m.aux_weights,
    );
    let _ = writeln!(out, "{:<36} {:>12}", "module", "parameters");
    let rows = model.param_rows();
    for (module, n) in &rows {
        let _ = writeln!(out, "{module:<36} {n:>12}");
    }
    let total: usize = rows.iter().map(|r| r.1).sum();
    let _ = writeln!(out, "{:<36} {:>12}", "total (inference)", total);
    if model.aux_params() > 0 {
        let _ = writeln!(
            out,
            "{:<36} {:>12}",
            "auxiliary heads (training only)",
            model.aux_params()
        );
    }
    if row != AblationRow::Baseline {
        let _ = writeln!(
            out,
            "the paper's Table 5 for this row: {paper_params} M parameters, {paper_gflops} GFLOPs, \
             {paper_fps} FPS on an RTX 3090"
        );
    }
    let costs = stage_costs(voxel, dasanet, &model);
    let _ = writeln!(
        out,
        "\nMultiply-adds per frame on a typical scene ({} LiDAR voxels, {} pseudo voxels; RoI \
         stages at {} proposals):",
        costs.lidar_voxels, costs.pseudo_voxels, voxel.proposals.test.post_max
    );
    for (stage, macs) in &costs.rows {
        let _ = writeln!(out, "{stage:<36} {:>9.2} G", *macs as f64 / 1e9);
    }
    let total: u64 = costs.rows.iter().map(|r| r.1).sum();
    let _ = writeln!(out, "{:<36} {:>9.2} G", "total", total as f64 / 1e9);
    Ok(out)
}
