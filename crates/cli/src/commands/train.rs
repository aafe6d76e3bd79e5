//! `fusiondet train`: trains a frustum detector from a TOML experiment configuration.

use fusiondet_train::{ExperimentConfig, TrainOptions, train};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct TrainArgs {
    /// Experiment configuration (TOML: [frustum], [model], [loss], [train], [detect]).
    #[arg(long)]
    pub config: PathBuf,
    /// Dataset root with training/ and ImageSets/ (e.g. made by `fusiondet simulate`).
    #[arg(long)]
    pub data: PathBuf,
    /// Run directory: checkpoints, metrics.jsonl, model.bpk.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the run in --out from its last finished epoch.
    #[arg(long)]
    pub resume: bool,
    /// Override train.epochs.
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Override train.seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override train.max_frames (0 = all frames of the split).
    #[arg(long)]
    pub max_frames: Option<usize>,
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let mut config = ExperimentConfig::from_file(&args.config)?;
    if let Some(e) = args.epochs {
        config.train.epochs = e;
    }
    if let Some(s) = args.seed {
        config.train.seed = s;
    }
    if let Some(m) = args.max_frames {
        config.train.max_frames = m;
    }
    let summary = train(&TrainOptions {
        config,
        data_dir: args.data,
        run_dir: args.out,
        resume: args.resume,
        progress: std::io::stderr().is_terminal(),
    })?;
    println!(
        "trained on {} frustums from {} frames: {} epoch(s) run, {} done, final loss {}",
        summary.frustums,
        summary.frames,
        summary.epochs_run,
        summary.epochs_done,
        summary
            .final_loss
            .map_or("-".to_string(), |l| format!("{l:.4}"))
    );
    println!("model: {}", summary.model.display());
    Ok(())
}
