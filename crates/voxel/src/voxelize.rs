//! Points → voxels, as OpenPCDet's `transform_points_to_voxels` (spconv's point-to-voxel
//! generator) followed by its `MeanVFE`: each in-range point falls into the voxel
//! floor((p − range_min) / voxel_size); points are taken in order, a voxel keeps its first
//! `max_points_per_voxel` points, and once `max_voxels` voxels exist the points of any
//! new voxel are dropped. The voxel's feature is the mean (x, y, z, intensity) of the
//! points it kept.
//!
//! Training shuffles the points first (OpenPCDet's `shuffle_points`), so which voxels
//! survive the cap and which points a full voxel keeps are random; here the shuffle
//! draws from the caller's [`Sampler`], so the result is a function of the seed.
//!
//! The camera field-of-view filter ([`points_in_fov`]) is separate: OpenPCDet applies it
//! when a frame is read, before augmentation pastes objects into the scene.

use crate::config::VoxelConfig;
use crate::error::Result;
use crate::scene::PseudoPoint;
use fusiondet_dataset::rng::Sampler;
use fusiondet_geometry::CameraModel;
use fusiondet_kitti::LidarPoint;
use rustc_hash::FxHashMap;

/// Which points project into a `width × height` image (image_size = [width, height])
/// in front of the camera: 0 ≤ u < width, 0 ≤ v < height, positive depth.
pub fn fov_mask(points: &[LidarPoint], camera: &CameraModel, image_size: [f64; 2]) -> Vec<bool> {
    // P2 · velo_to_rect as plain rows: one 3 × 4 product per point.
    let m = camera.p2 * camera.velo_to_rect;
    let rows: [[f64; 4]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
    let [w, h] = image_size;
    points
        .iter()
        .map(|p| {
            let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
            let [a, b, d] = rows.map(|r| r[0] * x + r[1] * y + r[2] * z + r[3]);
            if d <= 0.0 {
                return false;
            }
            let (u, v) = (a / d, b / d);
            (0.0..w).contains(&u) && (0.0..h).contains(&v)
        })
        .collect()
}

/// The points that project into the image (see [`fov_mask`]), in their order.
pub fn points_in_fov(
    points: &[LidarPoint],
    camera: &CameraModel,
    image_size: [f64; 2],
) -> Vec<LidarPoint> {
    let mask = fov_mask(points, camera, image_size);
    points
        .iter()
        .zip(mask)
        .filter_map(|(p, keep)| keep.then_some(*p))
        .collect()
}

/// The voxels of one frame. An input with no point in range gives no voxels (not an
/// error here: whether an empty frame is acceptable is the caller's decision).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Voxels {
    /// Grid coordinates [z, y, x] (the sparse convolution's order), one per voxel, in
    /// the order of each voxel's first point.
    pub coords: Vec<[i32; 3]>,
    /// Points each voxel kept (1 ..= max_points_per_voxel).
    pub num_points: Vec<u32>,
    /// Mean of the kept points' values, `channels` per voxel, row-major: the network's
    /// input features ((x, y, z, intensity) for LiDAR, (x, y, z, r, g, b) for pseudo).
    pub features: Vec<f32>,
    pub channels: usize,
    /// Voxels along [x, y, z].
    pub grid_size: [usize; 3],
    /// Input points inside the grid.
    pub points_in_range: usize,
    /// Points averaged into some voxel (the rest fell into full or dropped voxels).
    pub points_kept: usize,
    /// In-range points dropped because their voxel would have been made after
    /// `max_voxels` others.
    pub points_dropped: usize,
}

impl Voxels {
    pub fn len(&self) -> usize {
        self.coords.len()
    }

    pub fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }

    /// (batch, z, y, x) rows for a sparse grid holding this frame as batch item `batch`.
    pub fn coords_with_batch(&self, batch: i32) -> Vec<[i32; 4]> {
        self.coords
            .iter()
            .map(|&[z, y, x]| [batch, z, y, x])
            .collect()
    }

    /// The mean features as one row-major `len × channels` array.
    pub fn flat_features(&self) -> &[f32] {
        &self.features
    }

    /// The mean features of voxel `row`.
    pub fn features_of(&self, row: usize) -> &[f32] {
        &self.features[row * self.channels..(row + 1) * self.channels]
    }
}

/// A validated voxel grid that turns point lists into [`Voxels`].
#[derive(Debug, Clone)]
pub struct Voxelizer {
    config: VoxelConfig,
    grid: [usize; 3],
}

impl Voxelizer {
    pub fn new(config: &VoxelConfig) -> Result<Voxelizer> {
        config.validate()?;
        Ok(Voxelizer {
            config: config.clone(),
            grid: config.grid_size(),
        })
    }

