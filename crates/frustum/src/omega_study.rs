//! Choosing ω for depth-guided slicing (SAF gives no value).
//!
//! The near region [d_min, d_min + ω·L_depth] is one coarse sub-frustum: what falls
//! only there is barely seen by the network. Over the labelled frustums of a data set
//! this measures, for each candidate ω:
//!
//! - **object loss** (bad): the share of the object's own points (inside its
//!   ground-truth 3D box) that lie in the near region and in no other sub-frustum,
//!   i.e. at depth < d_min + a (the rest starts at d_min + a, ends included), averaged
//!   over frustums so that a far car with 30 points weighs as much as a near one;
//! - **clutter absorbed** (good): the share of the other points in front of the
//!   object (nearer than its nearest point: occluders, ground, clutter) that the near
//!   region takes, averaged over the frustums that have such points;
//! - the median length of a finest-scale sub-frustum behind the near region
//!   (2·(L_pc − a)/T: a longer near region leaves finer ones for the object).
//!
//! The rule for the default ω ([`OmegaStudy::recommended`]): the largest candidate
//! whose object loss stays below [`MAX_OBJECT_LOSS`] (1 %).
//!
//! The frustums are those [`FrustumDataset::from_labels`] makes, so the config's
//! `augment.box_jitter` and `copies` apply: jittered 2D boxes stand in for a 2D
//! detector's height errors, which move L_depth (ground-truth boxes alone would make
//! the loss look smaller than at test time).
//!
//! ```no_run
//! use fusiondet_frustum::{DEFAULT_OMEGAS, FrustumConfig, InMemoryFrames, omega_study_from_labels};
//! use fusiondet_kitti::FrameDir;
//!
//! let ids: Vec<String> = vec!["000000".into(), "000003".into()]; // e.g. ImageSets/train.txt
//! let frames = InMemoryFrames::load(&FrameDir::new("kitti/training"), &ids, true)?;
//! let study = omega_study_from_labels(frames, &FrustumConfig::saf_car(), 0, &DEFAULT_OMEGAS)?;
//! println!("{study}"); // the table and the recommended ω
//! let omega = study.recommended();
//! # Ok::<(), fusiondet_frustum::FrustumError>(())
//! ```

use crate::config::FrustumConfig;
use crate::dataset::{FrustumDataset, FrustumSpec};
use crate::error::{FrustumError, Result, SkipCounts, SkipReason};
use crate::frame::FrustumFrames;
use crate::frustum::extract_frustum;
use crate::slicing::{DepthGuidedSlicing, MAX_NEAR_FRACTION, SliceContext, SliceStrategy, Slicing};
use fusiondet_dataset::Class;
use fusiondet_geometry::points_in_box;
use fusiondet_kitti::Box2d;
use rayon::prelude::*;
use std::fmt;

/// The rule's threshold on object loss.
pub const MAX_OBJECT_LOSS: f64 = 0.01;

/// Candidate ω: 0 to 0.95 in steps of 0.05.
pub const DEFAULT_OMEGAS: [f64; 20] = [
    0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8,
    0.85, 0.9, 0.95,
];

/// What the study needs of one labelled frustum.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyFrustum {
    pub class: Class,
    /// The frustum's (clipped) 2D box.
    pub box2d: Box2d,
    /// Vertical focal length of P2 in pixels.
    pub focal_v: f64,
    pub depth_range: [f64; 2],
    /// Frustum depths of the points inside the ground-truth box (at least one).
    pub object_depths: Vec<f64>,
    /// Frustum depths of the other points nearer than the nearest object point.
    pub clutter_depths: Vec<f64>,
}

impl StudyFrustum {
    fn context(&self) -> SliceContext<'_> {
        SliceContext {
            depth_range: self.depth_range,
            class: self.class,
            box2d: &self.box2d,
            focal_v: self.focal_v,
        }
    }
}

/// The study's result for one ω.
#[derive(Debug, Clone, PartialEq)]
pub struct OmegaRow {
    pub omega: f64,
    /// Mean over frustums of the share of object points lost to the near region.
    pub object_loss: f64,
    /// Frustums that lose at least one object point.
    pub frustums_with_loss: usize,
    /// Mean over frustums with clutter in front of the object of the share of it
    /// that the near region absorbs (NaN when no frustum has any).
    pub clutter_absorbed: f64,
    /// Frustums whose ω·L_depth was cut to [`MAX_NEAR_FRACTION`] of the range.
    pub clamped: usize,
    /// Median over frustums of the finest-scale length 2·(L_pc − a)/T, metres.
    pub median_finest_length: f64,
}

