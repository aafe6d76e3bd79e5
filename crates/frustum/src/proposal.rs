//! Frustums cut around 3D proposals: F-ConvNet's refinement stage.
//!
//! A first-stage box B becomes a second-stage input the same network can read: the
//! frustum frame through the pixel of B's centre, its origin moved along the axis to
//! B's centre depth ([`FrustumFrame::with_depth_origin`]), and the LiDAR points inside
//! B enlarged by [`ProposalCrop::enlarge`]. The configured depth range is then relative
//! to B's centre (e.g. [−3.2, 3.2] m for cars), so one fixed set of fine sub-frustums
//! (strides 0.1/0.2/0.4/0.8 m) tiles every proposal. Targets, decoding and the
//! projection loss work unchanged through the frame.

use crate::error::SkipReason;
use crate::frame::{NEAR_DEPTH, ProjectedFrame};
use crate::frustum::{FrustumFrame, FrustumPoints, clip_box};
use fusiondet_geometry::{iou_bev, points_in_box};
use fusiondet_kitti::{Box2d, Box3d, Object};
use serde::{Deserialize, Serialize};

/// How refinement frustums are cut (`[frustum.proposal_crop]` in TOML). Its presence
/// makes a configuration a second stage: frustums come from first-stage boxes, not 2D
/// boxes, so `augment.copies` and `augment.box_jitter` do not apply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProposalCrop {
    /// Factor on the proposal's length, width and height (about its centre) for the
    /// region whose points are kept: context for a box that is too small or misplaced.
    pub enlarge: f64,
    /// Training only: a proposal is trained on the ground truth of its class with the
    /// highest bird's-eye-view IoU when that IoU reaches this; others are left out.
    pub match_iou: f64,
}

impl Default for ProposalCrop {
    fn default() -> Self {
        ProposalCrop {
            enlarge: 1.2,
            match_iou: 0.3,
        }
    }
}

impl ProposalCrop {
    /// The error names the field and the allowed values.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.enlarge.is_finite() && self.enlarge >= 1.0) {
            return Err(format!(
                "`proposal_crop.enlarge` = {} must be a factor >= 1 (e.g. 1.2)",
                self.enlarge
            ));
        }
        if !(self.match_iou.is_finite() && self.match_iou > 0.0 && self.match_iou <= 1.0) {
            return Err(format!(
                "`proposal_crop.match_iou` = {} must be in (0, 1]",
                self.match_iou
            ));
        }
        Ok(())
    }
}

/// `b` scaled by `factor` about its centre (the location stays the bottom centre).
pub fn enlarged(b: &Box3d, factor: f64) -> Box3d {
    let h = b.h * factor;
    Box3d {
        l: b.l * factor,
        w: b.w * factor,
        h,
        y: b.y - 0.5 * b.h + 0.5 * h,
        ..*b
    }
}

/// The frame of a proposal: the ray through the pixel of its centre, with z_f = 0 at
/// the centre. `None` when the centre is not in front of the camera.
pub fn proposal_frame(frame: &ProjectedFrame, proposal: &Box3d) -> Option<FrustumFrame> {
    let centre = [proposal.x, proposal.y - 0.5 * proposal.h, proposal.z];
    let (u, v, depth) = frame.camera.rect_to_image(centre);
    if !(depth > NEAR_DEPTH && u.is_finite() && v.is_finite()) {
        return None;
    }
    let ray = FrustumFrame::through_pixel(&frame.camera, u, v);
    Some(ray.with_depth_origin(ray.to_frustum(centre)[2]))
}

/// The refinement frustum of `proposal` (camera frame) whose first-stage result line
/// had the 2D box `box2d`: the points inside the enlarged proposal, in the proposal's
/// frame, with relative depth in `depth_range`. Skips: centre behind the camera or 2D
/// box outside the image ([`SkipReason::OutsideImage`]), no points
/// ([`SkipReason::NoPoints`]).
pub fn extract_proposal_frustum(
    frame: &ProjectedFrame,
    proposal: &Box3d,
    box2d: &Box2d,
    crop: &ProposalCrop,
    depth_range: [f64; 2],
) -> Result<FrustumPoints, SkipReason> {
    let b = clip_box(box2d, frame.image_size).ok_or(SkipReason::OutsideImage)?;
    let ff = proposal_frame(frame, proposal).ok_or(SkipReason::OutsideImage)?;
    let region = enlarged(proposal, crop.enlarge);
    let inside = points_in_box(&region, &frame.cloud.rect);
    let points: Vec<[f64; 3]> = frame
        .cloud
        .rect
        .iter()
        .zip(inside)
        .filter(|(_, keep)| *keep)
        .map(|(r, _)| ff.to_frustum(*r))
        .filter(|q| q[2] >= depth_range[0] && q[2] <= depth_range[1])
        .collect();
    FrustumPoints::non_empty(b, ff, points)
}

