//! A detect result directory and who owns it: refused where it touches what detect reads, new,
//! empty or an earlier detect's (replaced only with `--force`, and then only the files its
//! manifest lists); written frame by frame under its manifest ([`ResultWriter`]) or one
//! shard's frames under its shard record ([`ShardWriter`]), the last shard writing the
//! manifest. Below the families, which write their results through it.

use crate::error::{PipelineError, Result};
use fusiondet_kitti::atomic::DirLock;
use fusiondet_kitti::shard::{self, ShardRecord};
use fusiondet_kitti::{
    Object, ResultsManifest, Shard, read_manifest, write_manifest, write_objects,
};
use std::path::{Path, PathBuf};

fn out_err(path: &Path, message: impl Into<String>) -> PipelineError {
    PipelineError::RunDir {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Refuses a result directory that is, lies inside or contains anything detect reads: the
/// data set (`--out DATA/training/label_2` would overwrite its labels), the checkpoint, the
/// 2D detections, the completed depth maps (see [`fusiondet_kitti::paths`]).
pub(crate) fn refuse_input_dir(options: &crate::detection::DetectOptions) -> Result<()> {
    use fusiondet_kitti::paths::{Inputs, check_output_dir};
    let inputs = Inputs::new()
        .with("--data", Some(&options.data_dir))
        .with("--checkpoint", Some(&options.checkpoint))
        .with("--detections", options.detections.as_deref())
        .with("--depth-dir", options.depth_dir.as_deref());
    check_output_dir("--out", &options.out_dir, &inputs)
        .map_err(|e| PipelineError::Invalid(e.to_string()))
}

/// A result directory must be new, empty, or an earlier detect's: one that finished only
/// with `replace`, one that did not (killed, or stopped by an error; its results are
/// unusable, and eval refuses them) always. Files another program or the user put there are
/// never overwritten.
pub fn check_result_dir(out_dir: &Path, replace: bool) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(out_dir) else {
        return if out_dir.exists() {
            Err(out_err(out_dir, "exists and is not a directory"))
        } else {
            Ok(())
        };
    };
    let sharded = shard::read_records(out_dir)?
        .iter()
        .any(|r| r.command == DETECT);
    // The records folder alone is what a shard starting here makes first.
    let others = entries.flatten().any(|e| {
        e.file_name() != shard::SHARDS_DIR
            && e.file_name() != fusiondet_kitti::atomic::WRITER_LOCK_FILE
    });
    if !others && !sharded {
        return Ok(());
    }
    match read_manifest(out_dir)? {
        None if sharded && !replace => Err(out_err(
            out_dir,
            "holds a sharded detect's results (its shards may still be running; `fusiondet \
             merge` tells); pass --force to replace them, or choose another --out",
        )),
        None if sharded => Ok(()),
        None => Err(out_err(
            out_dir,
            "holds files that `fusiondet detect` did not write; choose a new or empty --out",
        )),
        Some(earlier) if earlier.complete && !replace => Err(out_err(
            out_dir,
            "holds the results of an earlier detect; pass --force to replace them, or choose \
             another --out",
        )),
        Some(_) => Ok(()),
    }
}

/// Removes an earlier detect's files from `out_dir`: the frames its manifest and its shard
/// records list, then the records and the manifest (nothing else). The manifest is first
/// marked unfinished, so a kill while removing leaves a directory eval refuses.
fn remove_earlier_results(out_dir: &Path) -> Result<()> {
    let manifest = read_manifest(out_dir)?;
    let records = shard::read_records(out_dir)?;
    if let Some(old) = &manifest {
        write_manifest(
            out_dir,
            &ResultsManifest {
                complete: false,
                ..old.clone()
            },
        )?;
    }
    let listed = manifest
        .iter()
        .flat_map(|m| m.frames.iter())
        .chain(records.iter().flat_map(|r| r.frames.iter()));
    for id in listed {
        remove_if_present(&out_dir.join(format!("{id}.txt")))?;
    }
    for r in &records {
        remove_if_present(&shard::record_path(out_dir, &r.command, r.shard))?;
    }
    if manifest.is_some() {
        remove_if_present(&fusiondet_kitti::results::manifest_path(out_dir))?;
    }
    Ok(())
}

fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(out_err(
            path,
            format!("cannot remove the earlier result: {e}"),
        )),
        _ => Ok(()),
    }
}

/// Writes a result directory frame by frame under its manifest: it lists the frames
/// first (marked incomplete), then each frame's file is written, then the manifest is
/// marked complete (see [`fusiondet_kitti::results`]).
pub struct ResultWriter {
    out_dir: PathBuf,
    pub(crate) manifest: ResultsManifest,
    /// Held until the writer is dropped: a second detect into the same directory is refused.
    _lock: DirLock,
}

