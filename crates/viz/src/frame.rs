//! One frame's picture: legend strip, camera image with projected boxes, and the
//! bird's-eye view below it at the same width, as in detection papers' qualitative
//! figures.

use crate::bev::{self, BevMap, BevRange};
use crate::camera_view;
use crate::legend::{Entry, Icon, render_legend};
use crate::style::{self, BACKGROUND, Source};
use fusiondet_geometry::CameraModel;
use fusiondet_kitti::{DepthMap, LidarPoint, Object, ObjectClass};
use image::{GenericImage, Rgb, RgbImage};

/// Everything drawn for one frame.
#[derive(Debug, Clone)]
pub struct FrameView {
    /// Shown first in the legend, e.g. the frame id.
    pub title: String,
    /// The left colour camera image (`image_2`).
    pub image: RgbImage,
    pub camera: CameraModel,
    /// The LiDAR scan in the LiDAR frame.
    pub points: Vec<LidarPoint>,
    /// Ground-truth labels, DontCare included (drawn as faint 2D regions).
    pub ground_truth: Vec<Object>,
    /// Detections, or `None` when none were asked for (the legend then omits them;
    /// `Some(vec![])` says "0 detections").
    pub detections: Option<Vec<Object>>,
    /// Remarks printed under the legend, e.g. that a result file was missing.
    pub notes: Vec<String>,
    /// Pseudo points (LiDAR frame, metres), drawn on the bird's-eye view when present.
    pub pseudo_points: Option<Vec<[f32; 3]>>,
    /// A completed depth map of the image, drawn as a colour map above it when present.
    pub depth: Option<DepthMap>,
    /// Each point's own colour (an RGB-D camera's), one per point of `points`: the
    /// bird's-eye view then draws them so instead of by height.
    pub point_colours: Option<Vec<Rgb<u8>>>,
    /// Class names of the boxes where KITTI's classes do not name them (SUN RGB-D's
    /// boxes are `Misc` objects): the labels then show these.
    pub class_names: Option<ClassNames>,
}

/// The names shown on box labels, one per object of [`FrameView::ground_truth`] and of
/// [`FrameView::detections`], in their order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClassNames {
    pub ground_truth: Vec<String>,
    pub detections: Vec<String>,
}

/// How to draw; the defaults suit KITTI's 1242×375 images.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Detections scoring below this are not drawn (detections without a score always are).
    pub score_threshold: Option<f64>,
    pub bev_range: BevRange,
    /// Spacing of the BEV grid and its distance labels, metres.
    pub grid_step: f64,
    /// Draw DontCare regions (faint dashed 2D boxes on the image; never in the BEV).
    pub dont_care: bool,
    /// Side of the square drawn for each LiDAR point in the BEV, pixels.
    pub point_size: u32,
    /// Integer scale of the 8×8 font for box labels.
    pub label_scale: u32,
    /// Integer scale of the 8×8 font for the legend and grid labels.
    pub text_scale: u32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            score_threshold: None,
            bev_range: BevRange::default(),
            grid_step: 10.0,
            dont_care: true,
            point_size: 2,
            label_scale: 1,
            text_scale: 2,
        }
    }
}

impl FrameView {
    /// Ground-truth objects with a 3D box (DontCare left out).
    pub fn boxes_gt(&self) -> Vec<&Object> {
        self.ground_truth
            .iter()
            .filter(|o| o.class != ObjectClass::DontCare)
            .collect()
    }

    /// Detections passing the threshold, lowest score first so that the best are
    /// drawn on top.
    pub fn boxes_detected(&self, options: &RenderOptions) -> Vec<&Object> {
        let mut shown: Vec<&Object> = self
            .detections
            .iter()
            .flatten()
            .filter(|o| o.class != ObjectClass::DontCare)
            .filter(|o| match (o.score, options.score_threshold) {
                (Some(s), Some(t)) => s >= t,
                _ => true,
            })
            .collect();
        shown.sort_by(|a, b| {
            a.score
                .unwrap_or(f64::INFINITY)
                .total_cmp(&b.score.unwrap_or(f64::INFINITY))
        });
        shown
    }

