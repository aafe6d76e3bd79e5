//! `fusiondet demo`: the whole pipeline on data built into the binary (see
//! `fusiondet_workflows::demo`).

use fusiondet_workflows::demo::{DemoOptions, ShippedModel};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output directory (sim/, kitti/, run/, model/, results/, pictures/, eval-*.json).
    #[arg(long, default_value = "fusiondet-demo")]
    pub out: PathBuf,
    /// Simulated frames (half train, half val).
    #[arg(long, default_value_t = 16)]
    pub frames: usize,
    /// Seed of the simulated world (and of training, with --train-tiny).
    #[arg(long, default_value_t = 2026)]
    pub seed: u64,
    /// Which shipped Car model detects (all trained on simulated data and built into the
    /// binary; see the README).
    #[arg(long, default_value = "fconvnet", value_parser = ["fconvnet", "fcam", "saf"])]
    pub model: String,
    /// Train the tiny network on the simulated train split and detect with it instead of
    /// a shipped model.
    #[arg(long, conflicts_with = "model")]
    pub train_tiny: bool,
    /// Training epochs of the tiny network (with --train-tiny).
    #[arg(long, default_value_t = 8)]
    pub epochs: usize,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let model: ShippedModel = args.model.parse().map_err(anyhow::Error::msg)?;
    fusiondet_workflows::demo::run(&DemoOptions {
        out: args.out,
        frames: args.frames,
        seed: args.seed,
        model,
        train_tiny: args.train_tiny,
        epochs: args.epochs,
    })
}
