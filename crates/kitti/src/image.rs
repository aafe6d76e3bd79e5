//! `image_2/NNNNNN.png`: the left colour camera image.

use crate::error::{FormatError, MAX_IMAGE_BYTES, Result, read_regular};
use image::RgbImage;
use std::path::Path;

pub fn read_image(path: &Path) -> Result<RgbImage> {
    let img = image_reader(path)?
        .decode()
        .map_err(|e| FormatError::file(path, format!("cannot decode image: {e}")))?;
    Ok(img.to_rgb8())
}

/// A reader over an image file's bytes, read whole as a regular file within
/// [`MAX_IMAGE_BYTES`] (a pipe or device in the image's place is refused, never waited on).
pub fn image_reader(path: &Path) -> Result<image::ImageReader<std::io::Cursor<Vec<u8>>>> {
    let bytes = read_regular(path, MAX_IMAGE_BYTES)?;
    image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| FormatError::io(path, e))
}

/// Width and height from an image file's header: the file is checked as [`image_reader`]
/// checks it, but only its header is read.
pub fn image_size(path: &Path) -> Result<(u32, u32)> {
    let (file, _) = crate::error::open_regular(path, MAX_IMAGE_BYTES)?;
    image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| FormatError::io(path, e))?
        .into_dimensions()
        .map_err(|e| FormatError::file(path, format!("cannot read the image's size: {e}")))
}

/// Encodes `image` as PNG and writes it atomically.
pub fn write_png(path: &Path, image: &RgbImage) -> Result<()> {
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| FormatError::file(path, format!("cannot encode PNG: {e}")))?;
    crate::atomic::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let img = RgbImage::from_fn(7, 3, |x, y| image::Rgb([x as u8, y as u8, 9]));
        write_png(&path, &img).unwrap();
        assert_eq!(read_image(&path).unwrap(), img);
    }

    #[test]
    fn garbage_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        std::fs::write(&path, b"not a png").unwrap();
        let err = read_image(&path).unwrap_err().to_string();
        assert!(err.contains("x.png"), "{err}");
    }
}
