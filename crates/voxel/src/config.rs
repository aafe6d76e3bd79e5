//! The voxel family's configuration: serde structs meant to be embedded as tables of an
//! experiment TOML. Every field defaults to the published Voxel R-CNN KITTI Car
//! configuration (OpenPCDet's `voxel_rcnn_car.yaml` over `kitti_dataset.yaml`), so a
//! table only lists what it changes; unknown keys are errors.

use crate::error::{Result, VoxelError};
use fusiondet_kitti::ObjectClass;
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

fn bad<T>(message: String) -> Result<T> {
    Err(VoxelError::Config(message))
}

fn finite_in(name: &str, value: f64, lo: f64, hi: f64) -> Result<()> {
    if !(value.is_finite() && (lo..=hi).contains(&value)) {
        return bad(format!("`{name}` is {value}; it must lie in [{lo}, {hi}]"));
    }
    Ok(())
}

/// Bounds on the sizes the configuration sets, so that a mistyped value is refused with its
/// key instead of exhausting memory: far above the published configurations (1,408 × 1,600
/// × 40 voxels, 16,000 / 40,000 voxels, 5 points each, 128 RoIs).
pub const MAX_GRID_CELLS_PER_AXIS: usize = 8192;
pub const MAX_BEV_CELLS: usize = 1 << 24;
pub const MAX_VOXELS: usize = 2_000_000;
pub const MAX_POINTS_PER_VOXEL: usize = 256;
pub const MAX_ROIS_PER_FRAME: usize = 4096;

/// The point-cloud range and the voxel grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelConfig {
    /// [x_min, y_min, z_min, x_max, y_max, z_max] in metres, LiDAR frame.
    pub point_range: [f64; 6],
    /// Voxel edge lengths [x, y, z] in metres; each must divide its range into a whole
    /// number of voxels.
    pub voxel_size: [f64; 3],
    /// Points kept per voxel (the first ones met); the voxel feature is their mean.
    pub max_points_per_voxel: usize,
    /// Voxels kept per training frame.
    pub max_voxels_train: usize,
    /// Voxels kept per detection frame.
    pub max_voxels_test: usize,
    /// Keep only the points that project into the camera image (KITTI labels only
    /// objects in the image; OpenPCDet's `FOV_POINTS_ONLY`).
    pub fov_only: bool,
}

impl Default for VoxelConfig {
    fn default() -> Self {
        VoxelConfig {
            point_range: [0.0, -40.0, -3.0, 70.4, 40.0, 1.0],
            voxel_size: [0.05, 0.05, 0.1],
            max_points_per_voxel: 5,
            max_voxels_train: 16_000,
            max_voxels_test: 40_000,
            fov_only: true,
        }
    }
}

impl VoxelConfig {
    /// Voxels along [x, y, z]: the range over the voxel size, rounded (the published
    /// configuration gives [1408, 1600, 40]). Meaningful once [`VoxelConfig::validate`]
    /// has passed.
    pub fn grid_size(&self) -> [usize; 3] {
        std::array::from_fn(|a| self.grid_extent(a).round() as usize)
    }

    /// The sparse 3D backbone's input shape [z, y, x]: OpenPCDet's `VoxelBackBone8x`
    /// pads the grid with one extra height ([41, 1600, 1408] published), so that its
    /// strided convolutions reduce z to 2 before the BEV height compression.
    pub fn sparse_shape(&self) -> [usize; 3] {
        let [nx, ny, nz] = self.grid_size();
        [nz + 1, ny, nx]
    }

    fn grid_extent(&self, axis: usize) -> f64 {
        (self.point_range[axis + 3] - self.point_range[axis]) / self.voxel_size[axis]
    }

    /// The voxel cap of training or detection.
    pub fn max_voxels(&self, training: bool) -> usize {
        if training {
            self.max_voxels_train
        } else {
            self.max_voxels_test
        }
    }

