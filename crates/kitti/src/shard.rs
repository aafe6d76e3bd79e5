//! Sharded runs: `--shard i/n` gives a command the frames at positions k with k mod n = i,
//! so n processes (a Slurm job array, a Kubernetes indexed Job, or n runs one after another)
//! share a split. Each shard writes its own frames' files atomically and a shard record,
//! `DIR/.fusiondet-shards/<command>-<i>-of-<n>`, that lists them:
//!
//! ```text
//! fusiondet shard
//! command: detect
//! shard: 2/4
//! run: 5f0c1b2a9d3e7788
//! complete: yes|no
//! 000002
//! 000006
//! ```
//!
//! `run` fingerprints what defines the run (model, configuration, split, settings), so the
//! shards of two different runs are never mixed in one directory. When every shard's record
//! is complete and every listed frame's file exists, the directory is whole: the last shard
//! to finish (or `fusiondet merge`) then writes what an unsharded run writes at its end.

use crate::error::{FormatError, Result, read_text};
use crate::write_atomic;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// The folder of shard records inside an output directory.
pub const SHARDS_DIR: &str = ".fusiondet-shards";
const HEADER: &str = "fusiondet shard";
/// The advisory lock that orders shards preparing or finishing one directory.
const LOCK_FILE: &str = ".lock";

/// One shard of n: the frames at positions k of a list with k mod `count` = `index`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    /// The whole list as one shard.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Whether position `k` of a list belongs to this shard.
    pub fn owns(&self, k: usize) -> bool {
        k % self.count == self.index
    }

    /// This shard's items of `items`, in their order.
    pub fn select<T: Clone>(&self, items: &[T]) -> Vec<T> {
        items
            .iter()
            .enumerate()
            .filter(|(k, _)| self.owns(*k))
            .map(|(_, item)| item.clone())
            .collect()
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let usage = "expected I/N with 0 <= I < N, e.g. 0/4 (Slurm: \
                     $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)";
        let (i, n) = s.split_once('/').ok_or_else(|| format!("`{s}`: {usage}"))?;
        let (Ok(index), Ok(count)) = (i.trim().parse::<usize>(), n.trim().parse::<usize>()) else {
            return Err(format!("`{s}`: {usage}"));
        };
        if count == 0 || index >= count {
            return Err(format!("`{s}`: {usage}"));
        }
        Ok(Shard { index, count })
    }
}

/// A shard's record of the frames it writes and whether it finished.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShardRecord {
    /// The command that wrote it (`detect`, `simulate`, `depth-complete`, `pseudo-points`).
    pub command: String,
    pub shard: Shard,
    /// The run's fingerprint ([`fingerprint`]).
    pub run: String,
    pub complete: bool,
    /// The frames this shard writes, in the list's order.
    pub frames: Vec<String>,
}

/// The folder of shard records of output directory `dir`.
pub fn shards_dir(dir: &Path) -> PathBuf {
    dir.join(SHARDS_DIR)
}

/// Where the record of `command`'s `shard` lives in `dir`.
pub fn record_path(dir: &Path, command: &str, shard: Shard) -> PathBuf {
    shards_dir(dir).join(format!("{command}-{}-of-{}", shard.index, shard.count))
}

