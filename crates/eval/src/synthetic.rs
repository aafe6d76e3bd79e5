//! A deterministic synthetic KITTI-like evaluation set (ground truth with neighbours,
//! other classes and DontCare regions; noisy detections with misses and false
//! positives), for benchmarks and tests. Same seed, same data, on every platform.

use crate::frames::{FrameDet, FrameGt};
use fusiondet_geometry::{alpha_from_ry, corners};
use fusiondet_kitti::{Box2d, Box3d, Object, ObjectClass};
use std::f64::consts::PI;

/// SplitMix64: tiny, seedable and platform independent.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// Roughly normal (sum of uniforms), mean 0, standard deviation `sigma`.
    fn normal(&mut self, sigma: f64) -> f64 {
        let s: f64 = (0..4).map(|_| self.unit()).sum::<f64>() - 2.0;
        s * sigma * 3f64.sqrt()
    }
}

/// KITTI's DontCare 3D fields: sizes −1 at −1000 m.
const DONTCARE_3D: Box3d = Box3d {
    h: -1.0,
    w: -1.0,
    l: -1.0,
    x: -1000.0,
    y: -1000.0,
    z: -1000.0,
    ry: -10.0,
};

const IMAGE_W: f64 = 1242.0;
const IMAGE_H: f64 = 375.0;
const FOCAL: f64 = 721.5377;
const CU: f64 = 609.5593;
const CV: f64 = 172.854;

/// Image box of a 3D box through a plain pinhole camera, clipped to the image; `None`
/// if it is behind the camera or outside the image.
fn image_box(b: &Box3d) -> Option<(Box2d, f64)> {
    let c = corners(b);
    if c.iter().any(|p| p[2] < 0.5) {
        return None;
    }
    let (mut x1, mut y1, mut x2, mut y2) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in c {
        let u = FOCAL * p[0] / p[2] + CU;
        let v = FOCAL * p[1] / p[2] + CV;
        x1 = x1.min(u);
        x2 = x2.max(u);
        y1 = y1.min(v);
        y2 = y2.max(v);
    }
    let full = (x2 - x1) * (y2 - y1);
    let clipped = Box2d {
        x1: x1.max(0.0),
        y1: y1.max(0.0),
        x2: x2.min(IMAGE_W - 1.0),
        y2: y2.min(IMAGE_H - 1.0),
    };
    if clipped.x2 <= clipped.x1 || clipped.y2 <= clipped.y1 {
        return None;
    }
    let truncation = 1.0 - clipped.width() * clipped.height() / full;
    Some((clipped, truncation))
}

fn dims(class: ObjectClass, rng: &mut Rng) -> (f64, f64, f64) {
    let (h, w, l) = match class {
        ObjectClass::Car => (1.53, 1.63, 3.88),
        ObjectClass::Van => (2.2, 1.9, 5.1),
        ObjectClass::Truck => (3.2, 2.6, 10.0),
        ObjectClass::Pedestrian => (1.76, 0.66, 0.84),
        ObjectClass::PersonSitting => (1.27, 0.59, 0.80),
        ObjectClass::Cyclist => (1.74, 0.60, 1.76),
        ObjectClass::Tram => (3.5, 2.6, 16.0),
        _ => (1.9, 1.1, 3.0),
    };
    let f = |v: f64, rng: &mut Rng| v * (1.0 + rng.normal(0.08));
    (f(h, rng), f(w, rng), f(l, rng))
}

fn pick_class(rng: &mut Rng) -> ObjectClass {
    let r = rng.unit();
    let table = [
        (0.50, ObjectClass::Car),
        (0.58, ObjectClass::Van),
        (0.76, ObjectClass::Pedestrian),
        (0.79, ObjectClass::PersonSitting),
        (0.88, ObjectClass::Cyclist),
        (0.92, ObjectClass::Truck),
        (0.96, ObjectClass::Misc),
        (1.01, ObjectClass::Tram),
    ];
    table
        .iter()
        .find(|(p, _)| r < *p)
        .map_or(ObjectClass::Car, |t| t.1)
}

fn object(
    class: ObjectClass,
    b: Box3d,
    bbox: Box2d,
    truncation: f64,
    occlusion: i32,
    score: Option<f64>,
) -> Object {
    Object {
        class,
        truncation,
        occlusion,
        alpha: alpha_from_ry(b.ry, b.x, b.z),
        bbox,
        box3d: b,
        score,
    }
}

