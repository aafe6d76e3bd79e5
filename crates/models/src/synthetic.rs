//! Synthetic frustum batches with realistic ragged pair counts, for tests and benchmarks
//! (the real ones come from `fusiondet-frustum`).
//!
//! Each frustum holds one car-sized box at a random depth (more points the nearer it is)
//! plus clutter; sub-frustum k of a scale with S slices over depth D is centred at
//! (0, 0, (k + ½) · D / S) and takes the points within one stride of its centre in depth
//! (so most points fall in two slices per scale, as in F-ConvNet), first come first served
//! up to the scale's cap.

use crate::boxes::box_corners;
use fusiondet_frustum::BoxCoder;
use fusiondet_frustum::{BatchScale, BatchTargets, FrustumBatch};

/// Shape of a synthetic batch.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticSpec {
    pub batch_size: usize,
    pub points_per_frustum: usize,
    /// Slices per frustum of the four scales.
    pub slices: [usize; 4],
    /// Cap on points per slice of the four scales.
    pub caps: [usize; 4],
    /// Depth range covered by the slices, metres.
    pub depth: f32,
    pub with_targets: bool,
}

impl SyntheticSpec {
    /// F-ConvNet's Car setting: 1024 points, 280/140/70/35 slices, caps 32/64/64/128, 70 m.
    pub fn car(batch_size: usize) -> Self {
        Self {
            batch_size,
            points_per_frustum: 1024,
            slices: [280, 140, 70, 35],
            caps: [32, 64, 64, 128],
            depth: 70.0,
            with_targets: true,
        }
    }

    /// A small setting for the tiny configuration: 128 points, 24/12/6/3 slices over 24 m.
    pub fn tiny(batch_size: usize) -> Self {
        Self {
            batch_size,
            points_per_frustum: 128,
            slices: [24, 12, 6, 3],
            caps: [16, 24, 32, 48],
            depth: 24.0,
            with_targets: true,
        }
    }
}

/// splitmix64: small, seedable, good enough for test data.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next_u64() >> 40) as f32 / (1u64 << 24) as f32)
    }
}

