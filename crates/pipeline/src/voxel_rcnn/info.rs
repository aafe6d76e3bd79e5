//! `fusiondet info` for a Voxel R-CNN configuration: parameters per module and the
//! multiply-adds of each stage on a typical scan (the KITTI-like synthetic sweep of
//! `models::voxel_rcnn::synthetic` on this configuration's grid; the RoI stages at the
//! test-time proposal count).

use super::config::VoxelRcnnSection;
use crate::error::{PipelineError, Result};
use burn::prelude::*;
use fusiondet_models::info::trainable_params;
use fusiondet_models::voxel_rcnn::synthetic::synthetic_sweep;
use fusiondet_models::voxel_rcnn::{BackbonePlan, BevBackbone, VoxelRcnn, bev_heights};
use std::fmt::Write;
use std::sync::Arc;

/// Multiply-adds per stage of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StageCosts {
    pub voxels: usize,
    pub rows: Vec<(&'static str, u64)>,
}

/// The costs of `section`'s network on the synthetic sweep.
pub fn stage_costs(section: &VoxelRcnnSection, model: &VoxelRcnn) -> StageCosts {
    let v = &section.voxels;
    let range = v.point_range;
    let sweep = synthetic_sweep(1, range, v.voxel_size);
    let device = Device::flex();
    // The sweep comes voxelized on this grid, with the backbone's extra height.
    let shape = sweep.sites.spatial_shape();
    debug_assert_eq!(shape, v.sparse_shape());
    let voxels = sweep.sites.len();
    let plan = BackbonePlan::new(Arc::new(sweep.sites), &device);
    let net = &section.network;
    let [nx, ny, _] = v.grid_size();
    let bev_in = net.bev_input_channels(bev_heights(shape[0]));
    let map = [ny / 8, nx / 8];
    let bev_out = BevBackbone::output_channels(&net.bev);
    let anchor_cells = (map[0] * net.bev.upsample_strides[0] / net.bev.layer_strides[0])
        * (map[1] * net.bev.upsample_strides[0] / net.bev.layer_strides[0]);
    let rois = section.proposals.test.post_max;
    let grid_points = rois * net.roi.grid_size.pow(3);
    let level_voxels: Vec<usize> = net
        .roi
        .levels
        .iter()
        .map(|l| plan.site_counts()[l.stage - 1])
        .collect();
    StageCosts {
        voxels,
        rows: vec![
            ("3D backbone", plan.multiply_adds(net)),
            (
                "BEV backbone",
                BevBackbone::multiply_adds(&net.bev, bev_in, map),
            ),
            (
                "anchor head",
                model.anchor_head.multiply_adds(bev_out, anchor_cells),
            ),
            (
                "RoI grid pooling",
                model.roi_pool.multiply_adds(&level_voxels, grid_points),
            ),
            (
                "RoI head",
                model.roi_head.multiply_adds_per_roi() * rois as u64,
            ),
        ],
    }
}

pub fn render_info(name: &str, section: &VoxelRcnnSection) -> Result<String> {
    let shape = section.shape();
    let model = VoxelRcnn::new(&shape.network, shape.grid_z, &Device::flex())
        .map_err(PipelineError::Invalid)?;
    let v = &section.voxels;
    let [nx, ny, nz] = v.grid_size();
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Voxel R-CNN ({name}): range {:?} m, voxels {:?} m (grid x {nx} × y {ny} × z {nz}), ≤ {} points per voxel, \
         ≤ {} voxels (training) / {} (test); backbone widths {:?} → {}; BEV {:?} filters, {:?} layers; \
         {} anchors per cell; RoI grid {}³ over stages {:?}",
        v.point_range,
        v.voxel_size,
        v.max_points_per_voxel,
        v.max_voxels_train,
        v.max_voxels_test,
        shape.network.backbone_channels,
        shape.network.backbone_out_channels,
        shape.network.bev.num_filters,
        shape.network.bev.layer_nums,
        shape.network.anchors_per_location,
        shape.network.roi.grid_size,
        shape
            .network
            .roi
            .levels
            .iter()
            .map(|l| l.stage)
            .collect::<Vec<_>>(),
    );
    let _ = writeln!(out, "{:<32} {:>12}", "module", "parameters");
    for (module, n) in model.param_rows() {
        let _ = writeln!(out, "{module:<32} {n:>12}");
    }
    let _ = writeln!(out, "{:<32} {:>12}", "total", trainable_params(&model));
    let costs = stage_costs(section, &model);
    let _ = writeln!(
        out,
        "\nMultiply-adds per frame on a typical scan ({} voxels; RoI stages at {} proposals):",
        costs.voxels, section.proposals.test.post_max
    );
    for (stage, macs) in &costs.rows {
        let _ = writeln!(out, "{stage:<32} {:>9.2} G", *macs as f64 / 1e9);
    }
    let total: u64 = costs.rows.iter().map(|r| r.1).sum();
    let _ = writeln!(out, "{:<32} {:>9.2} G", "total", total as f64 / 1e9);
    Ok(out)
}
