//! The anchor head's anchors: a fixed set of boxes on the bird's-eye feature map (the
//! voxel grid's x–y over the feature-map stride, 176 × 200 for the published Car
//! configuration), one per class and rotation at every cell.
//!
//! Order, as OpenPCDet's `AnchorGenerator` (and so the head's output channels): row-major
//! over the feature map, y outer and x inner, then the classes in configuration order,
//! then each class's rotations: index = (y·nx + x)·per_location + slot.
//!
//! Positions: with `align_center` false (published) the first and last anchors sit on
//! the range's edges, x_i = x_min + i·(x_max − x_min)/(nx − 1); with it true at the
//! cell centres x_min + (i + ½)·(x_max − x_min)/nx. The anchor centre is the class's
//! bottom z plus half its height.

use crate::boxes::LidarBox;
use crate::config::{AnchorConfig, VoxelConfig};
use crate::error::Result;
use std::ops::Range;

/// Anchor centres along one axis: `start + i·step` for i < n.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Axis {
    start: f64,
    step: f64,
    n: usize,
}

impl Axis {
    fn new(lo: f64, hi: f64, n: usize, align_center: bool) -> Axis {
        if align_center {
            let step = (hi - lo) / n as f64;
            Axis {
                start: lo + step / 2.0,
                step,
                n,
            }
        } else {
            Axis {
                start: lo,
                step: (hi - lo) / (n - 1) as f64,
                n,
            }
        }
    }

    fn at(&self, i: usize) -> f64 {
        self.start + i as f64 * self.step
    }

    /// The indices whose centres lie in [lo, hi] (empty when none do).
    fn within(&self, lo: f64, hi: f64) -> Range<usize> {
        let first = ((lo - self.start) / self.step).ceil().max(0.0);
        let last = ((hi - self.start) / self.step).floor();
        if !(first.is_finite() && last.is_finite()) || last < first || last < 0.0 {
            return 0..0;
        }
        (first as usize).min(self.n)..((last as usize) + 1).min(self.n)
    }
}

/// All anchors of a frame (the same for every frame of a configuration).
#[derive(Debug, Clone, PartialEq)]
pub struct Anchors {
    /// Every anchor, in the order described in the module documentation.
    pub boxes: Vec<LidarBox>,
    /// The bird's-eye feature map's [nx, ny].
    pub feature_map_size: [usize; 2],
    /// Anchors per feature-map cell.
    pub per_location: usize,
    /// The anchor class (index into `AnchorConfig::classes`) of each slot of a cell.
    pub slot_class: Vec<usize>,
    x: Axis,
    y: Axis,
}

impl Anchors {
    /// Lays the anchors of `config` on the feature map of `voxel`'s grid.
    pub fn generate(voxel: &VoxelConfig, config: &AnchorConfig) -> Result<Anchors> {
        voxel.validate()?;
        config.validate(voxel)?;
        let [nx, ny] = config.feature_map_size(voxel);
        let r = &voxel.point_range;
        let x = Axis::new(r[0], r[3], nx, config.align_center);
        let y = Axis::new(r[1], r[4], ny, config.align_center);
        let mut cell: Vec<LidarBox> = Vec::with_capacity(config.per_location());
        let mut slot_class = Vec::with_capacity(config.per_location());
        for (k, class) in config.classes.iter().enumerate() {
            let [dx, dy, dz] = class.size;
            for &heading in &class.rotations {
                cell.push(LidarBox {
                    x: 0.0,
                    y: 0.0,
                    z: class.bottom_z + dz / 2.0,
                    dx,
                    dy,
                    dz,
                    heading,
                });
                slot_class.push(k);
            }
        }
        let mut boxes = Vec::with_capacity(nx * ny * cell.len());
        for iy in 0..ny {
            for ix in 0..nx {
                let (cx, cy) = (x.at(ix), y.at(iy));
                boxes.extend(cell.iter().map(|a| LidarBox { x: cx, y: cy, ..*a }));
            }
        }
        Ok(Anchors {
            boxes,
            feature_map_size: [nx, ny],
            per_location: cell.len(),
            slot_class,
            x,
            y,
        })
    }

