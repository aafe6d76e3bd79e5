//! The simulated 2D detector of indoor scenes, written to `det_2d/<id>.txt`: the KITTI
//! simulator's model ([`crate::detector`]) carried over to the ten classes. Each labelled
//! piece gets a latent quality `L = base(class) + 1.5·ln(h/100 px) − 3.5·hidden −
//! 2.5·max(0, truncation − 0.1) + split bonus + N(0, 1.5²)`; its score is `sigmoid(L)` and it
//! is reported at 0.05 or more; 5% are missed whatever their quality. Similar classes are
//! confused (table ↔ desk, dresser ↔ night stand, sofa ↔ chair, bookshelf → dresser), box
//! jitter shrinks as the score grows (the KITTI detector's `jitter`), 8% get a low-scoring
//! duplicate, and false positives (Poisson, 1.5 a scene on the validation split, 70% of that
//! on the training split, scores mostly 0.05–0.2) sit on look-alike clutter (cabinets as
//! dressers, cardboard boxes as night stands) or anywhere in the image. Classes with flat,
//! distinctive shapes (beds, toilets, bathtubs) score highest, as in the detectors'
//! published per-class APs.

use super::clutter::Lookalike;
use super::labels::{ObjectView, clip, projected_bounds};
use crate::detector::{Split, jitter, sigmoid};
use crate::math::ln;
use crate::rng::Sampler;
use fusiondet_geometry::Box2d;
use fusiondet_sunrgbd::{Calib, Detection2d, SunClass, UprightBox};

/// Parameters of the simulated detector.
#[derive(Debug, Clone, PartialEq)]
pub struct Detector2dSpec {
    /// Base latent quality per class ([`SunClass::ALL`] order) of a clear piece 100 px high.
    pub base: [f64; 10],
    pub height_gain: f64,
    pub hidden_penalty: f64,
    pub truncation_penalty: f64,
    pub noise: f64,
    pub train_bonus: f64,
    pub flat_miss: f64,
    pub duplicate: f64,
    /// Mean false positives per scene (validation split).
    pub false_positives: f64,
    pub min_score: f64,
}

impl Default for Detector2dSpec {
    fn default() -> Self {
        Detector2dSpec {
            base: [4.5, 2.0, 3.0, 2.6, 4.5, 1.8, 2.2, 2.0, 2.4, 3.5],
            height_gain: 1.5,
            hidden_penalty: 3.5,
            truncation_penalty: 2.5,
            noise: 1.5,
            train_bonus: 0.7,
            flat_miss: 0.05,
            duplicate: 0.08,
            false_positives: 1.5,
            min_score: 0.05,
        }
    }
}

/// What the detector may call a piece of `class` instead, and how often.
fn confusion(class: SunClass) -> Option<(SunClass, f64)> {
    Some(match class {
        SunClass::Table => (SunClass::Desk, 0.12),
        SunClass::Desk => (SunClass::Table, 0.15),
        SunClass::Dresser => (SunClass::NightStand, 0.08),
        SunClass::NightStand => (SunClass::Dresser, 0.08),
        SunClass::Sofa => (SunClass::Chair, 0.03),
        SunClass::Chair => (SunClass::Sofa, 0.02),
        SunClass::Bookshelf => (SunClass::Dresser, 0.04),
        _ => return None,
    })
}

/// The detections of one scene, best first. `lookalikes` are in the upright frame.
pub fn detect(
    spec: &Detector2dSpec,
    s: &mut Sampler,
    views: &[ObjectView],
    lookalikes: &[Lookalike],
    calib: &Calib,
    size: (u32, u32),
    split: Split,
) -> Vec<Detection2d> {
    let (w, h) = (size.0 as f64 + 1.0, size.1 as f64 + 1.0);
    let bonus = if split == Split::Train {
        spec.train_bonus
    } else {
        0.0
    };
    let mut out = Vec::new();
    let mut push = |class: SunClass, score: f64, bbox: Box2d| {
        out.push(Detection2d {
            class: class.as_str().to_string(),
            bbox,
            score: (score * 1e6).round() / 1e6,
        })
    };
    for v in views.iter().filter(|v| v.labelled) {
        let Some(full) = v.bbox else {
            continue;
        };
        let (class, penalty) = match confusion(v.class) {
            Some((other, p)) if s.chance(p) => (other, 1.0),
            _ => (v.class, 0.0),
        };
        if s.chance(spec.flat_miss) {
            continue;
        }
        let height = (full.y2 - full.y1).max(1.0);
        let latent = spec.base[v.class.index()] + spec.height_gain * ln(height / 100.0)
            - spec.hidden_penalty * v.hidden()
            - spec.truncation_penalty * (v.truncation() - 0.1).max(0.0)
            - penalty
            + bonus
            + spec.noise * s.normal();
        let score = sigmoid(latent);
        if score < spec.min_score {
            continue;
        }
        let sigma = 0.03 + 0.08 * (1.0 - score) + 0.03 * v.hidden();
        if let Some(b) = jitter(s, &full, sigma, w, h) {
            push(class, score, b);
            if s.chance(spec.duplicate) {
                let dup = score * s.range(0.05, 0.3);
                if dup >= spec.min_score
                    && let Some(d) = jitter(s, &full, 0.15, w, h)
                {
                    push(class, dup, d);
                }
            }
        }
    }
    let scale = if split == Split::Train { 0.7 } else { 1.0 };
    // Look-alikes in view, by their projected boxes.
    let in_view: Vec<(SunClass, Box2d)> = lookalikes
        .iter()
        .filter_map(|l| {
            let f = l.pose.rot.cols[0];
            let b = UprightBox {
                centre: l
                    .pose
                    .point(crate::math::v3(0.0, 0.0, l.size[2] / 2.0))
                    .to_array(),
                size: l.size,
                yaw: crate::math::atan2(f.y, f.x),
            };
            let p = projected_bounds(calib, &b)?;
            Some((l.resembles, clip(&p, size.0, size.1)?))
        })
        .collect();
    for _ in 0..s.poisson(spec.false_positives * scale) {
        let (class, b) = if !in_view.is_empty() && s.chance(0.6) {
            *s.pick(&in_view)
        } else {
            let class = SunClass::ALL[s.below(10)];
            let (bw, bh) = (s.range(40.0, 260.0), s.range(40.0, 240.0));
            let (x, y) = (s.range(1.0, w - bw), s.range(1.0, h - bh));
            (
                class,
                Box2d {
                    x1: x,
                    y1: y,
                    x2: x + bw,
                    y2: y + bh,
                },
            )
        };
        let score = sigmoid(-2.6 + 1.3 * s.normal());
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
