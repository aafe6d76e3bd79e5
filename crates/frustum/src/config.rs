//! The frustum data set's configuration: a serde struct meant to be embedded as a
//! table (e.g. `[frustum]`) in a model's TOML. Every field has a default (the
//! published F-ConvNet Car configuration), so a table only lists what it changes.

use crate::coder::BoxCoder;
use crate::error::{FrustumError, Result};
use crate::proposal::ProposalCrop;
use crate::slicing::{DepthGuidedSlicing, SliceStrategy, Slicing, UniformSlicing};
use fusiondet_dataset::Class;
use fusiondet_kitti::ObjectClass;
use serde::{Deserialize, Serialize};

/// The most points a frustum (or one sub-frustum) may be sampled to; F-ConvNet uses 1,024.
pub const MAX_POINTS_PER_FRUSTUM: usize = 65_536;
/// The farthest depth a frustum may reach, in metres (KITTI's LiDAR sees about 120 m).
pub const MAX_DEPTH: f64 = 500.0;
/// The most sub-frustums over all scales (F-ConvNet's Car configuration has 280).
pub const MAX_SLICES: usize = 4096;
/// The most augmented copies of each labelled frustum per epoch.
pub const MAX_COPIES: usize = 1000;

/// How the data set is made and sliced.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FrustumConfig {
    /// Classes that become frustums, as their format spells them (KITTI: `["Car"]`,
    /// `["Pedestrian", "Cyclist"]`; SUN RGB-D: `["bed", "table", ...]`). Only the
    /// classes of the coder's class set have a one-hot slot and a size cluster.
    #[serde(with = "class_names")]
    pub classes: Vec<Class>,
    /// Points sampled per frustum (with repetition when the frustum has fewer).
    pub points_per_frustum: usize,
    /// Sub-frustums are cut from the first this many sampled points (0 = all). SAF's LFA
    /// takes 4096 points and halves them twice at random; the samples are in random
    /// order, so its survivors are the first 1024, and only those are sliced.
    pub sliced_points: usize,
    /// [min, max] depth in metres along the frustum axis (the frustum frame's z):
    /// points outside are not part of the frustum and the sub-frustums tile this range.
    pub depth_range: [f64; 2],
    /// How the frustum is cut into sub-frustums along depth.
    pub slicing: Slicing,
    /// Index of the scale whose sub-frustum centres are the output positions.
    pub output_scale: usize,
    /// Training frustums whose (jittered, clipped) 2D box is shorter are dropped.
    pub min_box_height_train: f64,
    /// Detection frustums whose (clipped) 2D box is shorter are dropped.
    pub min_box_height_test: f64,
    /// Training frustums with fewer LiDAR points inside the ground-truth 3D box are
    /// dropped (F-PointNet's rule; 0 keeps every frustum that has any point at all).
    pub min_object_points: usize,
    /// Training-time augmentation.
    pub augment: AugmentConfig,
    /// Set for a refinement (second) stage: frustums are cut around first-stage 3D
    /// boxes and `depth_range` is relative to each box's centre.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub proposal_crop: Option<ProposalCrop>,
    /// The box coder of the targets (and of decoding): not a key of its own, but built
    /// by the experiment configuration from the network's heading bins and the data
    /// set's class set (F-ConvNet's KITTI coder by default).
    #[serde(skip)]
    pub coder: BoxCoder,
}

/// Training-time augmentation. The 2D jitter is drawn once, when the training set is
/// prepared (as F-PointNet's prepared pickles do); flip, depth shift and the point
/// sampling are drawn afresh for every epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AugmentConfig {
    /// Frustums per ground-truth object, each from its own jittered 2D box.
    pub copies: usize,
    /// Relative 2D box jitter r: centre shifted by up to ±r·(w, h), width and height
    /// scaled by a factor in [1 − r, 1 + r], all uniform. 0 uses the label box as is.
    pub box_jitter: f64,
    /// Mirror x in the frustum frame with probability 1/2.
    pub flip: bool,
    /// Random shift of points and ground truth along the frustum axis; `None` disables.
    pub depth_shift: Option<DepthShift>,
}

