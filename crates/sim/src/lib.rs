//! LiDAR + camera street-scene simulator writing KITTI-format datasets.
//!
//! Each frame is a random street (city, residential, arterial or campus: road,
//! sidewalks, façades, trees, poles, parked and driving cars, vans, trucks,
//! pedestrians, cyclists) seen by a Velodyne HDL-64E and KITTI's left colour camera.
//! Both sensors ray cast the *same* scene (analytic boxes, rounded boxes, ellipsoids
//! and cylinders), so a LiDAR point projected into the image lands on the surface it
//! hit. Labels (truncation, z-buffer occlusion, DontCare) and a simulated
//! F-PointNet-style 2D detector complete the frame.
//!
//! The indoor simulator ([`indoor`]: furnished rooms seen by an RGB-D camera, written as a
//! prepared SUN RGB-D data set) shares the primitives, BVH, materials and seeding.
//!
//! # Using it
//! * [`simulate_frame`]`(seed, index, &SimConfig)` builds one frame in memory
//!   ([`SimFrame`]: points, image, calibration, `label_2` objects, 2D detections, and
//!   the ground truth behind them: scene, per-point and per-pixel hits, per-object
//!   visibility).
//! * [`write_dataset`] writes a whole dataset (frames in parallel, each file atomic,
//!   split lists and detection files last) and returns its [`DatasetStats`], which
//!   are also written to `sim_stats.json`.
//! * [`FrameStats`] / [`DatasetStats`] compute the realism report for frames made
//!   in-process.
//!
//! # Determinism
//! Every random choice flows from `(seed, frame index)` ([`rng`]): sequential choices
//! from per-concern ChaCha8 streams, per-ray noise from a stateless hash of the ray
//! index. Transcendental functions come from the pure-Rust `libm`, integer powers are
//! explicit products, and parallel work is collected in a fixed order, so the same
//! seed gives byte-identical files on any machine and any thread count.
//!
//! # Sensors
//! The LiDAR beam pattern (64 measured ring elevations, 2,160 firings per laser on a
//! 0.09° encoder grid, the ego car's shadow) and why a KITTI frame has ~120k points
//! rather than 64 × 4,500 are explained in [`sensors`]; the return model (foliage,
//! glass, weak returns from dark, grazing or far surfaces) in [`lidar`]. The camera
//! uses one of KITTI's two real calibrations with small per-frame changes.
//!
//! # Speed
//! Both sensors cast from one point, so each frame bins its primitives by viewing
//! direction ([`viewgrid`]: rings × azimuth for the LiDAR, pixel tiles for the camera,
//! an orthographic grid along the sun for shadows); a ray tests only its cell's
//! primitives, nearest first. The [`bvh`] serves general rays.
//!
//! # Realism
//! [`stats`] compares against KITTI: points inside car boxes by distance against the
//! curve measured on real frames, class mix, occlusion and truncation shares,
//! difficulty counts and the detector's score and recall profile.

pub mod bvh;
pub mod camera;
pub mod dataset;
pub mod detector;
pub mod indoor;
pub mod label;
pub mod layout;
pub mod lidar;
pub mod material;
pub mod math;
mod output_dir;
pub mod parts;
pub mod primitive;
pub mod rng;
pub mod scene;
pub mod sensors;
pub mod sharded;
pub mod stats;
pub mod viewgrid;

pub use camera::{CameraSpec, Render};
pub use dataset::{DatasetOptions, SimError, write_dataset};
pub use detector::{DetectorSpec, Split};
pub use label::ActorView;
pub use layout::{LayoutConfig, LayoutInfo, SceneKind};
pub use lidar::{LidarScan, PointInfo};
pub use scene::Scene;
pub use sensors::LidarSpec;
pub use sharded::{ShardOutcome, complete_sharded_dataset, write_dataset_shard};
pub use stats::{DatasetStats, FrameStats};

use fusiondet_geometry::{CameraModel, points_in_box};
use fusiondet_kitti::{Calib, Detection2d, LidarPoint, Object, ObjectClass, frame_id};
use image::RgbImage;
use rayon::prelude::*;
use rng::{Stream, frame_key, frame_sampler};

/// Everything that shapes a simulated dataset besides the seed.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    pub lidar: LidarSpec,
    pub camera: CameraSpec,
    pub layout: LayoutConfig,
    pub detector: DetectorSpec,
    /// Share of frames in the validation split (KITTI's usual split is about half).
    pub val_fraction: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            lidar: LidarSpec::default(),
            camera: CameraSpec::default(),
            layout: LayoutConfig::default(),
            detector: DetectorSpec::default(),
            val_fraction: 0.5,
        }
    }
}

