//! STCA, the Siamese three-dimension coordinate attention (DASANet, Section 3.3,
//! Figure 4): the LiDAR points P^S and the pseudo points P^P inside each RoI go through
//! one weight-shared encoder — a two-layer point MLP, max-pooled into an RoI-adaptive
//! voxel grid, then two submanifold convolutions and one strided sparse convolution —
//! giving F^ES and F^EP; their channel concatenation F^C goes through the
//! three-dimension coordinate attention ([`super::tca`]) to give F^A.
//!
//! What the paper leaves open, and what is chosen here:
//! - points are cropped from the RoI enlarged by `margin` metres per side (a proposal
//!   that cuts an object short still sees it), in the RoI's canonical frame (centre at
//!   the origin, heading along +x); the grid spans that enlarged box;
//! - the shared MLP sees what both clouds have: canonical x, y, z in metres and the
//!   same divided by the enlarged box's sizes;
//! - at most `max_points` points per RoI and cloud, an evenly strided subset when there
//!   are more (near cars hold tens of thousands of pseudo points), so no seed is needed;
//! - a RoI without points of a cloud leaves that cloud's map at zero.
//!
//! The cropping and voxel assignment are index work on the CPU ([`RoiPoints`]); the
//! network part ([`Stca`]) runs on the index, so gradients reach the MLP and encoder.

use super::bev_buckets::BevBuckets;
use super::tca::CoordinateAttention3d;
use crate::voxel_rcnn::roi_pool::RoiBox;
use burn::prelude::*;
use fusiondet_nn::gather::RowGather;
use fusiondet_nn::sparse::{ConvGeometry, Rulebook, SparseConv3d, SparseConvBlock, SparseSites};
use fusiondet_nn::{MlpLayer, NormConfig, SegmentPool, mlp_stack};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Point features the shared MLP reads: canonical (x, y, z) and the same over the sizes.
pub const POINT_FEATURES: usize = 6;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StcaConfig {
    /// Voxels per edge of the RoI-adaptive grid (the strided convolution halves it).
    pub grid: usize,
    /// Metres added on each side of a RoI before cropping.
    pub margin: f64,
    /// Points per RoI and cloud, at most.
    pub max_points: usize,
    /// Widths of the shared two-layer point MLP.
    pub point_mlp: [usize; 2],
    /// Width of the two submanifold convolutions.
    pub encoder_channels: usize,
    /// Width of the strided convolution (F^ES and F^EP each; F^C has twice this).
    pub output_channels: usize,
    /// Channel reduction of the coordinate attention's squeeze (16 in the paper).
    pub reduction: usize,
}

impl Default for StcaConfig {
    fn default() -> Self {
        Self {
            grid: 12,
            margin: 0.2,
            max_points: 1024,
            point_mlp: [32, 64],
            encoder_channels: 64,
            output_channels: 240,
            reduction: 16,
        }
    }
}

impl StcaConfig {
    pub fn validate(&self) -> Result<(), String> {
        // The crop is a grid³ sparse volume a RoI, bounded before anything is allocated.
        if !(2..=32).contains(&self.grid)
            || !(1..=65_536).contains(&self.max_points)
            || self.reduction == 0
        {
            return Err(format!(
                "[dasanet.stca]: grid must be in 2..=32 (the paper's is 8), max_points in \
                 1..=65536, reduction positive; got grid {}, max_points {}",
                self.grid, self.max_points
            ));
        }
        if self
            .point_mlp
            .iter()
            .chain([&self.encoder_channels, &self.output_channels])
            .any(|&w| w > 4096)
        {
            return Err("[dasanet.stca]: channel widths must be at most 4096".into());
        }
        if self.margin > 10.0 {
            return Err(format!(
                "[dasanet.stca] margin {} must be at most 10 m",
                self.margin
            ));
        }
        if self.point_mlp.contains(&0) || self.encoder_channels == 0 || self.output_channels == 0 {
            return Err("[dasanet.stca]: channel widths must be positive".into());
        }
        if !(self.margin >= 0.0 && self.margin.is_finite()) {
            return Err(format!(
                "[dasanet.stca] margin {} must be a finite number ≥ 0",
                self.margin
            ));
        }
        Ok(())
    }