    pub fn validate(&self) -> Result<()> {
        let axes = ["x", "y", "z"];
        for (a, axis) in axes.iter().enumerate() {
            let (lo, hi) = (self.point_range[a], self.point_range[a + 3]);
            if !(lo.is_finite() && hi.is_finite() && hi > lo) {
                return bad(format!(
                    "`point_range` {axis}: [{lo}, {hi}] must be finite with min < max"
                ));
            }
            let size = self.voxel_size[a];
            if !(size.is_finite() && size > 0.0) {
                return bad(format!(
                    "`voxel_size` {axis} is {size}; it must be positive"
                ));
            }
            let n = self.grid_extent(a);
            if (n - n.round()).abs() > 1e-6 || n.round() < 1.0 {
                return bad(format!(
                    "`voxel_size` {axis} {size} does not divide the range [{lo}, {hi}] into a \
                     whole number of voxels ({n}); change the range or the size"
                ));
            }
            // Every dense map (the BEV, the anchors) is sized by the grid: bounded before
            // anything is allocated from it.
            if n.round() > MAX_GRID_CELLS_PER_AXIS as f64 {
                return bad(format!(
                    "`voxel_size` {axis} {size} makes {n:.0} voxels along {axis} over [{lo}, {hi}]; \
                     at most {MAX_GRID_CELLS_PER_AXIS} are allowed (KITTI's published grid has \
                     1,600): make the voxels larger or the range smaller"
                ));
            }
        }
        if !(1..=MAX_POINTS_PER_VOXEL).contains(&self.max_points_per_voxel) {
            return bad(format!(
                "`max_points_per_voxel` {} must be in 1..={MAX_POINTS_PER_VOXEL}",
                self.max_points_per_voxel
            ));
        }
        for (name, v) in [
            ("max_voxels_train", self.max_voxels_train),
            ("max_voxels_test", self.max_voxels_test),
        ] {
            if !(1..=MAX_VOXELS).contains(&v) {
                return bad(format!("`{name}` {v} must be in 1..={MAX_VOXELS}"));
            }
        }
        let [nx, ny, _] = self.grid_size();
        if nx * ny > MAX_BEV_CELLS {
            return bad(format!(
                "the grid is {nx} × {ny} voxels in bird's-eye view; at most {MAX_BEV_CELLS} cells \
                 are allowed (KITTI's published grid has 2,252,800): make the voxels larger or \
                 the range smaller"
            ));
        }
        Ok(())
    }
}

/// The anchors of one class.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnchorClass {
    /// The class, as KITTI spells it.
    #[serde(with = "class_name")]
    pub class: ObjectClass,
    /// [dx (length), dy (width), dz (height)] in metres.
    pub size: [f64; 3],
    /// LiDAR z of the anchors' bottom face; their centre is `size[2] / 2` above it.
    pub bottom_z: f64,
    /// Headings of the anchors at each location, radians.
    pub rotations: Vec<f64>,
    /// Anchors with nearest-BEV IoU ≥ this with a ground truth are positive.
    pub matched_iou: f64,
    /// Anchors with IoU < this with every ground truth are negative; between the two,
    /// ignored.
    pub unmatched_iou: f64,
}

impl AnchorClass {
    /// The published Car anchors (the configuration writes π/2 as 1.57).
    pub fn car() -> AnchorClass {
        AnchorClass {
            class: ObjectClass::Car,
            size: [3.9, 1.6, 1.56],
            bottom_z: -1.78,
            rotations: vec![0.0, FRAC_PI_2],
            matched_iou: 0.6,
            unmatched_iou: 0.45,
        }
    }
}

