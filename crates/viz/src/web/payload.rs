//! The frame as the page's script reads it (`#frame-data`, JSON): point clouds quantised
//! and base64-encoded, boxes as corners in the LiDAR frame with their edges already
//! projected and near-plane-clipped onto the image, the image as JPEG.

use super::{PageOptions, PseudoCloud};
use crate::camera_view::{FRONT_CROSS, project_segment};
use crate::frame::FrameView;
use crate::style;
use base64::Engine;
use base64::engine::general_purpose::STANDARD as BASE64;
use fusiondet_geometry::{BOX_EDGES, CameraModel, corners};
use fusiondet_kitti::{LidarPoint, Object, ObjectClass};
use image::Rgb;
use serde_json::{Value, json};

/// Point coordinates travel as int16 multiples of this (1 cm: ±327 m of range, half the
/// bytes of f32; the sensor's own noise is a few centimetres).
pub const POINT_STEP_M: f64 = 0.01;
const INT16_LIMIT_M: f64 = i16::MAX as f64 * POINT_STEP_M;

/// Depth of the camera frustum's far face drawn in the 3D view, metres.
const FRUSTUM_DEPTH_M: f64 = 40.0;

/// Evenly spaced indices keeping at most `cap` of `n` (all when `n <= cap`): a
/// deterministic thinning that keeps the scan's structure, unlike a random subset.
pub fn thin(n: usize, cap: usize) -> Vec<usize> {
    if n <= cap {
        return (0..n).collect();
    }
    (0..cap).map(|j| j * n / cap).collect()
}

/// Quantised little-endian int16 triples of the points within ±327 m (others dropped),
/// and the indices kept.
fn quantise(points: impl Iterator<Item = [f32; 3]>) -> (Vec<u8>, Vec<usize>) {
    let mut bytes = Vec::new();
    let mut kept = Vec::new();
    for (i, p) in points.enumerate() {
        if p.iter()
            .any(|v| !v.is_finite() || f64::from(v.abs()) > INT16_LIMIT_M)
        {
            continue;
        }
        for v in p {
            let q = (f64::from(v) / POINT_STEP_M).round() as i16;
            bytes.extend_from_slice(&q.to_le_bytes());
        }
        kept.push(i);
    }
    (bytes, kept)
}

