//! One error type for every KITTI reader and writer, so that a user always learns
//! the file, the line and the field at fault, and what to do about it.

use std::path::{Path, PathBuf};

/// Why a KITTI file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    /// The file could not be opened, read or written at all.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// One field of one line is wrong.
    #[error("{}:{line}: field `{field}`: {message}", path.display())]
    Field {
        path: PathBuf,
        /// 1-based line number (for binary point clouds: the 0-based point index).
        line: usize,
        field: String,
        message: String,
    },
    /// The file as a whole is wrong (missing key, bad size, ...).
    #[error("{}: {message}", path.display())]
    File { path: PathBuf, message: String },
}

impl FormatError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        FormatError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    pub fn field(path: &Path, line: usize, field: &str, message: impl Into<String>) -> Self {
        FormatError::Field {
            path: path.to_path_buf(),
            line,
            field: field.to_string(),
            message: message.into(),
        }
    }

    pub fn file(path: &Path, message: impl Into<String>) -> Self {
        FormatError::File {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, FormatError>;

/// Parses one finite f64 field; NaN and infinities are rejected because every
/// later computation (IoU, projection, training targets) would silently break on them.
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

/// The largest text file a reader takes (labels, calibrations, splits, 2D detections):
/// KITTI's largest, a full split's 2D detections, is a few MB.
pub const MAX_TEXT_BYTES: u64 = 256 << 20;

/// The largest binary file a reader takes (a LiDAR scan is about 2 MB).
pub const MAX_BINARY_BYTES: u64 = 1 << 30;

/// The largest image a reader takes (a KITTI PNG is under 1 MB; SUN RGB-D's JPEGs less).
pub const MAX_IMAGE_BYTES: u64 = 64 << 20;

/// Opens a regular file of at most `cap` bytes for reading, naming the file on failure. A
/// FIFO, a device (`/dev/zero`, also through a link) or a directory is refused before it is
/// opened: opening or reading one would block or grow without bound.
pub fn open_regular(path: &Path, cap: u64) -> Result<(std::fs::File, u64)> {
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
    // The file opened may not be the one looked at (replaced in between): look again.
    let opened = file.metadata().map_err(|e| FormatError::io(path, e))?;
    if !opened.is_file() || opened.len() > cap {
        return Err(FormatError::file(
            path,
            "changed while it was opened (now not a regular file within its size cap)",
        ));
    }
    Ok((file, opened.len()))
}

/// Reads a whole regular file of at most `cap` bytes (see [`open_regular`]).
pub fn read_regular(path: &Path, cap: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let (file, len) = open_regular(path, cap)?;
    let mut bytes = Vec::with_capacity(len as usize);
    // `take` guards against a file that grows while it is read.
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

/// Reads a whole text file, naming the file on failure. A UTF-8 byte-order mark (which
/// some editors add) is dropped, so that it does not become part of the first field.
pub fn read_text(path: &Path) -> Result<String> {
    let text = String::from_utf8(read_regular(path, MAX_TEXT_BYTES)?).map_err(|e| {
        FormatError::file(path, format!("not UTF-8 text ({e}); is it the right file?"))
    })?;
    Ok(match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
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
        assert_eq!(read_regular(&big, 100).unwrap().len(), 100);
        std::fs::write(&big, [0xff, 0xfe]).unwrap();
        let err = read_text(&big).unwrap_err().to_string();
        assert!(err.contains("not UTF-8 text"), "{err}");
    }
}
