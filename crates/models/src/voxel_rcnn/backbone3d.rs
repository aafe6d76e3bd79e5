//! VoxelBackBone8x (SECOND's sparse backbone as Voxel R-CNN uses it): a submanifold
//! input layer, then four stages that each halve the grid with a regular sparse
//! convolution and refine it with two submanifold ones, and a (3,1,1) convolution that
//! leaves two heights for the bird's-eye view. Every layer is conv → BN → ReLU.

use super::config::VoxelRcnnNetConfig;
use burn::prelude::*;
use fusiondet_nn::sparse::{ConvGeometry, Rulebook, SparseConv3d, SparseConvBlock, SparseSites};
use std::sync::Arc;

/// Features on active sites: one row per site.
#[derive(Debug, Clone)]
pub struct SparseMap {
    pub features: Tensor<2>,
    pub sites: Arc<SparseSites>,
}

/// The downsampling convolution of each stage (stage 1 has none) and the output layer.
pub fn stage_geometry(stage: usize) -> Option<ConvGeometry> {
    match stage {
        1 => None,
        2 | 3 => Some(ConvGeometry::strided([3; 3], [2; 3], [1; 3])),
        _ => Some(ConvGeometry::strided([3; 3], [2; 3], [0, 1, 1])),
    }
}

/// The (3,1,1)/(2,1,1) convolution that squeezes the height before the BEV view.
pub fn output_geometry() -> ConvGeometry {
    ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3])
}

/// Every rulebook one forward pass needs, built from the input voxels alone, so a data
/// loader can build them ahead of the network. Each stage's submanifold layers share
/// one rulebook.
#[derive(Debug, Clone)]
pub struct BackbonePlan {
    pub input: Arc<SparseSites>,
    /// Per stage: the downsampling rulebook (none for stage 1), then the submanifold one.
    pub stages: Vec<(Option<Rulebook>, Rulebook)>,
    pub output: Rulebook,
}

impl BackbonePlan {
    pub fn new(input: Arc<SparseSites>, device: &Device) -> BackbonePlan {
        let mut sites = input.clone();
        let mut stages = Vec::with_capacity(4);
        for stage in 1..=4 {
            let down = stage_geometry(stage).map(|g| Rulebook::strided(&sites, g, device));
            if let Some(d) = &down {
                sites = d.output.clone();
            }
            let subm = Rulebook::submanifold(&sites, [3; 3], device);
            stages.push((down, subm));
        }
        let output = Rulebook::strided(&sites, output_geometry(), device);
        BackbonePlan {
            input,
            stages,
            output,
        }
    }

    /// Active sites per stage (1–4) and of the output map.
    pub fn site_counts(&self) -> [usize; 5] {
        let s = |i: usize| self.stages[i].1.output_rows();
        [s(0), s(1), s(2), s(3), self.output.output_rows()]
    }

    /// Multiply-adds of the backbone over these sites with these widths.
    pub fn multiply_adds(&self, config: &VoxelRcnnNetConfig) -> u64 {
        let mut c_in = config.input_channels;
        let mut total = 0u64;
        for (i, (down, subm)) in self.stages.iter().enumerate() {
            let c = config.backbone_channels[i];
            if let Some(d) = down {
                total += (d.total_pairs() * c_in * c) as u64;
                c_in = c;
            }
            // Stage 1: the input layer (4 → c) and one more; later stages: two layers.
            let layers = [(c_in, c), (c, c)];
            total += layers
                .iter()
                .map(|&(a, b)| (subm.total_pairs() * a * b) as u64)
                .sum::<u64>();
            c_in = c;
        }
        total + (self.output.total_pairs() * c_in * config.backbone_out_channels) as u64
    }
}

/// One resolution: an optional downsampling block, then submanifold blocks.
#[derive(Module, Debug)]
pub struct SparseStage {
    pub down: Option<SparseConvBlock>,
    pub refine: Vec<SparseConvBlock>,
}

#[derive(Module, Debug)]
pub struct VoxelBackbone {
    pub stages: Vec<SparseStage>,
    pub output: SparseConvBlock,
}

/// What the backbone hands on: each stage's map (x_conv1 … x_conv4) and the output map.
#[derive(Debug, Clone)]
pub struct BackboneOutput {
    pub stages: Vec<SparseMap>,
    pub output: SparseMap,
}

impl VoxelBackbone {
    pub fn new(config: &VoxelRcnnNetConfig, device: &Device) -> Self {
        let norm = config.backbone_norm();
        let block = |conv| SparseConvBlock::new(conv, &norm, device);
        let subm = |a, b| block(SparseConv3d::submanifold([a, b], [3; 3], device));
        let mut c_in = config.input_channels;
        let mut stages = Vec::with_capacity(4);
        for stage in 1..=4 {
            let c = config.stage_channels(stage);
            let (down, refine) = match stage_geometry(stage) {
                // Stage 1 is the input layer and conv1, both submanifold.
                None => (None, vec![subm(c_in, c), subm(c, c)]),
                Some(g) => (
                    Some(block(SparseConv3d::regular([c_in, c], g, device))),
                    vec![subm(c, c), subm(c, c)],
                ),
            };
            stages.push(SparseStage { down, refine });
            c_in = c;
        }
        let output = block(SparseConv3d::regular(
            [c_in, config.backbone_out_channels],
            output_geometry(),
            device,
        ));
        Self { stages, output }
    }

    /// Mean voxel features [voxels, input channels] on the plan's input sites.
    pub fn forward(&self, voxel_features: Tensor<2>, plan: &BackbonePlan) -> BackboneOutput {
        let mut x = voxel_features;
        let mut maps = Vec::with_capacity(self.stages.len());
        for (stage, (down_book, subm_book)) in self.stages.iter().zip(&plan.stages) {
            if let (Some(down), Some(book)) = (&stage.down, down_book) {
                x = down.forward(x, book);
            }
            for layer in &stage.refine {
                x = layer.forward(x, subm_book);
            }
            maps.push(SparseMap {
                features: x.clone(),
                sites: subm_book.output.clone(),
            });
        }
        let out = self.output.forward(x, &plan.output);
        BackboneOutput {
            stages: maps,
            output: SparseMap {
                features: out,
                sites: plan.output.output.clone(),
            },
        }
    }
}
