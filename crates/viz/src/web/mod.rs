//! Interactive pages (`fusiondet view`): one self-contained HTML file per frame that opens
//! from disk with no network — the point cloud, ground-truth and detected boxes, pseudo
//! points and the camera frustum in a three.js scene (orbit, pan, zoom, bird's-eye view),
//! the camera image with the projected boxes beside it, layer toggles and a score slider.
//!
//! three.js is vendored, not hand-written WebGL: `assets/web/three.bundle.min.js` is three
//! 0.187.0 tree-shaken to the classes the viewer uses (MIT, `assets/web/THREE-LICENSE`;
//! rebuilt by `assets/web/build-three.sh`). The page's own script is `assets/web/viewer.js`.
//! Everything is inlined, so a page is one file to copy or mail.

mod payload;

pub use payload::{POINT_STEP_M, thin};

use crate::frame::FrameView;
use image::ImageEncoder;
use image::codecs::jpeg::JpegEncoder;

const PAGE: &str = include_str!("../../assets/web/page.html");
const CSS: &str = include_str!("../../assets/web/viewer.css");
const VIEWER: &str = include_str!("../../assets/web/viewer.js");
const THREE: &str = include_str!("../../assets/web/three.bundle.min.js");
const THREE_LICENSE: &str = include_str!("../../assets/web/THREE-LICENSE");

/// JPEG quality of the embedded camera image: sharp enough to read the scene, ~150 kB for
/// a KITTI image.
const JPEG_QUALITY: u8 = 85;

/// LiDAR points kept per page by default: a whole KITTI scan (~120k points) fits, and the
/// page stays under ~5 MB with pseudo points besides.
pub const DEFAULT_MAX_POINTS: usize = 150_000;

/// Pseudo points kept per page by default (a completed KITTI image back-projects to
/// several hundred thousand).
pub const DEFAULT_MAX_PSEUDO_POINTS: usize = 150_000;

/// Links to the neighbouring pages of a browsable set (relative file names).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Nav {
    pub prev: Option<String>,
    pub next: Option<String>,
    pub index: Option<String>,
}

/// A pseudo point cloud to show: LiDAR-frame positions and the image colour of each point.
#[derive(Debug, Clone, Default)]
pub struct PseudoCloud {
    pub xyz: Vec<[f32; 3]>,
    pub rgb: Vec<[u8; 3]>,
}

/// What a page shows beyond the frame itself.
#[derive(Debug, Clone)]
pub struct PageOptions {
    /// The frame id (page title and links).
    pub id: String,
    /// Where the score slider starts (detections below it hidden until moved).
    pub score_threshold: Option<f64>,
    pub nav: Nav,
    /// LiDAR points kept (evenly spaced through the scan when it has more).
    pub max_points: usize,
    pub pseudo: Option<PseudoCloud>,
    pub max_pseudo_points: usize,
}

impl PageOptions {
    pub fn new(id: &str) -> Self {
        PageOptions {
            id: id.to_string(),
            score_threshold: None,
            nav: Nav::default(),
            max_points: DEFAULT_MAX_POINTS,
            pseudo: None,
            max_pseudo_points: DEFAULT_MAX_PSEUDO_POINTS,
        }
    }
}

