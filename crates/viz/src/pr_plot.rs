//! Precision–recall figures as in detection papers: recall on x and precision on y,
//! both in [0, 1], with a light grid, one coloured curve per configuration and a legend
//! giving each configuration's AP; optionally one panel per difficulty.
//!
//! A curve is drawn as the official devkit plots it: the interpolated precision
//! ([`PrCurve::interpolated`], made monotone from the right) at recall i / 40 for each
//! of the 41 samples, so that the area under the drawn curve is the AP the legend and
//! the tables print.

use crate::draw::{Px, fill_rect, fill_rect_blended, line};
use crate::error::VizError;
use crate::style::{PLOT_AXIS, PLOT_BACKGROUND, PLOT_GRID, PLOT_TEXT, series_colour};
use crate::text::{GLYPH, draw_text, text_size};
use fusiondet_eval::{Difficulty, MetricResult, N_SAMPLE_PTS, PrCurve};
use image::RgbImage;
use std::path::Path;

/// Which AP the legend prints next to a configuration's name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LegendAp {
    /// AP over 40 recall points (the current benchmark).
    R40,
    /// AP over 11 recall points (older papers).
    R11,
}

impl LegendAp {
    fn label(self) -> &'static str {
        match self {
            LegendAp::R40 => "AP_R40",
            LegendAp::R11 => "AP11",
        }
    }

    /// AP in percent, `None` for a curve without the 41 samples (nothing evaluated).
    fn of(self, curve: &PrCurve) -> Option<f64> {
        (curve.interpolated.len() == N_SAMPLE_PTS).then(|| match self {
            LegendAp::R40 => curve.ap40(),
            LegendAp::R11 => curve.ap11(),
        })
    }
}

/// How to draw a precision–recall figure.
#[derive(Debug, Clone, PartialEq)]
pub struct PrPlotOptions {
    /// Width and height of one panel in pixels (axes, labels and legend included).
    pub panel_size: (u32, u32),
    /// Integer scale of the 8×8 font.
    pub text_scale: u32,
    /// Width of the curves in pixels.
    pub line_thickness: u32,
    pub legend_ap: LegendAp,
}

impl Default for PrPlotOptions {
    fn default() -> Self {
        PrPlotOptions {
            panel_size: (600, 500),
            text_scale: 2,
            line_thickness: 2,
            legend_ap: LegendAp::R40,
        }
    }
}

/// Where recall 0..1 and precision 0..1 lie in a panel, in panel pixels: (x0, y0) is
/// (recall 0, precision 1), (x1, y1) is (recall 1, precision 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotArea {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl PlotArea {
    /// The plot area of a `width` × `height` panel drawn at text scale `scale`: margins
    /// leave room for the panel title, tick labels and axis names.
    pub fn of_panel(width: u32, height: u32, scale: u32) -> PlotArea {
        let g = (GLYPH * scale.max(1)) as f64;
        let x0 = 5.0 * g;
        let y0 = 3.0 * g;
        PlotArea {
            x0,
            y0,
            x1: (width as f64 - 2.0 * g).max(x0 + 1.0),
            y1: (height as f64 - 4.0 * g).max(y0 + 1.0),
        }
    }

    /// The pixel of a (recall, precision) point.
    pub fn to_pixel(&self, recall: f64, precision: f64) -> Px {
        (
            self.x0 + recall * (self.x1 - self.x0),
            self.y1 - precision * (self.y1 - self.y0),
        )
    }
}

/// The points the devkit plots for a curve: (i / 40, interpolated precision i).
pub fn curve_points(curve: &PrCurve) -> Vec<(f64, f64)> {
    let n = curve.interpolated.len();
    let step = (n.max(2) - 1) as f64;
    curve
        .interpolated
        .iter()
        .enumerate()
        .map(|(i, &p)| (i as f64 / step, p.clamp(0.0, 1.0)))
        .collect()
}

/// A legend entry's text: the name and the AP with two decimals, as in the tables.
pub fn legend_label(name: &str, curve: &PrCurve, ap: LegendAp) -> String {
    match ap.of(curve) {
        Some(v) => format!("{name} ({v:.2})"),
        None => format!("{name} (no data)"),
    }
}