    /// The strided convolution after the two submanifold ones.
    pub fn down_geometry() -> ConvGeometry {
        ConvGeometry::strided([3; 3], [2; 3], [1; 3])
    }

    /// Cells per edge of F^ES / F^EP.
    pub fn output_grid(&self) -> usize {
        Self::down_geometry().output_shape([self.grid; 3])[0]
    }

    /// Width of the flattened F^A per RoI.
    pub fn flattened_width(&self) -> usize {
        self.output_grid().pow(3) * 2 * self.output_channels
    }
}

/// One cloud's points inside every RoI, grouped by voxel of the RoI's grid.
#[derive(Debug, Clone)]
pub struct RoiPoints {
    /// [points, POINT_FEATURES], sorted by voxel.
    pub features: Vec<f32>,
    /// Points per voxel and the first point of each, in the order of `sites`.
    pub counts: Vec<usize>,
    pub starts: Vec<usize>,
    /// Occupied voxels as (RoI, z, y, x) of a `grid`³ grid per RoI.
    pub sites: Arc<SparseSites>,
    pub num_rois: usize,
    pub grid: usize,
}

impl RoiPoints {
    /// `points` are x, y, z (LiDAR frame) with `stride` floats per point; `rois` all RoIs of
    /// the batch in order, with `batch_of_roi[r]` naming the cloud (in `clouds`) of RoI r.
    pub fn new(
        clouds: &[(&[f32], usize)],
        rois: &[RoiBox],
        batch_of_roi: &[usize],
        config: &StcaConfig,
    ) -> RoiPoints {
        let g = config.grid;
        let buckets: Vec<BevBuckets> = clouds
            .iter()
            .map(|&(points, stride)| BevBuckets::new(points, stride))
            .collect();
        // (voxel key, features) of every kept point, RoI by RoI (in parallel, joined in order),
        // each RoI's sorted by voxel: a RoI's keys all lie above the RoI before's, so the
        // joined list is sorted as a whole. Stable: points keep their cloud order within a
        // voxel.
        let per_roi: Vec<Vec<(u64, [f32; POINT_FEATURES])>> = rois
            .par_iter()
            .enumerate()
            .map(|(r, roi)| {
                let (points, stride) = clouds[batch_of_roi[r]];
                let mut inside = crop(points, stride, &buckets[batch_of_roi[r]], r, roi, config);
                inside.sort_by_key(|(key, _)| *key);
                inside
            })
            .collect();
        let kept: Vec<(u64, [f32; POINT_FEATURES])> = per_roi.into_iter().flatten().collect();
        debug_assert!(kept.is_sorted_by_key(|(key, _)| *key));
        let mut counts = Vec::new();
        let mut starts = Vec::new();
        let mut coords = Vec::new();
        for (i, (key, _)) in kept.iter().enumerate() {
            if i == 0 || kept[i - 1].0 != *key {
                let k = *key as usize;
                let (x, rest) = (k % g, k / g);
                let (y, rest) = (rest % g, rest / g);
                let (z, r) = (rest % g, rest / g);
                coords.push([r as i32, z as i32, y as i32, x as i32]);
                starts.push(i);
                counts.push(0);
            }
            *counts.last_mut().expect("a voxel was opened") += 1;
        }
        let sites = SparseSites::new(coords, [g; 3], rois.len().max(1))
            .expect("voxel keys are distinct and inside the grid");
        RoiPoints {
            features: kept.into_iter().flat_map(|(_, f)| f).collect(),
            counts,
            starts,
            sites: Arc::new(sites),
            num_rois: rois.len(),
            grid: g,
        }
    }

    pub fn num_points(&self) -> usize {
        self.features.len() / POINT_FEATURES
    }
}

