//! `fusiondet merge`: checks a directory that sharded runs (`--shard i/n`) wrote into and
//! finishes it: every shard ran to its end and every frame has its file, else the missing
//! shards and frames are named and the exit status is non-zero. For a simulated data set
//! and a detect result directory it then writes what the last shard would have (split
//! lists, 2D detections and statistics; the result manifest), so a run whose last shard
//! was killed after its frames can be finished without running again.

use anyhow::{Context, bail};
use fusiondet_kitti::shard;
use fusiondet_workflows::outln;
use std::collections::BTreeSet;
use std::path::PathBuf;

#[derive(clap::Args)]
#[command(after_help = "\
Examples:
  fusiondet merge --dir results/val                       # a sharded detect's results
  fusiondet merge --dir results/val --data DATA --split val   # ... and every val frame has one
  fusiondet merge --dir data/sim-big                      # a sharded simulate
  fusiondet merge --dir pseudo/ --data DATA --split trainval   # pseudo points of every frame")]
pub struct MergeArgs {
    /// A directory sharded runs wrote into: a simulated data set, a detect result
    /// directory, completed depth maps or pseudo points.
    #[arg(long, value_name = "DIR")]
    dir: PathBuf,
    /// Data set root whose --split lists the frames that must all have their output.
    #[arg(long, requires = "split")]
    data: Option<PathBuf>,
    /// Split name (ImageSets/<split>.txt) or a split file.
    #[arg(long, requires = "data")]
    split: Option<String>,
}

pub fn run(args: MergeArgs) -> anyhow::Result<()> {
    if !args.dir.is_dir() {
        bail!("{}: no such directory", args.dir.display());
    }
    let records = shard::read_records(&args.dir)?;
    let commands: BTreeSet<&str> = records.iter().map(|r| r.command.as_str()).collect();
    // A directory detect wrote without shards has a manifest and no records.
    let unsharded_results = commands.is_empty()
        && fusiondet_kitti::read_manifest(&args.dir)?.is_some_and(|m| m.complete);
    if commands.is_empty() && !unsharded_results {
        bail!(
            "{}: holds no shard records (`.fusiondet-shards/`) and no finished detect results; \
             nothing to merge",
            args.dir.display()
        );
    }
    let mut problems = Vec::new();
    for &command in &commands {
        let progress = {
            let _lock = shard::lock_records(&args.dir)?;
            match command {
                "simulate" => fusiondet_sim::complete_sharded_dataset(&args.dir)?.0,
                "detect" => fusiondet_pipeline::complete_sharded_results(&args.dir)?,
                _ => {
                    let records = shard::run_records(&args.dir, command)?.unwrap_or_default();
                    let progress = shard::progress(&args.dir, &records, &|id| {
                        super::shards::frame_file(command, id).unwrap_or_default()
                    });
                    // Every shard finished: the temporary files that killed writes left
                    // behind go, unless a shard is running again (it holds the writer lock).
                    if progress.is_whole()
                        && let Ok(Some(_writer)) =
                            fusiondet_kitti::atomic::lock_dir(&args.dir, false)
                    {
                        let ids: Vec<String> = records
                            .iter()
                            .flat_map(|r| r.frames.iter().cloned())
                            .collect();
                        super::shards::remove_stale_temp_files(command, &args.dir, &ids);
                    }
                    progress
                }
            }
        };
        let frames: usize = shard::run_records(&args.dir, command)?
            .unwrap_or_default()
            .iter()
            .map(|r| r.frames.len())
            .sum();
        if progress.is_whole() {
            outln!(
                "{command}: {} shards, {frames} frames: complete{}",
                progress.count,
                match command {
                    "simulate" => " (split lists, 2D detections and statistics written)",
                    "detect" => " (result manifest written)",
                    _ => "",
                }
            );
        } else {
            outln!("{command}: {}", progress.describe());
            problems.push(format!("{command}: {}", progress.describe()));
        }
    }
    if let (Some(data), Some(split)) = (&args.data, &args.split) {
        let ids = fusiondet_dataset::split_ids(data, split, 0)
            .with_context(|| format!("cannot read split `{split}` of {}", data.display()))?;
        let command = if unsharded_results {
            "detect"
        } else {
            match commands.iter().find(|c| **c != "simulate") {
                Some(c) => *c,
                None => bail!("--split checks per-frame outputs; a simulated data set has none"),
            }
        };
        let missing: Vec<String> = ids
            .iter()
            .filter(|id| {
                let file = super::shards::frame_file(command, id).unwrap_or_default();
                !args.dir.join(file).is_file()
            })
            .cloned()
            .collect();
        if missing.is_empty() {
            outln!(
                "all {} frames of split `{split}` have their output",
                ids.len()
            );
        } else {
            let mut named = missing
                .iter()
                .take(20)
                .cloned()
                .collect::<Vec<_>>()
                .join(", ");
            if missing.len() > 20 {
                named.push_str(&format!(" and {} more", missing.len() - 20));
            }
            problems.push(format!(
                "{} of {} frames of split `{split}` have no output: {named}",
                missing.len(),
                ids.len()
            ));
        }
    }
    if !problems.is_empty() {
        bail!(
            "{} is not complete: {}",
            args.dir.display(),
            problems.join("; ")
        );
    }
    Ok(())
}