/// The rows of a study and what they were measured on.
#[derive(Debug, Clone, PartialEq)]
pub struct OmegaStudy {
    /// Frustums measured.
    pub frustums: usize,
    /// Of those, frustums with other points in front of the object.
    pub with_clutter: usize,
    /// Labelled frustums left out because no point lies inside the ground truth
    /// (only when the config's `min_object_points` is 0).
    pub without_object_points: usize,
    /// What the data set skipped when it was made.
    pub dataset_skips: SkipCounts,
    pub rows: Vec<OmegaRow>,
}

impl OmegaStudy {
    /// The largest ω whose object loss is below [`MAX_OBJECT_LOSS`].
    pub fn recommended(&self) -> Option<f64> {
        self.recommended_below(MAX_OBJECT_LOSS)
    }

    /// The largest ω whose object loss is below `max_loss`.
    pub fn recommended_below(&self, max_loss: f64) -> Option<f64> {
        self.rows
            .iter()
            .filter(|r| r.object_loss < max_loss)
            .map(|r| r.omega)
            .max_by(f64::total_cmp)
    }
}

impl fmt::Display for OmegaStudy {
    /// A plain-text table, one row per ω, and the recommendation.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} frustums ({} with points in front of the object), {}",
            self.frustums, self.with_clutter, self.dataset_skips
        )?;
        writeln!(
            f,
            "{:>6}  {:>12}  {:>15}  {:>16}  {:>8}  {:>16}",
            "omega",
            "object lost",
            "frustums losing",
            "clutter absorbed",
            "clamped",
            "finest length m"
        )?;
        for r in &self.rows {
            writeln!(
                f,
                "{:>6.3}  {:>11.3}%  {:>15}  {:>15.1}%  {:>8}  {:>16.4}",
                r.omega,
                100.0 * r.object_loss,
                r.frustums_with_loss,
                100.0 * r.clutter_absorbed,
                r.clamped,
                r.median_finest_length
            )?;
        }
        match self.recommended() {
            Some(w) => write!(
                f,
                "recommended omega = {w} (largest with object loss < {}%)",
                100.0 * MAX_OBJECT_LOSS
            ),
            None => write!(
                f,
                "no candidate keeps the object loss below {}%",
                100.0 * MAX_OBJECT_LOSS
            ),
        }
    }
}

/// The config's depth-guided slicing, or an error saying the study needs one.
fn depth_guided(config: &FrustumConfig) -> Result<&DepthGuidedSlicing> {
    match &config.slicing {
        Slicing::DepthGuided(s) => Ok(s),
        _ => Err(FrustumError::Config(
            "the omega study needs `[frustum.slicing] kind = \"depth_guided\"`".into(),
        )),
    }
}

