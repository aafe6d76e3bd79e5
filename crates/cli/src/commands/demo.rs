//! `fusiondet demo`: the whole pipeline on data built into the binary (see
//! `fusiondet_workflows::demo`); with `--indoor`, on simulated rooms and the real SUN RGB-D
//! scene (see `fusiondet_workflows::indoor_demo`).

use anyhow::bail;
use fusiondet_workflows::demo::{DemoOptions, ShippedModel};
use fusiondet_workflows::indoor_demo::IndoorDemoOptions;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output directory (sim/, kitti/ or real/, run/, model/, results/, pictures/,
    /// eval-*.json) [default: fusiondet-demo; fusiondet-demo-indoor with --indoor].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Simulated frames, half train, half val [default: 16; 24 rooms with --indoor].
    #[arg(long)]
    pub frames: Option<usize>,
    /// Seed of the simulated world (and of training, with --train-tiny or --indoor).
    #[arg(long, default_value_t = 2026)]
    pub seed: u64,
    /// Which shipped model detects (all trained on simulated data and built into the
    /// binary; see the README): a Car model, or with `-people` a Pedestrian + Cyclist one;
    /// `fconvnet-refine*` is F-ConvNet with its refinement stage.
    #[arg(long, default_value = "fconvnet", value_parser = clap::builder::PossibleValuesParser::new(ShippedModel::names()))]
    pub model: String,
    /// Train the tiny network on the simulated train split and detect with it instead of
    /// a shipped model.
    #[arg(long, conflicts_with = "model")]
    pub train_tiny: bool,
    /// Indoor: simulate rooms, train the tiny network on SUN RGB-D's ten classes, detect
    /// on the simulated val rooms and on the bundled real SUN RGB-D scene, evaluate with
    /// the indoor protocol and draw pictures.
    #[arg(long, conflicts_with_all = ["model", "train_tiny"])]
    pub indoor: bool,
    /// Training epochs of the tiny network (with --train-tiny or --indoor)
    /// [default: 8; 15 with --indoor].
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Points kept per simulated room (with --indoor) [default: 20000].
    #[arg(long)]
    pub points: Option<usize>,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if args.indoor {
        return fusiondet_workflows::indoor_demo::run(&IndoorDemoOptions {
            out: args
                .out
                .unwrap_or_else(|| PathBuf::from("fusiondet-demo-indoor")),
            frames: args.frames.unwrap_or(24),
            seed: args.seed,
            epochs: args.epochs.unwrap_or(15),
            points: args.points.unwrap_or(20_000),
        });
    }
    if args.points.is_some() {
        bail!("--points is for --indoor");
    }
    let model: ShippedModel = args.model.parse().map_err(anyhow::Error::msg)?;
    fusiondet_workflows::demo::run(&DemoOptions {
        out: args.out.unwrap_or_else(|| PathBuf::from("fusiondet-demo")),
        frames: args.frames.unwrap_or(16),
        seed: args.seed,
        model,
        train_tiny: args.train_tiny,
        epochs: args.epochs.unwrap_or(8),
    })
}