fn offset(p: Px, dx: i32, dy: i32) -> Px {
    (p.0 + dx as f64, p.1 + dy as f64)
}

fn centred_text(img: &mut RgbImage, cx: f64, y: i32, text: &str, scale: u32) {
    let w = text_size(text, scale).0 as f64;
    draw_text(
        img,
        (cx - w / 2.0).round() as i32,
        y,
        text,
        PLOT_TEXT,
        scale,
    );
}

/// Legends with more entries than this are drawn one text scale smaller.
const LARGE_LEGEND_ROWS: usize = 5;

/// Draws one panel with its top-left corner at (ox, oy).
fn draw_panel(
    img: &mut RgbImage,
    (ox, oy): (i32, i32),
    title: &str,
    curves: &[(&str, &PrCurve)],
    opts: &PrPlotOptions,
) {
    let s = opts.text_scale.max(1);
    let g = (GLYPH * s) as i32;
    let (pw, ph) = opts.panel_size;
    let area = PlotArea::of_panel(pw, ph, s);
    let at = |r: f64, p: f64| offset(area.to_pixel(r, p), ox, oy);

    // Grid every 0.1, ticks and labels every 0.2.
    for k in 0..=10 {
        let v = k as f64 / 10.0;
        line(img, at(v, 0.0), at(v, 1.0), PLOT_GRID, 1);
        line(img, at(0.0, v), at(1.0, v), PLOT_GRID, 1);
        if k % 2 == 0 {
            let label = format!("{v:.1}");
            let (lw, lh) = text_size(&label, s);
            let (bx, by) = at(v, 0.0);
            line(img, (bx, by), (bx, by + g as f64 / 2.0), PLOT_AXIS, 1);
            centred_text(img, bx, (by + g as f64 * 0.75).round() as i32, &label, s);
            let (lx, ly) = at(0.0, v);
            line(img, (lx - g as f64 / 2.0, ly), (lx, ly), PLOT_AXIS, 1);
            draw_text(
                img,
                (lx - g as f64 * 0.75).round() as i32 - lw as i32,
                (ly - lh as f64 / 2.0).round() as i32,
                &label,
                PLOT_AXIS,
                s,
            );
        }
    }
    let corners = [at(0.0, 1.0), at(1.0, 1.0), at(1.0, 0.0), at(0.0, 0.0)];
    for i in 0..4 {
        line(img, corners[i], corners[(i + 1) % 4], PLOT_AXIS, 1);
    }
    // Axis names: "Recall" under the tick labels, "Precision" above the y axis (the
    // bitmap font has no vertical text).
    let (x_mid, y_bottom) = at(0.5, 0.0);
    centred_text(
        img,
        x_mid,
        (y_bottom + 2.0 * g as f64).round() as i32,
        "Recall",
        s,
    );
    let (ax, ay) = at(0.0, 1.0);
    draw_text(
        img,
        ax as i32 - 4 * g,
        ay as i32 - 3 * g / 2 - g / 4,
        "Precision",
        PLOT_TEXT,
        s,
    );
    centred_text(img, x_mid, oy + g / 4, title, s);

    // Curves, in order (later ones on top).
    for (i, (_, curve)) in curves.iter().enumerate() {
        let colour = series_colour(i);
        let pts: Vec<Px> = curve_points(curve)
            .into_iter()
            .map(|(r, p)| at(r, p))
            .collect();
        match pts.as_slice() {
            [] => {}
            [p] => {
                let t = opts.line_thickness.max(1) + 2;
                let h = (t / 2) as f64;
                fill_rect(img, (p.0 - h) as i32, (p.1 - h) as i32, t, t, colour);
            }
            _ => {
                for w in pts.windows(2) {
                    line(img, w[0], w[1], colour, opts.line_thickness);
                }
            }
        }
    }

    // Legend in the lower left, where precision–recall curves rarely run, on a mostly
    // opaque backdrop so a curve passing beneath stays faintly visible. A long legend
    // (an ablation's rows) uses a smaller font so it stays in the lower half.
    if curves.is_empty() {
        return;
    }
    let s = if curves.len() > LARGE_LEGEND_ROWS {
        (s - 1).max(1)
    } else {
        s
    };
    let g = (GLYPH * s) as i32;
    let header = format!("{} in %", opts.legend_ap.label());
    let texts: Vec<String> = curves
        .iter()
        .map(|(name, c)| legend_label(name, c, opts.legend_ap))
        .collect();
    let swatch = 3 * g;
    let line_h = g + g / 2;
    let pad = g / 2;
    let text_w = texts
        .iter()
        .map(|t| swatch + g / 2 + text_size(t, s).0 as i32)
        .chain([text_size(&header, s).0 as i32])
        .max()
        .unwrap_or(0);
    let box_w = text_w + 2 * pad;
    let box_h = line_h * (texts.len() as i32 + 1) - g / 2 + 2 * pad;
    let (bx, by) = at(0.0, 0.0);
    let (x, y) = (bx as i32 + g / 2, by as i32 - g / 2 - box_h);
    fill_rect_blended(img, x, y, box_w as u32, box_h as u32, PLOT_BACKGROUND, 0.85);
    let frame = [
        (x, y),
        (x + box_w - 1, y),
        (x + box_w - 1, y + box_h - 1),
        (x, y + box_h - 1),
    ]
    .map(|(a, b)| (a as f64, b as f64));
    for i in 0..4 {
        line(img, frame[i], frame[(i + 1) % 4], PLOT_GRID, 1);
    }
    draw_text(img, x + pad, y + pad, &header, PLOT_TEXT, s);
    for (i, text) in texts.iter().enumerate() {
        let ty = y + pad + line_h * (i as i32 + 1);
        let mid = (ty + g / 2) as f64;
        let sx = (x + pad) as f64;
        line(
            img,
            (sx, mid),
            (sx + swatch as f64 - 1.0, mid),
            series_colour(i),
            opts.line_thickness.max(1) + 1,
        );
        draw_text(img, x + pad + swatch + g / 2, ty, text, PLOT_TEXT, s);
    }
}