impl ResultWriter {
    /// Opens `out_dir` for the frames `ids`. With `replace`, an earlier detect's files are
    /// removed first (those its manifest lists, nothing else).
    pub fn begin(out_dir: &Path, ids: &[String], replace: bool) -> Result<ResultWriter> {
        check_result_dir(out_dir, replace)?;
        std::fs::create_dir_all(out_dir)
            .map_err(|e| out_err(out_dir, format!("cannot create the result directory: {e}")))?;
        let lock = lock_results(out_dir, false)?;
        // Again under the lock: another detect may have begun since the first look.
        check_result_dir(out_dir, replace)?;
        // Temporary files that killed writes of detect's own files left behind.
        fusiondet_kitti::atomic::remove_temp_files(out_dir, is_result_file);
        remove_earlier_results(out_dir)?;
        let manifest = ResultsManifest {
            complete: false,
            frames: ids.to_vec(),
        };
        write_manifest(out_dir, &manifest)?;
        Ok(ResultWriter {
            out_dir: out_dir.to_path_buf(),
            manifest,
            _lock: lock,
        })
    }

    /// Writes frame `id`'s results.
    pub fn write(&mut self, id: &str, objects: &[Object]) -> Result<()> {
        write_objects(&self.out_dir.join(format!("{id}.txt")), objects)?;
        Ok(())
    }

    /// Writes scene `id`'s SUN RGB-D result lines.
    pub fn write_scene(&mut self, id: &str, objects: &[fusiondet_sunrgbd::Object]) -> Result<()> {
        fusiondet_sunrgbd::write_objects(&self.out_dir.join(format!("{id}.txt")), objects)?;
        Ok(())
    }

    /// Marks the directory complete.
    pub fn finish(mut self) -> Result<()> {
        self.manifest.complete = true;
        write_manifest(&self.out_dir, &self.manifest)?;
        Ok(())
    }
}

/// Takes the result directory's writer lock ([`fusiondet_kitti::atomic::lock_dir`]).
fn lock_results(out_dir: &Path, shared: bool) -> Result<DirLock> {
    fusiondet_kitti::atomic::lock_dir(out_dir, shared)
        .map_err(|e| out_err(out_dir, format!("cannot lock the result directory: {e}")))?
        .ok_or_else(|| {
            out_err(
                out_dir,
                "another detect is writing into this directory now; wait for it to end, or \
                 choose another --out",
            )
        })
}

/// The command name in a result directory's shard records.
const DETECT: &str = "detect";

/// Writes one shard's frames of a result directory under its shard record; the shard that
/// finds every shard finished writes the directory's manifest, as an unsharded run's end
/// does, so the directory is then the same as one detect over the whole split would leave.
pub struct ShardWriter {
    out_dir: PathBuf,
    pub(crate) record: ShardRecord,
    /// Shared with the other shards of the run, held until the writer is dropped: an
    /// unsharded detect into the same directory meanwhile is refused.
    _lock: DirLock,
}

impl ShardWriter {
    /// Opens `out_dir` for shard `shard` of run `run`, writing `frames`. The directory may
    /// be new, empty, or hold other shards of the same run (also a re-run of this shard);
    /// anything else of detect's is replaced only with `replace`, anything not detect's
    /// never.
    pub fn begin(
        out_dir: &Path,
        shard: Shard,
        run: String,
        frames: Vec<String>,
        replace: bool,
    ) -> Result<ShardWriter> {
        std::fs::create_dir_all(out_dir)
            .map_err(|e| out_err(out_dir, format!("cannot create the result directory: {e}")))?;
        let writer_lock = lock_results(out_dir, true)?;
        // Shards starting together take turns to look at and prepare the directory.
        let _lock = shard::lock_records(out_dir)?;
        let earlier = shard::run_records(out_dir, DETECT);
        let same_run = matches!(&earlier, Ok(Some(records)) if records[0].run == run);
        if !same_run {
            match earlier {
                Err(e) if !replace => return Err(e.into()),
                Ok(Some(_)) if !replace => {
                    return Err(out_err(
                        out_dir,
                        "holds the shards of another detect run (another model, \
                         configuration, split or shard count); pass --force to replace them, \
                         or choose another --out",
                    ));
                }
                _ => {}
            }
            check_result_dir(out_dir, replace)?;
            fusiondet_kitti::atomic::remove_temp_files(out_dir, is_result_file);
            remove_earlier_results(out_dir)?;
        }
        let record = ShardRecord {
            command: DETECT.to_string(),
            shard,
            run,
            complete: false,
            frames,
        };
        shard::write_record(out_dir, &record)?;
        Ok(ShardWriter {
            out_dir: out_dir.to_path_buf(),
            record,
            _lock: writer_lock,
        })
    }

    /// Writes frame `id`'s results.
    pub fn write(&mut self, id: &str, objects: &[Object]) -> Result<()> {
        write_objects(&self.out_dir.join(format!("{id}.txt")), objects)?;
        Ok(())
    }

