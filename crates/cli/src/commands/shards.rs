//! `--shard i/n` for the per-frame commands with nothing to finish at the end
//! (`depth-complete`, `pseudo-points`): the shard's frames and its record before and after
//! (see `fusiondet_kitti::shard`). `detect` and `simulate` keep theirs in their crates,
//! since their last shard writes what spans all frames.

use anyhow::bail;
use fusiondet_kitti::Shard;
use fusiondet_kitti::shard::{self, ShardProgress, ShardRecord};
use fusiondet_workflows::outln;
use std::path::{Path, PathBuf};

/// The file each command writes per frame, by the command's name in shard records.
pub fn frame_file(command: &str, id: &str) -> Option<PathBuf> {
    let name = match command {
        "detect" => format!("{id}.txt"),
        "depth-complete" => format!("{id}.png"),
        "pseudo-points" => format!("{id}.bin"),
        "simulate" => format!("training/label_2/{id}.txt"),
        _ => return None,
    };
    Some(PathBuf::from(name))
}

/// Runs `work` on shard `shard` of `ids` (all of them without a shard), recording the
/// shard in `out_dir` before and after; `run` lists what defines the run (options, inputs)
/// and the fingerprint adds what the frames of `frames` are ([`shard::frames_summary`]), so
/// that another run's shards are never mixed into the same directory. The directory's
/// writer lock is held throughout (shared between the shards of a run, exclusive for an
/// unsharded one), and the temporary files that killed writes of this run's frames left
/// behind are removed first.
pub fn run_frames<T>(
    command: &str,
    out_dir: &Path,
    shard: Option<Shard>,
    run: &[&[u8]],
    frames: &fusiondet_kitti::FrameDir,
    ids: Vec<String>,
    work: impl FnOnce(&[String]) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    let Some(shard) = shard else {
        let _lock = lock_out_dir(command, out_dir, false)?;
        remove_stale_temp_files(command, out_dir, &ids);
        return work(&ids);
    };
    let fingerprint = {
        let count = shard.count.to_string();
        let list = ids.join("\n");
        let frames_summary = shard::frames_summary(frames, &ids);
        let mut parts = run.to_vec();
        parts.extend([
            frames_summary.as_slice(),
            command.as_bytes(),
            list.as_bytes(),
            count.as_bytes(),
        ]);
        shard::fingerprint(&parts)
    };
    let mine = shard.select(&ids);
    let _writer_lock = lock_out_dir(command, out_dir, true)?;
    let mut record = ShardRecord {
        command: command.to_string(),
        shard,
        run: fingerprint,
        complete: false,
        frames: mine.clone(),
    };
    {
        let _lock = shard::lock_records(out_dir)?;
        if let Some(earlier) = shard::run_records(out_dir, command)?
            && earlier[0].run != record.run
        {
            bail!(
                "{}: holds the shards of another `{command}` run (other inputs, options or \
                 shard count); choose another output directory",
                out_dir.display()
            );
        }
        shard::write_record(out_dir, &record)?;
    }
    remove_stale_temp_files(command, out_dir, &mine);
    let result = work(&mine)?;
    record.complete = true;
    shard::write_record(out_dir, &record)?;
    let records = shard::run_records(out_dir, command)?.unwrap_or_default();
    let progress = shard::progress(out_dir, &records, &|id| {
        frame_file(command, id).unwrap_or_default()
    });
    report(shard, out_dir, &progress);
    Ok(result)
}

/// Creates `out_dir` and takes its writer lock ([`fusiondet_kitti::atomic::lock_dir`]).
fn lock_out_dir(
    command: &str,
    out_dir: &Path,
    shared: bool,
) -> anyhow::Result<fusiondet_kitti::atomic::DirLock> {
    std::fs::create_dir_all(out_dir)
        .map_err(|e| anyhow::anyhow!("{}: cannot create: {e}", out_dir.display()))?;
    match fusiondet_kitti::atomic::lock_dir(out_dir, shared) {
        Ok(Some(lock)) => Ok(lock),
        Ok(None) => bail!(
            "{}: another `fusiondet {command}` (or another shard count's run) is writing into \
             this directory now; wait for it to end, or choose another --out-dir",
            out_dir.display()
        ),
        Err(e) => bail!("{}: cannot lock: {e}", out_dir.display()),
    }
}

/// Removes the temporary files that killed writes of the frames `ids` left in `out_dir`
/// (the caller owns those frames: no other writer is writing them).
pub fn remove_stale_temp_files(command: &str, out_dir: &Path, ids: &[String]) {
    let mine: std::collections::HashSet<PathBuf> = ids
        .iter()
        .filter_map(|id| frame_file(command, id))
        .collect();
    fusiondet_kitti::atomic::remove_temp_files(out_dir, |target| mine.contains(Path::new(target)));
}

/// A path as one string for a run's fingerprint, links resolved where it exists.
pub fn canonical(path: &Path) -> String {
    path.canonicalize()
        .unwrap_or_else(|_| path.to_path_buf())
        .display()
        .to_string()
}

/// The line a finished shard prints.
pub fn report(shard: Shard, out_dir: &Path, progress: &ShardProgress) {
    if progress.is_whole() {
        outln!(
            "shard {shard} done: every shard has finished; {} is complete",
            out_dir.display()
        );
    } else {
        outln!(
            "shard {shard} done; the run is not complete yet ({}); `fusiondet merge --dir {}` \
             checks it",
            progress.describe(),
            out_dir.display()
        );
    }
}