/// Text placed inside HTML elements.
fn escape_html(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// JSON placed inside a `<script>` element: `</script>` would end it early, and `<!--` or
/// `<script` inside it change how HTML parses the rest. `<` occurs only inside JSON strings,
/// where `\u003c` means the same.
fn escape_script_json(s: &str) -> String {
    s.replace('<', "\\u003c")
}

fn nav_html(nav: &Nav) -> String {
    let link = |target: &Option<String>, text: &str| match target {
        Some(t) => format!("<a href=\"{}\">{text}</a>", escape_html(t)),
        None => format!("<span class=\"off\">{text}</span>"),
    };
    if *nav == Nav::default() {
        return String::new();
    }
    format!(
        "{}{}{}",
        link(&nav.prev, "← prev"),
        link(&nav.index, "index"),
        link(&nav.next, "next →")
    )
}

/// The three.js bundle with its licence in a comment at its head, as MIT asks.
fn three_with_licence() -> String {
    format!("/*\n{}*/\n{THREE}", THREE_LICENSE.replace("*/", "* /"))
}

/// One frame's page.
pub fn render_page(view: &FrameView, options: &PageOptions) -> String {
    let mut jpeg = Vec::new();
    JpegEncoder::new_with_quality(&mut jpeg, JPEG_QUALITY)
        .write_image(
            view.image.as_raw(),
            view.image.width(),
            view.image.height(),
            image::ExtendedColorType::Rgb8,
        )
        .expect("an RGB image encodes to JPEG in memory");
    let data = payload::frame_payload(view, options, &jpeg);
    // Substituted in one pass, so text in the frame (a title, a class) can never be taken
    // for a placeholder.
    let mut out = String::with_capacity(THREE.len() + 4 * jpeg.len() + (1 << 20));
    let mut rest = PAGE;
    while let Some(start) = rest.find("{{") {
        out.push_str(&rest[..start]);
        let end = start + rest[start..].find("}}").expect("placeholders are closed") + 2;
        match &rest[start + 2..end - 2] {
            "TITLE" => out.push_str(&escape_html(&view.title)),
            "CSS" => out.push_str(CSS),
            "NAV" => out.push_str(&nav_html(&options.nav)),
            "DATA" => out.push_str(&escape_script_json(&data.to_string())),
            "THREE" => out.push_str(&three_with_licence()),
            "VIEWER" => out.push_str(VIEWER),
            other => panic!("unknown placeholder {other} in page.html"),
        }
        rest = &rest[end..];
    }
    out.push_str(rest);
    out
}

/// One row of a browsable set's index page.
#[derive(Debug, Clone)]
pub struct IndexEntry {
    pub id: String,
    pub page: String,
    pub ground_truth: usize,
    /// `None` when no detections were given for the set.
    pub detections: Option<usize>,
}

/// The index page of a browsable set: a table of frames linking to their pages.
pub fn render_index(title: &str, entries: &[IndexEntry]) -> String {
    let with_dets = entries.iter().any(|e| e.detections.is_some());
    let mut rows = String::new();
    for e in entries {
        let dets = match (with_dets, e.detections) {
            (false, _) => String::new(),
            (true, Some(n)) => format!("<td>{n}</td>"),
            (true, None) => "<td>—</td>".into(),
        };
        rows.push_str(&format!(
            "<tr><td><a href=\"{}\">{}</a></td><td>{}</td>{dets}</tr>\n",
            escape_html(&e.page),
            escape_html(&e.id),
            e.ground_truth
        ));
    }
    let first = entries
        .first()
        .map(|e| escape_html(&e.page))
        .unwrap_or_default();
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n\
         <style>body{{background:#111318;color:#dde1e6;font:14px system-ui,sans-serif;margin:2em}}\
         a{{color:#8ab4ff}}td,th{{padding:2px 14px;text-align:left}}</style></head><body>\n\
         <h1>{t}</h1>\n<p>{n} frames. Open one and step through with <kbd>←</kbd> / \
         <kbd>→</kbd>; <kbd>i</kbd> comes back here.</p>\n\
         <table><tr><th>frame</th><th>ground-truth boxes</th>{dh}</tr>\n{rows}</table>\n\
         <script>window.addEventListener('keydown',e=>{{if(e.key==='Enter'||e.key==='ArrowRight')\
         {{const f='{first}';if(f)location.href=f;}}}});</script>\n</body></html>\n",
        t = escape_html(title),
        n = entries.len(),
        dh = if with_dets { "<th>detections</th>" } else { "" },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::load_frame;
    use crate::testutil::sample_dir;

    fn data_of(page: &str) -> serde_json::Value {
        let start = page.find("type=\"application/json\">").unwrap() + 24;
        let end = start + page[start..].find("</script>").unwrap();
        serde_json::from_str(&page[start..end]).unwrap()
    }

    #[test]
    fn a_page_holds_the_frame_and_its_scripts_and_fetches_nothing() {
        let view = load_frame(&sample_dir(), "000001", None).unwrap();
        let page = render_page(&view, &PageOptions::new("000001"));
        assert!(!page.contains("{{"), "a placeholder was left");
        // Nothing is loaded from elsewhere: no src/href to the network, no import.
        for bad in ["src=\"http", "href=\"http", "import(", "fetch("] {
            assert!(!page.contains(bad), "page contains {bad}");
        }
        assert!(
            page.contains("Permission is hereby granted"),
            "three.js licence"
        );
        let data = data_of(&page);
        assert_eq!(data["lidar"]["count"], view.points.len());
        let gt = view.boxes_gt().len();
        assert_eq!(data["boxes"].as_array().unwrap().len(), gt);
        let dont_care = view.ground_truth.len() - gt;
        assert_eq!(data["dontcare"].as_array().unwrap().len(), dont_care);
        // The first car's corners are the label's, moved into the LiDAR frame.
        let first = &data["boxes"][0];
        let c = fusiondet_geometry::corners(&view.boxes_gt()[0].box3d);
        let want = view.camera.rect_to_velo(c[0]);
        for k in 0..3 {
            let got = first["corners"][k].as_f64().unwrap();
            assert!((got - want[k]).abs() < 1e-3, "{got} vs {}", want[k]);
        }
        // In-image boxes have projected edges (12 edges + 2 front diagonals, 4 numbers each).
        assert_eq!(first["image"].as_array().unwrap().len(), 14 * 4);
    }

    #[test]
    fn the_point_cap_thins_the_scan_and_scores_set_the_slider() {
        let mut view = load_frame(&sample_dir(), "000001", None).unwrap();
        let mut det = view.boxes_gt()[0].clone();
        det.score = Some(1.7);
        view.detections = Some(vec![det]);
        let mut options = PageOptions::new("000001");
        options.max_points = 1000;
        options.score_threshold = Some(5.0);
        let data = data_of(&render_page(&view, &options));
        assert_eq!(data["lidar"]["count"], 1000);
        assert_eq!(data["score_range"][1], 1.7);
        // A threshold above every score is clamped to the slider's range.
        assert_eq!(data["score_threshold"], 1.7);
        assert_eq!(
            data["boxes"].as_array().unwrap().last().unwrap()["kind"],
            "det"
        );
    }

    #[test]
    fn titles_cannot_break_out_of_the_page() {
        let mut view = load_frame(&sample_dir(), "000001", None).unwrap();
        view.title = "</script><script>alert(1)</script>{{DATA}}".into();
        let page = render_page(&view, &PageOptions::new("000001"));
        assert!(!page.contains("<script>alert"));
        assert_eq!(data_of(&page)["title"], view.title.as_str());
    }

    #[test]
    fn the_index_links_every_frame() {
        let entries: Vec<IndexEntry> = ["000001", "000002"]
            .iter()
            .map(|id| IndexEntry {
                id: id.to_string(),
                page: format!("{id}.html"),
                ground_truth: 3,
                detections: Some(2),
            })
            .collect();
        let page = render_index("val", &entries);
        assert!(page.contains("href=\"000001.html\"") && page.contains("href=\"000002.html\""));
        assert!(page.contains("<th>detections</th>"));
    }
}
