//! `[dasanet]`: what a DASANet configuration sets beyond Voxel R-CNN's `[voxel_rcnn]`
//! sections (which configure its LiDAR branch, BEV network, anchors, heads and data):
//! the modules of its ablation row, the GIoU weight and the pseudo point cloud.

use fusiondet_models::dasanet::{DasanetModules, DasanetNetConfig, DasanetShape};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DasanetSection {
    pub modules: DasanetModules,
    /// Weight of the detection head's 3D GIoU term (the paper gives none: 1).
    pub giou_weight: f64,
    pub pseudo: PseudoCloudConfig,
}

impl Default for DasanetSection {
    fn default() -> Self {
        Self {
            modules: DasanetModules::default(),
            giou_weight: 1.0,
            pseudo: PseudoCloudConfig::default(),
        }
    }
}

/// How a frame's pseudo point cloud is made and voxelized: IP-Basic's fast pipeline
/// (Gaussian blur, no extrapolation, so no depth is invented above the scan), every
/// completed pixel back-projected, optionally thinned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PseudoCloudConfig {
    /// Pseudo points averaged per voxel (the paper: 15).
    pub max_points_per_voxel: usize,
    /// Pseudo voxels kept per training / detection frame (the paper: LiDAR's caps).
    pub max_voxels_train: usize,
    pub max_voxels_test: usize,
    /// SFD's near-range thinning (below 13 m only pixels with odd u and v).
    pub thinning: bool,
    /// Keep every `pixel_stride`-th pixel along u and v (1: all): a CPU knob that cuts
    /// the cloud by its square.
    pub pixel_stride: usize,
    /// Voxelize the pseudo cloud in training by the detection rule: points in pixel order
    /// (no shuffle) and `max_voxels_test`. The paper gives the pseudo branch LiDAR's rule
    /// (a shuffled 16,000-voxel cap in training, 40,000 at test), but a sim-car frame has
    /// about 37,000 pseudo voxels: training would build P3/P4, and so F^P, from under half
    /// of the cloud the head later meets (issue 34). Off (the paper's split rule) unless a
    /// file sets it, so older runs resume and retrain as they were; detection is the same
    /// either way.
    pub same_voxels_as_test: bool,
}

impl Default for PseudoCloudConfig {
    fn default() -> Self {
        Self {
            max_points_per_voxel: 15,
            max_voxels_train: 16_000,
            max_voxels_test: 40_000,
            thinning: false,
            pixel_stride: 1,
            same_voxels_as_test: false,
        }
    }
}

impl PseudoCloudConfig {
    /// The voxel cap of a training or detection frame.
    pub fn max_voxels(&self, training: bool) -> usize {
        if training && !self.same_voxels_as_test {
            self.max_voxels_train
        } else {
            self.max_voxels_test
        }
    }

    /// Whether a frame's pseudo points are visited in a shuffled order before the caps
    /// (training under the paper's split rule only).
    pub fn shuffles(&self, training: bool) -> bool {
        training && !self.same_voxels_as_test
    }
}