/// The points of one cloud inside RoI `r` (enlarged by the margin), as (voxel key,
/// features) in cloud order, thinned evenly to `max_points`. Only the points of the cells
/// the enlarged box's footprint touches are tested; each test is exact.
fn crop(
    points: &[f32],
    stride: usize,
    buckets: &BevBuckets,
    r: usize,
    roi: &RoiBox,
    config: &StcaConfig,
) -> Vec<(u64, [f32; POINT_FEATURES])> {
    let g = config.grid;
    let [cx, cy, cz, dx, dy, dz, heading] = *roi;
    let size = [
        dx + 2.0 * config.margin,
        dy + 2.0 * config.margin,
        dz + 2.0 * config.margin,
    ];
    let (sin, cos) = heading.sin_cos();
    // The turned box's axis-aligned footprint, widened by far more than the test's rounding.
    let half = [
        0.5 * (size[0] * cos.abs() + size[1] * sin.abs()) + 1e-6,
        0.5 * (size[0] * sin.abs() + size[1] * cos.abs()) + 1e-6,
    ];
    let candidates = buckets.candidates([cx - half[0], cy - half[1]], [cx + half[0], cy + half[1]]);
    let mut inside: Vec<(u64, [f32; POINT_FEATURES])> = candidates
        .into_iter()
        .filter_map(|i| {
            let p = &points[i as usize * stride..];
            let (x, y, z) = (p[0] as f64 - cx, p[1] as f64 - cy, p[2] as f64 - cz);
            // Into the RoI's frame: rotate by −heading.
            let local = [x * cos + y * sin, -x * sin + y * cos, z];
            let unit: [f64; 3] = std::array::from_fn(|a| local[a] / size[a] + 0.5);
            if unit.iter().any(|u| !(0.0..1.0).contains(u)) {
                return None;
            }
            let cell = unit.map(|u| ((u * g as f64) as usize).min(g - 1));
            let key = (((r * g + cell[2]) * g + cell[1]) * g + cell[0]) as u64;
            let f = [
                local[0] as f32,
                local[1] as f32,
                local[2] as f32,
                (unit[0] - 0.5) as f32,
                (unit[1] - 0.5) as f32,
                (unit[2] - 0.5) as f32,
            ];
            Some((key, f))
        })
        .collect();
    if inside.len() > config.max_points {
        let n = inside.len();
        inside = (0..config.max_points)
            .map(|k| inside[k * n / config.max_points])
            .collect();
    }
    inside
}

/// The weight-shared encoder of both clouds.
#[derive(Module, Debug)]
pub struct SiameseEncoder {
    pub point_mlp: Vec<MlpLayer>,
    pub subm: Vec<SparseConvBlock>,
    pub down: SparseConvBlock,
}

#[derive(Module, Debug)]
pub struct Stca {
    pub encoder: SiameseEncoder,
    pub attention: CoordinateAttention3d,
    #[module(skip)]
    pub output_grid: usize,
    #[module(skip)]
    pub output_channels: usize,
}

impl Stca {
    pub fn new(config: &StcaConfig, norm: &NormConfig, device: &Device) -> Self {
        let [_, mlp_out] = config.point_mlp;
        let e = config.encoder_channels;
        let block = |conv| SparseConvBlock::new(conv, norm, device);
        Self {
            encoder: SiameseEncoder {
                point_mlp: mlp_stack(POINT_FEATURES, &config.point_mlp, norm, device),
                subm: vec![
                    block(SparseConv3d::submanifold([mlp_out, e], [3; 3], device)),
                    block(SparseConv3d::submanifold([e, e], [3; 3], device)),
                ],
                down: block(SparseConv3d::regular(
                    [e, config.output_channels],
                    StcaConfig::down_geometry(),
                    device,
                )),
            },
            attention: CoordinateAttention3d::new(
                2 * config.output_channels,
                config.reduction,
                device,
            ),
            output_grid: config.output_grid(),
            output_channels: config.output_channels,
        }
    }

    /// F^ES or F^EP: [RoIs, g, g, g, C] (x, y, z, channel), zeros where no voxel is active.
    pub fn encode(&self, points: &RoiPoints, device: &Device) -> Tensor<5> {
        let (r, g, c) = (points.num_rois, self.output_grid, self.output_channels);
        if points.sites.is_empty() {
            return Tensor::zeros([r, g, g, g, c], device);
        }
        let n = points.num_points();
        let mut x = Tensor::<2>::from_data(
            TensorData::new(points.features.clone(), [n, POINT_FEATURES]),
            device,
        );
        for layer in &self.encoder.point_mlp {
            x = layer.forward(x);
        }
        let pool = SegmentPool::new(&points.counts, &points.starts, device);
        let mut x = pool.max_pool(x);
        let subm = Rulebook::submanifold(&points.sites, [3; 3], device);
        for layer in &self.encoder.subm {
            x = layer.forward(x, &subm);
        }
        let down = Rulebook::strided(&points.sites, StcaConfig::down_geometry(), device);
        let x = self.encoder.down.forward(x, &down);
        densify(x, &down.output, r, g)
    }

