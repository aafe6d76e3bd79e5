//! Reading whole files the way the `kitti` readers do (regular files only, within a size
//! cap), and the one number parser every text reader uses. The `kitti` crate keeps its own
//! helpers private, so the few lines are repeated here rather than widening its API.

use fusiondet_kitti::{FormatError, Result};
use std::path::Path;

pub(crate) use fusiondet_kitti::error::{MAX_BINARY_BYTES, MAX_TEXT_BYTES};

/// Reads a whole regular file of at most `cap` bytes. A FIFO, a device or a directory is
/// refused before reading: reading one would block or grow without bound.
pub(crate) fn read_regular(path: &Path, cap: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let meta = std::fs::metadata(path).map_err(|e| FormatError::io(path, e))?;
    if !meta.is_file() {
        return Err(FormatError::file(
            path,
            "not a regular file (a directory, pipe or device); give the file itself",
        ));
    }
    if meta.len() > cap {
        return Err(FormatError::file(
            path,
            format!(
                "{} bytes is more than such a file can hold ({cap} at most)",
                meta.len()
            ),
        ));
    }
    let file = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(cap + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| FormatError::io(path, e))?;
    if bytes.len() as u64 > cap {
        return Err(FormatError::file(
            path,
            "grew beyond its size cap while read",
        ));
    }
    Ok(bytes)
}

pub(crate) fn read_text(path: &Path) -> Result<String> {
    String::from_utf8(read_regular(path, MAX_TEXT_BYTES)?).map_err(|e| {
        FormatError::file(path, format!("not UTF-8 text ({e}); is it the right file?"))
    })
}

/// Parses one finite number: NaN and infinities would break every IoU and projection later.
pub(crate) fn parse_finite(path: &Path, line: usize, field: &str, text: &str) -> Result<f64> {
    let value: f64 = text
        .parse()
        .map_err(|_| FormatError::field(path, line, field, format!("`{text}` is not a number")))?;
    if !value.is_finite() {
        return Err(FormatError::field(
            path,
            line,
            field,
            format!("`{text}` is not a finite number; fix or remove this line"),
        ));
    }
    Ok(value)
}

/// The lines a text reader looks at: 1-based numbers with the line, skipping blank lines and
/// `#` comments (the prepared files open with a comment naming the columns).
pub(crate) fn content_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter_map(|(i, line)| {
        let t = line.trim();
        (!t.is_empty() && !t.starts_with('#')).then_some((i + 1, line))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_within_the_cap_are_read() {
        let dir = tempfile::tempdir().unwrap();
        let err = read_text(dir.path()).unwrap_err().to_string();
        assert!(err.contains("not a regular file"), "{err}");
        #[cfg(unix)]
        {
            let err = read_text(Path::new("/dev/zero")).unwrap_err().to_string();
            assert!(err.contains("/dev/zero: not a regular file"), "{err}");
        }
        let big = dir.path().join("big.txt");
        std::fs::write(&big, vec![b'a'; 100]).unwrap();
        let err = read_regular(&big, 99).unwrap_err().to_string();
        assert!(err.contains("100 bytes is more than"), "{err}");
        std::fs::write(&big, [0xff, 0xfe]).unwrap();
        let err = read_text(&big).unwrap_err().to_string();
        assert!(err.contains("not UTF-8 text"), "{err}");
    }

    #[test]
    fn comments_and_blank_lines_are_skipped_with_their_numbers_kept() {
        let lines: Vec<_> = content_lines("# head\n\na b\n  # note\n c\n").collect();
        assert_eq!(lines, [(3, "a b"), (5, " c")]);
    }
}
