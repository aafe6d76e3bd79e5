//! `fusiondet`: camera + LiDAR 3D object detection on KITTI-format data.

mod commands;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "fusiondet", version, about = "Camera + LiDAR 3D object detection on KITTI-format data")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Official KITTI object evaluation (devkit-exact AP11/AP40, bbox/bev/3d/aos).
    Eval(commands::eval::EvalArgs),
    /// Draw a frame: image with projected 3D boxes above a bird's-eye view.
    Viz(commands::viz::VizArgs),
    /// Simulate a LiDAR + camera dataset in KITTI format.
    Simulate(commands::simulate::SimulateArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Eval(args) => commands::eval::run(args),
        Command::Viz(args) => commands::viz::run(args),
        Command::Simulate(args) => commands::simulate::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