    /// F^A flattened: [RoIs, g³ · 2C].
    pub fn forward(&self, lidar: &RoiPoints, pseudo: &RoiPoints, device: &Device) -> Tensor<2> {
        let features = Tensor::cat(
            vec![self.encode(lidar, device), self.encode(pseudo, device)],
            4,
        );
        let [r, g, _, _, c] = features.dims();
        self.attention.forward(features).reshape([r, g * g * g * c])
    }

    /// Multiply-adds per pass: the MLP over the points, the convolutions over their
    /// pairs, the attention per RoI.
    pub fn multiply_adds(&self, lidar: &RoiPoints, pseudo: &RoiPoints, device: &Device) -> u64 {
        let mut total = 0u64;
        for points in [lidar, pseudo] {
            let n = points.num_points() as u64;
            let mut c_in = POINT_FEATURES as u64;
            for layer in &self.encoder.point_mlp {
                let c = layer.out_channels() as u64;
                total += n * c_in * c;
                c_in = c;
            }
            if points.sites.is_empty() {
                continue;
            }
            let subm = Rulebook::submanifold(&points.sites, [3; 3], device);
            for layer in &self.encoder.subm {
                let [a, b] = layer.conv.channels();
                total += (subm.total_pairs() * a * b) as u64;
            }
            let down = Rulebook::strided(&points.sites, StcaConfig::down_geometry(), device);
            let [a, b] = self.encoder.down.conv.channels();
            total += (down.total_pairs() * a * b) as u64;
        }
        let g = self.output_grid;
        total + lidar.num_rois as u64 * self.attention.multiply_adds_per_roi([g; 3])
    }
}

