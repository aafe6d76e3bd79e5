//! Pictures of KITTI frames: the camera image with projected 3D boxes above a
//! bird's-eye view of the point cloud with the same boxes, as in detection papers'
//! qualitative figures. Ground truth is green, detections orange; DontCare regions
//! are faint dashed 2D rectangles on the image only (they carry no 3D box).
//!
//! [`load_frame`] reads a frame, [`render_frame`] draws it; the pieces
//! ([`render_camera`], [`render_bev`], [`legend`], [`draw`], [`text`]) are public so
//! that other figures (several frames on one sheet, curves) can reuse them.
//!
//! [`web`] writes the interactive pages of `fusiondet view` (three.js, self-contained).
//!
//! [`render_pr_curves`] / [`render_pr_difficulties`] draw precision–recall figures
//! from the evaluation's curves, e.g. to compare the configurations of an ablation.

pub mod bev;
pub mod camera_view;
pub mod draw;
pub mod error;
pub mod frame;
pub mod indoor;
pub mod legend;
pub mod load;
pub mod pr_plot;
pub mod style;
pub mod text;
pub mod web;

#[cfg(test)]
mod testutil;

/// The `image` crate of this API's [`image::RgbImage`]s, for callers without their own.
pub use image;

pub use bev::{BevMap, BevRange};
pub use error::VizError;
pub use frame::{
    ClassNames, FrameView, RenderOptions, render_bev, render_camera, render_frame,
    render_frame_with, stack_vertical,
};
pub use indoor::{indoor_render_options, is_sun_rgbd_dir, load_indoor_scene};
pub use load::{load_frame, result_file};
pub use pr_plot::{
    LegendAp, PlotArea, PrPlotOptions, render_pr_curves, render_pr_difficulties, write_plot_png,
};