/// Generates `n_frames` frames (ids `000000`, ...). Per frame about 10 labelled objects
/// (plus DontCare regions) and about 10 detections.
pub fn generate(n_frames: usize, seed: u64) -> (Vec<FrameGt>, Vec<FrameDet>) {
    let mut rng = Rng(seed);
    let mut gts = Vec::with_capacity(n_frames);
    let mut dets = Vec::with_capacity(n_frames);
    for f in 0..n_frames {
        let id = format!("{f:06}");
        let mut gt = Vec::new();
        let mut det = Vec::new();
        let n_obj = 6 + (rng.next_u64() % 9) as usize;
        while gt.len() < n_obj {
            let class = pick_class(&mut rng);
            let (h, w, l) = dims(class, &mut rng);
            let z = rng.range(4.0, 70.0);
            let b = Box3d {
                h,
                w,
                l,
                x: rng.range(-0.75, 0.75) * z,
                y: 1.65 + rng.normal(0.1),
                z,
                ry: rng.range(-PI, PI),
            };
            let Some((bbox, truncation)) = image_box(&b) else {
                continue;
            };
            let occlusion = (rng.unit() * rng.unit() * 4.0) as i32;
            gt.push(object(
                class,
                b,
                bbox,
                (truncation * 100.0).round() / 100.0,
                occlusion,
                None,
            ));
        }
        for _ in 0..(rng.next_u64() % 4) {
            let x1 = rng.range(0.0, IMAGE_W - 80.0);
            let y1 = rng.range(120.0, 220.0);
            let bbox = Box2d {
                x1,
                y1,
                x2: x1 + rng.range(10.0, 80.0),
                y2: y1 + rng.range(8.0, 40.0),
            };
            gt.push(Object {
                class: ObjectClass::DontCare,
                truncation: -1.0,
                occlusion: -1,
                alpha: -10.0,
                bbox,
                box3d: DONTCARE_3D,
                score: None,
            });
        }
        // Detections: most labelled objects, perturbed; better-localised ones score higher.
        for o in &gt {
            if o.class == ObjectClass::DontCare || rng.unit() < 0.15 {
                continue;
            }
            let noise = rng.unit();
            let s = 0.05 + 0.3 * noise;
            let mut b = o.box3d;
            b.x += rng.normal(s * b.l.max(1.0) * 0.3);
            b.z += rng.normal(s * b.l.max(1.0) * 0.3);
            b.y += rng.normal(0.1);
            b.h *= 1.0 + rng.normal(0.05);
            b.w *= 1.0 + rng.normal(0.05);
            b.l *= 1.0 + rng.normal(0.05);
            b.ry += if rng.unit() < 0.1 {
                PI
            } else {
                rng.normal(0.1)
            };
            let Some((bbox, _)) = image_box(&b) else {
                continue;
            };
            let class = if rng.unit() < 0.05 {
                pick_class(&mut rng)
            } else {
                o.class
            };
            let score = (1.0 - noise) * 0.8 + rng.unit() * 0.2;
            det.push(object(
                class,
                b,
                bbox,
                -1.0,
                -1,
                Some((score * 1e4).round() / 1e4),
            ));
        }
        // False positives.
        for _ in 0..(rng.next_u64() % 4) {
            let class = pick_class(&mut rng);
            let (h, w, l) = dims(class, &mut rng);
            let z = rng.range(5.0, 60.0);
            let b = Box3d {
                h,
                w,
                l,
                x: rng.range(-0.7, 0.7) * z,
                y: 1.65,
                z,
                ry: rng.range(-PI, PI),
            };
            if let Some((bbox, _)) = image_box(&b) {
                let score = (rng.unit() * 0.6 * 1e4).round() / 1e4;
                det.push(object(class, b, bbox, -1.0, -1, Some(score)));
                // Detectors fire on unlabelled objects, which KITTI marks DontCare: a
                // region around (or partly over) some false positives.
                if rng.unit() < 0.4 {
                    let grow = rng.range(-0.3, 0.3);
                    let (w, h) = (bbox.width(), bbox.height());
                    gt.push(Object {
                        class: ObjectClass::DontCare,
                        truncation: -1.0,
                        occlusion: -1,
                        alpha: -10.0,
                        bbox: Box2d {
                            x1: bbox.x1 - grow * w,
                            y1: bbox.y1 - 0.1 * h,
                            x2: bbox.x2 + 0.1 * w,
                            y2: bbox.y2 + 0.1 * h,
                        },
                        box3d: DONTCARE_3D,
                        score: None,
                    });
                }
            }
        }
        gts.push(FrameGt::new(id.clone(), gt));
        dets.push(FrameDet::new(id, det));
    }
    (gts, dets)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn is_deterministic_and_sized_like_kitti_val() {
        let (g1, d1) = generate(50, 7);
        let (g2, d2) = generate(50, 7);
        assert_eq!(g1, g2);
        assert_eq!(d1, d2);
        let n_gt: usize = g1.iter().map(|f| f.objects.len()).sum();
        let n_det: usize = d1.iter().map(|f| f.objects.len()).sum();
        assert!((400..=700).contains(&n_gt), "{n_gt}");
        assert!((350..=650).contains(&n_det), "{n_det}");
    }
}