/// A short, stable fingerprint (SHA-256, 16 hex digits) of the parts that define a run;
/// each part is length-prefixed so that no two different lists hash alike by concatenation.
pub fn fingerprint(parts: &[&[u8]]) -> String {
    let mut hasher = Sha256::new();
    for part in parts {
        hasher.update((part.len() as u64).to_le_bytes());
        hasher.update(part);
    }
    hasher.finalize()[..8]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// What a run reads of the frames `ids` of `frames`, for its fingerprint: each frame's scan,
/// image and calibration ([`files_summary`]). Shards that read two different data sets
/// through the same split and 2D detections then never share a directory.
pub fn frames_summary(frames: &crate::FrameDir, ids: &[String]) -> Vec<u8> {
    files_summary(
        ids.iter()
            .flat_map(|id| [frames.velodyne(id), frames.image(id), frames.calib(id)]),
    )
}

/// Every file's size (`-` where it is missing) and every small text file's bytes
/// (calibrations): looking at the files costs one `stat` each (a scan is not read whole).
fn files_summary(files: impl IntoIterator<Item = std::path::PathBuf>) -> Vec<u8> {
    let mut summary = Vec::new();
    for path in files {
        match std::fs::metadata(&path) {
            Ok(meta) => {
                summary.extend_from_slice(format!("{}\n", meta.len()).as_bytes());
                let small_text = path.extension().is_some_and(|e| e == "txt") && meta.len() < 4096;
                if small_text && let Ok(bytes) = crate::error::read_regular(&path, 4096) {
                    summary.extend_from_slice(&bytes);
                }
            }
            Err(_) => summary.extend_from_slice(b"-\n"),
        }
    }
    summary
}

/// Writes a shard record atomically (creating the records folder).
pub fn write_record(dir: &Path, record: &ShardRecord) -> Result<()> {
    let folder = shards_dir(dir);
    std::fs::create_dir_all(&folder).map_err(|e| FormatError::io(&folder, e))?;
    let mut text = format!(
        "{HEADER}\ncommand: {}\nshard: {}\nrun: {}\ncomplete: {}\n",
        record.command,
        record.shard,
        record.run,
        if record.complete { "yes" } else { "no" }
    );
    for id in &record.frames {
        text.push_str(id);
        text.push('\n');
    }
    write_atomic(
        &record_path(dir, &record.command, record.shard),
        text.as_bytes(),
    )
}

/// Reads one shard record, naming the file, line and field of anything malformed.
pub fn read_record(path: &Path) -> Result<ShardRecord> {
    let text = read_text(path)?;
    let mut lines = text.lines();
    if lines.next() != Some(HEADER) {
        return Err(FormatError::field(
            path,
            1,
            "header",
            format!("expected `{HEADER}`"),
        ));
    }
    let mut value = |line: usize, key: &str| -> Result<String> {
        lines
            .next()
            .and_then(|l| l.strip_prefix(&format!("{key}: ")))
            .map(str::to_string)
            .ok_or_else(|| FormatError::field(path, line, key, format!("expected `{key}: …`")))
    };
    let command = value(2, "command")?;
    let shard = value(3, "shard")?
        .parse::<Shard>()
        .map_err(|e| FormatError::field(path, 3, "shard", e))?;
    let run = value(4, "run")?;
    let complete = match value(5, "complete")?.as_str() {
        "yes" => true,
        "no" => false,
        other => {
            return Err(FormatError::field(
                path,
                5,
                "complete",
                format!("expected `yes` or `no`, found `{other}`"),
            ));
        }
    };
    let frames = crate::split::parse_split(&lines.collect::<Vec<_>>().join("\n"), path)?;
    Ok(ShardRecord {
        command,
        shard,
        run,
        complete,
        frames,
    })
}

/// Every shard record in `dir` (none when it has no records folder), in file-name order.
/// Records have no extension; other files in the folder (a command's own per-shard data,
/// the lock) are not records.
pub fn read_records(dir: &Path) -> Result<Vec<ShardRecord>> {
    let folder = shards_dir(dir);
    let Ok(entries) = std::fs::read_dir(&folder) else {
        return Ok(Vec::new());
    };
    let mut paths: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| !n.contains('.') && n.contains("-of-"))
        })
        .collect();
    paths.sort();
    paths.iter().map(|p| read_record(p)).collect()
}

/// An exclusive advisory lock on `dir`'s shard records, held until dropped: shards that
/// prepare or finish the same directory at once take turns.
pub struct RecordsLock {
    _file: std::fs::File,
}

/// Waits for and takes `dir`'s records lock (creating the records folder).
pub fn lock_records(dir: &Path) -> Result<RecordsLock> {
    let folder = shards_dir(dir);
    std::fs::create_dir_all(&folder).map_err(|e| FormatError::io(&folder, e))?;
    let path = folder.join(LOCK_FILE);
    let file = std::fs::File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|e| FormatError::io(&path, e))?;
    file.lock().map_err(|e| FormatError::io(&path, e))?;
    Ok(RecordsLock { _file: file })
}

/// How far the shards of one run in a directory have got.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShardProgress {
    pub count: usize,
    /// Shard indices without a record.
    pub missing_shards: Vec<usize>,
    /// Shard indices whose record says unfinished.
    pub unfinished_shards: Vec<usize>,
    /// Frames a finished record lists whose file is not there.
    pub missing_frames: Vec<String>,
}