/// Runs the study over the frustums of a labelled data set (the data set's config
/// must use depth-guided slicing; its ω is replaced by each candidate in turn).
pub fn omega_study<S: FrustumFrames>(
    dataset: &FrustumDataset<S>,
    omegas: &[f64],
) -> Result<OmegaStudy> {
    let config = dataset.config();
    let slicing = depth_guided(config)?;
    for &omega in omegas {
        DepthGuidedSlicing {
            omega,
            ..slicing.clone()
        }
        .validate(config.depth_range)
        .map_err(|e| FrustumError::Config(format!("omega study candidate {omega}: {e}")))?;
    }
    if let Some(i) = dataset.specs().iter().position(|s| s.object.is_none()) {
        return Err(FrustumError::Config(format!(
            "the omega study needs labelled frustums (FrustumDataset::from_labels); frustum {i} is a detection"
        )));
    }
    // Specs come frame by frame: each group loads its frame once.
    let mut groups: Vec<(usize, &[FrustumSpec])> = Vec::new();
    let mut start = 0;
    for g in dataset.specs().chunk_by(|a, b| a.frame == b.frame) {
        groups.push((start, g));
        start += g.len();
    }
    let measured = groups
        .par_iter()
        .map(|&(start, group)| {
            let frame = dataset.source().frame(group[0].frame)?;
            group
                .iter()
                .enumerate()
                .map(|(i, spec)| {
                    let fp = extract_frustum(&frame, &spec.box2d, config.depth_range, 0.0)
                        .map_err(|reason| FrustumError::Stale {
                            frame: frame.id.clone(),
                            index: start + i,
                            reason,
                        })?;
                    let object =
                        spec.object
                            .and_then(|o| frame.objects.get(o))
                            .ok_or_else(|| FrustumError::Stale {
                                frame: frame.id.clone(),
                                index: start + i,
                                reason: SkipReason::NoObjectPoints,
                            })?;
                    let gt = fp.frame.box_to_frustum(&object.box3d);
                    let inside = points_in_box(&gt, &fp.points);
                    Ok(study_frustum(
                        spec.class,
                        fp.box2d,
                        frame.camera.fv(),
                        config.depth_range,
                        &fp.points,
                        &inside,
                    ))
                })
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<Vec<_>>>()?;
    let all: Vec<Option<StudyFrustum>> = measured.into_iter().flatten().collect();
    let without_object_points = all.iter().filter(|f| f.is_none()).count();
    let frustums: Vec<StudyFrustum> = all.into_iter().flatten().collect();
    if frustums.is_empty() {
        // Every share in the table would be 0/0.
        return Err(FrustumError::Config(format!(
            "no labelled frustum of the configured classes with points on its object in these \
             frames ({without_object_points} without object points): nothing to study; give \
             frames whose labels hold such objects"
        )));
    }
    Ok(OmegaStudy {
        frustums: frustums.len(),
        with_clutter: frustums
            .iter()
            .filter(|f| !f.clutter_depths.is_empty())
            .count(),
        without_object_points,
        dataset_skips: dataset.skips(),
        rows: study_rows(&frustums, slicing, omegas),
    })
}

/// [`omega_study`] over the frustums [`FrustumDataset::from_labels`] makes from
/// `frames` with `config` and `seed` (the seed draws the 2D box jitter).
pub fn omega_study_from_labels<S: FrustumFrames>(
    frames: S,
    config: &FrustumConfig,
    seed: u64,
    omegas: &[f64],
) -> Result<OmegaStudy> {
    depth_guided(config)?;
    omega_study(
        &FrustumDataset::from_labels(frames, config.clone(), seed)?,
        omegas,
    )
}

/// One frustum's object and clutter depths from its points (frustum frame) and
/// which of them lie inside the ground truth; `None` when none does.
pub fn study_frustum(
    class: Class,
    box2d: Box2d,
    focal_v: f64,
    depth_range: [f64; 2],
    points: &[[f64; 3]],
    inside: &[bool],
) -> Option<StudyFrustum> {
    let object_depths: Vec<f64> = points
        .iter()
        .zip(inside)
        .filter(|(_, i)| **i)
        .map(|(p, _)| p[2])
        .collect();
    let nearest = object_depths.iter().copied().min_by(f64::total_cmp)?;
    let clutter_depths = points
        .iter()
        .zip(inside)
        .filter(|(p, i)| !**i && p[2] < nearest)
        .map(|(p, _)| p[2])
        .collect();
    Some(StudyFrustum {
        class,
        box2d,
        focal_v,
        depth_range,
        object_depths,
        clutter_depths,
    })
}

/// The rows for `omegas` over measured frustums, with `slicing`'s T, mean heights
/// and clamp (its own ω is ignored).
pub fn study_rows(
    frustums: &[StudyFrustum],
    slicing: &DepthGuidedSlicing,
    omegas: &[f64],
) -> Vec<OmegaRow> {
    let share = |depths: &[f64], end: f64| {
        depths.iter().filter(|&&d| d < end).count() as f64 / depths.len() as f64
    };
    omegas
        .iter()
        .map(|&omega| {
            let s = DepthGuidedSlicing {
                omega,
                ..slicing.clone()
            };
            let (mut loss, mut with_loss, mut absorbed, mut clamped) = (0.0, 0, 0.0, 0);
            let mut with_clutter = 0;
            let mut lengths = Vec::with_capacity(frustums.len());
            for f in frustums {
                let ctx = f.context();
                let near = s.near_length(&ctx);
                let [lo, hi] = f.depth_range;
                let end = lo + near;
                let lost = share(&f.object_depths, end);
                loss += lost;
                with_loss += (lost > 0.0) as usize;
                if !f.clutter_depths.is_empty() {
                    absorbed += share(&f.clutter_depths, end);
                    with_clutter += 1;
                }
                clamped += (omega * s.coarse_depth(&ctx) > MAX_NEAR_FRACTION * (hi - lo)) as usize;
                lengths.push(2.0 * (hi - lo - near) / s.slices as f64);
            }
            OmegaRow {
                omega,
                object_loss: loss / frustums.len() as f64,
                frustums_with_loss: with_loss,
                clutter_absorbed: absorbed / with_clutter as f64,
                clamped,
                median_finest_length: median(&mut lengths),
            }
        })
        .collect()
}

/// The median (mean of the middle two for an even count); NaN when empty.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::AugmentConfig;
    use crate::frame::{InMemoryFrames, ProjectedCloud, ProjectedFrame};
    use crate::frustum::FrustumFrame;
    use crate::test_data::sample_camera;
    use fusiondet_kitti::{Box3d, Object, ObjectClass};

    /// One car whose 2D box makes L_depth exactly 20 m, 100 points on it at depths
    /// 19.355 + 0.01·k, 10 clutter points at 3–4 m, 50 occluder points at
    /// 8 + 0.03·k m (8–9.47) and 30 background points behind it.
    fn synthetic_frame() -> ProjectedFrame {
        let camera = sample_camera();
        let f = camera.fv();
        let h0 = f * 1.56 / 20.0;
        let bbox = Box2d {
            x1: 470.0,
            y1: 190.0 - 0.5 * h0,
            x2: 770.0,
            y2: 190.0 + 0.5 * h0,
        };
        let ff = FrustumFrame::for_box(&camera, &bbox);
        let ray_y = |z: f64| ff.ray_point(z)[1];
        let in_frustum = Box3d {
            h: 1.56,
            w: 1.6,
            l: 3.9,
            x: 0.0,
            y: ray_y(20.0) + 0.78,
            z: 20.0,
            ry: 0.0,
        };
        let mut q: Vec<[f64; 3]> = Vec::new();
        q.extend((0..100).map(|k| {
            let z = 19.355 + 0.01 * k as f64;
            [0.3 * (k as f64).sin(), ray_y(z) + 0.1 * (k as f64).cos(), z]
        }));
        q.extend((0..10).map(|k| {
            let z = 3.0 + 0.1 * k as f64;
            [0.05, ray_y(z) + 0.05, z]
        }));
        q.extend((0..50).map(|k| {
            let z = 8.0 + 0.03 * k as f64;
            [0.2, ray_y(z), z]
        }));
        q.extend((0..30).map(|k| {
            let z = 35.0 + 0.1 * k as f64;
            [-0.5, ray_y(z), z]
        }));
        let rect: Vec<[f64; 3]> = q.iter().map(|&p| ff.to_rect(p)).collect();
        let uv = rect
            .iter()
            .map(|&r| {
                let (u, v, _) = camera.rect_to_image(r);
                [u, v]
            })
            .collect();
        ProjectedFrame {
            id: "synthetic".into(),
            camera,
            image_size: [1242.0, 375.0],
            cloud: ProjectedCloud { rect, uv },
            classes: vec![ObjectClass::Car.into()],
            objects: vec![Object {
                class: ObjectClass::Car,
                truncation: 0.0,
                occlusion: 0,
                alpha: 0.0,
                bbox,
                box3d: ff.box_to_rect(&in_frustum),
                score: None,
            }],
        }
    }

    fn config() -> FrustumConfig {
        FrustumConfig {
            augment: AugmentConfig::none(),
            ..FrustumConfig::saf_car()
        }
    }

    #[test]
    fn synthetic_case_has_the_known_answer() {
        let frames = InMemoryFrames::new(vec![synthetic_frame()]);
        let omegas = [0.1, 0.3, 0.45, 0.5, 0.9, 0.97];
        let study = omega_study_from_labels(frames, &config(), 0, &omegas).unwrap();
        assert_eq!((study.frustums, study.with_clutter), (1, 1));
        // Near region ends at 20·ω: 2, 6, 9, 10, 18, 19.4 m.
        let loss: Vec<f64> = study.rows.iter().map(|r| r.object_loss).collect();
        assert_eq!(loss, [0.0, 0.0, 0.0, 0.0, 0.0, 0.05]);
        let absorbed: Vec<f64> = study.rows.iter().map(|r| r.clutter_absorbed).collect();
        // 10 of 60 below 6 m; 10 + 34 (8 + 0.03·k < 9 for k ≤ 33) below 9 m.
        let expect = [0.0, 10.0 / 60.0, 44.0 / 60.0, 1.0, 1.0, 1.0];
        for (a, e) in absorbed.iter().zip(expect) {
            assert!((a - e).abs() < 1e-12, "{absorbed:?}");
        }
        let losing: Vec<usize> = study.rows.iter().map(|r| r.frustums_with_loss).collect();
        assert_eq!(losing, [0, 0, 0, 0, 0, 1]);
        for r in &study.rows {
            let finest = 2.0 * (75.0 - 20.0 * r.omega) / 240.0;
            assert!((r.median_finest_length - finest).abs() < 1e-9, "{r:?}");
            assert_eq!(r.clamped, 0);
        }
        assert_eq!(study.recommended(), Some(0.9));
        assert_eq!(study.recommended_below(0.1), Some(0.97));
        assert_eq!(study.recommended_below(0.0), None);
        let table = study.to_string();
        assert!(table.contains("recommended omega = 0.9"), "{table}");
        assert!(table.contains(" 5.000%"), "{table}");
    }

    #[test]
    fn loss_is_what_only_the_near_sub_frustum_holds_in_the_layout() {
        let frame = synthetic_frame();
        let c = config();
        let fp = extract_frustum(&frame, &frame.objects[0].bbox, c.depth_range, 0.0).unwrap();
        let gt = fp.frame.box_to_frustum(&frame.objects[0].box3d);
        let inside = points_in_box(&gt, &fp.points);
        let sf = study_frustum(
            ObjectClass::Car.into(),
            fp.box2d,
            frame.camera.fv(),
            c.depth_range,
            &fp.points,
            &inside,
        )
        .unwrap();
        assert_eq!((sf.object_depths.len(), sf.clutter_depths.len()), (100, 60));
        let Slicing::DepthGuided(base) = &c.slicing else {
            unreachable!()
        };
        for omega in [0.3, 0.7, 0.97] {
            let s = DepthGuidedSlicing {
                omega,
                ..base.clone()
            };
            let row = &study_rows(std::slice::from_ref(&sf), &s, &[omega])[0];
            for layout in s.layout(&sf.context()) {
                let near_only = |d: &f64| {
                    layout.slices[0].contains(*d)
                        && !layout.slices[1..].iter().any(|iv| iv.contains(*d))
                };
                let n = sf.object_depths.iter().filter(|d| near_only(d)).count();
                assert_eq!(n as f64 / 100.0, row.object_loss, "omega {omega}");
                let n = sf.clutter_depths.iter().filter(|d| near_only(d)).count();
                assert_eq!(n as f64 / 60.0, row.clutter_absorbed, "omega {omega}");
            }
        }
    }

    #[test]
    fn study_refuses_what_it_cannot_measure() {
        let frames = || InMemoryFrames::new(vec![synthetic_frame()]);
        let e = omega_study_from_labels(frames(), &FrustumConfig::car(), 0, &[0.5])
            .unwrap_err()
            .to_string();
        assert!(e.contains("kind = \"depth_guided\""), "{e}");
        let e = omega_study_from_labels(frames(), &config(), 0, &[0.5, 1.2])
            .unwrap_err()
            .to_string();
        assert!(e.contains("candidate 1.2") && e.contains("[0, 1)"), "{e}");
        let det = fusiondet_kitti::Detection2d {
            frame_id: "synthetic".into(),
            class: ObjectClass::Car,
            score: 0.9,
            bbox: synthetic_frame().objects[0].bbox,
        };
        let d = FrustumDataset::from_detections(frames(), &[det], config()).unwrap();
        let e = omega_study(&d, &[0.5]).unwrap_err().to_string();
        assert!(e.contains("labelled frustums"), "{e}");
        let mut empty = synthetic_frame();
        empty.objects.clear();
        let e = omega_study_from_labels(InMemoryFrames::new(vec![empty]), &config(), 0, &[0.5])
            .unwrap_err()
            .to_string();
        assert!(e.contains("nothing to study"), "{e}");
    }

    /// The study that chose [`crate::DEFAULT_OMEGA`].
    #[test]
    fn bundled_frames_pick_the_default_omega() {
        let dir = crate::test_data::sample_dir();
        let ids: Vec<String> = [
            "000000", "000001", "000002", "000003", "000004", "000005", "000134",
        ]
        .map(String::from)
        .to_vec();
        let frames = InMemoryFrames::load(&dir, &ids, true).unwrap();
        let mut config = FrustumConfig::saf_car();
        config.augment.copies = 40;
        let study = omega_study_from_labels(frames, &config, 0, &DEFAULT_OMEGAS).unwrap();
        assert_eq!(study.frustums, 240, "{study}");
        assert_eq!(study.recommended(), Some(crate::DEFAULT_OMEGA), "{study}");
        // Loss grows with ω; absorption too.
        for w in study.rows.windows(2) {
            assert!(w[0].object_loss <= w[1].object_loss, "{study}");
            assert!(w[0].clutter_absorbed <= w[1].clutter_absorbed, "{study}");
            assert!(w[0].median_finest_length >= w[1].median_finest_length);
        }
    }

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&mut []).is_nan());
    }
}
