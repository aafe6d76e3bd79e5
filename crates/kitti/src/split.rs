//! `ImageSets/*.txt`: one frame id per line.

use crate::error::{FormatError, Result, read_text};
use std::path::Path;

/// Parses a split file; every non-blank line must be a frame id of ASCII digits, each id
/// once (a repeated id would count its frame twice in every evaluation and epoch).
pub fn parse_split(text: &str, path: &Path) -> Result<Vec<String>> {
    let mut ids = Vec::new();
    let mut first_line = std::collections::HashMap::new();
    for (index, line) in text.lines().enumerate() {
        let id = line.trim();
        if id.is_empty() {
            continue;
        }
        if !id.bytes().all(|b| b.is_ascii_digit()) {
            return Err(FormatError::field(
                path,
                index + 1,
                "frame id",
                format!("`{id}` is not a frame id (digits, e.g. 000042)"),
            ));
        }
        if let Some(first) = first_line.insert(id, index + 1) {
            return Err(FormatError::field(
                path,
                index + 1,
                "frame id",
                format!("`{id}` is listed again (first on line {first}); list each frame once"),
            ));
        }
        ids.push(id.to_string());
    }
    Ok(ids)
}

pub fn read_split(path: &Path) -> Result<Vec<String>> {
    parse_split(&read_text(path)?, path)
}

pub fn write_split(path: &Path, ids: &[String]) -> Result<()> {
    let mut text = ids.join("\n");
    if !text.is_empty() {
        text.push('\n');
    }
    crate::atomic::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_ids_and_skips_blank_lines() {
        let ids = parse_split("000001\n\n000002\r\n", Path::new("val.txt")).unwrap();
        assert_eq!(ids, ["000001", "000002"]);
    }

    #[test]
    fn rejects_non_ids() {
        let err = parse_split("000001\n0000x2\n", Path::new("val.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("val.txt:2"), "{err}");
    }

    #[test]
    fn rejects_an_id_listed_twice() {
        let err = parse_split("000000\n000002\n000000\n", Path::new("val.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("val.txt:3"), "{err}");
        assert!(err.contains("first on line 1"), "{err}");
    }
}