/// The anchor head's anchors, their assignment and the direction classifier.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnchorConfig {
    /// One entry per class; at each location the anchors are listed class by class,
    /// rotations within a class.
    pub classes: Vec<AnchorClass>,
    /// Voxels per BEV feature-map cell along x and y (the 3D backbone's 8× and the BEV
    /// backbone's 1×).
    pub feature_map_stride: usize,
    /// false: anchors at range_min + i·(range / (n − 1)), the first and last on the
    /// range's edges (OpenPCDet's `align_center: False`); true: at the cell centres.
    pub align_center: bool,
    /// The direction bins start at this heading (radians).
    pub dir_offset: f64,
    /// Where in its period a decoded heading is wrapped before the bin is added
    /// (OpenPCDet's `DIR_LIMIT_OFFSET`).
    pub dir_limit_offset: f64,
    /// Direction bins over 2π (2: which way along the box's axis the object faces).
    pub num_dir_bins: usize,
}

impl Default for AnchorConfig {
    fn default() -> Self {
        AnchorConfig {
            classes: vec![AnchorClass::car()],
            feature_map_stride: 8,
            align_center: false,
            dir_offset: FRAC_PI_4,
            dir_limit_offset: 0.0,
            num_dir_bins: 2,
        }
    }
}

impl AnchorConfig {
    /// Anchors per feature-map location (all classes).
    pub fn per_location(&self) -> usize {
        self.classes.iter().map(|c| c.rotations.len()).sum()
    }

    /// The BEV feature map's [nx, ny] for a voxel grid.
    pub fn feature_map_size(&self, voxel: &VoxelConfig) -> [usize; 2] {
        let g = voxel.grid_size();
        [
            g[0] / self.feature_map_stride.max(1),
            g[1] / self.feature_map_stride.max(1),
        ]
    }

    /// The index of a class among the anchor classes.
    pub fn class_index(&self, class: ObjectClass) -> Option<usize> {
        self.classes.iter().position(|c| c.class == class)
    }

    /// Checks the anchors against the voxel grid they are laid on (which must be valid).
    pub fn validate(&self, voxel: &VoxelConfig) -> Result<()> {
        if self.classes.is_empty() {
            return bad("`anchors.classes` is empty".into());
        }
        for (i, c) in self.classes.iter().enumerate() {
            let name = c.class.as_str();
            if self.classes[..i].iter().any(|d| d.class == c.class) {
                return bad(format!("anchor class {name} is listed twice"));
            }
            if c.class == ObjectClass::DontCare {
                return bad("DontCare cannot have anchors".into());
            }
            if c.size.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
                return bad(format!(
                    "anchor class {name}: `size` {:?} must be positive",
                    c.size
                ));
            }
            if !c.bottom_z.is_finite() {
                return bad(format!("anchor class {name}: `bottom_z` must be finite"));
            }
            if c.rotations.is_empty() || c.rotations.iter().any(|r| !r.is_finite()) {
                return bad(format!(
                    "anchor class {name}: `rotations` must list at least one finite angle"
                ));
            }
            finite_in("unmatched_iou", c.unmatched_iou, 0.0, 1.0)?;
            finite_in("matched_iou", c.matched_iou, 0.0, 1.0)?;
            if c.unmatched_iou > c.matched_iou {
                return bad(format!(
                    "anchor class {name}: `unmatched_iou` {} exceeds `matched_iou` {}",
                    c.unmatched_iou, c.matched_iou
                ));
            }
        }
        let s = self.feature_map_stride;
        let g = voxel.grid_size();
        if s == 0 || !g[0].is_multiple_of(s) || !g[1].is_multiple_of(s) {
            return bad(format!(
                "`feature_map_stride` {s} must divide the grid's x and y voxels ({} × {}), \
                 so that every feature-map cell covers whole voxels",
                g[0], g[1]
            ));
        }
        let [nx, ny] = self.feature_map_size(voxel);
        if !self.align_center && (nx < 2 || ny < 2) {
            return bad(format!(
                "a {nx} × {ny} feature map is too small for edge-aligned anchors (2 × 2 at least)"
            ));
        }
        if self.num_dir_bins == 0 {
            return bad("`num_dir_bins` must be at least 1".into());
        }
        if !(self.dir_offset.is_finite() && self.dir_limit_offset.is_finite()) {
            return bad("`dir_offset` and `dir_limit_offset` must be finite".into());
        }
        Ok(())
    }
}