/// One simulated frame with everything a KITTI frame has, plus the ground truth
/// behind it (scene, per-point and per-pixel hits, per-object views).
#[derive(Debug, Clone)]
pub struct SimFrame {
    pub index: usize,
    /// KITTI's six-digit frame id.
    pub id: String,
    pub split: Split,
    pub calib: Calib,
    /// LiDAR frame points (x, y, z, reflectance), KITTI ring order.
    pub points: Vec<LidarPoint>,
    pub point_info: Vec<PointInfo>,
    /// Rays cast (after the ego-car mask).
    pub rays: usize,
    pub image: RgbImage,
    /// Primitive seen at each pixel ([`camera::SKY`] for sky).
    pub pixel_prim: Vec<u32>,
    /// Rectified-camera depth of the surface seen at each pixel (0 for sky): the dense
    /// truth of depth completion, written to `training/depth_2/`.
    pub depth: fusiondet_kitti::DepthMap,
    /// The `label_2` lines.
    pub objects: Vec<Object>,
    /// Every object that shows in the image, labelled or not.
    pub views: Vec<ActorView>,
    pub detections: Vec<Detection2d>,
    pub scene: Scene,
    pub layout: LayoutInfo,
}

/// Which split frame `index` belongs to: validation frames are spread evenly
/// (a Bresenham pattern), so any prefix of the dataset has the requested share.
pub fn split_of(index: usize, val_fraction: f64) -> Split {
    let f = val_fraction.clamp(0.0, 1.0);
    let before = (index as f64 * f + 0.5).floor();
    let after = ((index + 1) as f64 * f + 0.5).floor();
    if after > before {
        Split::Val
    } else {
        Split::Train
    }
}

/// Simulates frame `index` of the dataset with seed `seed`.
pub fn simulate_frame(seed: u64, index: usize, cfg: &SimConfig) -> SimFrame {
    let idx = index as u64;
    let (scene, layout) =
        layout::build_scene(&mut frame_sampler(seed, idx, Stream::Layout), &cfg.layout);
    let calib = sensors::sample_calib(&mut frame_sampler(seed, idx, Stream::Calib));
    let cam = calib
        .camera_model()
        .expect("simulated calibrations are invertible");
    let lidar_key = frame_key(seed, idx, Stream::Lidar);
    let (scan, render) = rayon::join(
        || lidar::scan(&scene, &cfg.lidar, lidar_key),
        || camera::render(&scene, &cam, &cfg.camera),
    );
    let mut views = label::label_frame(&scene, &cam, &render);
    count_points(&mut views, &scene, &cam, &scan.points);
    let split = split_of(index, cfg.val_fraction);
    let id = frame_id(index);
    let detections = detector::detect(
        &cfg.detector,
        &mut frame_sampler(seed, idx, Stream::Detector),
        &id,
        &views,
        &scene,
        &cam,
        (cfg.camera.width as f64, cfg.camera.height as f64),
        split,
    );
    // Labelled objects nearest first, DontCare regions last (as KITTI's files do).
    let mut labelled: Vec<&ActorView> = views.iter().filter(|v| v.is_labelled()).collect();
    labelled.sort_by(|a, b| a.box3d.z.total_cmp(&b.box3d.z));
    let objects: Vec<Object> = labelled
        .iter()
        .chain(
            views
                .iter()
                .filter(|v| v.is_dontcare())
                .collect::<Vec<_>>()
                .iter(),
        )
        .filter_map(|v| v.label.clone())
        .collect();
    SimFrame {
        index,
        id,
        split,
        calib,
        points: scan.points,
        point_info: scan.info,
        rays: scan.rays,
        image: render.image,
        pixel_prim: render.prim,
        depth: fusiondet_kitti::DepthMap {
            width: render.width as usize,
            height: render.height as usize,
            data: render.depth,
        },
        objects,
        views,
        detections,
        scene,
        layout,
    }
}

/// Counts LiDAR points inside each labelled object's 3D box (in the rectified camera
/// frame, as KITTI's points-per-object statistics are measured).
fn count_points(views: &mut [ActorView], scene: &Scene, cam: &CameraModel, points: &[LidarPoint]) {
    views
        .par_iter_mut()
        .filter(|v| v.is_labelled())
        .for_each(|v| {
            let a = &scene.actors[v.actor];
            let centre = a.bottom_center + a.up * (a.h / 2.0);
            let r = 0.5 * (a.l * a.l + a.w * a.w + a.h * a.h).sqrt() + 0.1;
            let near: Vec<[f64; 3]> = points
                .iter()
                .filter(|p| {
                    let d = math::v3(
                        p[0] as f64 - centre.x,
                        p[1] as f64 - centre.y,
                        p[2] as f64 - centre.z,
                    );
                    d.dot(d) <= r * r
                })
                .map(|p| cam.velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64]))
                .collect();
            v.points_in_box = points_in_box(&v.box3d, &near)
                .into_iter()
                .filter(|&x| x)
                .count();
        });
}

/// The classes the KITTI benchmark evaluates, for convenience.
pub const EVALUATED: [ObjectClass; 3] = ObjectClass::EVALUATED;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_are_spread_evenly() {
        let val = (0..100).filter(|&i| split_of(i, 0.3) == Split::Val).count();
        assert_eq!(val, 30);
        assert!((0..10).all(|i| split_of(i, 0.0) == Split::Train));
        assert!((0..10).all(|i| split_of(i, 1.0) == Split::Val));
        let val2 = (0..2).filter(|&i| split_of(i, 0.5) == Split::Val).count();
        assert_eq!(val2, 1);
    }
}