impl ShardProgress {
    /// Every shard finished and every frame's file present.
    pub fn is_whole(&self) -> bool {
        self.missing_shards.is_empty()
            && self.unfinished_shards.is_empty()
            && self.missing_frames.is_empty()
    }

    /// What is missing, in a sentence naming at most ten of each.
    pub fn describe(&self) -> String {
        fn first(items: &[String]) -> String {
            let mut s = items
                .iter()
                .take(10)
                .cloned()
                .collect::<Vec<_>>()
                .join(", ");
            if items.len() > 10 {
                s.push_str(&format!(" and {} more", items.len() - 10));
            }
            s
        }
        let shards = |v: &[usize]| {
            first(
                &v.iter()
                    .map(|i| format!("{i}/{}", self.count))
                    .collect::<Vec<_>>(),
            )
        };
        let mut parts = Vec::new();
        if !self.missing_shards.is_empty() {
            parts.push(format!(
                "shards not started: {}",
                shards(&self.missing_shards)
            ));
        }
        if !self.unfinished_shards.is_empty() {
            parts.push(format!(
                "shards not finished: {}",
                shards(&self.unfinished_shards)
            ));
        }
        if !self.missing_frames.is_empty() {
            parts.push(format!(
                "{} frames without their file: {}",
                self.missing_frames.len(),
                first(&self.missing_frames)
            ));
        }
        if parts.is_empty() {
            "all shards finished".to_string()
        } else {
            parts.join("; ")
        }
    }
}

/// The records of `command` in `dir`, checked to be one run: the same fingerprint and shard
/// count throughout. `None` when there are none.
pub fn run_records(dir: &Path, command: &str) -> Result<Option<Vec<ShardRecord>>> {
    let records: Vec<ShardRecord> = read_records(dir)?
        .into_iter()
        .filter(|r| r.command == command)
        .collect();
    let Some(first) = records.first() else {
        return Ok(None);
    };
    if let Some(other) = records
        .iter()
        .find(|r| r.run != first.run || r.shard.count != first.shard.count)
    {
        return Err(FormatError::file(
            &shards_dir(dir),
            format!(
                "holds shards of two different `{command}` runs ({} of run {} and {} of run \
                 {}); remove the stale records or use a new directory",
                first.shard, first.run, other.shard, other.run
            ),
        ));
    }
    Ok(Some(records))
}

/// How far a run's `records` in `dir` have got; `file_of(id)` names a frame's file.
pub fn progress(
    dir: &Path,
    records: &[ShardRecord],
    file_of: &dyn Fn(&str) -> PathBuf,
) -> ShardProgress {
    let count = records.first().map_or(1, |r| r.shard.count);
    let have: std::collections::HashMap<usize, &ShardRecord> =
        records.iter().map(|r| (r.shard.index, r)).collect();
    let mut p = ShardProgress {
        count,
        missing_shards: Vec::new(),
        unfinished_shards: Vec::new(),
        missing_frames: Vec::new(),
    };
    for i in 0..count {
        match have.get(&i) {
            None => p.missing_shards.push(i),
            Some(r) if !r.complete => p.unfinished_shards.push(i),
            Some(r) => p.missing_frames.extend(
                r.frames
                    .iter()
                    .filter(|id| !dir.join(file_of(id)).is_file())
                    .cloned(),
            ),
        }
    }
    p
}

