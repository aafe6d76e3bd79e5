//! Bitmap text from the public-domain 8×8 font of `font8x8`: no font file to ship or
//! load, identical pixels on every machine (which the tests rely on), and crisp at
//! integer scales.

use crate::draw::fill_rect;
use font8x8::legacy::{BASIC_LEGACY, LATIN_LEGACY};
use image::{Rgb, RgbImage};

/// Glyph cell size in pixels at scale 1.
pub const GLYPH: u32 = 8;

fn glyph(c: char) -> [u8; 8] {
    match c as u32 {
        code @ 0..=127 => BASIC_LEGACY[code as usize],
        code @ 0xA0..=0xFF => LATIN_LEGACY[(code - 0xA0) as usize],
        _ => BASIC_LEGACY['?' as usize],
    }
}

/// Width and height in pixels of `text` drawn at `scale` (one line).
pub fn text_size(text: &str, scale: u32) -> (u32, u32) {
    (text.chars().count() as u32 * GLYPH * scale, GLYPH * scale)
}

/// Draws `text` with its top-left corner at (x, y); pixels off the canvas are skipped.
/// Characters outside ASCII and Latin-1 are drawn as `?`.
pub fn draw_text(img: &mut RgbImage, x: i32, y: i32, text: &str, colour: Rgb<u8>, scale: u32) {
    let s = scale.max(1);
    for (i, c) in text.chars().enumerate() {
        let rows = glyph(c);
        let cx = x + (i as u32 * GLYPH * s) as i32;
        for (r, bits) in rows.iter().enumerate() {
            for col in 0..8 {
                // Bit 0 is the leftmost pixel.
                if bits >> col & 1 == 1 {
                    fill_rect(
                        img,
                        cx + (col * s) as i32,
                        y + (r as u32 * s) as i32,
                        s,
                        s,
                        colour,
                    );
                }
            }
        }
    }
}

/// Where [`draw_label`] would put `text` asked at (x, y): the box (x, y, width,
/// height) including `scale` pixels of padding, moved as little as needed to lie
/// wholly inside the canvas.
pub fn label_rect(img: &RgbImage, x: i32, y: i32, text: &str, scale: u32) -> (i32, i32, u32, u32) {
    let pad = scale.max(1);
    let (tw, th) = text_size(text, scale);
    let (w, h) = (tw + 2 * pad, th + 2 * pad);
    let x = x.min(img.width() as i32 - w as i32).max(0);
    let y = y.min(img.height() as i32 - h as i32).max(0);
    (x, y, w, h)
}

/// Draws `text` on a filled `background` box at [`label_rect`]'s place, so labels of
/// boxes near the border stay readable. Returns that box.
pub fn draw_label(
    img: &mut RgbImage,
    x: i32,
    y: i32,
    text: &str,
    colour: Rgb<u8>,
    background: Rgb<u8>,
    scale: u32,
) -> (i32, i32, u32, u32) {
    let (x, y, w, h) = label_rect(img, x, y, text, scale);
    let pad = scale.max(1) as i32;
    fill_rect(img, x, y, w, h, background);
    draw_text(img, x + pad, y + pad, text, colour, scale);
    (x, y, w, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    const WHITE: Rgb<u8> = Rgb([255, 255, 255]);

    fn lit(img: &RgbImage) -> usize {
        img.pixels().filter(|&&p| p == WHITE).count()
    }

    #[test]
    fn size_scales_with_length_and_scale() {
        assert_eq!(text_size("Car", 1), (24, 8));
        assert_eq!(text_size("10 m", 2), (64, 16));
    }

    #[test]
    fn glyphs_light_pixels_inside_their_cell_only() {
        let mut img = RgbImage::new(40, 20);
        draw_text(&mut img, 4, 4, "I", WHITE, 2);
        let n = lit(&img);
        assert!(
            n > 0 && n.is_multiple_of(4),
            "scale 2 lights 2x2 blocks, got {n}"
        );
        for (x, y, p) in img.enumerate_pixels() {
            if *p == WHITE {
                assert!((4..20).contains(&x) && (4..20).contains(&y), "({x},{y})");
            }
        }
        // A space draws nothing, an unknown character draws the `?` glyph.
        let mut blank = RgbImage::new(40, 20);
        draw_text(&mut blank, 0, 0, " ", WHITE, 1);
        assert_eq!(lit(&blank), 0);
        let (mut q, mut other) = (RgbImage::new(8, 8), RgbImage::new(8, 8));
        draw_text(&mut q, 0, 0, "?", WHITE, 1);
        draw_text(&mut other, 0, 0, "≥", WHITE, 1);
        assert_eq!(q, other);
    }

    #[test]
    fn label_is_pushed_inside_the_canvas() {
        let mut img = RgbImage::new(100, 30);
        let (x, y, w, h) = draw_label(&mut img, 90, -5, "Car", Rgb([0, 0, 0]), WHITE, 1);
        assert_eq!((w, h), (26, 10));
        assert_eq!((x, y), (74, 0));
        assert_eq!(*img.get_pixel(99, 0), WHITE);
    }
}