/// A figure of `panels` side by side (title, curves) under a `title` band.
fn render_panels(
    title: &str,
    panels: &[(&str, Vec<(&str, &PrCurve)>)],
    opts: &PrPlotOptions,
) -> RgbImage {
    let s = opts.text_scale.max(1);
    let band = 2 * GLYPH * s;
    let (pw, ph) = opts.panel_size;
    let width = (pw * panels.len().max(1) as u32).max(1);
    let mut img = RgbImage::from_pixel(width, band + ph.max(1), PLOT_BACKGROUND);
    centred_text(
        &mut img,
        width as f64 / 2.0,
        (GLYPH * s / 2) as i32,
        title,
        s,
    );
    for (k, (panel_title, curves)) in panels.iter().enumerate() {
        let origin = ((pw * k as u32) as i32, band as i32);
        draw_panel(&mut img, origin, panel_title, curves, opts);
    }
    img
}

/// One precision–recall panel: one curve per `(name, curve)`, coloured in order
/// ([`series_colour`]), under `title`. The image is `opts.panel_size` plus a title band
/// of 2 text lines at the top.
pub fn render_pr_curves(
    title: &str,
    curves: &[(&str, &PrCurve)],
    opts: &PrPlotOptions,
) -> RgbImage {
    render_panels(title, &[("", curves.to_vec())], opts)
}

/// Easy, moderate and hard side by side, as papers show them: one curve per
/// configuration in each panel, from a result row of each (e.g. Car 3D at the strict
/// overlap: `report.get(ObjectClass::Car, Metric::ThreeD, 0)`). The image is three
/// panels wide plus the title band.
pub fn render_pr_difficulties(
    title: &str,
    results: &[(&str, &MetricResult)],
    opts: &PrPlotOptions,
) -> RgbImage {
    let panels: Vec<(&str, Vec<(&str, &PrCurve)>)> = Difficulty::ALL
        .iter()
        .map(|&d| {
            let name = match d {
                Difficulty::Easy => "Easy",
                Difficulty::Moderate => "Moderate",
                Difficulty::Hard => "Hard",
            };
            (
                name,
                results.iter().map(|(n, r)| (*n, r.curve(d))).collect(),
            )
        })
        .collect();
    render_panels(title, &panels, opts)
}