/// The second stage's RoI sampling and targets (OpenPCDet's `ROI_HEAD.TARGET_CONFIG`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RoiTargetConfig {
    /// RoIs sampled per frame (with repetition when the proposals are fewer).
    pub rois_per_frame: usize,
    /// Target fraction of foreground RoIs.
    pub fg_fraction: f64,
    /// RoIs with 3D IoU above this get a regression target (and with IoU at least
    /// min(this, `cls_fg_iou`) are sampled as foreground).
    pub reg_fg_iou: f64,
    /// Classification target 1 above this IoU…
    pub cls_fg_iou: f64,
    /// …0 below this, linear in between.
    pub cls_bg_iou: f64,
    /// Background RoIs with IoU in [this, `reg_fg_iou`) are "hard", below it "easy".
    pub hard_bg_min_iou: f64,
    /// Target fraction of hard RoIs among the background.
    pub hard_bg_fraction: f64,
    /// Match each RoI only with ground truth of its own class.
    pub sample_by_class: bool,
}

impl Default for RoiTargetConfig {
    fn default() -> Self {
        RoiTargetConfig {
            rois_per_frame: 128,
            fg_fraction: 0.5,
            reg_fg_iou: 0.55,
            cls_fg_iou: 0.75,
            cls_bg_iou: 0.25,
            hard_bg_min_iou: 0.1,
            hard_bg_fraction: 0.8,
            sample_by_class: true,
        }
    }
}

impl RoiTargetConfig {
    /// The IoU from which an RoI counts as foreground when sampling.
    pub fn fg_iou(&self) -> f64 {
        self.reg_fg_iou.min(self.cls_fg_iou)
    }

    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_ROIS_PER_FRAME).contains(&self.rois_per_frame) {
            return bad(format!(
                "`rois_per_frame` {} must be in 1..={MAX_ROIS_PER_FRAME}",
                self.rois_per_frame
            ));
        }
        finite_in("fg_fraction", self.fg_fraction, 0.0, 1.0)?;
        finite_in("hard_bg_fraction", self.hard_bg_fraction, 0.0, 1.0)?;
        for (name, v) in [
            ("reg_fg_iou", self.reg_fg_iou),
            ("cls_fg_iou", self.cls_fg_iou),
            ("cls_bg_iou", self.cls_bg_iou),
            ("hard_bg_min_iou", self.hard_bg_min_iou),
        ] {
            finite_in(name, v, 0.0, 1.0)?;
        }
        if self.cls_bg_iou >= self.cls_fg_iou {
            return bad(format!(
                "`cls_bg_iou` {} must be below `cls_fg_iou` {}",
                self.cls_bg_iou, self.cls_fg_iou
            ));
        }
        if self.hard_bg_min_iou > self.reg_fg_iou {
            return bad(format!(
                "`hard_bg_min_iou` {} exceeds `reg_fg_iou` {}",
                self.hard_bg_min_iou, self.reg_fg_iou
            ));
        }
        Ok(())
    }
}

/// Ground-truth sampling of one class: paste up to `count` database objects that have
/// at least `min_points` points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleGroup {
    #[serde(with = "class_name")]
    pub class: ObjectClass,
    pub count: usize,
    pub min_points: usize,
}

/// Training-time augmentation, in the order it is applied: ground-truth sampling, the
/// per-object noise (off by default; DASANet's "local rotation and noising"), flip along
/// x, rotation about z, scaling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AugmentConfig {
    /// Classes pasted from the ground-truth database (empty: no sampling).
    pub sample_groups: Vec<SampleGroup>,
    /// Database objects of these KITTI difficulties (0 easy, 1 moderate, 2 hard, −1
    /// none of them) are never pasted.
    pub removed_difficulties: Vec<i8>,
    /// Sample `count` minus the scene's objects of the class instead of `count`.
    pub limit_whole_scene: bool,
    /// Mirror the scene across the x axis (y → −y) with probability 1/2.
    pub flip_x: bool,
    /// Rotate the scene about z by an angle uniform in [min, max] radians.
    pub rotation: [f64; 2],
    /// Scale the scene by a factor uniform in [min, max].
    pub scaling: [f64; 2],
    /// Turn each object (its box and the points in it) about its own centre by an angle
    /// uniform in [min, max] radians; [0, 0]: off.
    pub local_rotation: [f64; 2],
    /// Move each object by a normal offset of these standard deviations (x, y, z, metres);
    /// zeros: off. An object whose moved box would overlap another keeps its place.
    pub local_translation_std: [f64; 3],
}

