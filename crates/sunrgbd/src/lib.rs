//! SUN RGB-D (Song, Lichtenberg & Xiao, CVPR 2015) in the prepared layout indoor 3D-detection
//! code works on (VoteNet / mmdetection3d style): strict readers whose errors name file, line
//! and field (the `kitti` crate's [`FormatError`]), and atomic writers for what a simulator or
//! a detector produces.
//!
//! # A prepared data set
//!
//! ```text
//! ROOT/
//!   points/<id>.bin   float32 × 6 per point, little-endian: x, y, z (metres, upright depth),
//!                     r, g, b (each in [0, 1])
//!   image/<id>.jpg    the colour image the points were made from
//!   calib/<id>.txt    the 3×3 depth-to-image matrix M: [u·w, v·w, w] = M · [x, y, z]
//!   label/<id>.txt    ground truth, one box per line
//!   det_2d/<id>.txt   a 2D detector's boxes, `class x1 y1 x2 y2 score` ([`detections2d`])
//!   splits/train.txt  scene ids, one per line (also val.txt)
//! ```
//!
//! A result directory holds `<id>.txt` per scene, the label lines with a score appended.
//! [`SunRgbdDir`] names these paths; [`read_scene`](SunRgbdDir::read_scene) reads a scene.
//!
//! # Coordinates
//!
//! Upright depth: x right, y forward, z up (gravity-aligned: the sensor's tilt `Rtilt` is
//! already applied), metres. A box is its centre, its full sizes `dx dy dz` and `yaw`, the
//! counter-clockwise angle (seen from above, about +z) from +x to the box's `dx` side: that
//! side runs along (cos yaw, sin yaw). The sign was settled on the real scene 000017: with it
//! the bed's projected corners fall on its annotated 2D box, with the opposite sign 100 px
//! off (`layout`'s tests).
//!
//! Lines (`label/`, results), whitespace-separated; `#` starts a comment line (the prepared
//! files open with one naming the columns), blank lines are skipped:
//!
//! ```text
//! class cx cy cz dx dy dz yaw x1 y1 x2 y2 [score]
//! ```
//!
//! `x1 y1 x2 y2` is the 2D box in pixels. Class names are kept as written; the ten that
//! are evaluated are [`SunClass`], others (SUN RGB-D annotates hundreds) are not an error.
//!
//! The raw SUN RGB-D frames (`depth/*.png` beside `image/*.jpg`) are read by [`depth`], which
//! turns them into upright-depth points with a camera matrix.

pub mod calib;
pub mod depth;
pub mod detections2d;
mod io;
pub mod label;
pub mod layout;
pub mod points;

pub use calib::{Calib, Mat33, read_calib, write_calib};
pub use depth::{DepthToPoints, PixelOrigin, RawDepth, depth_to_points, read_depth_png};
pub use detections2d::{Detection2d, read_detections_2d, write_detections_2d};
pub use fusiondet_kitti::{FormatError, Result};
pub use label::{Object, SunClass, UprightBox, read_labels, read_results, write_objects};
pub use layout::{Scene, SunRgbdDir, read_image};
pub use points::{Point, read_points, write_points};