    /// The label text of `object`, one of this view's boxes from `source`: the class
    /// name given in [`FrameView::class_names`] where there is one, else KITTI's.
    pub fn label(&self, source: Source, object: &Object) -> String {
        let named = self.class_names.as_ref().and_then(|names| {
            let (objects, names) = match source {
                Source::GroundTruth => (self.ground_truth.as_slice(), &names.ground_truth),
                Source::Detection => (self.detections.as_deref().unwrap_or(&[]), &names.detections),
            };
            let i = objects.iter().position(|o| std::ptr::eq(o, object))?;
            names.get(i).cloned()
        });
        match named {
            None => source.label(object),
            Some(name) => match (source, object.score) {
                (Source::Detection, Some(score)) => format!("{name} {score:.2}"),
                _ => name,
            },
        }
    }
}

/// The camera image with DontCare regions, ground truth and detections drawn on it.
pub fn render_camera(view: &FrameView, options: &RenderOptions) -> RgbImage {
    let mut img = view.image.clone();
    if options.dont_care {
        camera_view::draw_dont_care(&mut img, &view.ground_truth);
    }
    let (gt, det) = (view.boxes_gt(), view.boxes_detected(options));
    camera_view::draw_boxes(&mut img, &view.camera, &gt, Source::GroundTruth);
    camera_view::draw_boxes(&mut img, &view.camera, &det, Source::Detection);
    let mut placed = Vec::new();
    let scale = options.label_scale;
    let text = |source: Source, o: &Object| view.label(source, o);
    camera_view::draw_labels_with(
        &mut img,
        &view.camera,
        &gt,
        Source::GroundTruth,
        scale,
        &mut placed,
        &text,
    );
    camera_view::draw_labels_with(
        &mut img,
        &view.camera,
        &det,
        Source::Detection,
        scale,
        &mut placed,
        &text,
    );
    img
}

/// A depth map as a colour image (near warm, far dark, empty the background).
pub fn render_depth(depth: &DepthMap) -> RgbImage {
    RgbImage::from_fn(depth.width as u32, depth.height as u32, |x, y| {
        style::depth_colour(depth.get(x as usize, y as usize) as f64)
    })
}

/// The bird's-eye view, `width` pixels wide; also returns how many points were dimmed
/// for lying outside the camera's view.
pub fn render_bev(view: &FrameView, options: &RenderOptions, width: u32) -> (RgbImage, usize) {
    let map = BevMap::new(options.bev_range, width);
    let mut img = RgbImage::from_pixel(map.width, map.height, BACKGROUND);
    bev::draw_grid(&mut img, &map, options.grid_step, options.text_scale);
    bev::draw_fov(&mut img, &map, &view.camera, view.image.width());
    if let Some(points) = &view.pseudo_points {
        bev::draw_pseudo_points(&mut img, &map, &view.camera, points);
    }
    let dimmed = match &view.point_colours {
        Some(colours) => {
            bev::draw_coloured_points(
                &mut img,
                &map,
                &view.camera,
                &view.points,
                colours,
                options.point_size,
            );
            0
        }
        None => bev::draw_points(
            &mut img,
            &map,
            &view.camera,
            view.image.dimensions(),
            &view.points,
            options.point_size,
        ),
    };
    bev::draw_footprints(&mut img, &map, &view.boxes_gt(), Source::GroundTruth);
    bev::draw_footprints(
        &mut img,
        &map,
        &view.boxes_detected(options),
        Source::Detection,
    );
    bev::draw_ego(&mut img, &map);
    (img, dimmed)
}