/// A deterministic synthetic batch.
pub fn synthetic_batch(spec: &SyntheticSpec, seed: u64) -> FrustumBatch {
    let mut rng = Rng(seed ^ 0x5EED_F00D);
    let (b, n) = (spec.batch_size, spec.points_per_frustum);
    let d = spec.depth;
    let mut points = Vec::with_capacity(b * n * 3);
    let mut objects = Vec::with_capacity(b);
    for _ in 0..b {
        let z0 = rng.uniform(0.15 * d, 0.7 * d);
        let x0 = rng.uniform(-1.0, 1.0);
        let heading = rng.uniform(-std::f32::consts::PI, std::f32::consts::PI);
        let mean = BoxCoder::kitti().mean_sizes_f32()[0];
        let size: [f32; 3] = std::array::from_fn(|k| mean[k] * rng.uniform(0.9, 1.1));
        let center = [x0, 0.9, z0];
        let frac = (0.3 * d / z0).clamp(0.1, 0.8);
        let (s, c) = heading.sin_cos();
        for _ in 0..n {
            let p = if rng.uniform(0.0, 1.0) < frac {
                let (lx, ly, lz) = (
                    rng.uniform(-0.5, 0.5) * size[0],
                    rng.uniform(-0.5, 0.5) * size[2],
                    rng.uniform(-0.5, 0.5) * size[1],
                );
                [
                    c * lx + s * lz + center[0],
                    ly + center[1],
                    -s * lx + c * lz + center[2],
                ]
            } else {
                let z = if rng.uniform(0.0, 1.0) < 0.5 {
                    rng.uniform((z0 - 0.15 * d).max(0.5), (z0 + 0.2 * d).min(d))
                } else {
                    rng.uniform(0.5, d)
                };
                [rng.uniform(-0.05, 0.05) * z, rng.uniform(-1.0, 1.7), z]
            };
            points.extend_from_slice(&p);
        }
        objects.push((center, heading, size));
    }

    let scales = (0..4)
        .map(|k| {
            let s = spec.slices[k];
            let stride = d / s as f32;
            let mut slice_centers = Vec::with_capacity(b * s * 3);
            let (mut pair_point, mut pair_slice) = (Vec::new(), Vec::new());
            for f in 0..b {
                let zs: Vec<f32> = (0..n).map(|i| points[(f * n + i) * 3 + 2]).collect();
                for j in 0..s {
                    let zc = (j as f32 + 0.5) * stride;
                    slice_centers.extend_from_slice(&[0.0, 0.0, zc]);
                    let members = (0..n)
                        .filter(|&i| (zs[i] - zc).abs() <= stride)
                        .take(spec.caps[k]);
                    for i in members {
                        pair_point.push((f * n + i) as i64);
                        pair_slice.push((f * s + j) as i64);
                    }
                }
            }
            BatchScale {
                slices_per_frustum: s,
                slice_centers,
                pair_point,
                pair_slice,
                max_points_per_slice: spec.caps[k],
                relative_depth_gains: Vec::new(),
            }
        })
        .collect::<Vec<_>>();

    let targets = spec.with_targets.then(|| {
        let out = &scales[1];
        let p = out.slices_per_frustum;
        let stride = d / p as f32;
        let mut t = BatchTargets {
            labels: Vec::with_capacity(b * p),
            center: vec![],
            heading_bin: vec![],
            heading_residual: vec![],
            size_cluster: vec![],
            size_residual: vec![],
            corners: vec![],
        };
        for (f, (center, heading, size)) in objects.iter().enumerate() {
            for j in 0..p {
                let dz = (out.slice_centers[(f * p + j) * 3 + 2] - center[2]).abs();
                t.labels.push(if dz <= stride.max(0.5) {
                    1
                } else if dz <= 2.0 * stride.max(0.5) {
                    -1
                } else {
                    0
                });
            }
            t.center.extend_from_slice(center);
            let (bin, res) = BoxCoder::kitti().heading_to_bin_f32(*heading);
            t.heading_bin.push(bin as i64);
            t.heading_residual.push(res);
            t.size_cluster.push(0);
            let mean = BoxCoder::kitti().mean_sizes_f32()[0];
            t.size_residual
                .extend((0..3).map(|k| (size[k] - mean[k]) / mean[k]));
            t.corners
                .extend(box_corners(*center, *heading, *size).iter().flatten());
        }
        t
    });

    FrustumBatch {
        batch_size: b,
        points_per_frustum: n,
        points,
        class_one_hot: (0..b).flat_map(|_| [1.0, 0.0, 0.0]).collect(),
        // A KITTI-like pinhole looking down the frustum axis.
        image_projection: (0..b)
            .flat_map(|_| {
                [
                    721.5, 0.0, 609.6, 44.9, 0.0, 721.5, 172.9, 0.2, 0.0, 0.0, 1.0, 0.003,
                ]
            })
            .collect(),
        scales,
        output_scale: 1,
        targets,
    }
}

/// A synthetic tiny batch grown to `factor`× the points per frustum for LFA: the original
/// points first (the ones the slices use), jittered copies after.
pub fn lfa_batch(spec: &SyntheticSpec, seed: u64, factor: usize) -> FrustumBatch {
    let mut batch = synthetic_batch(spec, seed);
    let n = batch.points_per_frustum;
    let mut points = Vec::with_capacity(batch.points.len() * factor);
    for f in 0..batch.batch_size {
        let own = &batch.points[f * n * 3..(f + 1) * n * 3];
        points.extend_from_slice(own);
        for copy in 1..factor {
            points.extend(
                own.iter()
                    .enumerate()
                    .map(|(i, v)| v + 0.01 * (((i * 7 + copy * 13) % 11) as f32 - 5.0)),
            );
        }
    }
    for scale in &mut batch.scales {
        for p in &mut scale.pair_point {
            let (f, i) = (*p as usize / n, *p as usize % n);
            *p = (f * n * factor + i) as i64;
        }
    }
    batch.points = points;
    batch.points_per_frustum = n * factor;
    batch
}
