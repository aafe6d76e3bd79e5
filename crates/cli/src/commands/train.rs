//! `fusiondet train`: trains a detector of any family from a TOML experiment configuration.

use fusiondet_pipeline::{ComputeDevice, ExperimentConfig, PipelineError, TrainOptions, train};
use fusiondet_workflows::outln;
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct TrainArgs {
    /// Experiment configuration (TOML): `[detector] kind` and `[dataset] format`, `classes`
    /// (both required), then the family's sections (frustum: [frustum], [model], [loss];
    /// voxel_rcnn: [voxel_rcnn]; dasanet: [voxel_rcnn] and [dasanet]) and [train], [detect].
    /// configs/ holds one for every model.
    #[arg(long)]
    pub config: PathBuf,
    /// Dataset root with training/ and ImageSets/ (e.g. made by `fusiondet simulate`), or a
    /// prepared SUN RGB-D directory for a `[dataset] format = "sun_rgbd"` config.
    #[arg(long)]
    pub data: PathBuf,
    /// Run directory: checkpoints, metrics.jsonl, model.bpk.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the run in --out from its last finished epoch.
    #[arg(long)]
    pub resume: bool,
    #[command(flatten)]
    pub overrides: TrainOverrides,
    /// Refinement configs: the first-stage checkpoint whose boxes are refined
    /// (overrides refine.first_stage).
    #[arg(long)]
    pub first_stage: Option<PathBuf>,
    /// Where the network trains: `cpu`; `wgpu`, `cuda` or `cuda:N` in builds with the cargo
    /// feature of that name.
    #[arg(long, default_value = "cpu")]
    pub device: ComputeDevice,
}

/// `[train]` values given on the command line (`train`, and `ablation` for every config).
#[derive(clap::Args)]
pub struct TrainOverrides {
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

impl TrainOverrides {
    pub fn apply(&self, config: &mut ExperimentConfig) {
        if let Some(e) = self.epochs {
            config.train.epochs = e;
        }
        if let Some(s) = self.seed {
            config.train.seed = s;
        }
        if let Some(m) = self.max_frames {
            config.train.max_frames = m;
        }
    }

    /// The same overrides as `fusiondet train` flags.
    pub fn to_args(&self) -> Vec<String> {
        [
            ("--epochs", self.epochs.map(|v| v.to_string())),
            ("--seed", self.seed.map(|v| v.to_string())),
            ("--max-frames", self.max_frames.map(|v| v.to_string())),
        ]
        .into_iter()
        .filter_map(|(flag, value)| Some([flag.to_string(), value?]))
        .flatten()
        .collect()
    }
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let mut config = ExperimentConfig::from_file(&args.config)?;
    args.overrides.apply(&mut config);
    if let Some(path) = args.first_stage {
        let Some(refine) = &mut config.refine else {
            anyhow::bail!(
                "--first-stage: {} has no [refine] table; only a refinement stage has a first stage",
                args.config.display()
            );
        };
        refine.first_stage = path;
    }
    super::data_root::check_root("--data", &args.data)?;
    stop_on_ctrl_c();
    let summary = match train(&TrainOptions {
        config,
        data_dir: args.data,
        run_dir: args.out,
        resume: args.resume,
        progress: std::io::stderr().is_terminal(),
        device: args.device,
    }) {
        Ok(summary) => summary,
        Err(e @ PipelineError::Interrupted { .. }) => {
            eprintln!("{e}");
            // The shell's code for a process ended by SIGINT.
            std::process::exit(130);
        }
        Err(e) => return Err(e.into()),
    };
    outln!(
        "trained on {}: {} epoch(s) run, {} done, final loss {}",
        if summary.sample_noun == "frames" {
            let skipped = summary.frames - summary.samples;
            format!(
                "{} frames{}",
                summary.samples,
                if skipped > 0 {
                    format!(" ({skipped} without a LiDAR point in range skipped)")
                } else {
                    String::new()
                }
            )
        } else {
            format!(
                "{} {} from {} frames",
                summary.samples, summary.sample_noun, summary.frames
            )
        },
        summary.epochs_run,
        summary.epochs_done,
        summary
            .final_loss
            .map_or("-".to_string(), |l| format!("{l:.4}"))
    );
    outln!("model: {}", summary.model.display());
    Ok(())
}

/// Ctrl-C asks the training to stop at its next step (the run keeps its committed epochs
/// and says how to resume); a second Ctrl-C ends the process at once.
#[cfg(unix)]
fn stop_on_ctrl_c() {
    use std::sync::atomic::Ordering;
    extern "C" fn on_sigint(_: libc::c_int) {
        // Only async-signal-safe work here: an atomic swap and _exit.
        if fusiondet_pipeline::trainer::STOP_REQUESTED.swap(true, Ordering::SeqCst) {
            // SAFETY: _exit is async-signal-safe.
            unsafe { libc::_exit(130) };
        }
    }
    let handler: extern "C" fn(libc::c_int) = on_sigint;
    // SAFETY: installs a handler that only touches an atomic and calls _exit.
    unsafe { libc::signal(libc::SIGINT, handler as libc::sighandler_t) };
}

#[cfg(not(unix))]
fn stop_on_ctrl_c() {}