    pub fn len(&self) -> usize {
        self.boxes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }

    /// The index of the anchor in slot `slot` of feature-map cell (x, y).
    pub fn index(&self, x: usize, y: usize, slot: usize) -> usize {
        (y * self.feature_map_size[0] + x) * self.per_location + slot
    }

    /// The anchor class of anchor `index`.
    pub fn class_of(&self, index: usize) -> usize {
        self.slot_class[index % self.per_location]
    }

    /// The feature-map cells whose anchor centres lie in the bird's-eye rectangle
    /// [x_lo, x_hi] × [y_lo, y_hi], as x and y index ranges.
    pub fn cells_within(
        &self,
        x_lo: f64,
        x_hi: f64,
        y_lo: f64,
        y_hi: f64,
    ) -> (Range<usize>, Range<usize>) {
        (self.x.within(x_lo, x_hi), self.y.within(y_lo, y_hi))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn published_car_anchors() {
        let a = Anchors::generate(&VoxelConfig::default(), &AnchorConfig::default()).unwrap();
        assert_eq!(a.feature_map_size, [176, 200]);
        assert_eq!(a.len(), 176 * 200 * 2);
        // First cell: both rotations at the range's corner, centre z = −1.78 + 0.78.
        let (first, second) = (a.boxes[0], a.boxes[1]);
        assert_eq!((first.x, first.y), (0.0, -40.0));
        assert!(close(first.z, -1.0));
        assert_eq!((first.heading, second.heading), (0.0, FRAC_PI_2));
        assert_eq!((first.dx, first.dy, first.dz), (3.9, 1.6, 1.56));
        // x runs fastest: anchor 2 is cell (1, 0), 70.4 / 175 further along x.
        assert!(close(a.boxes[2].x, 70.4 / 175.0) && a.boxes[2].y == -40.0);
        // Row y = 1 starts after 176 cells; the last cell is the far corner.
        assert!(close(a.boxes[a.index(0, 1, 0)].y, -40.0 + 80.0 / 199.0));
        let last = a.boxes[a.len() - 1];
        assert!(close(last.x, 70.4) && close(last.y, 40.0) && last.heading == FRAC_PI_2);
        assert_eq!(a.index(175, 199, 1), a.len() - 1);
        assert_eq!(a.class_of(3), 0);
    }

    #[test]
    fn centre_aligned_anchors_and_several_classes() {
        let voxel = VoxelConfig {
            point_range: [0.0, 0.0, -3.0, 8.0, 4.0, 1.0],
            voxel_size: [1.0, 1.0, 4.0],
            ..Default::default()
        };
        let mut ped = crate::config::AnchorClass::car();
        ped.class = fusiondet_kitti::ObjectClass::Pedestrian;
        ped.rotations = vec![0.5];
        let config = AnchorConfig {
            classes: vec![crate::config::AnchorClass::car(), ped],
            feature_map_stride: 2,
            align_center: true,
            ..Default::default()
        };
        let a = Anchors::generate(&voxel, &config).unwrap();
        // 8 × 4 voxels / 2 = 4 × 2 cells of 2 m, centres at 1, 3, 5, 7 and 1, 3.
        assert_eq!(a.feature_map_size, [4, 2]);
        assert_eq!(a.per_location, 3);
        assert_eq!(a.slot_class, vec![0, 0, 1]);
        let b = a.boxes[a.index(2, 1, 2)];
        assert_eq!((b.x, b.y, b.heading), (5.0, 3.0, 0.5));
        assert_eq!(a.class_of(a.index(2, 1, 2)), 1);
        // Cells whose centres lie in [2.5, 7.0] × [−1, 1.5].
        assert_eq!(a.cells_within(2.5, 7.0, -1.0, 1.5), (1..4, 0..1));
        assert_eq!(a.cells_within(9.0, 12.0, 0.0, 4.0).0, 4..4);
        assert!(a.cells_within(-5.0, -1.0, 0.0, 4.0).0.is_empty());
    }
}