impl Default for AugmentConfig {
    fn default() -> Self {
        AugmentConfig {
            sample_groups: vec![SampleGroup {
                class: ObjectClass::Car,
                count: 15,
                min_points: 5,
            }],
            removed_difficulties: vec![-1],
            limit_whole_scene: false,
            flip_x: true,
            rotation: [-FRAC_PI_4, FRAC_PI_4],
            scaling: [0.95, 1.05],
            local_rotation: [0.0, 0.0],
            local_translation_std: [0.0; 3],
        }
    }
}

impl AugmentConfig {
    /// No augmentation at all.
    pub fn none() -> AugmentConfig {
        AugmentConfig {
            sample_groups: Vec::new(),
            removed_difficulties: Vec::new(),
            limit_whole_scene: false,
            flip_x: false,
            rotation: [0.0, 0.0],
            scaling: [1.0, 1.0],
            local_rotation: [0.0, 0.0],
            local_translation_std: [0.0; 3],
        }
    }

    /// Whether the per-object noise is on.
    pub fn local_noise(&self) -> bool {
        self.local_rotation != [0.0, 0.0] || self.local_translation_std != [0.0; 3]
    }

    pub fn validate(&self) -> Result<()> {
        let [l0, l1] = self.local_rotation;
        if !(l0.is_finite() && l1.is_finite() && l0 <= l1) {
            return bad(format!(
                "`local_rotation` [{l0}, {l1}] must be finite with min ≤ max"
            ));
        }
        if self
            .local_translation_std
            .iter()
            .any(|s| !(s.is_finite() && *s >= 0.0))
        {
            return bad(format!(
                "`local_translation_std` {:?} must be finite and ≥ 0",
                self.local_translation_std
            ));
        }
        let [r0, r1] = self.rotation;
        if !(r0.is_finite() && r1.is_finite() && r0 <= r1) {
            return bad(format!(
                "`rotation` [{r0}, {r1}] must be finite with min ≤ max"
            ));
        }
        let [s0, s1] = self.scaling;
        if !(s0.is_finite() && s1.is_finite() && 0.0 < s0 && s0 <= s1) {
            return bad(format!("`scaling` [{s0}, {s1}] must satisfy 0 < min ≤ max"));
        }
        for (i, g) in self.sample_groups.iter().enumerate() {
            if self.sample_groups[..i].iter().any(|h| h.class == g.class) {
                return bad(format!("`sample_groups`: {} is listed twice", g.class));
            }
            if g.class == ObjectClass::DontCare {
                return bad("`sample_groups`: DontCare cannot be sampled".into());
            }
        }
        Ok(())
    }
}

/// A KITTI class name in a config file.
pub(crate) mod class_name {
    use fusiondet_kitti::ObjectClass;
    use serde::{Deserialize, Deserializer, Serializer, de::Error as _};

