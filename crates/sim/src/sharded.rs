//! `simulate --shard i/n`: n processes share one data set, shard i simulating the frames
//! k with k mod n = i into the same directory (see [`fusiondet_kitti::shard`]). A frame
//! depends only on the seed and its index, so every shard writes exactly the bytes one
//! unsharded run would. What spans all frames (split lists, 2D detection files,
//! statistics) is written once every shard has finished, by the last shard to finish or
//! by `fusiondet merge`, from what each shard kept of its frames
//! (`.fusiondet-shards/simulate-<i>-of-<n>.frames.json`).

use crate::dataset::{
    DatasetOptions, FrameSummary, SimError, create_layout, io_err, read_marker, remove_earlier_run,
    simulate_frames, validate, write_index_files, write_marker,
};
use crate::stats::DatasetStats;
use fusiondet_kitti::DatasetDir;
use fusiondet_kitti::shard::{self, Shard, ShardProgress, ShardRecord};
use std::path::{Path, PathBuf};

/// The command name in a data set's shard records.
pub const SIMULATE: &str = "simulate";

/// How a shard's run ended.
#[derive(Debug, Clone)]
pub struct ShardOutcome {
    /// Frames this shard wrote.
    pub frames: usize,
    /// How far all the run's shards have got.
    pub progress: ShardProgress,
    /// The statistics, once every shard has finished and the index files are written.
    pub stats: Option<DatasetStats>,
}

/// What defines the data set, so that shards of two different ones never share a directory.
fn run_fingerprint(opts: &DatasetOptions, shards: usize) -> String {
    shard::fingerprint(&[
        SIMULATE.as_bytes(),
        opts.frames.to_string().as_bytes(),
        opts.seed.to_string().as_bytes(),
        format!("{:?}", opts.config).as_bytes(),
        shards.to_string().as_bytes(),
    ])
}

/// Where shard `shard` keeps its frames' summaries.
fn frames_path(root: &Path, shard: Shard) -> PathBuf {
    let record = shard::record_path(root, SIMULATE, shard);
    record.with_file_name(format!(
        "{}.frames.json",
        record.file_name().unwrap_or_default().to_string_lossy()
    ))
}

/// Simulates and writes shard `shard` of the data set `opts` describes; `progress(done,
/// total)` counts this shard's frames.
pub fn write_dataset_shard(
    opts: &DatasetOptions,
    shard: Shard,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<ShardOutcome, SimError> {
    validate(opts)?;
    let run = run_fingerprint(opts, shard.count);
    let indices: Vec<usize> = (0..opts.frames).filter(|&k| shard.owns(k)).collect();
    let ds = prepare_shard_dir(opts, shard, &run, &indices)?;
    let summaries = simulate_frames(opts, &ds, &indices, progress)?;
    let json = serde_json::to_string(&summaries)
        .map_err(|e| SimError::InvalidArgument(format!("cannot encode frame summaries: {e}")))?;
    fusiondet_kitti::write_atomic(&frames_path(&opts.out, shard), json.as_bytes())?;
    shard::write_record(
        &opts.out,
        &ShardRecord {
            command: SIMULATE.to_string(),
            shard,
            run,
            complete: true,
            frames: summaries.iter().map(|s| s.id.clone()).collect(),
        },
    )?;
    let (progress, stats) = {
        let _lock = shard::lock_records(&opts.out)?;
        complete_sharded_dataset(&opts.out)?
    };
    Ok(ShardOutcome {
        frames: indices.len(),
        progress,
        stats,
    })
}

/// Opens the output directory for one shard: new, empty, or holding other shards of the
/// same data set (a re-run of this shard too). Anything else is refused, or with --force
/// replaced where it is a data set the simulator wrote (only its own files are removed).
fn prepare_shard_dir(
    opts: &DatasetOptions,
    shard: Shard,
    run: &str,
    indices: &[usize],
) -> Result<DatasetDir, SimError> {
    let root = &opts.out;
    if root.exists() && !root.is_dir() {
        return Err(SimError::InvalidArgument(format!(
            "{}: the output path exists and is not a directory",
            root.display()
        )));
    }
    crate::output_dir::refuse_linked_folders(root)?;
    std::fs::create_dir_all(root).map_err(io_err(root))?;
    // Shards starting together take turns to look at and prepare the directory.
    let _lock = shard::lock_records(root)?;
    let earlier = shard::run_records(root, SIMULATE);
    let same_run = matches!(&earlier, Ok(Some(records)) if records[0].run == run);
    if !same_run {
        let others = std::fs::read_dir(root)
            .map_err(io_err(root))?
            .flatten()
            .any(|e| e.file_name() != shard::SHARDS_DIR);
        let records = !matches!(earlier, Ok(None));
        if (others || records) && !opts.force {
            return Err(SimError::NotEmpty(root.clone()));
        }
        if others || records {
            let Some(frames) = read_marker(root) else {
                return Err(SimError::InvalidArgument(format!(
                    "{}: --force replaces only a data set that `fusiondet simulate` wrote (it \
                     has no {}), and this directory holds other files; choose an empty \
                     directory",
                    root.display(),
                    crate::dataset::MARKER_FILE
                )));
            };
            remove_earlier_run(root, frames)?;
        }
    }
    if read_marker(root) != Some(opts.frames) {
        write_marker(root, opts.frames)?;
    }
    let ds = create_layout(root)?;
    shard::write_record(
        root,
        &ShardRecord {
            command: SIMULATE.to_string(),
            shard,
            run: run.to_string(),
            complete: false,
            frames: indices
                .iter()
                .map(|&k| fusiondet_kitti::frame_id(k))
                .collect(),
        },
    )?;
    Ok(ds)
}

/// Checks a sharded data set and, when every shard finished and every frame is on disk,
/// writes its split lists, 2D detection files and statistics as an unsharded run would.
/// Returns how far the shards have got and, when whole, the statistics. The caller holds
/// the records lock (or nothing else writes the directory).
pub fn complete_sharded_dataset(
    root: &Path,
) -> Result<(ShardProgress, Option<DatasetStats>), SimError> {
    let Some(records) = shard::run_records(root, SIMULATE)? else {
        return Err(SimError::InvalidArgument(format!(
            "{}: holds no shard records of `fusiondet simulate --shard`",
            root.display()
        )));
    };
    // The label is each frame's last file.
    let progress = shard::progress(root, &records, &|id| {
        PathBuf::from(format!("training/label_2/{id}.txt"))
    });
    if !progress.is_whole() {
        return Ok((progress, None));
    }
    let order = shard::interleave(&records).ok_or_else(|| {
        SimError::InvalidArgument(format!(
            "{}: its shard records do not split one frame list; run the shards again with \
             --force",
            shard::shards_dir(root).display()
        ))
    })?;
    let mut by_id = std::collections::HashMap::new();
    for r in &records {
        let path = frames_path(root, r.shard);
        let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
        let summaries: Vec<FrameSummary> = serde_json::from_str(&text).map_err(|e| {
            SimError::InvalidArgument(format!(
                "{}: cannot read the shard's frame summaries ({e}); run shard {} again",
                path.display(),
                r.shard
            ))
        })?;
        by_id.extend(summaries.into_iter().map(|s| (s.id.clone(), s)));
    }
    let summaries = order
        .iter()
        .map(|id| {
            by_id.remove(id).ok_or_else(|| {
                SimError::InvalidArgument(format!(
                    "{}: no frame summary of frame {id}; run its shard again",
                    shard::shards_dir(root).display()
                ))
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let stats = write_index_files(&DatasetDir::new(root), root, summaries)?;
    Ok((progress, Some(stats)))
}