/// F-ConvNet's depth shift: `clip(N(0,1) · sigma · d, ±max · d)` with `d` the
/// ground truth's bird's-eye diagonal √(l² + w²), then clipped so that the box centre
/// stays inside the depth range.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthShift {
    pub sigma: f64,
    pub max: f64,
}

impl Default for AugmentConfig {
    fn default() -> Self {
        AugmentConfig {
            copies: 5,
            box_jitter: 0.1,
            flip: true,
            depth_shift: Some(DepthShift {
                sigma: 0.2,
                max: 0.5,
            }),
        }
    }
}

impl AugmentConfig {
    /// No augmentation at all: one frustum per object from its label box.
    pub fn none() -> Self {
        AugmentConfig {
            copies: 1,
            box_jitter: 0.0,
            flip: false,
            depth_shift: None,
        }
    }
}

impl Default for FrustumConfig {
    fn default() -> Self {
        FrustumConfig::car()
    }
}

impl FrustumConfig {
    /// The published F-ConvNet Car model: 1024 points, 0–70 m, strides
    /// 0.25/0.5/1/2 m with lengths twice the stride (280/140/70/35 sub-frustums),
    /// at most 32/64/64/128 points each, output at the second scale.
    pub fn car() -> Self {
        FrustumConfig {
            classes: vec![ObjectClass::Car.into()],
            points_per_frustum: 1024,
            sliced_points: 0,
            depth_range: [0.0, 70.0],
            slicing: Slicing::Uniform(UniformSlicing::with_double_lengths(
                &[0.25, 0.5, 1.0, 2.0],
                &[32, 64, 64, 128],
            )),
            output_scale: 1,
            min_box_height_train: 25.0,
            min_box_height_test: 5.0,
            min_object_points: 1,
            augment: AugmentConfig::default(),
            proposal_crop: None,
            coder: BoxCoder::kitti(),
        }
    }

    /// F-ConvNet's refinement stage for cars: 512 points from the first-stage box
    /// enlarged 1.2×, strides 0.1/0.2/0.4/0.8 m over ±3.2 m about its centre
    /// (64/32/16/8 sub-frustums), output at the second scale.
    pub fn car_refinement() -> Self {
        FrustumConfig {
            points_per_frustum: 512,
            depth_range: [-3.2, 3.2],
            slicing: Slicing::Uniform(UniformSlicing::with_double_lengths(
                &[0.1, 0.2, 0.4, 0.8],
                &[32, 64, 64, 128],
            )),
            proposal_crop: Some(ProposalCrop::default()),
            ..FrustumConfig::car()
        }
    }

    /// The Pedestrian + Cyclist model: strides 0.1/0.2/0.4/0.8 m with the Car
    /// model's sub-frustum counts (280/140/70/35), hence a 0–28 m depth range. Widen
    /// `depth_range` to cover farther people with more sub-frustums per scale.
    pub fn pedestrian_cyclist() -> Self {
        FrustumConfig {
            classes: vec![ObjectClass::Pedestrian.into(), ObjectClass::Cyclist.into()],
            depth_range: [0.0, 28.0],
            slicing: Slicing::Uniform(UniformSlicing::with_double_lengths(
                &[0.1, 0.2, 0.4, 0.8],
                &[32, 64, 64, 128],
            )),
            ..FrustumConfig::car()
        }
    }

    /// SUN RGB-D's ten classes (F-ConvNet and FCAM's indoor row): 1024 points over
    /// 0–8 m (rooms; the depth sensors see little beyond), F-ConvNet's
    /// Pedestrian/Cyclist strides 0.1/0.2/0.4/0.8 m (indoor objects are 0.4–2.1 m, the
    /// size of people rather than cars) with lengths twice the stride, hence
    /// 80/40/20/10 sub-frustums, at most 32/64/64/128 points each, output at the second
    /// scale (0.2 m apart); one-hot and size clusters over [`ClassSet::sun_rgbd`]'s ten
    /// classes (12 heading bins, as for KITTI).
    ///
    /// [`ClassSet::sun_rgbd`]: fusiondet_dataset::ClassSet::sun_rgbd
    pub fn sun_rgbd() -> Self {
        FrustumConfig {
            classes: fusiondet_sunrgbd_classes(),
            depth_range: [0.0, 8.0],
            slicing: Slicing::Uniform(UniformSlicing::with_double_lengths(
                &[0.1, 0.2, 0.4, 0.8],
                &[32, 64, 64, 128],
            )),
            coder: BoxCoder::new(12, fusiondet_dataset::ClassSet::sun_rgbd())
                .expect("12 heading bins"),
            ..FrustumConfig::car()
        }
    }