    pub fn serialize<S: Serializer>(class: &ObjectClass, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(class.as_str())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<ObjectClass, D::Error> {
        String::deserialize(d)?
            .parse::<ObjectClass>()
            .map_err(D::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_published_configuration() {
        let v = VoxelConfig::default();
        v.validate().unwrap();
        assert_eq!(v.grid_size(), [1408, 1600, 40]);
        assert_eq!(v.sparse_shape(), [41, 1600, 1408]);
        assert_eq!((v.max_voxels(true), v.max_voxels(false)), (16_000, 40_000));
        let a = AnchorConfig::default();
        a.validate(&v).unwrap();
        assert_eq!(a.feature_map_size(&v), [176, 200]);
        assert_eq!(a.per_location(), 2);
        let r = RoiTargetConfig::default();
        r.validate().unwrap();
        assert_eq!(r.fg_iou(), 0.55);
        AugmentConfig::default().validate().unwrap();
        AugmentConfig::none().validate().unwrap();
    }

    #[test]
    fn a_table_lists_only_what_it_changes_and_unknown_keys_are_errors() {
        let v: VoxelConfig = toml::from_str("voxel_size = [0.1, 0.1, 0.2]").unwrap();
        assert_eq!(v.grid_size(), [704, 800, 20]);
        assert_eq!(v.max_points_per_voxel, 5);
        let err = toml::from_str::<VoxelConfig>("voxel_sise = [0.1, 0.1, 0.2]")
            .unwrap_err()
            .to_string();
        assert!(err.contains("voxel_sise"), "{err}");
        let a: AnchorConfig = toml::from_str(
            "classes = [{ class = \"Pedestrian\", size = [0.8, 0.6, 1.73], bottom_z = -0.6, \
             rotations = [0.0, 1.57], matched_iou = 0.5, unmatched_iou = 0.35 }]",
        )
        .unwrap();
        assert_eq!(a.classes[0].class, ObjectClass::Pedestrian);
        assert_eq!(a.feature_map_stride, 8);
        let err = toml::from_str::<AnchorConfig>(
            "classes = [{ class = \"Truck!\", size = [1, 1, 1], bottom_z = 0, rotations = [0], \
             matched_iou = 0.5, unmatched_iou = 0.3 }]",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("Truck!"), "{err}");
        // Round trip through TOML.
        let text = toml::to_string(&AugmentConfig::default()).unwrap();
        assert_eq!(
            toml::from_str::<AugmentConfig>(&text).unwrap(),
            AugmentConfig::default()
        );
    }

    #[test]
    fn validation_names_the_field() {
        let err = |v: VoxelConfig| v.validate().unwrap_err().to_string();
        let e = err(VoxelConfig {
            voxel_size: [0.07, 0.05, 0.1],
            ..Default::default()
        });
        assert!(
            e.contains("voxel_size") && e.contains("whole number"),
            "{e}"
        );
        let e = err(VoxelConfig {
            point_range: [0.0, 40.0, -3.0, 70.4, -40.0, 1.0],
            ..Default::default()
        });
        assert!(e.contains("point_range") && e.contains("y"), "{e}");
        let e = err(VoxelConfig {
            voxel_size: [0.05, 0.0, 0.1],
            ..Default::default()
        });
        assert!(e.contains("positive"), "{e}");
        let e = err(VoxelConfig {
            max_points_per_voxel: 0,
            ..Default::default()
        });
        assert!(e.contains("max_points_per_voxel"), "{e}");

        let v = VoxelConfig::default();
        let a = AnchorConfig {
            feature_map_stride: 3,
            ..Default::default()
        };
        assert!(a.validate(&v).unwrap_err().to_string().contains("stride"));
        let mut a = AnchorConfig::default();
        a.classes[0].unmatched_iou = 0.7;
        assert!(
            a.validate(&v)
                .unwrap_err()
                .to_string()
                .contains("unmatched_iou")
        );
        a.classes = vec![AnchorClass::car(), AnchorClass::car()];
        assert!(a.validate(&v).unwrap_err().to_string().contains("twice"));

        let r = RoiTargetConfig {
            cls_bg_iou: 0.8,
            ..Default::default()
        };
        assert!(r.validate().unwrap_err().to_string().contains("cls_bg_iou"));
        let g = AugmentConfig {
            scaling: [1.05, 0.95],
            ..Default::default()
        };
        assert!(g.validate().unwrap_err().to_string().contains("scaling"));
    }
}
