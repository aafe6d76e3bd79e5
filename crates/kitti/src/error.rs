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

/// Reads a whole text file, naming the file on failure.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| FormatError::io(path, e))
}