    pub fn config(&self) -> &VoxelConfig {
        &self.config
    }

    /// Voxels along [x, y, z].
    pub fn grid_size(&self) -> [usize; 3] {
        self.grid
    }

    /// The LiDAR-frame centre of voxel [z, y, x].
    pub fn voxel_centre(&self, coord: [i32; 3]) -> [f64; 3] {
        let (r, s) = (&self.config.point_range, &self.config.voxel_size);
        let xyz = [coord[2], coord[1], coord[0]];
        std::array::from_fn(|a| r[a] + (xyz[a] as f64 + 0.5) * s[a])
    }

    /// The [z, y, x] voxel a point falls in, or `None` outside the grid (a point on a
    /// range's upper edge is outside; NaN is outside).
    pub fn coord_of(&self, p: [f64; 3]) -> Option<[i32; 3]> {
        let (r, s) = (&self.config.point_range, &self.config.voxel_size);
        let mut c = [0i32; 3];
        for a in 0..3 {
            let f = (p[a] - r[a]) / s[a];
            if !(f >= 0.0 && f < self.grid[a] as f64) {
                return None;
            }
            c[2 - a] = f as i32; // f ≥ 0: truncation is floor
        }
        Some(c)
    }

    /// Voxelizes `points` keeping at most `max_voxels` voxels; with a sampler the
    /// points are first visited in a shuffled order (training).
    pub fn voxelize(
        &self,
        points: &[LidarPoint],
        max_voxels: usize,
        shuffle: Option<&mut Sampler>,
    ) -> Voxels {
        let max_points = self.config.max_points_per_voxel;
        self.run(points, max_points, max_voxels, shuffle, false).0
    }

    /// Voxelizes pseudo points on the same grid, averaging at most
    /// `max_points_per_voxel` per voxel (DASANet: 15) over all six values.
    pub fn voxelize_pseudo(
        &self,
        points: &[PseudoPoint],
        max_points_per_voxel: usize,
        max_voxels: usize,
        shuffle: Option<&mut Sampler>,
    ) -> Voxels {
        self.run(points, max_points_per_voxel, max_voxels, shuffle, false)
            .0
    }

    /// As [`Voxelizer::voxelize`], also giving each input point's voxel row (`None` for
    /// points outside the grid or in a dropped voxel). A point beyond its voxel's
    /// `max_points_per_voxel` still maps to the voxel it lies in.
    pub fn voxelize_with_point_map(
        &self,
        points: &[LidarPoint],
        max_voxels: usize,
        shuffle: Option<&mut Sampler>,
    ) -> (Voxels, Vec<Option<u32>>) {
        let max_points = self.config.max_points_per_voxel;
        let (voxels, map) = self.run(points, max_points, max_voxels, shuffle, true);
        (voxels, map.unwrap_or_default())
    }

