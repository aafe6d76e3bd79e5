//! The legend strip above the picture: title, what each colour and mark means, and
//! any notes (e.g. a missing result file), laid out left to right and wrapped.

use crate::draw::{dashed_line, fill_rect, line};
use crate::style::{self, BACKGROUND, DONT_CARE, NOTE, Source, TEXT};
use crate::text::{GLYPH, draw_text, text_size};
use image::{Rgb, RgbImage};

/// The small picture before a legend entry's text.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Icon {
    /// A solid line as boxes of this source are drawn.
    Line(Source),
    /// A faint dashed line (DontCare regions).
    Dashed,
    /// A box face with the X that marks a front face, and a heading tick.
    Front,
    /// The point colour ramp from the road up to [`style::HEIGHT_RAMP_TOP`].
    Ramp,
    /// A dimmed ramp: points outside the camera's view.
    DimRamp,
    /// A small square of one colour (pseudo points).
    Swatch(Rgb<u8>),
    /// The depth colour ramp from near to [`style::DEPTH_RAMP_FAR`].
    DepthRamp,
}

/// One legend entry.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    pub icon: Option<Icon>,
    pub text: String,
    pub colour: Rgb<u8>,
}

impl Entry {
    pub fn new(icon: Icon, text: impl Into<String>) -> Entry {
        Entry {
            icon: Some(icon),
            text: text.into(),
            colour: TEXT,
        }
    }
}

fn icon_width(icon: Icon, scale: u32) -> u32 {
    match icon {
        Icon::Ramp | Icon::DimRamp | Icon::DepthRamp => 6 * GLYPH * scale,
        _ => 4 * GLYPH * scale,
    }
}

fn draw_icon(img: &mut RgbImage, icon: Icon, x: i32, y: i32, scale: u32) {
    let w = icon_width(icon, scale) as i32;
    let h = (GLYPH * scale) as i32;
    let mid = (y + h / 2) as f64;
    let (x0, x1) = (x as f64, (x + w - 1) as f64);
    match icon {
        Icon::Line(source) => line(
            img,
            (x0, mid),
            (x1, mid),
            source.colour(),
            source.thickness(),
        ),
        Icon::Dashed => {
            for dy in [-(h / 3), h / 3] {
                dashed_line(
                    img,
                    (x0, mid + dy as f64),
                    (x1, mid + dy as f64),
                    DONT_CARE,
                    3,
                    0.8,
                );
            }
        }
        Icon::Front => {
            // A face seen head-on with its X, then a BEV heading tick to the right.
            let (fx1, top, bottom) = (x0 + h as f64, y as f64, (y + h - 1) as f64);
            for (a, b) in [
                ((x0, top), (fx1, top)),
                ((fx1, top), (fx1, bottom)),
                ((fx1, bottom), (x0, bottom)),
                ((x0, bottom), (x0, top)),
                ((x0, top), (fx1, bottom)),
                ((x0, bottom), (fx1, top)),
            ] {
                line(img, a, b, TEXT, 1);
            }
            let tx = fx1 + (GLYPH * scale) as f64;
            line(img, (tx, top), (tx, bottom), TEXT, 1);
            line(img, (tx, mid), (x1, mid), TEXT, 2);
            line(img, (x1, top), (x1, bottom), TEXT, 1);
        }
        Icon::Swatch(colour) => {
            fill_rect(
                img,
                x + w / 4,
                y + h / 4,
                (w / 2) as u32,
                (h / 2).max(1) as u32,
                colour,
            );
        }
        Icon::DepthRamp => {
            for k in 0..w {
                let depth = style::DEPTH_RAMP_FAR * (k + 1) as f64 / w as f64;
                fill_rect(
                    img,
                    x + k,
                    y + h / 4,
                    1,
                    (h / 2).max(1) as u32,
                    style::depth_colour(depth),
                );
            }
        }
        Icon::Ramp | Icon::DimRamp => {
            for k in 0..w {
                let height = style::HEIGHT_RAMP_TOP * k as f64 / (w - 1).max(1) as f64;
                let mut c = style::height_colour(height);
                if icon == Icon::DimRamp {
                    c = style::dim(c, crate::bev::OUT_OF_VIEW);
                }
                fill_rect(img, x + k, y + h / 4, 1, (h / 2).max(1) as u32, c);
            }
        }
    }
}

/// Renders `title`, `entries` and `notes` (one line each, in the note colour) as a
/// strip `width` pixels wide, as tall as the wrapped content needs.
pub fn render_legend(
    width: u32,
    title: &str,
    entries: &[Entry],
    notes: &[String],
    scale: u32,
) -> RgbImage {
    let s = scale.max(1);
    let pad = (GLYPH * s) as i32;
    let gap = (GLYPH * s) as i32 / 2;
    let line_h = (GLYPH * s) as i32 + gap;
    let (mut x, mut y) = (pad, pad);
    // Lay out first (positions only), then draw on a canvas of the right height.
    let mut items = vec![Entry {
        icon: None,
        text: title.to_string(),
        colour: TEXT,
    }];
    items.extend(entries.iter().cloned());
    let mut placed: Vec<(i32, i32, Entry)> = Vec::new();
    for item in items {
        let iw = item.icon.map_or(0, |i| icon_width(i, s) as i32 + gap);
        let w = iw + text_size(&item.text, s).0 as i32;
        if x > pad && x + w > width as i32 - pad {
            x = pad;
            y += line_h;
        }
        placed.push((x, y, item));
        x += w + 2 * pad;
    }
    for note in notes {
        y += line_h;
        placed.push((
            pad,
            y,
            Entry {
                icon: None,
                text: note.clone(),
                colour: NOTE,
            },
        ));
    }
    let height = (y + line_h - gap + pad) as u32;
    let mut img = RgbImage::from_pixel(width, height, BACKGROUND);
    for (x, y, item) in placed {
        let mut tx = x;
        if let Some(icon) = item.icon {
            draw_icon(&mut img, icon, x, y, s);
            tx += icon_width(icon, s) as i32 + gap;
        }
        draw_text(&mut img, tx, y, &item.text, item.colour, s);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::style::{DETECTION, GT};
    use crate::testutil::count_colour;

    #[test]
    fn entries_show_their_colours_and_notes_add_lines() {
        let entries = [
            Entry::new(Icon::Line(Source::GroundTruth), "ground truth (3)"),
            Entry::new(Icon::Line(Source::Detection), "detections (2)"),
        ];
        let one = render_legend(1000, "000001", &entries, &[], 2);
        assert!(count_colour(&one, GT) > 0 && count_colour(&one, DETECTION) > 0);
        assert_eq!(count_colour(&one, NOTE), 0);
        let two = render_legend(1000, "000001", &entries, &["no result file".into()], 2);
        assert!(two.height() > one.height());
        assert!(count_colour(&two, NOTE) > 0);
    }

    #[test]
    fn narrow_legend_wraps_instead_of_cutting_text() {
        let entries = [
            Entry::new(Icon::Line(Source::GroundTruth), "ground truth (3)"),
            Entry::new(Icon::Line(Source::Detection), "detections (2)"),
            Entry::new(Icon::Ramp, "point height 0-3 m"),
        ];
        let wide = render_legend(2000, "000001", &entries, &[], 1);
        let narrow = render_legend(300, "000001", &entries, &[], 1);
        assert!(narrow.height() > wide.height());
        assert_eq!(count_colour(&wide, TEXT), count_colour(&narrow, TEXT));
    }
}
