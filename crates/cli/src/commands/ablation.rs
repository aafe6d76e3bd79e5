//! `fusiondet ablation`: trains and evaluates a list of configurations (or evaluates trained
//! checkpoints) on one dataset and
//! prints the seeds' ablation tables (AP3D and APBEV, easy/moderate/hard, AP40 and AP11),
//! the per-occlusion / per-distance / per-LiDAR-points breakdown, and draws the
//! precision–recall curves.
//!
//! The work is `fusiondet_workflows::ablation`; each training runs in a child
//! `fusiondet train` process of this executable.

use crate::commands::train::TrainOverrides;
use anyhow::Context;
use fusiondet_workflows::ablation::AblationOptions;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
#[command(after_help = "\
Writes OUT/runs/<name>/ (training), OUT/results/<name>/ (KITTI result files of the val split), \
OUT/ablation.md (the tables), OUT/ablation.json and OUT/pr-<class>-3d.png / -bev.png \
(precision-recall curves, easy/moderate/hard). Frames/s is detection on the val split \
without reading files from disk (frustums + network + decoding and NMS), divided into frames.")]
pub struct AblationArgs {
    /// Configurations to compare (TOML files), in table order; the first is the baseline.
    /// A refinement config (`[refine]`) refines the nearest first-stage config before it.
    #[arg(long, num_args = 1.., required_unless_present = "models")]
    pub configs: Vec<PathBuf>,
    /// Trained checkpoints to compare instead (nothing is trained), in table order: the
    /// shipped models (`models/*.bpk`, their configuration beside them) or runs'
    /// `model.bpk`; a refinement model brings its first stage. Results go to
    /// OUT/results/<config name>/.
    #[arg(long, num_args = 1.., conflicts_with_all = ["configs", "seeds"])]
    pub models: Vec<PathBuf>,
    /// Dataset root with training/, ImageSets/{train,val}.txt and rgb_detections/.
    #[arg(long)]
    pub data: PathBuf,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Applied to every configuration.
    #[command(flatten)]
    pub overrides: TrainOverrides,
    /// Train every configuration once per seed (e.g. `--seeds 1,2`): runs go to
    /// OUT/runs/<name>/seed-<s>/, and the tables add each configuration's mean over seeds,
    /// their range, and which differences from the baseline exceed it.
    #[arg(long, value_delimiter = ',', conflicts_with = "seed")]
    pub seeds: Vec<u64>,
    /// Resamples of the val frames for the tables of each row's difference from the baseline
    /// with its 95% interval (a paired bootstrap, as `eval --baseline`); 0: no such tables.
    #[arg(long, value_name = "N", default_value_t = 1000)]
    pub resamples: usize,
    /// Seed of those resamples.
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub resample_seed: u64,
}

pub fn run(args: AblationArgs) -> anyhow::Result<()> {
    fusiondet_workflows::ablation::run(&AblationOptions {
        configs: args.configs,
        models: args.models,
        data: args.data,
        out: args.out,
        train_flags: args.overrides.to_args(),
        seeds: args.seeds,
        executable: own_executable()?,
        device: Default::default(),
        resamples: args.resamples,
        resample_seed: args.resample_seed,
    })
}

/// The executable the trainings run in. On Linux this process's own image
/// (`/proc/self/exe`), which stays runnable when the file it was started from is replaced or
/// removed during a long ablation (a rebuild, an upgrade): `current_exe()` then names a path
/// that no longer exists, and the next row could not start.
fn own_executable() -> anyhow::Result<PathBuf> {
    let image = Path::new("/proc/self/exe");
    if cfg!(target_os = "linux") && image.exists() {
        return Ok(image.to_path_buf());
    }
    std::env::current_exe().context("cannot locate the fusiondet binary")
}