    /// SAF's Car model: the F-ConvNet Car model with depth-guided slicing
    /// ([`DepthGuidedSlicing::saf_car`]: 240/120/60/30 sub-frustums, the first of each
    /// scale the near region) over SAF's 0–75 m; output at the second scale (120).
    pub fn saf_car() -> Self {
        FrustumConfig {
            depth_range: [0.0, 75.0],
            slicing: Slicing::DepthGuided(DepthGuidedSlicing::saf_car()),
            ..FrustumConfig::car()
        }
    }

    /// Checks every field, also against sizes a real model could use (a larger value would
    /// abort on allocation or run for minutes); the error names the field and what is wrong
    /// with it.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(FrustumError::Config(m));
        if self.classes.is_empty() {
            return bad("`classes` is empty".into());
        }
        for c in &self.classes {
            if self.coder.cluster_of(c.as_str()).is_none() {
                return bad(format!(
                    "`classes`: {c} has no size cluster; use {}",
                    self.coder.classes().names().join(", ")
                ));
            }
        }
        if let Slicing::DepthGuided(d) = &self.slicing
            && let Some(c) = self
                .classes
                .iter()
                .find(|c| d.mean_heights.of(**c).is_none())
        {
            return bad(format!(
                "`slicing.kind = \"depth_guided\"` has no mean height for {c} (SAF's are \
                 Car, Pedestrian and Cyclist); use `kind = \"uniform\"`"
            ));
        }
        if !(1..=MAX_POINTS_PER_FRUSTUM).contains(&self.points_per_frustum) {
            return bad(format!(
                "`points_per_frustum` must be in [1, {MAX_POINTS_PER_FRUSTUM}], not {}",
                self.points_per_frustum
            ));
        }
        if self.sliced_points > self.points_per_frustum {
            return bad(format!(
                "`sliced_points` {} exceeds `points_per_frustum` {}; use at most that many (0 = all)",
                self.sliced_points, self.points_per_frustum
            ));
        }
        let [lo, hi] = self.depth_range;
        if !(lo.abs() <= MAX_DEPTH && hi.abs() <= MAX_DEPTH) {
            return bad(format!(
                "`depth_range` [{lo:e}, {hi:e}] must lie within ±{MAX_DEPTH} m"
            ));
        }
        match &self.proposal_crop {
            None if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo) => {
                return bad(format!(
                    "`depth_range` [{lo}, {hi}] must satisfy 0 <= min < max"
                ));
            }
            Some(_) if !(lo.is_finite() && hi.is_finite() && lo < 0.0 && hi > 0.0) => {
                return bad(format!(
                    "`depth_range` [{lo}, {hi}] of a refinement stage is relative to the \
                     proposal's centre and must satisfy min < 0 < max (e.g. [-3.2, 3.2])"
                ));
            }
            _ => {}
        }
        if let Some(crop) = &self.proposal_crop {
            crop.validate().map_err(FrustumError::Config)?;
            if !matches!(self.slicing, Slicing::Uniform(_)) {
                return bad(
                    "a refinement stage (`proposal_crop`) needs `slicing.kind = \"uniform\"`: \
                     depth-guided slicing reads the depth from a 2D box"
                        .into(),
                );
            }
        }
        self.slicing.validate(self.depth_range)?;
        let slices: usize = self.slicing.slices_per_scale(self.depth_range).iter().sum();
        if slices > MAX_SLICES {
            return bad(format!(
                "`slicing` makes {slices} sub-frustums over `depth_range`; at most {MAX_SLICES} \
                 (use longer strides)"
            ));
        }
        if let Some(m) = self
            .slicing
            .max_points_per_scale()
            .into_iter()
            .find(|&m| m > MAX_POINTS_PER_FRUSTUM)
        {
            return bad(format!(
                "`slicing` max_points {m} exceeds {MAX_POINTS_PER_FRUSTUM} per sub-frustum"
            ));
        }
        let scales = self.slicing.num_scales();
        if self.output_scale >= scales {
            return bad(format!(
                "`output_scale` {} is not one of the {scales} scales",
                self.output_scale
            ));
        }
        for (name, v) in [
            ("min_box_height_train", self.min_box_height_train),
            ("min_box_height_test", self.min_box_height_test),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("`{name}` must be a finite number >= 0, got {v}"));
            }
        }
        let a = &self.augment;
        if !(1..=MAX_COPIES).contains(&a.copies) {
            return bad(format!(
                "`augment.copies` must be in [1, {MAX_COPIES}], not {}",
                a.copies
            ));
        }
        if !(a.box_jitter.is_finite() && (0.0..1.0).contains(&a.box_jitter)) {
            return bad(format!(
                "`augment.box_jitter` must be in [0, 1), got {}",
                a.box_jitter
            ));
        }
        if let Some(s) = a.depth_shift
            && !(s.sigma.is_finite() && s.max.is_finite() && s.sigma >= 0.0 && s.max >= 0.0)
        {
            return bad(format!(
                "`augment.depth_shift` needs sigma, max >= 0, got {s:?}"
            ));
        }
        Ok(())
    }

    /// Whether frustums of this class are made.
    pub fn wants(&self, class: Class) -> bool {
        self.classes.contains(&class)
    }

    /// The KITTI classes among `classes` (what KITTI's evaluation is asked about).
    pub fn kitti_classes(&self) -> Vec<ObjectClass> {
        self.classes.iter().filter_map(|c| c.kitti()).collect()
    }
}

