//! Reading whole files the way the `kitti` readers do (its `read_regular` and `read_text`:
//! regular files only, within a size cap, a byte-order mark dropped), and the one number
//! parser every text reader uses.

use fusiondet_kitti::{FormatError, Result};
use std::path::Path;

pub(crate) use fusiondet_kitti::error::{MAX_BINARY_BYTES, read_regular, read_text};

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
