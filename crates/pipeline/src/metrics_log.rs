//! Per-epoch metrics as JSON lines. On resume the log is cut back to the epochs that
//! the restored checkpoint has seen, so a killed run never logs an epoch twice.

use fusiondet_kitti::{FormatError, write_atomic};
use serde_json::Value;
use std::path::{Path, PathBuf};

pub struct MetricsLog {
    path: PathBuf,
}

impl MetricsLog {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        MetricsLog { path: path.into() }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// All logged records (an absent log is empty).
    pub fn read(&self) -> Result<Vec<Value>, FormatError> {
        let text = match std::fs::read_to_string(&self.path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(FormatError::io(&self.path, e)),
        };
        text.lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, l)| {
                serde_json::from_str(l)
                    .map_err(|e| FormatError::field(&self.path, i + 1, "json", e.to_string()))
            })
            .collect()
    }

    /// Appends one record, rewriting the file atomically (logs are small: one line an epoch).
    pub fn append(&self, record: &Value) -> Result<(), FormatError> {
        let mut records = self.read()?;
        records.push(record.clone());
        self.write_all(&records)
    }

    /// Keeps only records whose `epoch` field is below `epochs_done`.
    pub fn truncate_to(&self, epochs_done: usize) -> Result<(), FormatError> {
        let records: Vec<Value> = self
            .read()?
            .into_iter()
            .filter(|r| {
                r.get("epoch")
                    .and_then(Value::as_u64)
                    .is_some_and(|e| (e as usize) < epochs_done)
            })
            .collect();
        self.write_all(&records)
    }

    fn write_all(&self, records: &[Value]) -> Result<(), FormatError> {
        let mut text = String::new();
        for r in records {
            text.push_str(&r.to_string());
            text.push('\n');
        }
        write_atomic(&self.path, text.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn append_read_and_truncate() {
        let dir = tempfile::tempdir().unwrap();
        let log = MetricsLog::new(dir.path().join("metrics.jsonl"));
        assert!(log.read().unwrap().is_empty());
        for e in 0..3 {
            log.append(&json!({"epoch": e, "loss": 1.0 / (e as f64 + 1.0)}))
                .unwrap();
        }
        assert_eq!(log.read().unwrap().len(), 3);
        log.truncate_to(2).unwrap();
        let recs = log.read().unwrap();
        assert_eq!(recs.len(), 2);
        assert_eq!(recs[1]["epoch"], 1);
    }

    #[test]
    fn corrupt_line_is_reported_with_line_number() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.jsonl");
        std::fs::write(&path, "{\"epoch\":0}\nnot json\n").unwrap();
        let err = MetricsLog::new(&path).read().unwrap_err().to_string();
        assert!(err.contains("metrics.jsonl:2"), "{err}");
    }
}
