//! Colours and sizes shared by every picture, in one place so that the camera view,
//! the bird's-eye view and the legend can never disagree about what a colour means.

use fusiondet_kitti::{Object, ObjectClass};
use image::Rgb;

/// Where a box comes from; decides its colour, line width and label.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    GroundTruth,
    Detection,
}

impl Source {
    pub fn colour(self) -> Rgb<u8> {
        match self {
            Source::GroundTruth => GT,
            Source::Detection => DETECTION,
        }
    }

    pub fn thickness(self) -> u32 {
        match self {
            Source::GroundTruth => GT_THICKNESS,
            Source::Detection => DETECTION_THICKNESS,
        }
    }

    /// The label text: the short class name, and for detections the score with two
    /// decimals ("Ped 0.87"); short, because crowded street scenes have dozens.
    pub fn label(self, object: &Object) -> String {
        let class = short_class(object.class);
        match (self, object.score) {
            (Source::Detection, Some(score)) => format!("{class} {score:.2}"),
            _ => class.to_string(),
        }
    }
}

/// Ground truth: green, drawn thicker and underneath so that a detection lying
/// exactly on it still leaves a green rim.
pub const GT: Rgb<u8> = Rgb([40, 230, 90]);
/// Detections: orange, far from green in hue and brightness and from the blue points.
pub const DETECTION: Rgb<u8> = Rgb([255, 120, 20]);
/// KITTI's DontCare regions: faint grey, dashed, image only (they have no 3D box).
pub const DONT_CARE: Rgb<u8> = Rgb([210, 210, 210]);
/// Text drawn on a coloured label background.
pub const LABEL_TEXT: Rgb<u8> = Rgb([0, 0, 0]);
/// Background of the bird's-eye view and of the legend.
pub const BACKGROUND: Rgb<u8> = Rgb([16, 17, 24]);
/// Metric grid lines of the bird's-eye view.
pub const GRID: Rgb<u8> = Rgb([52, 56, 72]);
/// Grid distance labels and ordinary legend text.
pub const TEXT: Rgb<u8> = Rgb([200, 204, 216]);
/// Warnings shown in the picture (e.g. "no result file for this frame").
pub const NOTE: Rgb<u8> = Rgb([255, 214, 80]);
/// The ego vehicle marker and the camera's field-of-view edges.
pub const EGO: Rgb<u8> = Rgb([235, 235, 235]);

/// Plots (precision-recall curves) are printed on paper, so they use a white
/// background with dark ink, unlike the dark frame pictures.
pub const PLOT_BACKGROUND: Rgb<u8> = Rgb([255, 255, 255]);
/// The plot frame, tick marks and tick labels.
pub const PLOT_AXIS: Rgb<u8> = Rgb([40, 40, 40]);
/// Grid lines of a plot: light enough that curves always dominate.
pub const PLOT_GRID: Rgb<u8> = Rgb([226, 226, 226]);
/// Titles and legend text of a plot.
pub const PLOT_TEXT: Rgb<u8> = Rgb([0, 0, 0]);

/// One colour per curve of a plot, well apart in hue (the common "tab10" set without its
/// grey, then three dark tones), so the seeds' largest ablation tables (11 rows) need no
/// colour twice; none is grey or black, so a curve never reads as an axis or a grid line.
pub const SERIES: [Rgb<u8>; 12] = [
    Rgb([31, 119, 180]),
    Rgb([255, 127, 14]),
    Rgb([44, 160, 44]),
    Rgb([214, 39, 40]),
    Rgb([148, 103, 189]),
    Rgb([140, 86, 75]),
    Rgb([227, 119, 194]),
    Rgb([188, 189, 34]),
    Rgb([23, 190, 207]),
    Rgb([0, 0, 128]),
    Rgb([128, 0, 0]),
    Rgb([0, 110, 110]),
];

/// The colour of the `i`-th curve; colours repeat after [`SERIES`]'s length.
pub fn series_colour(i: usize) -> Rgb<u8> {
    SERIES[i % SERIES.len()]
}

/// A class name of at most five letters for box labels.
pub fn short_class(class: ObjectClass) -> &'static str {
    match class {
        ObjectClass::Pedestrian => "Ped",
        ObjectClass::PersonSitting => "Sit",
        ObjectClass::Cyclist => "Cyc",
        other => other.as_str(),
    }
}