/// The legend entries that apply to this frame.
fn legend_entries(view: &FrameView, options: &RenderOptions, dimmed: usize) -> Vec<Entry> {
    let mut entries = vec![Entry::new(
        Icon::Line(Source::GroundTruth),
        format!("ground truth ({})", view.boxes_gt().len()),
    )];
    if view.detections.is_some() {
        let n = view.boxes_detected(options).len();
        let text = match options.score_threshold {
            Some(t) => format!("detections >= {t:.2} ({n})"),
            None => format!("detections ({n})"),
        };
        entries.push(Entry::new(Icon::Line(Source::Detection), text));
    }
    if options.dont_care
        && view
            .ground_truth
            .iter()
            .any(|o| o.class == ObjectClass::DontCare)
    {
        entries.push(Entry::new(Icon::Dashed, "DontCare (2D)"));
    }
    entries.push(Entry::new(Icon::Front, "front / heading"));
    match &view.point_colours {
        Some(_) => entries.push(Entry::new(
            Icon::Swatch(style::TEXT),
            "points in their camera colour",
        )),
        None => entries.push(Entry::new(
            Icon::Ramp,
            format!("height 0-{:.0} m", style::HEIGHT_RAMP_TOP),
        )),
    }
    if dimmed > 0 {
        entries.push(Entry::new(Icon::DimRamp, "outside image"));
    }
    if let Some(points) = &view.pseudo_points {
        entries.push(Entry::new(
            Icon::Swatch(style::PSEUDO),
            format!("pseudo points ({})", points.len()),
        ));
    }
    if view.depth.is_some() {
        entries.push(Entry::new(
            Icon::DepthRamp,
            format!("depth 0-{:.0} m", style::DEPTH_RAMP_FAR),
        ));
    }
    entries
}

/// Stacks pictures top to bottom, centred, separated by `gap` background rows: the
/// whole figure of [`render_frame_with`], or several frames into one sheet.
pub fn stack_vertical(parts: &[RgbImage], gap: u32) -> RgbImage {
    let width = parts.iter().map(|p| p.width()).max().unwrap_or(0);
    let height =
        parts.iter().map(|p| p.height()).sum::<u32>() + gap * parts.len().saturating_sub(1) as u32;
    let mut out = RgbImage::from_pixel(width.max(1), height.max(1), BACKGROUND);
    let mut y = 0;
    for p in parts {
        // Cannot fail: `out` is as wide as the widest part and as tall as all of them.
        let _ = out.copy_from(p, (width - p.width()) / 2, y);
        y += p.height() + gap;
    }
    out
}

/// The whole figure with default options.
pub fn render_frame(view: &FrameView) -> RgbImage {
    render_frame_with(view, &RenderOptions::default())
}

/// The whole figure: legend, camera image, bird's-eye view (same width as the image).
pub fn render_frame_with(view: &FrameView, options: &RenderOptions) -> RgbImage {
    let width = view.image.width();
    let camera = render_camera(view, options);
    let (bev, dimmed) = render_bev(view, options, width);
    let legend = render_legend(
        width,
        &view.title,
        &legend_entries(view, options, dimmed),
        &view.notes,
        options.text_scale,
    );
    let mut parts = vec![legend];
    parts.extend(view.depth.as_ref().map(render_depth));
    parts.extend([camera, bev]);
    stack_vertical(&parts, 4)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::load_frame;
    use crate::testutil::{count_colour, sample_dir};

    #[test]
    fn pseudo_points_and_depth_are_drawn_when_given() {
        let mut view = load_frame(&sample_dir(), "000001", None).unwrap();
        let plain = render_frame(&view);
        assert_eq!(count_colour(&plain, style::PSEUDO), 0);
        // A row of pseudo points 20 m ahead (LiDAR x forward, y left).
        view.pseudo_points = Some(
            (0..50)
                .map(|k| [20.0, -5.0 + 0.2 * k as f32, -1.0])
                .collect(),
        );
        let mut depth = DepthMap::empty(view.image.width() as usize, view.image.height() as usize);
        depth.data[..1000].fill(10.0);
        view.depth = Some(depth);
        let rich = render_frame(&view);
        assert!(count_colour(&rich, style::PSEUDO) >= 20);
        // The depth panel (as tall as the image) sits between legend and image.
        assert!(rich.height() >= plain.height() + view.image.height());
        assert!(count_colour(&rich, style::depth_colour(10.0)) >= 1000);
    }
}