    /// One voxelizer for points of any width N (x, y, z first).
    fn run<const N: usize>(
        &self,
        points: &[[f32; N]],
        max_points: usize,
        max_voxels: usize,
        shuffle: Option<&mut Sampler>,
        with_map: bool,
    ) -> (Voxels, Option<Vec<Option<u32>>>) {
        let order: Option<Vec<u32>> = shuffle.map(|s| {
            let mut idx: Vec<u32> = (0..points.len() as u32).collect();
            s.shuffle(&mut idx);
            idx
        });
        let max_points = max_points as u32;
        let [nx, ny, _] = self.grid.map(|n| n as u64);
        let mut rows: FxHashMap<u64, u32> = FxHashMap::default();
        rows.reserve(points.len().min(max_voxels.saturating_mul(2)));
        let mut out = Voxels {
            grid_size: self.grid,
            channels: N,
            ..Voxels::default()
        };
        let mut sums: Vec<[f64; N]> = Vec::new();
        let mut map = with_map.then(|| vec![None; points.len()]);
        for k in 0..points.len() {
            let i = order.as_ref().map_or(k, |o| o[k] as usize);
            let p = points[i];
            let Some(c) = self.coord_of([p[0] as f64, p[1] as f64, p[2] as f64]) else {
                continue;
            };
            out.points_in_range += 1;
            let key = (c[0] as u64 * ny + c[1] as u64) * nx + c[2] as u64;
            let row = match rows.get(&key) {
                Some(&row) => row,
                // Once the cap is reached the map only answers look-ups: it stays the
                // size of the kept voxels, however many more the scan would make.
                None if out.coords.len() >= max_voxels => {
                    out.points_dropped += 1;
                    continue;
                }
                None => {
                    let row = out.coords.len() as u32;
                    rows.insert(key, row);
                    out.coords.push(c);
                    out.num_points.push(0);
                    sums.push([0.0; N]);
                    row
                }
            };
            if let Some(m) = map.as_mut() {
                m[i] = Some(row);
            }
            let r = row as usize;
            if out.num_points[r] < max_points {
                out.num_points[r] += 1;
                out.points_kept += 1;
                for (s, v) in sums[r].iter_mut().zip(p) {
                    *s += v as f64;
                }
            }
        }
        out.features = sums
            .iter()
            .zip(&out.num_points)
            .flat_map(|(s, &n)| s.map(|v| (v / n as f64) as f32))
            .collect();
        (out, map)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boxes::tests::axis_camera;

    /// A 4 m cube of 1 m voxels, at most 2 points per voxel.
    fn cube() -> Voxelizer {
        Voxelizer::new(&VoxelConfig {
            point_range: [0.0, 0.0, 0.0, 4.0, 4.0, 4.0],
            voxel_size: [1.0, 1.0, 1.0],
            max_points_per_voxel: 2,
            max_voxels_train: 3,
            max_voxels_test: 10,
            fov_only: false,
        })
        .unwrap()
    }

    /// Pseudo points: six-channel means, their own per-voxel cap, a seeded shuffle.
    #[test]
    fn pseudo_points_average_six_values_up_to_their_cap() {
        let v = cube();
        let mut pts: Vec<PseudoPoint> = (0..20)
            .map(|k| [0.5, 0.5, 0.5, k as f32, 1.0, 0.5])
            .collect();
        pts.push([2.5, 0.5, 0.5, 0.2, 0.4, 0.6]);
        let out = v.voxelize_pseudo(&pts, 15, 10, None);
        assert_eq!(out.channels, 6);
        assert_eq!(out.num_points, vec![15, 1]);
        // The first 15 in scan order: colours 0..14, mean 7.
        assert_eq!(out.features_of(0), [0.5, 0.5, 0.5, 7.0, 1.0, 0.5]);
        assert_eq!(out.features_of(1), [2.5, 0.5, 0.5, 0.2, 0.4, 0.6]);
        let shuffled = |seed| v.voxelize_pseudo(&pts, 15, 10, Some(&mut Sampler::new(seed)));
        assert_eq!(shuffled(4), shuffled(4));
        assert_ne!(shuffled(4).features_of(0)[3], 7.0);
    }

    #[test]
    fn points_fall_into_floor_voxels_and_features_are_means() {
        let v = cube();
        let pts: Vec<LidarPoint> = vec![
            [0.5, 0.5, 0.5, 1.0],
            [3.5, 1.5, 2.5, 0.25],
            [0.75, 0.25, 0.25, 0.0], // same voxel as the first
            [4.0, 1.0, 1.0, 0.0],    // on the upper x edge: outside
            [-0.1, 1.0, 1.0, 0.0],   // below x_min
            [1.0, 1.0, f32::NAN, 0.0],
            [0.1, 0.1, 0.1, 0.5], // third point of a full voxel: not averaged
        ];
        let out = v.voxelize(&pts, 10, None);
        assert_eq!(out.coords, vec![[0, 0, 0], [2, 1, 3]]);
        assert_eq!(out.num_points, vec![2, 1]);
        assert_eq!(out.features_of(0), [0.625, 0.375, 0.375, 0.5]);
        assert_eq!(out.features_of(1), [3.5, 1.5, 2.5, 0.25]);
        assert_eq!(
            (out.points_in_range, out.points_kept, out.points_dropped),
            (4, 3, 0)
        );
        assert_eq!(out.coords_with_batch(1)[1], [1, 2, 1, 3]);
        assert_eq!(out.flat_features().len(), 8);
        assert_eq!(v.voxel_centre([2, 1, 3]), [3.5, 1.5, 2.5]);
        let (same, map) = v.voxelize_with_point_map(&pts, 10, None);
        assert_eq!(same, out);
        assert_eq!(
            map,
            vec![Some(0), Some(1), Some(0), None, None, None, Some(0)]
        );
    }

    #[test]
    fn no_point_in_range_gives_empty_voxels() {
        let out = cube().voxelize(&[[9.0, 9.0, 9.0, 0.0]], 10, None);
        assert!(out.is_empty());
        assert_eq!(out.points_in_range, 0);
        assert!(cube().voxelize(&[], 10, None).is_empty());
    }

    /// Points in voxels x = 0, 1, 2, 3 (y = z = 0), twice over.
    fn four_voxels() -> Vec<LidarPoint> {
        (0..8)
            .map(|k| [(k % 4) as f32 + 0.5, 0.5, 0.5, k as f32])
            .collect()
    }

    #[test]
    fn the_cap_keeps_the_first_voxels_in_scan_order() {
        let out = cube().voxelize(&four_voxels(), 3, None);
        assert_eq!(out.coords, vec![[0, 0, 0], [0, 0, 1], [0, 0, 2]]);
        // Both points of voxel x = 3 are dropped; nothing else is lost (2 per voxel).
        assert_eq!(out.points_dropped, 2);
        assert_eq!(out.points_kept + out.points_dropped, out.points_in_range);
        assert_eq!(out.points_kept, 6);
        assert_eq!(out.points_in_range, 8);
        // Intensities of points 0 and 4 in voxel 0.
        assert_eq!(out.features_of(0)[3], 2.0);
    }

    #[test]
    fn the_training_shuffle_is_seeded() {
        let pts = four_voxels();
        let v = cube();
        let a = v.voxelize(&pts, 3, Some(&mut Sampler::new(7)));
        let b = v.voxelize(&pts, 3, Some(&mut Sampler::new(7)));
        assert_eq!(a, b);
        // The kept voxels are those of the first points of the seed's permutation.
        let mut order: Vec<u32> = (0..pts.len() as u32).collect();
        Sampler::new(7).shuffle(&mut order);
        let mut expected: Vec<[i32; 3]> = Vec::new();
        for &i in &order {
            let c = [0, 0, (i % 4) as i32];
            if !expected.contains(&c) && expected.len() < 3 {
                expected.push(c);
            }
        }
        assert_eq!(a.coords, expected);
        // Some seed orders the voxels differently from the scan.
        assert!((0..20).any(|s| {
            v.voxelize(&pts, 3, Some(&mut Sampler::new(s))).coords
                != v.voxelize(&pts, 3, None).coords
        }));
    }

    #[test]
    fn the_fov_filter_keeps_points_projecting_into_the_image() {
        // f = 700, principal point (600, 180), image 1200 × 360; LiDAR x is depth and
        // u = 600 − 700·y / x.
        let cam = axis_camera();
        let pts: Vec<LidarPoint> = vec![
            [10.0, 0.0, 0.0, 0.0],  // image centre
            [-10.0, 0.0, 0.0, 0.0], // behind
            [10.0, 20.0, 0.0, 0.0], // u = −800
            [10.0, -8.0, 0.0, 0.0], // u = 1160
            [10.0, -9.0, 0.0, 0.0], // u = 1230
            [10.0, 0.0, 2.0, 0.0],  // v = 180 − 140 = 40
            [10.0, 0.0, 3.0, 0.0],  // v = −30
        ];
        assert_eq!(
            fov_mask(&pts, &cam, [1200.0, 360.0]),
            [true, false, false, true, false, true, false]
        );
        assert_eq!(points_in_fov(&pts, &cam, [1200.0, 360.0]).len(), 3);
    }

    #[test]
    fn a_kitti_scan_voxelizes_with_means_inside_their_voxels() {
        let frame = crate::scene::tests::kitti_frame("000001");
        let config = VoxelConfig::default();
        let v = Voxelizer::new(&config).unwrap();
        let points = points_in_fov(&frame.lidar, &frame.camera, frame.image_size);
        let out = v.voxelize(&points, config.max_voxels_test, None);
        assert!(!out.is_empty() && out.len() <= config.max_voxels_test);
        assert_eq!(
            out.num_points.iter().map(|&n| n as usize).sum::<usize>(),
            out.points_kept
        );
        let mut seen = std::collections::HashSet::new();
        for (c, f) in out.coords.iter().zip(out.features.chunks_exact(4)) {
            assert!(seen.insert(*c), "voxel {c:?} listed twice");
            // The mean of points in a box-shaped cell lies in the cell.
            let centre = v.voxel_centre(*c);
            for a in 0..3 {
                let half = config.voxel_size[a] / 2.0 + 1e-5;
                assert!((f[a] as f64 - centre[a]).abs() <= half, "{c:?} {f:?}");
            }
        }
        // The training cap keeps fewer voxels, and says how many points it dropped.
        let capped = v.voxelize(&points, 1000, Some(&mut Sampler::new(1)));
        assert_eq!(capped.len(), 1000);
        assert!(capped.points_dropped >= out.len() - 1000);
    }

    #[test]
    fn the_published_grid_puts_a_point_where_openpcdet_does() {
        let v = Voxelizer::new(&VoxelConfig::default()).unwrap();
        // (10.02, −0.01, −0.95): x 200.4 → 200, y 799.8 → 799, z 20.5 → 20.
        assert_eq!(v.coord_of([10.02, -0.01, -0.95]), Some([20, 799, 200]));
        assert_eq!(v.coord_of([70.4, 0.0, 0.0]), None);
        assert_eq!(v.coord_of([0.0, -40.0, -3.0]), Some([0, 0, 0]));
    }
}
