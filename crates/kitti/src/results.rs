//! The manifest `fusiondet detect` keeps in a result directory (`.fusiondet-results`):
//! which frames it writes and whether it finished.
//!
//! It marks a directory as detect's own, so a later detect replaces only files it wrote
//! (and refuses directories holding anything else), and it lets `eval` refuse a directory
//! whose detect was interrupted: a kill or a full disk would otherwise leave a mix of
//! stale, new and missing result files that scores as if complete.
//!
//! ```text
//! fusiondet results
//! complete: yes|no
//! 000001
//! 000002
//! ```

use crate::error::{FormatError, Result, read_text};
use crate::write_atomic;
use std::path::{Path, PathBuf};

/// The manifest's file name inside a result directory.
pub const MANIFEST_FILE: &str = ".fusiondet-results";
const HEADER: &str = "fusiondet results";

/// A result directory's manifest.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ResultsManifest {
    /// Whether every listed frame's result file was written.
    pub complete: bool,
    /// The frames the run writes (`<id>.txt` each).
    pub frames: Vec<String>,
}

/// Where `dir`'s manifest is.
pub fn manifest_path(dir: &Path) -> PathBuf {
    dir.join(MANIFEST_FILE)
}

/// The manifest of `dir`; `None` when it has none (results from another tool).
pub fn read_manifest(dir: &Path) -> Result<Option<ResultsManifest>> {
    let path = manifest_path(dir);
    if !path.exists() {
        return Ok(None);
    }
    let text = read_text(&path)?;
    let mut lines = text.lines();
    if lines.next() != Some(HEADER) {
        return Err(FormatError::field(
            &path,
            1,
            "header",
            format!("expected `{HEADER}`"),
        ));
    }
    let complete = match lines.next() {
        Some("complete: yes") => true,
        Some("complete: no") => false,
        other => {
            return Err(FormatError::field(
                &path,
                2,
                "complete",
                format!("expected `complete: yes` or `complete: no`, found {other:?}"),
            ));
        }
    };
    let frames = crate::split::parse_split(&lines.collect::<Vec<_>>().join("\n"), &path)?;
    Ok(Some(ResultsManifest { complete, frames }))
}

/// Writes `dir`'s manifest atomically.
pub fn write_manifest(dir: &Path, manifest: &ResultsManifest) -> Result<()> {
    let mut text = format!(
        "{HEADER}\ncomplete: {}\n",
        if manifest.complete { "yes" } else { "no" }
    );
    for id in &manifest.frames {
        text.push_str(id);
        text.push('\n');
    }
    write_atomic(&manifest_path(dir), text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_absent_is_none() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(read_manifest(dir.path()).unwrap(), None);
        let m = ResultsManifest {
            complete: false,
            frames: vec!["000001".into(), "000007".into()],
        };
        write_manifest(dir.path(), &m).unwrap();
        assert_eq!(read_manifest(dir.path()).unwrap(), Some(m));
    }

    #[test]
    fn a_damaged_manifest_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            manifest_path(dir.path()),
            "fusiondet results\ncomplete: maybe\n",
        )
        .unwrap();
        let err = read_manifest(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains(".fusiondet-results:2: field `complete`"),
            "{err}"
        );
    }
}
