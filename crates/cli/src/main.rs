//! `fusiondet`: camera + LiDAR 3D object detection on KITTI-format data.

mod commands;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// mimalloc, keeping freed memory committed (`fusiondet_alloc` says why).
#[global_allocator]
static ALLOCATOR: fusiondet_alloc::MiMalloc = fusiondet_alloc::MiMalloc;

#[derive(Parser)]
#[command(
    name = "fusiondet",
    version,
    about = "Camera + LiDAR 3D object detection on KITTI-format data"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole pipeline on data built into the binary: simulate street frames, detect
    /// with a shipped model (training a tiny one only with --train-tiny), evaluate, draw;
    /// --indoor: simulated rooms (trains the tiny indoor network) and a real SUN RGB-D scene.
    Demo(commands::demo::DemoArgs),
    /// Train a detector (the frustum family, Voxel R-CNN or DASANet) from a TOML experiment
    /// configuration, on KITTI-format data or (frustum family) prepared SUN RGB-D scenes.
    Train(commands::train::TrainArgs),
    /// Detect 3D boxes with a trained checkpoint and write result files (KITTI's, or SUN
    /// RGB-D's for a model trained on it).
    Detect(commands::detect::DetectArgs),
    /// Print a network's per-module parameter table.
    Info(commands::info::InfoArgs),
    /// Official KITTI object evaluation (devkit-exact AP11/AP40, bbox/bev/3d/aos), or with
    /// --dataset sunrgbd SUN RGB-D's indoor evaluation (VoteNet's protocol, exact IoU).
    Eval(commands::eval::EvalArgs),
    /// Draw a frame: image with projected 3D boxes above a bird's-eye view (KITTI frames or
    /// prepared SUN RGB-D scenes).
    Viz(commands::viz::VizArgs),
    /// Interactive 3D pages of frames (self-contained HTML): points, boxes, image, toggles.
    View(commands::view::ViewArgs),
    /// Simulate a LiDAR + camera dataset in KITTI format, or (--indoor) RGB-D rooms as a
    /// prepared SUN RGB-D data set.
    Simulate(commands::simulate::SimulateArgs),
    /// Train and evaluate several configurations on one dataset: ablation tables and PR plots.
    Ablation(commands::ablation::AblationArgs),
    /// Choose SAF's ω: what the near sub-frustum takes from objects and clutter, per ω.
    OmegaStudy(commands::omega_study::OmegaStudyArgs),
    /// Detection speed of a trained model: frames/s and time per stage (medians).
    Bench(commands::bench::BenchArgs),
    /// Build the ground-truth database (objects and their points) Voxel R-CNN's augmentation pastes from.
    GtDatabase(commands::gt_database::GtDatabaseArgs),
    /// Dense depth from sparse depth (IP-Basic), or from each frame's projected LiDAR scan.
    DepthComplete(commands::depth_complete::DepthCompleteArgs),
    /// Coloured pseudo point clouds from completed depth (DASANet's second input).
    PseudoPoints(commands::pseudo_points::PseudoPointsArgs),
    /// Check (and finish) a directory that sharded runs (`--shard i/n`) wrote into.
    Merge(commands::merge::MergeArgs),
    /// Compare two result directories box by box (CPU against GPU, one build against another).
    Compare(commands::compare::CompareArgs),
}

fn main() -> ExitCode {
    fusiondet_alloc::keep_freed_memory();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo(args) => commands::demo::run(args),
        Command::Train(args) => commands::train::run(args),
        Command::Detect(args) => commands::detect::run(args),
        Command::Info(args) => commands::info::run(args),
        Command::Eval(args) => commands::eval::run(args),
        Command::Viz(args) => commands::viz::run(args),
        Command::View(args) => commands::view::run(args),
        Command::Simulate(args) => commands::simulate::run(args),
        Command::Ablation(args) => commands::ablation::run(args),
        Command::OmegaStudy(args) => commands::omega_study::run(args),
        Command::Bench(args) => commands::bench::run(args),
        Command::GtDatabase(args) => commands::gt_database::run(args),
        Command::DepthComplete(args) => commands::depth_complete::run(args),
        Command::PseudoPoints(args) => commands::pseudo_points::run(args),
        Command::Merge(args) => commands::merge::run(args),
        Command::Compare(args) => commands::compare::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", error_message(&err));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, `a: b: c`, leaving out a cause whose text the
/// line already holds: an error that prints its source (`path: No such file (os error
/// 2)`) would otherwise be followed by that source again.
fn error_message(err: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if message.contains(&text) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_already_in_the_message_is_not_repeated() {
        #[derive(Debug)]
        struct WithSource {
            path: String,
            source: std::io::Error,
        }
        impl std::fmt::Display for WithSource {
            fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "{}: {}", self.path, self.source)
            }
        }
        impl std::error::Error for WithSource {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.source)
            }
        }
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "gone (os error 2)");
        let err = anyhow::Error::new(WithSource {
            path: "a.txt".into(),
            source: io,
        })
        .context("cannot read the split");
        assert_eq!(
            error_message(&err),
            "cannot read the split: a.txt: gone (os error 2)"
        );
    }
}