fn lidar_payload(points: &[LidarPoint], cap: usize) -> Value {
    let chosen = thin(points.len(), cap);
    let (xyz, kept) = quantise(chosen.iter().map(|&i| {
        let p = points[i];
        [p[0], p[1], p[2]]
    }));
    let intensity: Vec<u8> = kept
        .iter()
        .map(|&k| (points[chosen[k]][3].clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    json!({
        "count": kept.len(),
        "scale": POINT_STEP_M,
        "xyz": BASE64.encode(xyz),
        "intensity": BASE64.encode(intensity),
    })
}

fn pseudo_payload(cloud: &PseudoCloud, cap: usize) -> Value {
    let chosen = thin(cloud.xyz.len(), cap);
    let (xyz, kept) = quantise(chosen.iter().map(|&i| cloud.xyz[i]));
    let rgb: Vec<u8> = kept.iter().flat_map(|&k| cloud.rgb[chosen[k]]).collect();
    json!({
        "count": kept.len(),
        "scale": POINT_STEP_M,
        "xyz": BASE64.encode(xyz),
        "rgb": BASE64.encode(rgb),
    })
}

/// Rounded to millimetres (or thousandths): the page needs no more, and the file stays small.
fn r3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

fn box_payload(object: &Object, kind: &str, camera: &CameraModel) -> Value {
    let b = &object.box3d;
    let cam_corners = corners(b);
    let velo = cam_corners.map(|c| camera.rect_to_velo(c));
    let mean = |idx: &[usize]| -> [f64; 3] {
        let mut m = [0.0; 3];
        for &i in idx {
            for k in 0..3 {
                m[k] += velo[i][k] / idx.len() as f64;
            }
        }
        m
    };
    let centre = mean(&[0, 1, 2, 3, 4, 5, 6, 7]);
    let front = mean(&[0, 1, 4, 5]);
    let mut image = Vec::new();
    for &(a, c) in BOX_EDGES.iter().chain(FRONT_CROSS.iter()) {
        if let Some(((u1, v1), (u2, v2))) = project_segment(camera, cam_corners[a], cam_corners[c])
            && [u1, v1, u2, v2]
                .iter()
                .all(|v| v.is_finite() && v.abs() < 1e6)
        {
            image.extend([u1, v1, u2, v2].map(|v| (v * 10.0).round() / 10.0));
        }
    }
    json!({
        "kind": kind,
        "class": object.class.as_str(),
        "score": object.score.map(r3),
        "occluded": object.occlusion,
        "truncated": r3(object.truncation),
        "size": [r3(b.l), r3(b.w), r3(b.h)],
        "distance": r3(centre[0].hypot(centre[1])),
        "corners": velo.iter().flatten().map(|&v| r3(v)).collect::<Vec<_>>(),
        "centre": centre.map(r3),
        "front": front.map(r3),
        "image": image,
    })
}

fn hex(c: Rgb<u8>) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

/// The camera's origin and the corners of the image at [`FRUSTUM_DEPTH_M`], LiDAR frame.
fn frustum_payload(view: &FrameView) -> Value {
    let cam = &view.camera;
    let (w, h) = (
        f64::from(view.image.width()),
        f64::from(view.image.height()),
    );
    let origin = cam.rect_to_velo(cam.image_to_rect(cam.cu(), cam.cv(), 0.0));
    let far: Vec<[f64; 3]> = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        .iter()
        .map(|&(u, v)| {
            cam.rect_to_velo(cam.image_to_rect(u, v, FRUSTUM_DEPTH_M))
                .map(r3)
        })
        .collect();
    json!({ "origin": origin.map(r3), "far": far })
}

/// The whole `#frame-data` object; `jpeg` is the image already encoded.
pub fn frame_payload(view: &FrameView, options: &PageOptions, jpeg: &[u8]) -> Value {
    let mut boxes = Vec::new();
    let mut dont_care = Vec::new();
    for o in &view.ground_truth {
        if o.class == ObjectClass::DontCare {
            let b = &o.bbox;
            dont_care.push([b.x1, b.y1, b.x2, b.y2].map(|v| (v * 10.0).round() / 10.0));
        } else {
            boxes.push(box_payload(o, "gt", &view.camera));
        }
    }
    let detections = view.detections.as_deref().unwrap_or(&[]);
    for o in detections {
        if o.class != ObjectClass::DontCare {
            boxes.push(box_payload(o, "det", &view.camera));
        }
    }
    let scores: Vec<f64> = detections.iter().filter_map(|o| o.score).collect();
    let lo = scores
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .min(0.0);
    let hi = scores
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .max(1.0);
    let threshold = options.score_threshold.unwrap_or(lo).clamp(lo, hi);
    json!({
        "id": options.id,
        "title": view.title,
        "nav": {
            "prev": options.nav.prev,
            "next": options.nav.next,
            "index": options.nav.index,
        },
        "lidar": (!view.points.is_empty()).then(|| lidar_payload(&view.points, options.max_points)),
        "pseudo": options.pseudo.as_ref().map(|c| pseudo_payload(c, options.max_pseudo_points)),
        "boxes": boxes,
        "dontcare": dont_care,
        "image": {
            "width": view.image.width(),
            "height": view.image.height(),
            "jpeg": BASE64.encode(jpeg),
        },
        "frustum": frustum_payload(view),
        "colours": {
            "gt": hex(style::GT),
            "det": hex(style::DETECTION),
            "dontcare": hex(style::DONT_CARE),
        },
        "score_threshold": r3(threshold),
        "score_range": [r3(lo), r3(hi)],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thinning_keeps_evenly_spaced_points_and_all_when_few() {
        assert_eq!(thin(5, 10), vec![0, 1, 2, 3, 4]);
        assert_eq!(thin(10, 4), vec![0, 2, 5, 7]);
        assert_eq!(thin(0, 4), Vec::<usize>::new());
    }

    #[test]
    fn quantisation_is_centimetres_little_endian_and_drops_what_does_not_fit() {
        let (bytes, kept) = quantise(
            [
                [1.234f32, -0.006, 0.0],
                [400.0, 0.0, 0.0],
                [f32::NAN, 0.0, 0.0],
            ]
            .into_iter(),
        );
        assert_eq!(kept, vec![0]);
        let q: Vec<i16> = bytes
            .chunks(2)
            .map(|c| i16::from_le_bytes([c[0], c[1]]))
            .collect();
        assert_eq!(q, vec![123, -1, 0]);
    }
}