impl DasanetSection {
    /// The network's shape on the Voxel R-CNN shape and grid of `[voxel_rcnn]`.
    pub fn shape(&self, voxel_rcnn: &crate::voxel_rcnn::VoxelRcnnSection) -> DasanetShape {
        DasanetShape {
            network: DasanetNetConfig {
                voxel_rcnn: voxel_rcnn.network.clone(),
                modules: self.modules.clone(),
            },
            grid_z: voxel_rcnn.voxels.sparse_shape()[0],
            inference_only: false,
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        self.modules.validate()?;
        let p = &self.pseudo;
        if p.max_points_per_voxel == 0 || p.max_voxels_train == 0 || p.max_voxels_test == 0 {
            return Err(
                "[dasanet.pseudo]: max_points_per_voxel, max_voxels_train and max_voxels_test \
                 must be at least 1"
                    .into(),
            );
        }
        if p.max_points_per_voxel > fusiondet_voxel::config::MAX_POINTS_PER_VOXEL
            || p.max_voxels_train.max(p.max_voxels_test) > fusiondet_voxel::config::MAX_VOXELS
        {
            return Err(format!(
                "[dasanet.pseudo]: max_points_per_voxel must be at most {}, max_voxels_train and \
                 max_voxels_test at most {}",
                fusiondet_voxel::config::MAX_POINTS_PER_VOXEL,
                fusiondet_voxel::config::MAX_VOXELS
            ));
        }
        if !(1..=64).contains(&p.pixel_stride) {
            return Err(format!(
                "[dasanet.pseudo] pixel_stride {} must be in 1..=64",
                p.pixel_stride
            ));
        }
        if !(self.giou_weight.is_finite() && self.giou_weight >= 0.0) {
            return Err(format!(
                "[dasanet] giou_weight {} must be finite and ≥ 0",
                self.giou_weight
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusiondet_dataset::rng::Sampler;
    use fusiondet_models::dasanet::config::TdisForm;
    use fusiondet_voxel::{PseudoPoint, VoxelConfig, Voxelizer, Voxels};

    /// One frame's pseudo cloud voxelized as `data.rs` does it, in training (with the
    /// augmentation's sampler) or at detection.
    fn voxelize(
        p: &PseudoCloudConfig,
        v: &Voxelizer,
        cloud: &[PseudoPoint],
        train: bool,
    ) -> Voxels {
        let mut rng = Sampler::new(11);
        let shuffle = p.shuffles(train).then_some(&mut rng);
        v.voxelize_pseudo(cloud, p.max_points_per_voxel, p.max_voxels(train), shuffle)
    }

    /// With `same_voxels_as_test`, a frame's pseudo cloud voxelizes to the same voxels in
    /// training as at detection, even when it holds more voxels than the training cap and
    /// more points than a voxel keeps; under the paper's split rule it does not.
    #[test]
    fn training_voxelizes_the_pseudo_cloud_as_detection_does() {
        let v = Voxelizer::new(&VoxelConfig {
            point_range: [0.0, 0.0, 0.0, 8.0, 8.0, 4.0],
            voxel_size: [1.0, 1.0, 1.0],
            max_points_per_voxel: 5,
            max_voxels_train: 20,
            max_voxels_test: 200,
            fov_only: false,
        })
        .unwrap();
        // 256 voxels' worth of space, three points in each occupied one (distinct colours).
        let cloud: Vec<PseudoPoint> = (0..3 * 100)
            .map(|k| {
                let cell = k % 100;
                let (x, y, z) = (cell % 8, (cell / 8) % 8, cell / 64);
                let f = |c: usize| c as f32 + 0.25 + 0.2 * (k / 100) as f32;
                [f(x), f(y), f(z), k as f32 / 300.0, 0.5, 0.5]
            })
            .collect();
        let split = PseudoCloudConfig {
            max_points_per_voxel: 2,
            max_voxels_train: 30,
            max_voxels_test: 150,
            ..PseudoCloudConfig::default()
        };
        let same = PseudoCloudConfig {
            same_voxels_as_test: true,
            ..split.clone()
        };
        let at_test = voxelize(&same, &v, &cloud, false);
        assert_eq!(at_test.len(), 100);
        assert_eq!(voxelize(&same, &v, &cloud, true), at_test);
        assert_eq!(voxelize(&split, &v, &cloud, false), at_test);
        assert_eq!(voxelize(&split, &v, &cloud, true).len(), 30);
    }

    #[test]
    fn the_rule_reads_from_a_file_and_defaults_to_the_papers() {
        let p: PseudoCloudConfig = toml::from_str("same_voxels_as_test = true").unwrap();
        assert!(p.same_voxels_as_test && !p.shuffles(true));
        assert_eq!(p.max_voxels(true), p.max_voxels_test);
        let d = PseudoCloudConfig::default();
        assert!(d.shuffles(true) && !d.shuffles(false));
        assert_eq!(d.max_voxels(true), 16_000);
    }

    fn load(name: &str) -> crate::ExperimentConfig {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs")
            .join(name);
        crate::ExperimentConfig::from_file(&path).unwrap()
    }

    /// The second-form ablation: the baseline row is the first form's with the RoI grid
    /// pooled from the stages the DASANet rows pool F^S from (so the rows differ only in
    /// the modules), and each DASANet row is its first form with the two fixes on.
    #[test]
    fn the_second_form_ablation_rows_differ_only_in_the_modules() {
        let old_base = load("voxel-rcnn-local-aug-car-sim.toml");
        let base = load("dasanet-baseline-voxel-rcnn-car-sim.toml");
        let (ob, b) = (
            old_base.voxel_rcnn.clone().unwrap(),
            base.voxel_rcnn.clone().unwrap(),
        );
        assert_ne!(ob.network.roi, b.network.roi);
        let mut b_other = b.clone();
        b_other.network.roi = ob.network.roi.clone();
        assert_eq!(b_other, ob);
        assert_eq!(
            (&base.train, &base.dataset),
            (&old_base.train, &old_base.dataset)
        );
        for (old, new, tdis) in [
            (
                "dasanet-tdis-car-sim.toml",
                "dasanet-v2-tdis-car-sim.toml",
                true,
            ),
            (
                "dasanet-stca-car-sim.toml",
                "dasanet-v2-stca-car-sim.toml",
                false,
            ),
            ("dasanet-car-sim.toml", "dasanet-v2-car-sim.toml", true),
        ] {
            let (old, row) = (load(old), load(new));
            let v = row.voxel_rcnn.as_ref().unwrap();
            assert_eq!(v.network.roi, b.network.roi, "{new}");
            assert_eq!(v, old.voxel_rcnn.as_ref().unwrap(), "{new}");
            assert_eq!(
                (&row.train, &row.dataset),
                (&base.train, &base.dataset),
                "{new}"
            );
            let (d, od) = (row.dasanet.clone().unwrap(), old.dasanet.clone().unwrap());
            assert!(
                d.pseudo.same_voxels_as_test && !od.pseudo.same_voxels_as_test,
                "{new}"
            );
            assert_eq!(d.modules.tdis, tdis, "{new}");
            let form = if tdis {
                TdisForm::Gated
            } else {
                TdisForm::Plain
            };
            assert_eq!(d.modules.tdis_form, form, "{new}");
            let mut d_old = d.clone();
            d_old.pseudo.same_voxels_as_test = false;
            d_old.modules.tdis_form = TdisForm::Plain;
            assert_eq!(d_old, od, "{new}");
        }
        // The bypass measurement is the +TDIS row with only TDIS's form changed.
        let (row, bypass) = (
            load("dasanet-tdis-car-sim.toml"),
            load("dasanet-tdis-bypass-car-sim.toml"),
        );
        let mut d = bypass.dasanet.clone().unwrap();
        assert_eq!(d.modules.tdis_form, TdisForm::Bypass);
        d.modules.tdis_form = TdisForm::Plain;
        assert_eq!(Some(d), row.dasanet);
        assert_eq!(
            (bypass.voxel_rcnn, bypass.train),
            (row.voxel_rcnn, row.train)
        );
    }

    /// The third form of the +TDIS row pools from Voxel R-CNN's three levels, so its
    /// baseline is the first ablation's baseline row itself; otherwise it is the second form.
    #[test]
    fn the_third_form_tdis_row_reads_what_the_first_baseline_reads() {
        let (base, v2, v3) = (
            load("voxel-rcnn-local-aug-car-sim.toml"),
            load("dasanet-v2-tdis-car-sim.toml"),
            load("dasanet-v3-tdis-car-sim.toml"),
        );
        let b = base.voxel_rcnn.as_ref().unwrap();
        let (r2, r3) = (v2.voxel_rcnn.unwrap(), v3.voxel_rcnn.unwrap());
        assert_eq!(r3.network.roi, b.network.roi);
        assert_eq!(r3.network.roi.levels.len(), 3);
        assert_ne!(r3.network.roi, r2.network.roi);
        let mut r3_as_v2 = r3.clone();
        r3_as_v2.network.roi = r2.network.roi.clone();
        assert_eq!(r3_as_v2, r2);
        assert_eq!(
            (&v3.dasanet, &v3.train, &v3.dataset),
            (&v2.dasanet, &v2.train, &v2.dataset)
        );
        assert_eq!((&v3.train, &v3.dataset), (&base.train, &base.dataset));
    }

    /// The third form's +STCA and full rows are its +TDIS row with only the modules
    /// switched, and each is the second form's row of the same modules but for the levels:
    /// the four rows over `voxel-rcnn-local-aug-car-sim.toml` differ only in the modules.
    #[test]
    fn the_third_form_rows_differ_only_in_the_modules() {
        let tdis = load("dasanet-v3-tdis-car-sim.toml");
        for (new, v2, has_tdis, has_stca) in [
            (
                "dasanet-v3-stca-car-sim.toml",
                "dasanet-v2-stca-car-sim.toml",
                false,
                true,
            ),
            (
                "dasanet-v3-car-sim.toml",
                "dasanet-v2-car-sim.toml",
                true,
                true,
            ),
        ] {
            let (row, second) = (load(new), load(v2));
            let (d, m) = (
                row.dasanet.clone().unwrap(),
                &row.dasanet.as_ref().unwrap().modules,
            );
            assert_eq!((m.tdis, m.stca), (has_tdis, has_stca), "{new}");
            let mut as_tdis = d.clone();
            as_tdis.modules.tdis = true;
            as_tdis.modules.stca = false;
            as_tdis.modules.tdis_form = TdisForm::Gated;
            assert_eq!(Some(as_tdis), tdis.dasanet, "{new}");
            assert_eq!(
                (&row.voxel_rcnn, &row.train, &row.dataset),
                (&tdis.voxel_rcnn, &tdis.train, &tdis.dataset),
                "{new}"
            );
            assert_eq!(row.dasanet, second.dasanet, "{new}");
            let (r, r2) = (row.voxel_rcnn.unwrap(), second.voxel_rcnn.unwrap());
            let mut r_as_v2 = r.clone();
            r_as_v2.network.roi = r2.network.roi.clone();
            assert_eq!(r_as_v2, r2, "{new}");
        }
    }
}