/// SUN RGB-D's ten classes in one-hot order.
fn fusiondet_sunrgbd_classes() -> Vec<Class> {
    fusiondet_dataset::ClassSet::sun_rgbd()
        .names()
        .iter()
        .map(|n| Class::parse(n).expect("SUN RGB-D's class names parse"))
        .collect()
}

/// `Vec<Class>` as a list of class names (KITTI's or SUN RGB-D's spelling).
mod class_names {
    use fusiondet_dataset::Class;
    use serde::{Deserialize, Deserializer, Serializer, de::Error as _};

    pub fn serialize<S: Serializer>(classes: &[Class], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(classes.iter().map(|c| c.as_str()))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Class>, D::Error> {
        Vec::<String>::deserialize(d)?
            .iter()
            .map(|name| {
                Class::parse(name)
                    .ok_or_else(|| D::Error::custom(format!("unknown class `{name}`")))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_have_the_published_counts() {
        let car = FrustumConfig::car();
        car.validate().unwrap();
        assert_eq!(
            car.slicing.slices_per_scale(car.depth_range),
            [280, 140, 70, 35]
        );
        let people = FrustumConfig::pedestrian_cyclist();
        people.validate().unwrap();
        assert_eq!(
            people.slicing.slices_per_scale(people.depth_range),
            [280, 140, 70, 35]
        );
    }

    #[test]
    fn toml_table_overrides_only_what_it_names() {
        let text = r#"
classes = ["Pedestrian", "Cyclist"]
depth_range = [0.0, 28.0]
[slicing]
kind = "uniform"
strides = [0.1, 0.2, 0.4, 0.8]
lengths = [0.2, 0.4, 0.8, 1.6]
max_points = [32, 64, 64, 128]
[augment]
copies = 2
depth_shift = { sigma = 0.1, max = 0.3 }
"#;
        let c: FrustumConfig = toml::from_str(text).unwrap();
        c.validate().unwrap();
        assert_eq!(
            c.classes,
            [ObjectClass::Pedestrian.into(), ObjectClass::Cyclist.into()]
        );
        assert_eq!(c.points_per_frustum, 1024);
        assert_eq!(c.augment.copies, 2);
        assert!(c.augment.flip);
        assert_eq!(
            c.augment.depth_shift,
            Some(DepthShift {
                sigma: 0.1,
                max: 0.3
            })
        );
        assert_eq!(c.slicing, FrustumConfig::pedestrian_cyclist().slicing);
        // And back.
        let again: FrustumConfig = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(again, c);
    }

    #[test]
    fn saf_car_preset_and_depth_guided_toml() {
        let saf = FrustumConfig::saf_car();
        saf.validate().unwrap();
        assert_eq!(
            saf.slicing.slices_per_scale(saf.depth_range),
            [240, 120, 60, 30]
        );
        assert_eq!(saf.slicing.max_points_per_scale(), [32, 64, 64, 128]);
        let text = r#"
depth_range = [0.0, 75.0]
[slicing]
kind = "depth_guided"
slices = 240
omega = 0.5
max_points = [32, 64, 64, 128]
mean_heights = { car = 1.56, pedestrian = 1.76, cyclist = 1.74 }
"#;
        let c: FrustumConfig = toml::from_str(text).unwrap();
        c.validate().unwrap();
        let Slicing::DepthGuided(s) = &c.slicing else {
            panic!("{:?}", c.slicing)
        };
        assert_eq!(
            (s.slices, s.omega, s.mean_heights.pedestrian),
            (240, 0.5, 1.76)
        );
        assert_eq!(s.max_points, [32, 64, 64, 128]);
        // Round trip, through the serialised form too.
        let out = toml::to_string(&c).unwrap();
        assert!(out.contains("kind = \"depth_guided\""), "{out}");
        let again: FrustumConfig = toml::from_str(&out).unwrap();
        assert_eq!(again, c);
        let again: FrustumConfig = toml::from_str(&toml::to_string(&saf).unwrap()).unwrap();
        assert_eq!(again, saf);
        // Only the kind: SAF's Car values; a partial table overrides what it names.
        let c: FrustumConfig =
            toml::from_str("depth_range = [0.0, 75.0]\n[slicing]\nkind = \"depth_guided\"\n")
                .unwrap();
        assert_eq!(c, saf);
        let c: FrustumConfig = toml::from_str(
            "[slicing]\nkind = \"depth_guided\"\nomega = 0.3\nmean_heights = { car = 1.5 }\n",
        )
        .unwrap();
        let Slicing::DepthGuided(s) = &c.slicing else {
            panic!()
        };
        assert_eq!(
            (s.omega, s.mean_heights.car, s.mean_heights.cyclist),
            (0.3, 1.5, 1.74)
        );
    }

    #[test]
    fn bad_depth_guided_tables_are_named() {
        for (text, want) in [
            (
                "kind = \"depth_guided\"\nstrides = [0.25]",
                "unknown field `strides`",
            ),
            (
                "kind = \"depth_guided\"\nmean_heights = { van = 2.0 }",
                "unknown field `van`",
            ),
            ("kind = \"sliding\"", "unknown variant `sliding`"),
        ] {
            let err = toml::from_str::<FrustumConfig>(&format!("[slicing]\n{text}\n"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(want), "{text}: {err}");
        }
        for (text, want) in [
            (
                "slices = 100",
                "`slicing.slices` = 100 must be divisible by 8",
            ),
            ("omega = 1.5", "`slicing.omega` = 1.5 must be in [0, 1)"),
            (
                "mean_heights = { car = -1.0 }",
                "`slicing.mean_heights.car` = -1",
            ),
            (
                "max_points = [32, 64, 0, 128]",
                "`slicing.max_points` scale 2 is 0",
            ),
        ] {
            let c: FrustumConfig =
                toml::from_str(&format!("[slicing]\nkind = \"depth_guided\"\n{text}\n")).unwrap();
            let err = c.validate().unwrap_err().to_string();
            assert!(err.contains(want), "{text}: {err}");
        }
    }

    #[test]
    fn bad_configs_are_named() {
        let err = toml::from_str::<FrustumConfig>("classes = [\"Bus\"]")
            .unwrap_err()
            .to_string();
        assert!(err.contains("unknown class `Bus`"), "{err}");
        let err = toml::from_str::<FrustumConfig>("point_per_frustum = 3")
            .unwrap_err()
            .to_string();
        assert!(err.contains("unknown field"), "{err}");
        let c = FrustumConfig {
            classes: vec![ObjectClass::Van.into()],
            ..FrustumConfig::car()
        };
        assert!(c.validate().unwrap_err().to_string().contains("Van"));
        let c = FrustumConfig {
            output_scale: 4,
            ..FrustumConfig::car()
        };
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("output_scale")
        );
        let c = FrustumConfig {
            depth_range: [10.0, 5.0],
            ..FrustumConfig::car()
        };
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("depth_range")
        );
    }
}