/// Line thickness of ground-truth boxes, in pixels.
pub const GT_THICKNESS: u32 = 3;
/// Line thickness of detection boxes, in pixels.
pub const DETECTION_THICKNESS: u32 = 2;

/// Height above the road that maps to the top of the point colour ramp (metres).
pub const HEIGHT_RAMP_TOP: f64 = 3.0;
/// KITTI's Velodyne is mounted 1.73 m above the road, so LiDAR z + 1.73 is the
/// height above a flat road; used only to colour points.
pub const LIDAR_MOUNT_HEIGHT: f64 = 1.73;

/// Point colour for a height above the road: a cool ramp from slate blue (road) over
/// sky blue to near-white (3 m and up), so points never look like a box colour.
pub fn height_colour(height: f64) -> Rgb<u8> {
    const STOPS: [[f64; 3]; 4] = [
        [75.0, 95.0, 175.0],
        [80.0, 145.0, 250.0],
        [120.0, 210.0, 255.0],
        [235.0, 240.0, 255.0],
    ];
    ramp(&STOPS, height / HEIGHT_RAMP_TOP)
}

/// The colour at `t` in [0, 1] (clamped) of a ramp through evenly spaced `stops`.
fn ramp(stops: &[[f64; 3]], t: f64) -> Rgb<u8> {
    let t = t.clamp(0.0, 1.0) * (stops.len() - 1) as f64;
    let i = (t.floor() as usize).min(stops.len() - 2);
    let f = t - i as f64;
    let mix = |k: usize| (stops[i][k] + f * (stops[i + 1][k] - stops[i][k])).round() as u8;
    Rgb([mix(0), mix(1), mix(2)])
}

/// Pseudo points (back-projected completed depth) on the bird's-eye view: a muted violet,
/// apart from the box colours and the LiDAR height ramp.
pub const PSEUDO: Rgb<u8> = Rgb([150, 95, 175]);

/// Depth (metres) that maps to the far end of the depth colour ramp.
pub const DEPTH_RAMP_FAR: f64 = 80.0;

/// Colour of a depth in the depth panel: warm yellow near, through red and violet, to a
/// dark blue at [`DEPTH_RAMP_FAR`] and beyond; no depth is the background.
pub fn depth_colour(depth: f64) -> Rgb<u8> {
    if depth <= 0.0 {
        return BACKGROUND;
    }
    const STOPS: [[f64; 3]; 4] = [
        [255.0, 230.0, 90.0],
        [230.0, 80.0, 60.0],
        [130.0, 50.0, 150.0],
        [30.0, 35.0, 90.0],
    ];
    ramp(&STOPS, depth / DEPTH_RAMP_FAR)
}

/// `colour` scaled towards black by `factor` in [0, 1] (used for points outside
/// the camera's field of view, which the image cannot confirm).
pub fn dim(colour: Rgb<u8>, factor: f64) -> Rgb<u8> {
    let f = factor.clamp(0.0, 1.0);
    Rgb(colour.0.map(|c| (c as f64 * f).round() as u8))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_is_clamped_and_monotone_in_brightness() {
        assert_eq!(height_colour(-5.0), height_colour(0.0));
        assert_eq!(height_colour(9.0), height_colour(HEIGHT_RAMP_TOP));
        let lum = |c: Rgb<u8>| c.0.iter().map(|&v| v as u32).sum::<u32>();
        let mut last = 0;
        for k in 0..=30 {
            let l = lum(height_colour(k as f64 * 0.1));
            assert!(l >= last, "brightness falls at {k}");
            last = l;
        }
    }

    #[test]
    fn depth_ramp_runs_from_warm_to_dark_and_empty_is_background() {
        assert_eq!(depth_colour(0.0), BACKGROUND);
        assert_eq!(depth_colour(200.0), depth_colour(DEPTH_RAMP_FAR));
        let lum = |c: Rgb<u8>| c.0.iter().map(|&v| v as u32).sum::<u32>();
        assert!(lum(depth_colour(2.0)) > lum(depth_colour(70.0)));
        assert_ne!(PSEUDO, GT);
        assert_ne!(PSEUDO, DETECTION);
    }

    #[test]
    fn points_never_take_a_box_colour() {
        for k in 0..=30 {
            let c = height_colour(k as f64 * 0.1);
            assert_ne!(c, GT);
            assert_ne!(c, DETECTION);
            // Blue dominates red in every point colour; both box colours are the opposite
            // or green-dominant.
            assert!(c.0[2] >= c.0[0]);
        }
    }
}
