//! A simulated 2D detector producing F-PointNet-style `rgb_detection_*.txt` lines.
//!
//! Modelled on F-PointNet's published detections (studied against KITTI labels):
//! ~7–8 detections per image above its 0.01 score cut, ~4 of them above 0.5; clear
//! objects get scores of 0.95–0.999 and boxes within IoU 0.85–0.95; occluded or
//! truncated ones get low scores (0.02–0.1) and looser boxes; far cars in DontCare
//! regions are sometimes detected; false positives are mostly low-scoring, some on
//! clutter (poles and trunks as pedestrians, parked bikes as cyclists, bushes as
//! cars); the detector's training split gets better scores than the validation split.
//!
//! Each object gets a latent quality `L = base(class) + 2·ln(h/40) − 4·hidden −
//! 3·max(0, trunc − 0.1) + split bonus + N(0, 2²)`; its score is `sigmoid(L)` and it
//! is reported when the score is at least 0.01 (F-PointNet's cut); 2% of cars and 7%
//! of people are missed whatever their quality. Box jitter shrinks as the score grows, occluded
//! objects are boxed towards their visible part, 8% of detections get a low-scoring
//! duplicate, and false positives (Poisson per class, mostly scored 0.01–0.2) sit on
//! look-alike clutter or on the ground plane with the class's size.

use crate::label::ActorView;
use crate::math::{exp, ln};
use crate::rng::Sampler;
use crate::scene::{ClutterKind, Scene};
use fusiondet_geometry::{CameraModel, clip_to_image, project_to_image};
use fusiondet_kitti::{Box2d, Box3d, Detection2d, ObjectClass};

/// Which split the detections are for (the detector was trained on `Train`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Split {
    Train,
    Val,
}

/// Parameters of the simulated detector.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorSpec {
    /// Base latent quality per class (car, pedestrian, cyclist) of a clear object
    /// 40 px high.
    pub base: [f64; 3],
    pub height_gain: f64,
    pub hidden_penalty: f64,
    pub truncation_penalty: f64,
    pub noise: f64,
    pub train_bonus: f64,
    /// Probability per class that an object is missed outright, whatever its quality.
    pub flat_miss: [f64; 3],
    /// Probability of a second, low-scoring box on the same object.
    pub duplicate: f64,
    /// Mean false positives per image and class (car, pedestrian, cyclist) on the
    /// validation split; the training split gets 70% of them.
    pub false_positives: [f64; 3],
    pub min_score: f64,
}

impl Default for DetectorSpec {
    fn default() -> Self {
        DetectorSpec {
            base: [6.4, 3.3, 3.1],
            height_gain: 2.0,
            hidden_penalty: 4.0,
            truncation_penalty: 3.0,
            noise: 2.0,
            train_bonus: 0.8,
            flat_miss: [0.02, 0.07, 0.07],
            duplicate: 0.08,
            false_positives: [2.5, 1.5, 1.2],
            min_score: 0.01,
        }
    }
}

pub(crate) fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + exp(-x))
}

fn class_index(c: ObjectClass) -> usize {
    match c {
        ObjectClass::Car => 0,
        ObjectClass::Pedestrian => 1,
        _ => 2,
    }
}

/// Jitters a box (relative deviation `sigma` of its size per side), rounds to whole
/// pixels as F-PointNet's files do, and clips it to the image.
pub(crate) fn jitter(s: &mut Sampler, b: &Box2d, sigma: f64, w: f64, h: f64) -> Option<Box2d> {
    let (bw, bh) = (b.x2 - b.x1, b.y2 - b.y1);
    let j = Box2d {
        x1: (b.x1 + sigma * bw * s.normal()).round(),
        y1: (b.y1 + sigma * bh * s.normal()).round(),
        x2: (b.x2 + sigma * bw * s.normal()).round(),
        y2: (b.y2 + sigma * bh * s.normal()).round(),
    };
    let c = clip_to_image(&j, w, h)?;
    (c.x2 - c.x1 >= 3.0 && c.y2 - c.y1 >= 3.0).then_some(c)
}

