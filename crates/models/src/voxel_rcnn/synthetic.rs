//! A LiDAR-like voxel input for benchmarks and tests that must not read a dataset: a
//! 64-beam sweep (elevations +2° … −24.8°, the camera's ±45° of azimuth at 0.09°) over a
//! ground plane, two building fronts and a dozen car-sized boxes, ray-cast and voxelized
//! on the published grid. Its sparsity is KITTI's: about 20,000–30,000 voxels.
//!
//! The same scene seen through a KITTI-sized camera (1242 × 375 pixels, focal 721 px,
//! one ray per pixel) stands in for a pseudo point cloud: one point per pixel whose ray
//! hits something within 80 m, as depth completion gives.

use fusiondet_nn::sparse::SparseSites;

/// Mean voxel features [voxels, C] and their sites (batch 0): x, y, z and intensity (C 4)
/// for the LiDAR sweep; x, y, z and a grey colour (C 6) for the camera cloud.
pub struct SyntheticSweep {
    pub sites: SparseSites,
    pub features: Vec<f32>,
    pub points: usize,
    /// Every point in range, C floats each.
    pub cloud: Vec<f32>,
    /// The cars of the scene as (x, y, z, dx, dy, dz, heading) boxes.
    pub cars: Vec<[f64; 7]>,
}

/// How the scene is sampled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sensor {
    /// 64 beams × 1000 columns, at most 5 points per voxel, (x, y, z, intensity).
    Lidar,
    /// One ray per pixel of a 1242 × 375 camera, at most 15 per voxel, (x, y, z, r, g, b).
    Camera,
}

impl Sensor {
    fn rays(self) -> Vec<[f64; 3]> {
        match self {
            Sensor::Lidar => (0..64)
                .flat_map(|beam| {
                    let elevation = (2.0 - 26.8 * beam as f64 / 63.0).to_radians();
                    (0..1000).map(move |column| {
                        let azimuth = (-45.0 + 0.09 * column as f64).to_radians();
                        [
                            elevation.cos() * azimuth.cos(),
                            elevation.cos() * azimuth.sin(),
                            elevation.sin(),
                        ]
                    })
                })
                .collect(),
            Sensor::Camera => {
                let (f, cx, cy) = (721.5, 609.6, 172.9);
                (0..375)
                    .flat_map(|v| {
                        (0..1242).map(move |u| {
                            // Camera (right, down, forward) → LiDAR (forward, left, up).
                            let d = [1.0, -(u as f64 + 0.5 - cx) / f, -(v as f64 + 0.5 - cy) / f];
                            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                            d.map(|x| x / n)
                        })
                    })
                    .collect()
            }
        }
    }

    fn max_points_per_voxel(self) -> u32 {
        match self {
            Sensor::Lidar => 5,
            Sensor::Camera => 15,
        }
    }
}

pub const PUBLISHED_RANGE: [f64; 6] = [0.0, -40.0, -3.0, 70.4, 40.0, 1.0];
pub const PUBLISHED_VOXEL: [f64; 3] = [0.05, 0.05, 0.1];

/// splitmix64 as a uniform draw in [0, 1): the sweep's generator, and the tests'.
pub(crate) fn unit(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// Distance along unit ray `d` from the origin to an axis-aligned box, if hit.
fn slab(d: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> Option<f64> {
    let (mut near, mut far) = (0f64, f64::INFINITY);
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            if 0.0 < lo[a] || 0.0 > hi[a] {
                return None;
            }
            continue;
        }
        let (t1, t2) = (lo[a] / d[a], hi[a] / d[a]);
        near = near.max(t1.min(t2));
        far = far.min(t1.max(t2));
    }
    (near <= far && near > 0.0).then_some(near)
}

/// The sweep of scene `seed` on a grid of `voxel` sizes over `range`.
pub fn synthetic_sweep(seed: u64, range: [f64; 6], voxel: [f64; 3]) -> SyntheticSweep {
    scan(seed, range, voxel, Sensor::Lidar)
}