/// The whole list back from its shards' records (position k is record k mod n's entry
/// k div n), or `None` when the records cannot come from one list split that way.
pub fn interleave(records: &[ShardRecord]) -> Option<Vec<String>> {
    let count = records.first()?.shard.count;
    let mut by_index: Vec<Option<&ShardRecord>> = vec![None; count];
    for r in records {
        *by_index.get_mut(r.shard.index)? = Some(r);
    }
    let by_index: Vec<&ShardRecord> = by_index.into_iter().collect::<Option<_>>()?;
    let total: usize = by_index.iter().map(|r| r.frames.len()).sum();
    // A split into n shards gives the first (total mod n) shards one frame more.
    for (i, r) in by_index.iter().enumerate() {
        if r.frames.len() != total / count + usize::from(i < total % count) {
            return None;
        }
    }
    Some(
        (0..total)
            .map(|k| by_index[k % count].frames[k / count].clone())
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids(n: usize) -> Vec<String> {
        (0..n).map(|i| format!("{i:06}")).collect()
    }

    #[test]
    fn shards_parse_and_split_a_list_by_position() {
        let s: Shard = "1/3".parse().unwrap();
        assert_eq!(s, Shard { index: 1, count: 3 });
        assert_eq!(s.select(&ids(7)), vec!["000001", "000004"]);
        for bad in ["3/3", "1/0", "-1/2", "1", "a/b", "1/2/3"] {
            let err = bad.parse::<Shard>().unwrap_err();
            assert!(err.contains("expected I/N"), "{bad}: {err}");
        }
        // Every position belongs to exactly one shard.
        let all: Vec<String> = (0..3)
            .flat_map(|i| Shard { index: i, count: 3 }.select(&ids(10)))
            .collect();
        assert_eq!(all.len(), 10);
    }

    #[test]
    fn records_round_trip_and_interleave_back_into_the_list() {
        let dir = tempfile::tempdir().unwrap();
        let list = ids(8);
        for i in 0..3 {
            let shard = Shard { index: i, count: 3 };
            write_record(
                dir.path(),
                &ShardRecord {
                    command: "detect".into(),
                    shard,
                    run: fingerprint(&[b"model", b"val"]),
                    complete: i != 1,
                    frames: shard.select(&list),
                },
            )
            .unwrap();
        }
        let records = run_records(dir.path(), "detect").unwrap().unwrap();
        assert_eq!(records.len(), 3);
        assert_eq!(interleave(&records).unwrap(), list);
        assert_eq!(run_records(dir.path(), "simulate").unwrap(), None);
        // Shard 1 unfinished, and shard 0's frames have no files yet.
        let p = progress(dir.path(), &records, &|id| {
            PathBuf::from(format!("{id}.txt"))
        });
        assert_eq!(p.unfinished_shards, vec![1]);
        assert_eq!(
            p.missing_frames,
            vec!["000000", "000003", "000006", "000002", "000005"]
        );
        assert!(!p.is_whole());
        assert!(
            p.describe().contains("shards not finished: 1/3"),
            "{}",
            p.describe()
        );
        // A record of another run in the same folder is refused, naming both.
        write_record(
            dir.path(),
            &ShardRecord {
                command: "detect".into(),
                shard: Shard { index: 0, count: 2 },
                run: "other".into(),
                complete: true,
                frames: vec![],
            },
        )
        .unwrap();
        let err = run_records(dir.path(), "detect").unwrap_err().to_string();
        assert!(err.contains("two different `detect` runs"), "{err}");
    }

    #[test]
    fn frame_summaries_tell_data_sets_apart() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        for (root, scan, calib) in [(&a, 10, "P2: 1"), (&b, 12, "P2: 2")] {
            for sub in ["velodyne", "calib"] {
                std::fs::create_dir_all(root.join(sub)).unwrap();
            }
            std::fs::write(root.join("velodyne/000001.bin"), vec![0u8; scan]).unwrap();
            std::fs::write(root.join("calib/000001.txt"), calib).unwrap();
        }
        let ids = ["000001".to_string()];
        let of = |root: &Path| frames_summary(&crate::FrameDir::new(root), &ids);
        assert_ne!(of(&a), of(&b));
        std::fs::write(b.join("velodyne/000001.bin"), vec![1u8; 10]).unwrap();
        std::fs::write(b.join("calib/000001.txt"), "P2: 1").unwrap();
        assert_eq!(of(&a), of(&b));
        assert_ne!(of(&a), files_summary([a.join("missing.bin")]));
    }

    #[test]
    fn fingerprints_separate_the_parts() {
        assert_ne!(fingerprint(&[b"ab", b"c"]), fingerprint(&[b"a", b"bc"]));
        assert_eq!(fingerprint(&[b"x"]), fingerprint(&[b"x"]));
        assert_eq!(fingerprint(&[b"x"]).len(), 16);
    }

    #[test]
    fn a_damaged_record_names_file_line_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("detect-0-of-2");
        std::fs::write(
            &path,
            "fusiondet shard\ncommand: detect\nshard: 2/2\nrun: x\ncomplete: yes\n",
        )
        .unwrap();
        let err = read_record(&path).unwrap_err().to_string();
        assert!(err.contains("detect-0-of-2:3: field `shard`"), "{err}");
    }
}