/// Detections of one frame.
#[allow(clippy::too_many_arguments)]
pub fn detect(
    spec: &DetectorSpec,
    s: &mut Sampler,
    frame_id: &str,
    views: &[ActorView],
    scene: &Scene,
    cam: &CameraModel,
    size: (f64, f64),
    split: Split,
) -> Vec<Detection2d> {
    let (w, h) = size;
    let bonus = if split == Split::Train {
        spec.train_bonus
    } else {
        0.0
    };
    let mut out = Vec::new();
    let mut push = |class, score: f64, bbox| {
        out.push(Detection2d {
            frame_id: frame_id.to_string(),
            class,
            score: (score * 1e6).round() / 1e6,
            bbox,
        })
    };
    for v in views {
        let Some(label) = &v.label else {
            continue;
        };
        // What the detector would call it (vans often pass as cars, trucks rarely).
        let (class, penalty) = match v.class {
            ObjectClass::Car => (ObjectClass::Car, 0.0),
            ObjectClass::Van if s.chance(0.55) => (ObjectClass::Car, 1.5),
            ObjectClass::Truck if s.chance(0.15) => (ObjectClass::Car, 2.5),
            ObjectClass::Pedestrian | ObjectClass::PersonSitting => (ObjectClass::Pedestrian, 0.0),
            ObjectClass::Cyclist => (ObjectClass::Cyclist, 0.0),
            _ => continue,
        };
        let class = match class {
            ObjectClass::Pedestrian if s.chance(0.03) => ObjectClass::Cyclist,
            ObjectClass::Cyclist if s.chance(0.08) => ObjectClass::Pedestrian,
            c => c,
        };
        if s.chance(spec.flat_miss[class_index(class)]) {
            continue;
        }
        let full = label.bbox;
        let height = (full.y2 - full.y1).max(1.0);
        let latent = spec.base[class_index(class)] + spec.height_gain * ln(height / 40.0)
            - spec.hidden_penalty * v.hidden
            - spec.truncation_penalty * (v.truncation - 0.1).max(0.0)
            - penalty
            + bonus
            + spec.noise * s.normal();
        let score = sigmoid(latent);
        if score < spec.min_score {
            continue;
        }
        // Occluded objects are boxed towards their visible part.
        let target = match v.visible_bbox {
            Some(vis) if v.hidden > 0.5 => {
                let k = 0.3 * v.hidden;
                Box2d {
                    x1: full.x1 + k * (vis.x1 - full.x1),
                    y1: full.y1 + k * (vis.y1 - full.y1),
                    x2: full.x2 + k * (vis.x2 - full.x2),
                    y2: full.y2 + k * (vis.y2 - full.y2),
                }
            }
            _ => full,
        };
        // Thin people are harder to box than cars.
        let thin = if class == ObjectClass::Car { 1.0 } else { 1.3 };
        let sigma = thin * (0.025 + 0.08 * (1.0 - score) + 0.02 * v.hidden);
        if let Some(b) = jitter(s, &target, sigma, w, h) {
            push(class, score, b);
            if s.chance(spec.duplicate) {
                let dup_score = score * s.range(0.01, 0.15);
                if dup_score >= spec.min_score
                    && let Some(d) = jitter(s, &target, 0.15, w, h)
                {
                    push(class, dup_score, d);
                }
            }
        }
    }
    // False positives, per class: on clutter that looks the part, or anywhere on
    // the ground plane with the class's size.
    let scale = if split == Split::Train { 0.7 } else { 1.0 };
    let mut fps = Vec::new();
    for (k, class) in [
        ObjectClass::Car,
        ObjectClass::Pedestrian,
        ObjectClass::Cyclist,
    ]
    .into_iter()
    .enumerate()
    {
        for _ in 0..s.poisson(spec.false_positives[k] * scale) {
            fps.push(class);
        }
    }
    for class in fps {
        let looks_like = |kind: ClutterKind| match class {
            ObjectClass::Car => kind == ClutterKind::Blob,
            ObjectClass::Pedestrian => kind == ClutterKind::Upright,
            _ => kind != ClutterKind::Blob,
        };
        // Clutter in view, 4–60 m ahead.
        let candidates: Vec<&crate::scene::Clutter> = scene
            .clutter
            .iter()
            .filter(|c| looks_like(c.kind))
            .filter(|c| {
                let (u, _, depth) = cam.velo_to_image(c.bottom_center.to_array());
                (4.0..60.0).contains(&depth) && (0.0..w).contains(&u)
            })
            .collect();
        let b3 = if s.chance(0.6) && !candidates.is_empty() {
            let c = **s.pick(&candidates);
            let h3 = match class {
                ObjectClass::Pedestrian => c.h.min(1.9),
                _ => c.h,
            };
            (c.bottom_center, c.w, h3)
        } else {
            let x = s.range(6.0, 70.0);
            let y = s.range(-0.7, 0.7) * x;
            let (l, w3, h3) = crate::parts::sample_dims(class, s);
            (crate::math::v3(x, y, -1.73), w3.max(l * 0.6), h3)
        };
        let (base, width, height) = b3;
        let loc = cam.velo_to_rect(base.to_array());
        if loc[2] < 3.0 {
            continue;
        }
        let bx = Box3d {
            h: height,
            w: width,
            l: width,
            x: loc[0],
            y: loc[1],
            z: loc[2],
            ry: 0.0,
        };
        let Some(b) = project_to_image(&bx, cam, w, h) else {
            continue;
        };
        let score = sigmoid(-2.7 + 1.4 * s.normal());
        if score < spec.min_score {
            continue;
        }
        if let Some(j) = jitter(s, &b, 0.1, w, h) {
            push(class, score, j);
        }
    }
    out.sort_by(|a, b| b.score.total_cmp(&a.score));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigmoid_and_jitter_behave() {
        assert!((sigmoid(0.0) - 0.5).abs() < 1e-12);
        let mut s = Sampler::new(1);
        let b = Box2d {
            x1: 100.0,
            y1: 150.0,
            x2: 200.0,
            y2: 220.0,
        };
        let j = jitter(&mut s, &b, 0.0, 1242.0, 375.0).unwrap();
        assert_eq!(j, b);
        let mut ious = Vec::new();
        for _ in 0..200 {
            let j = jitter(&mut s, &b, 0.03, 1242.0, 375.0).unwrap();
            assert_eq!(j.x1, j.x1.round());
            ious.push(fusiondet_geometry::iou_2d(&b, &j));
        }
        ious.sort_by(f64::total_cmp);
        let median = ious[100];
        assert!(median > 0.85 && median < 0.97, "{median}");
    }
}