/// The scene `seed` through the camera: a stand-in for its pseudo point cloud.
pub fn synthetic_pseudo_cloud(seed: u64, range: [f64; 6], voxel: [f64; 3]) -> SyntheticSweep {
    scan(seed, range, voxel, Sensor::Camera)
}

fn scan(seed: u64, range: [f64; 6], voxel: [f64; 3], sensor: Sensor) -> SyntheticSweep {
    let mut state = seed;
    let cars: Vec<([f64; 3], [f64; 3])> = (0..12)
        .map(|_| {
            let (x, y) = (
                5.0 + 55.0 * unit(&mut state),
                -20.0 + 40.0 * unit(&mut state),
            );
            ([x - 1.95, y - 0.8, -1.73], [x + 1.95, y + 0.8, -0.17])
        })
        .collect();
    let walls = [
        ([0.0, 15.0, -1.73], [80.0, 16.0, 10.0]),
        ([0.0, -17.0, -1.73], [80.0, -16.0, 10.0]),
    ];
    let channels = match sensor {
        Sensor::Lidar => 4,
        Sensor::Camera => 6,
    };
    let grid = [0, 1, 2].map(|a| ((range[a + 3] - range[a]) / voxel[a]).round() as usize);
    let mut voxels: std::collections::HashMap<[i32; 3], ([f64; 6], u32)> = Default::default();
    let mut order = Vec::new();
    let mut cloud = Vec::new();
    let mut points = 0;
    for d in sensor.rays() {
        let mut t = if d[2] < 0.0 {
            -1.73 / d[2]
        } else {
            f64::INFINITY
        };
        for (lo, hi) in cars.iter().chain(&walls) {
            if let Some(hit) = slab(d, *lo, *hi) {
                t = t.min(hit);
            }
        }
        if !t.is_finite() || t > 80.0 {
            continue;
        }
        let p = d.map(|v| v * t);
        if (0..3).any(|a| p[a] < range[a] || p[a] >= range[a + 3]) {
            continue;
        }
        points += 1;
        let c = [2, 1, 0].map(|a| (((p[a] - range[a]) / voxel[a]) as i32).min(grid[a] as i32 - 1));
        let attributes = match sensor {
            Sensor::Lidar => [0.2 + 0.6 * unit(&mut state), 0.0, 0.0],
            Sensor::Camera => [0.5; 3],
        };
        let values = [
            p[0],
            p[1],
            p[2],
            attributes[0],
            attributes[1],
            attributes[2],
        ];
        cloud.extend(values[..channels].iter().map(|&v| v as f32));
        let entry = voxels.entry(c).or_insert_with(|| {
            order.push(c);
            ([0.0; 6], 0)
        });
        if entry.1 < sensor.max_points_per_voxel() {
            for (s, v) in entry.0.iter_mut().zip(values) {
                *s += v;
            }
            entry.1 += 1;
        }
    }
    let mut features = Vec::with_capacity(order.len() * channels);
    let coords: Vec<[i32; 4]> = order
        .iter()
        .map(|c| {
            let (sum, n) = voxels[c];
            features.extend(sum[..channels].iter().map(|s| (s / n as f64) as f32));
            [0, c[0], c[1], c[2]]
        })
        .collect();
    SyntheticSweep {
        // One height more than the grid, as OpenPCDet's sparse shape: 41 → 21 → 11 → 5 → 2.
        sites: SparseSites::new(coords, [grid[2] + 1, grid[1], grid[0]], 1)
            .expect("sites lie in the grid"),
        features,
        points,
        cloud,
        cars: cars
            .iter()
            .map(|(lo, hi)| {
                let c: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
                [
                    c[0],
                    c[1],
                    c[2],
                    hi[0] - lo[0],
                    hi[1] - lo[1],
                    hi[2] - lo[2],
                    0.0,
                ]
            })
            .collect(),
    }
}