/// Rows on (RoI, z, y, x) sites of a g³ grid → [RoIs, g, g, g, C] in (x, y, z) order, by
/// gather (an appended zero row fills inactive cells).
fn densify(features: Tensor<2>, sites: &SparseSites, rois: usize, g: usize) -> Tensor<5> {
    let [rows, c] = features.dims();
    let mut index = vec![rows as u32; rois * g * g * g];
    for (row, s) in sites.coords().iter().enumerate() {
        let [r, z, y, x] = s.map(|v| v as usize);
        index[((r * g + x) * g + y) * g + z] = row as u32;
    }
    // On a GPU its backward adds each site's readers in one thread (`RowGather`).
    RowGather::new(&index, rows, &features.device())
        .gather(features)
        .reshape([rois, g, g, g, c])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> StcaConfig {
        StcaConfig {
            grid: 4,
            margin: 0.0,
            max_points: 64,
            point_mlp: [8, 8],
            encoder_channels: 8,
            output_channels: 16,
            reduction: 16,
        }
    }

    /// Points are cropped in the RoI's turned frame and land in the right voxel.
    #[test]
    fn crops_in_the_rois_frame() {
        // A 4 × 2 × 2 box at (10, 5, 0) turned 90°: its length runs along +y.
        let roi = [10.0, 5.0, 0.0, 4.0, 2.0, 2.0, std::f64::consts::FRAC_PI_2];
        let cloud: Vec<f32> = vec![
            9.75, 6.9, 0.9, // local (1.9, 0.25, 0.9): inside, last x cell
            11.5, 5.0, 0.0, // local (0, −1.5): outside (half width is 1)
            9.75, 3.2, -0.9, // local (−1.8, 0.25, −0.9): inside, first x cell
        ];
        let points = RoiPoints::new(&[(&cloud, 3)], &[roi], &[0], &small());
        assert_eq!(points.num_points(), 2);
        let mut coords = points.sites.coords().to_vec();
        coords.sort();
        // (RoI, z, y, x): local y = 0.25 lies in cell 2 of 4.
        assert_eq!(coords, vec![[0, 0, 2, 0], [0, 3, 2, 3]]);
    }

    /// A RoI with no points of a cloud leaves its map at zero, the other RoI's does not,
    /// and a batch where no RoI holds a point passes as zeros.
    #[test]
    fn empty_rois_are_zero() {
        let d = Device::flex();
        let config = small();
        let stca = Stca::new(&config, &NormConfig::default(), &d).valid();
        let near = [0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0];
        let far = [50.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0];
        let cloud: Vec<f32> = (0..20)
            .flat_map(|i| [-0.9 + 0.09 * i as f32, 0.1, 0.2, 1.0])
            .collect();
        let lidar = RoiPoints::new(&[(&cloud, 4)], &[near, far], &[0, 0], &config);
        let nothing = RoiPoints::new(&[(&[], 4)], &[near, far], &[0, 0], &config);
        assert_eq!(nothing.num_points(), 0);
        let encoded = stca.encode(&lidar, &d);
        assert_eq!(encoded.dims(), [2, 2, 2, 2, 16]);
        let per_roi: Vec<f32> = encoded
            .abs()
            .sum_dims(&[1, 2, 3, 4])
            .reshape([2])
            .into_data()
            .try_to_vec()
            .unwrap();
        assert!(per_roi[0] > 0.0 && per_roi[1] == 0.0, "{per_roi:?}");
        let fa = stca.forward(&lidar, &nothing, &d);
        assert_eq!(fa.dims(), [2, config.flattened_width()]);
        let values: Vec<f32> = fa.into_data().try_to_vec().unwrap();
        assert!(values.iter().all(|v| v.is_finite()));
        let both_empty = stca.forward(&nothing, &nothing, &d);
        assert_eq!(both_empty.abs().max().into_scalar::<f32>(), 0.0);
    }

    /// The bucketed crop keeps exactly what testing every point keeps, in the same order,
    /// for turned, enlarged, thinned and off-cloud RoIs.
    #[test]
    fn the_bucketed_crop_is_the_crop_of_every_point() {
        let mut state = 17u64;
        let mut unit = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let cloud: Vec<f32> = (0..20_000)
            .flat_map(|_| {
                [
                    (unit() * 40.0) as f32,
                    (unit() * 30.0 - 15.0) as f32,
                    (unit() * 3.0 - 2.0) as f32,
                    0.5,
                ]
            })
            .collect();
        let buckets = BevBuckets::new(&cloud, 4);
        let every_point = BevBuckets::one_cell(cloud.len() / 4);
        let mut config = small();
        let mut total = 0;
        for r in 0..60 {
            config.margin = [0.0, 0.2, 1.0][r % 3];
            config.max_points = [64, 5000][r % 2];
            let roi = [
                unit() * 50.0 - 5.0,
                unit() * 40.0 - 20.0,
                unit() * 2.0 - 1.0,
                1.0 + unit() * 4.0,
                1.0 + unit() * 2.0,
                1.0 + unit() * 2.0,
                unit() * 7.0 - 3.5,
            ];
            let fast = crop(&cloud, 4, &buckets, r, &roi, &config);
            let slow = crop(&cloud, 4, &every_point, r, &roi, &config);
            assert_eq!(fast, slow, "RoI {r}: {roi:?}");
            total += fast.len();
        }
        assert!(total > 1000, "the RoIs held points: {total}");
    }

    #[test]
    fn dense_rois_are_thinned_evenly() {
        let mut config = small();
        config.max_points = 10;
        let cloud: Vec<f32> = (0..100)
            .flat_map(|i| [-0.9 + 0.018 * i as f32, 0.0, 0.0])
            .collect();
        let points = RoiPoints::new(
            &[(&cloud, 3)],
            &[[0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0]],
            &[0],
            &config,
        );
        assert_eq!(points.num_points(), 10);
        // Every tenth point: spread over all four x cells.
        let xs: std::collections::BTreeSet<i32> =
            points.sites.coords().iter().map(|c| c[3]).collect();
        assert_eq!(xs.len(), 4);
    }
}