/// The ground truth a training proposal learns from: among `objects` of the
/// proposal's class, the one with the highest bird's-eye-view IoU, if it reaches
/// `match_iou` (the first such object on ties).
pub fn match_proposal(proposal: &Object, objects: &[Object], match_iou: f64) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, o) in objects.iter().enumerate() {
        if o.class != proposal.class {
            continue;
        }
        let iou = iou_bev(&proposal.box3d, &o.box3d);
        if iou >= match_iou && best.is_none_or(|(_, b)| iou > b) {
            best = Some((i, iou));
        }
    }
    best.map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_data::sample_frame;
    use fusiondet_geometry::count_points_in_box;
    use fusiondet_kitti::ObjectClass;

    fn first_car(frame: &ProjectedFrame) -> Object {
        frame
            .objects
            .iter()
            .find(|o| o.class == ObjectClass::Car)
            .cloned()
            .unwrap()
    }

    #[test]
    fn enlarging_keeps_the_centre_and_scales_every_side() {
        let b = Box3d {
            h: 1.5,
            w: 1.6,
            l: 4.0,
            x: 2.0,
            y: 1.7,
            z: 20.0,
            ry: 0.3,
        };
        let e = enlarged(&b, 1.2);
        assert!((e.l - 4.8).abs() < 1e-12 && (e.w - 1.92).abs() < 1e-12);
        assert!((e.h - 1.8).abs() < 1e-12);
        assert!(((e.y - 0.5 * e.h) - (b.y - 0.5 * b.h)).abs() < 1e-12);
        assert_eq!((e.x, e.z, e.ry), (b.x, b.z, b.ry));
    }

    #[test]
    fn a_proposal_frustum_holds_the_enlarged_box_points_around_depth_zero() {
        let frame = sample_frame("000003");
        let car = first_car(&frame);
        let crop = ProposalCrop::default();
        let fp =
            extract_proposal_frustum(&frame, &car.box3d, &car.bbox, &crop, [-4.0, 4.0]).unwrap();
        // Exactly the points of the enlarged box (all lie within 4 m of its centre).
        let region = enlarged(&car.box3d, crop.enlarge);
        assert_eq!(
            fp.points.len(),
            count_points_in_box(&region, &frame.cloud.rect)
        );
        assert!(fp.points.len() > count_points_in_box(&car.box3d, &frame.cloud.rect));
        // The box centre is the frame's origin on the axis; points map back exactly.
        let c = fp
            .frame
            .to_frustum([car.box3d.x, car.box3d.y - 0.5 * car.box3d.h, car.box3d.z]);
        assert!(c[0].abs() < 1e-9 && c[2].abs() < 1e-9, "{c:?}");
        for q in &fp.points {
            assert!(q[2].abs() <= 4.0);
            let r = fp.frame.to_rect(*q);
            assert!(points_in_box(&region, &[r])[0]);
        }
        // The ground truth in this frame is centred at the origin.
        let in_frame = fp.frame.box_to_frustum(&car.box3d);
        assert!(in_frame.x.abs() < 1e-9 && in_frame.z.abs() < 1e-9);
        // A narrower depth range drops the far end of the crop.
        let narrow =
            extract_proposal_frustum(&frame, &car.box3d, &car.bbox, &crop, [-0.5, 0.5]).unwrap();
        assert!(narrow.points.len() < fp.points.len());
    }

    #[test]
    fn proposals_behind_the_camera_or_in_empty_space_are_skipped() {
        let frame = sample_frame("000003");
        let car = first_car(&frame);
        let crop = ProposalCrop::default();
        let behind = Box3d {
            z: -5.0,
            ..car.box3d
        };
        assert_eq!(
            extract_proposal_frustum(&frame, &behind, &car.bbox, &crop, [-4.0, 4.0]).unwrap_err(),
            SkipReason::OutsideImage
        );
        let in_the_air = Box3d {
            y: car.box3d.y - 30.0,
            ..car.box3d
        };
        assert_eq!(
            extract_proposal_frustum(&frame, &in_the_air, &car.bbox, &crop, [-4.0, 4.0])
                .unwrap_err(),
            SkipReason::NoPoints
        );
    }

    #[test]
    fn proposals_match_the_best_overlapping_ground_truth_of_their_class() {
        let frame = sample_frame("000003");
        let car = first_car(&frame);
        let gt_index = frame.objects.iter().position(|o| *o == car).unwrap();
        let moved = |dx: f64| Object {
            box3d: Box3d {
                x: car.box3d.x + dx,
                ..car.box3d
            },
            ..car.clone()
        };
        assert_eq!(
            match_proposal(&moved(0.3), &frame.objects, 0.3),
            Some(gt_index)
        );
        // Shifted by more than its width: no overlap, no match.
        assert_eq!(match_proposal(&moved(5.0), &frame.objects, 0.3), None);
        // Another class never matches.
        let ped = Object {
            class: ObjectClass::Pedestrian,
            ..moved(0.0)
        };
        assert_eq!(match_proposal(&ped, &frame.objects, 0.3), None);
    }

    #[test]
    fn crop_settings_are_validated() {
        assert!(ProposalCrop::default().validate().is_ok());
        let e = ProposalCrop {
            enlarge: 0.9,
            ..Default::default()
        };
        assert!(e.validate().unwrap_err().contains("enlarge"));
        let m = ProposalCrop {
            match_iou: 0.0,
            ..Default::default()
        };
        assert!(m.validate().unwrap_err().contains("match_iou"));
    }
}