    /// Marks this shard finished; if every shard now is, writes the directory's manifest.
    pub fn finish(mut self) -> Result<shard::ShardProgress> {
        self.record.complete = true;
        shard::write_record(&self.out_dir, &self.record)?;
        let _lock = shard::lock_records(&self.out_dir)?;
        complete_sharded_results(&self.out_dir)
    }
}

/// Checks a sharded detect's result directory and, when every shard finished and every
/// listed frame's file is there, writes its manifest (complete, the split's frames in
/// order). Returns how far the shards have got. `fusiondet merge` runs this too.
pub fn complete_sharded_results(out_dir: &Path) -> Result<shard::ShardProgress> {
    let Some(records) = shard::run_records(out_dir, DETECT)? else {
        return Err(out_err(
            out_dir,
            "holds no shard records of `fusiondet detect --shard`",
        ));
    };
    let progress = shard::progress(out_dir, &records, &|id| PathBuf::from(format!("{id}.txt")));
    if progress.is_whole() {
        let frames = shard::interleave(&records).ok_or_else(|| {
            out_err(
                out_dir,
                "its shard records do not split one list (a record was edited?); run the \
                 shards again with --force",
            )
        })?;
        let manifest = ResultsManifest {
            complete: true,
            frames,
        };
        if read_manifest(out_dir)?.as_ref() != Some(&manifest) {
            write_manifest(out_dir, &manifest)?;
        }
    }
    Ok(progress)
}

/// Whether `name` is one of detect's own files in a result directory: a frame's result
/// (`NNNNNN.txt`) or the manifest.
fn is_result_file(name: &str) -> bool {
    let frame = name
        .strip_suffix(".txt")
        .is_some_and(|id| id.len() == 6 && id.bytes().all(|b| b.is_ascii_digit()));
    frame || name == fusiondet_kitti::results::MANIFEST_FILE
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn shards_share_a_directory_only_with_their_own_run() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("results");
        let split = ids(&["000001", "000002", "000003"]);
        let shard = |i| Shard { index: i, count: 2 };
        let mut w = ShardWriter::begin(
            &out,
            shard(0),
            "run-a".into(),
            shard(0).select(&split),
            false,
        )
        .unwrap();
        w.write("000001", &[]).unwrap();
        w.write("000003", &[]).unwrap();
        let p = w.finish().unwrap();
        assert_eq!(p.missing_shards, vec![1]);
        assert!(
            read_manifest(&out).unwrap().is_none(),
            "no manifest before the last shard"
        );
        // Another run's shard, or an unsharded detect, is refused without --force ...
        let err = ShardWriter::begin(&out, shard(1), "run-b".into(), vec![], false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("shards of another detect run"), "{err}");
        let err = ResultWriter::begin(&out, &split, false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("sharded detect"), "{err}");
        // ... the run's own second shard completes the directory ...
        let mut w = ShardWriter::begin(
            &out,
            shard(1),
            "run-a".into(),
            shard(1).select(&split),
            false,
        )
        .unwrap();
        w.write("000002", &[]).unwrap();
        assert!(w.finish().unwrap().is_whole());
        let manifest = read_manifest(&out).unwrap().unwrap();
        assert!(manifest.complete);
        assert_eq!(manifest.frames, split);
        // ... and --force replaces all of it: files, records and manifest.
        let mut w =
            ShardWriter::begin(&out, Shard::ALL, "run-b".into(), ids(&["000009"]), true).unwrap();
        assert!(!out.join("000001.txt").exists() && read_manifest(&out).unwrap().is_none());
        assert_eq!(shard::read_records(&out).unwrap().len(), 1);
        w.write("000009", &[]).unwrap();
        assert!(w.finish().unwrap().is_whole());
    }

    #[test]
    fn a_result_directory_is_replaced_only_where_it_is_detects_own() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("results");
        let mut w = ResultWriter::begin(&out, &ids(&["000001", "000002"]), false).unwrap();
        w.write("000001", &[]).unwrap();
        // Killed here: the directory is unfinished, with a temporary file left behind.
        drop(w);
        let stale = out.join(".000002.txt.k3Jx9a.tmp");
        std::fs::write(&stale, "partial").unwrap();
        let users = out.join("notes.md");
        std::fs::write(&users, "mine").unwrap();
        // An unfinished detect's directory is replaced without being told.
        let mut w = ResultWriter::begin(&out, &ids(&["000003"]), false).unwrap();
        assert!(!stale.exists() && !out.join("000001.txt").exists());
        assert!(users.is_file(), "only detect's own files are removed");
        w.write("000003", &[]).unwrap();
        w.finish().unwrap();
        let manifest = read_manifest(&out).unwrap().unwrap();
        assert!(manifest.complete);
        assert_eq!(manifest.frames, ids(&["000003"]));
        // A finished one only with `replace`.
        let err = ResultWriter::begin(&out, &ids(&["000004"]), false)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("pass --force"), "{err}");
        assert!(ResultWriter::begin(&out, &ids(&["000004"]), true).is_ok());
        assert!(!out.join("000003.txt").exists());
    }
}