/// Writes a figure as PNG atomically (a reader never sees half a file).
pub fn write_plot_png(path: &Path, img: &RgbImage) -> Result<(), VizError> {
    fusiondet_kitti::image::write_png(path, img)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::style::SERIES;
    use crate::testutil::count_colour;
    use fusiondet_eval::Metric;
    use fusiondet_kitti::ObjectClass;
    use image::Rgb;

    fn opts() -> PrPlotOptions {
        PrPlotOptions {
            panel_size: (400, 300),
            text_scale: 1,
            ..PrPlotOptions::default()
        }
    }

    /// The title band above the panels at text scale 1.
    const BAND: f64 = 16.0;

    fn constant(p: f64) -> PrCurve {
        PrCurve {
            interpolated: vec![p; N_SAMPLE_PTS],
            ..PrCurve::default()
        }
    }

    /// Figure pixel of (recall, precision) in panel `k`.
    fn pixel(k: u32, recall: f64, precision: f64) -> (u32, u32) {
        let o = opts();
        let area = PlotArea::of_panel(o.panel_size.0, o.panel_size.1, o.text_scale);
        let (x, y) = area.to_pixel(recall, precision);
        (
            (x + (k * o.panel_size.0) as f64).round() as u32,
            (y + BAND).round() as u32,
        )
    }

    /// Rows of column `x` that have `colour`.
    fn rows_with(img: &RgbImage, x: u32, colour: Rgb<u8>) -> Vec<u32> {
        (0..img.height())
            .filter(|&y| *img.get_pixel(x, y) == colour)
            .collect()
    }

    #[test]
    fn figure_sizes() {
        let c = constant(0.5);
        let one = render_pr_curves("t", &[("a", &c)], &PrPlotOptions::default());
        assert_eq!(one.dimensions(), (600, 532));
        let r = result([constant(0.9), constant(0.5), constant(0.2)]);
        let three = render_pr_difficulties("t", &[("a", &r)], &opts());
        assert_eq!(three.dimensions(), (1200, 316));
    }

    #[test]
    fn constant_precision_is_a_horizontal_line_at_its_height() {
        let (flat, step) = (constant(0.5), {
            let mut c = constant(0.0);
            c.interpolated[..=20].fill(1.0);
            c
        });
        let img = render_pr_curves("Car 3D", &[("flat", &flat), ("step", &step)], &opts());
        // Far right, clear of the legend: the flat curve is at the middle row only.
        let (x, mid) = pixel(0, 0.9, 0.5);
        let rows = rows_with(&img, x, SERIES[0]);
        assert!(!rows.is_empty());
        assert!(
            rows.iter().all(|&y| y.abs_diff(mid) <= 1),
            "{rows:?} vs {mid}"
        );
        // The step curve: precision 1 up to recall 0.5, then 0.
        let (x_left, top) = pixel(0, 0.25, 1.0);
        assert!(
            rows_with(&img, x_left, SERIES[1])
                .iter()
                .all(|&y| y.abs_diff(top) <= 1)
        );
        assert!(!rows_with(&img, x_left, SERIES[1]).is_empty());
        let (x_right, bottom) = pixel(0, 0.8, 0.0);
        let rows = rows_with(&img, x_right, SERIES[1]);
        assert!(!rows.is_empty() && rows.iter().all(|&y| y.abs_diff(bottom) <= 1));
    }

    fn result(curves: [PrCurve; 3]) -> MetricResult {
        MetricResult {
            class: ObjectClass::Car,
            metric: Metric::ThreeD,
            setting: 0,
            min_overlap: 0.7,
            ap11: [0.0; 3],
            ap40: [0.0; 3],
            curves,
        }
    }

    #[test]
    fn each_difficulty_has_its_panel() {
        let r = result([constant(0.9), constant(0.5), constant(0.2)]);
        let img = render_pr_difficulties("Car 3D AP_R40", &[("saf", &r)], &opts());
        for (k, p) in [(0, 0.9), (1, 0.5), (2, 0.2)] {
            let (x, y) = pixel(k, 0.95, p);
            let rows = rows_with(&img, x, SERIES[0]);
            assert!(!rows.is_empty(), "panel {k}");
            assert!(
                rows.iter().all(|&r| r.abs_diff(y) <= 1),
                "panel {k}: {rows:?} vs {y}"
            );
        }
    }

    #[test]
    fn legend_names_each_curve_with_its_ap() {
        assert_eq!(
            legend_label("flat", &constant(0.5), LegendAp::R40),
            "flat (50.00)"
        );
        assert_eq!(
            legend_label("flat", &constant(0.5), LegendAp::R11),
            "flat (50.00)"
        );
        let none = PrCurve::default();
        assert_eq!(legend_label("x", &none, LegendAp::R40), "x (no data)");
        // A curve without data draws no line, but its legend swatch and text are there,
        // in the lower left of the plot.
        let blank = render_pr_curves("", &[], &opts());
        let with = render_pr_curves("", &[("x", &none)], &opts());
        assert_eq!(count_colour(&blank, SERIES[0]), 0);
        let (x0, y1) = pixel(0, 0.0, 0.0);
        let swatch: Vec<(u32, u32)> = with
            .enumerate_pixels()
            .filter(|(_, _, p)| **p == SERIES[0])
            .map(|(x, y, _)| (x, y))
            .collect();
        assert!(!swatch.is_empty());
        assert!(swatch.iter().all(|&(x, y)| x > x0 && y < y1 && y > y1 - 60));
        assert!(count_colour(&with, PLOT_TEXT) > count_colour(&blank, PLOT_TEXT));
    }

    #[test]
    fn an_ablations_eleven_row_legend_stays_in_the_lower_half_in_distinct_colours() {
        let o = PrPlotOptions::default();
        let flat = constant(0.9);
        let names: Vec<String> = (0..11).map(|i| format!("tiny-saf-slicing-{i}")).collect();
        let curves: Vec<(&str, &PrCurve)> = names.iter().map(|n| (n.as_str(), &flat)).collect();
        let img = render_pr_curves("", &curves, &o);
        let area = PlotArea::of_panel(o.panel_size.0, o.panel_size.1, o.text_scale);
        let band = 2 * GLYPH * o.text_scale;
        let (x0, top) = area.to_pixel(0.0, 1.0);
        let (x1, half) = area.to_pixel(1.0, 0.5);
        // Legend text is the only black ink inside the plot frame.
        let text_above_half = img
            .enumerate_pixels()
            .filter(|(x, y, p)| {
                let (x, y) = (*x as f64, *y as f64 - band as f64);
                **p == PLOT_TEXT && x > x0 && x < x1 && y > top && y < half
            })
            .count();
        assert_eq!(text_above_half, 0);
        for i in 0..11 {
            assert!((0..i).all(|j| series_colour(i) != series_colour(j)), "{i}");
            assert!(count_colour(&img, series_colour(i)) > 0, "{i}");
        }
    }

    #[test]
    fn empty_inputs_draw_bare_axes() {
        let img = render_pr_curves("nothing", &[], &opts());
        assert_eq!(img.dimensions(), (400, 316));
        assert!(count_colour(&img, PLOT_AXIS) > 0);
        assert!(SERIES.iter().all(|&c| count_colour(&img, c) == 0));
        let img = render_pr_difficulties("nothing", &[], &opts());
        assert_eq!(img.dimensions(), (1200, 316));
        let tiny = PrPlotOptions {
            panel_size: (0, 0),
            ..opts()
        };
        let c = constant(0.5);
        render_pr_curves("tiny", &[("a", &c)], &tiny);
    }

    #[test]
    fn png_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pr.png");
        let c = constant(0.7);
        let img = render_pr_curves("t", &[("a", &c)], &opts());
        write_plot_png(&path, &img).unwrap();
        assert_eq!(fusiondet_kitti::image::read_image(&path).unwrap(), img);
    }
}
