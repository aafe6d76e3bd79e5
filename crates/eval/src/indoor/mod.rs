//! The indoor 3D-detection evaluation of SUN RGB-D, as indoor papers report it: AP per class
//! at rotated 3D IoU 0.25 and 0.5, and their means. The reference is VoteNet's
//! `utils/eval_det.py` (`eval_det_multiprocessing` with `get_iou_obb`, as its `APCalculator`
//! calls it); its numbers are reproduced (`reference.rs` pins them from running VoteNet's
//! code), with one deliberate difference: the IoU is exact.
//!
//! The protocol, class by class (the ten of [`SunClass`]; other class names are ignored):
//! * every detection of the class over all scenes, ranked by score, highest first;
//! * each takes the ground-truth box of the class in its scene with the largest IoU among
//!   all of them, matched or not (the first of equal IoUs). If that IoU is strictly above the
//!   threshold and the box is not yet matched, the detection is a true positive and the box
//!   matched; otherwise a false positive (VOC's rule: a detection whose best box is taken is
//!   a duplicate, even if another free box overlaps it enough);
//! * precision tp / max(tp + fp, ε), recall tp / (ground-truth boxes of the class);
//! * AP = the area under the precision envelope over all points (VOC 2010+, not 11-point);
//! * the mean over classes.
//!
//! Settled where VoteNet is silent or undefined:
//! * **A class without ground truth** has no AP (`None`; `null` in JSON, `-` in the table)
//!   and is left out of the mean. VoteNet leaves out a class with neither ground truth nor
//!   detections too, and counts a class with ground truth but no detections as 0 (as we
//!   do); but a class with detections and no ground truth makes its recall 0 / 0, its AP
//!   NaN and so the mean NaN. On SUN RGB-D's val split every class has ground truth.
//! * **Equal scores** keep their order: scenes in the order given (the split's), then
//!   detections in file order. VoteNet ranks with numpy's default (unstable) `argsort`,
//!   which reorders equal scores once there are more than a few (40 alternating scores
//!   come back scrambled), so its result with ties is arbitrary.
//!
//! **The deliberate difference: exact IoU** ([`iou_3d`]). VoteNet's `box3d_iou` clips with a
//! strict inside test and intersects nearly parallel lines, so boxes with (nearly)
//! coinciding edges get wrong overlaps: 1.56 for a box against itself, 3.77 for scene
//! 000017's night stand against itself; of 20,000 random boxes each against itself, 71 % came
//! out more than 1e-6 from 1 (16 % raised a qhull error, some gave thousands). Detections
//! are rarely that close to their ground truth, and where VoteNet's IoU is right the APs
//! agree to 1e-9 (on four generated cases of 20 to 300 scenes, to 6e-14).

mod ap;
mod iou;
mod load;
#[cfg(test)]
mod reference;
mod report;

pub use ap::{
    ClassResult, IOU_THRESHOLDS, IndoorReport, IndoorScene, MissingScore, evaluate_indoor, voc_ap,
};
pub use fusiondet_sunrgbd::SunClass;
pub use iou::iou_3d;
pub use load::{IndoorLoaded, load_indoor_dirs};
pub use report::{indoor_json, write_indoor_json};
