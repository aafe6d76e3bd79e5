//! A frame as the voxel family trains on it: the points (x, y, z, intensity), for
//! DASANet also the pseudo points of its camera, and the labelled boxes, all in the
//! LiDAR frame. Augmentation changes a scene; the targets and the voxels are made from it.

use crate::boxes::{GtBox, LidarBox};
use crate::config::VoxelConfig;
use crate::voxelize::points_in_fov;
use fusiondet_dataset::SensorFrame;
use fusiondet_kitti::{LidarPoint, ObjectClass};

/// A pseudo point: x, y, z (LiDAR frame, metres) and r, g, b (0–1) of its pixel.
pub type PseudoPoint = [f32; 6];

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    pub points: Vec<LidarPoint>,
    /// The camera's pseudo points (empty for LiDAR-only detectors).
    pub pseudo: Vec<PseudoPoint>,
    /// Every labelled object but DontCare: boxes of other classes still matter to
    /// augmentation (pasted objects must not collide with them).
    pub gts: Vec<GtBox>,
}

impl Scene {
    /// The scene of a frame: its full scan, or only the points that project into the
    /// image when `fov_only`, and its labels converted to the LiDAR frame (headings
    /// not wrapped yet: see [`Scene::keep_targets`]).
    pub fn from_frame(frame: &SensorFrame, fov_only: bool) -> Scene {
        let points = if fov_only {
            points_in_fov(&frame.lidar, &frame.camera, frame.image_size)
        } else {
            frame.lidar.clone()
        };
        let gts = frame
            .objects
            .iter()
            .filter(|o| o.class != ObjectClass::DontCare)
            .map(|o| GtBox {
                bbox: LidarBox::from_camera(&o.box3d, &frame.camera),
                class: o.class,
            })
            .collect();
        Scene {
            points,
            pseudo: Vec::new(),
            gts,
        }
    }

    /// What the targets are made from (after augmentation, as OpenPCDet's
    /// `prepare_data`): only the boxes of `classes`, headings wrapped into [−π, π), and
    /// only boxes whose centre lies in the point range (its bounds included). Points
    /// outside the range are left to the voxelizer, which drops them.
    pub fn keep_targets(&mut self, classes: &[ObjectClass], voxel: &VoxelConfig) {
        let r = &voxel.point_range;
        self.gts.retain(|g| {
            let c = [g.bbox.x, g.bbox.y, g.bbox.z];
            classes.contains(&g.class) && (0..3).all(|a| c[a] >= r[a] && c[a] <= r[a + 3])
        });
        for g in &mut self.gts {
            g.bbox = g.bbox.wrapped();
        }
    }

    /// The boxes alone.
    pub fn boxes(&self) -> Vec<LidarBox> {
        self.gts.iter().map(|g| g.bbox).collect()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use fusiondet_kitti::FrameDir;
    use std::path::Path;

    /// A bundled KITTI frame (CC BY-NC-SA 3.0; camera-cropped scan).
    pub(crate) fn kitti_frame(id: &str) -> SensorFrame {
        let dir = FrameDir::new(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training"),
        );
        SensorFrame::load(&dir, id, true).unwrap()
    }

    #[test]
    fn a_kitti_frame_becomes_a_lidar_scene() {
        let frame = kitti_frame("000001");
        let all = Scene::from_frame(&frame, false);
        let fov = Scene::from_frame(&frame, true);
        assert_eq!(all.points.len(), frame.lidar.len());
        assert!(fov.points.len() <= all.points.len() && !fov.points.is_empty());
        let labelled = frame
            .objects
            .iter()
            .filter(|o| o.class != ObjectClass::DontCare)
            .count();
        assert_eq!(all.gts.len(), labelled);
        // Every labelled car lies ahead of the LiDAR, and most of its box holds points.
        for g in all.gts.iter().filter(|g| g.class == ObjectClass::Car) {
            assert!(g.bbox.x > 0.0, "{g:?}");
        }
    }

    #[test]
    fn targets_keep_the_classes_in_range_with_wrapped_headings() {
        let b = |x: f64, heading: f64, class| GtBox {
            bbox: LidarBox {
                x,
                y: 0.0,
                z: -1.0,
                dx: 4.0,
                dy: 2.0,
                dz: 1.5,
                heading,
            },
            class,
        };
        let mut s = Scene {
            points: Vec::new(),
            pseudo: Vec::new(),
            gts: vec![
                b(10.0, 4.0, ObjectClass::Car),
                b(80.0, 0.0, ObjectClass::Car), // beyond x 70.4
                b(10.0, 0.0, ObjectClass::Van),
                b(70.4, -4.0, ObjectClass::Car), // on the bound: kept
            ],
        };
        s.keep_targets(&[ObjectClass::Car], &VoxelConfig::default());
        let kept: Vec<(f64, f64)> = s.gts.iter().map(|g| (g.bbox.x, g.bbox.heading)).collect();
        let tau = std::f64::consts::TAU;
        assert_eq!(kept.len(), 2);
        assert!((kept[0].1 - (4.0 - tau)).abs() < 1e-12);
        assert!((kept[1].1 - (tau - 4.0)).abs() < 1e-12 && kept[1].0 == 70.4);
    }
}
