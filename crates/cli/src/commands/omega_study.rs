//! `fusiondet omega-study`: measures, for candidate ω, what SAF's near "not-interesting"
//! sub-frustum (length ω·L_depth) takes from the objects and from the clutter in front of
//! them, on a dataset's ground-truth frustums, and recommends the largest ω that loses
//! under 1% of the objects' own points (the paper does not give ω).

use fusiondet_frustum::load_split;
use fusiondet_frustum::{DEFAULT_OMEGAS, Slicing, omega_study_from_labels};
use fusiondet_pipeline::ExperimentConfig;
use fusiondet_workflows::out;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct OmegaStudyArgs {
    /// Dataset root with training/ and ImageSets/.
    #[arg(long)]
    pub data: PathBuf,
    /// A configuration with depth-guided slicing (e.g. configs/saf-car.toml).
    #[arg(long)]
    pub config: PathBuf,
    /// Split to study.
    #[arg(long, default_value = "train")]
    pub split: String,
    /// Use at most this many frames of the split (0 = all).
    #[arg(long, default_value_t = 0)]
    pub max_frames: usize,
}

pub fn run(args: OmegaStudyArgs) -> anyhow::Result<()> {
    let config = ExperimentConfig::from_file(&args.config)?;
    if !matches!(config.frustum.slicing, Slicing::DepthGuided(_)) {
        anyhow::bail!(
            "{}: the study needs `[frustum.slicing] kind = \"depth_guided\"` (SAF's slicing)",
            args.config.display()
        );
    }
    super::data_root::check_root("--data", &args.data)?;
    let frames = load_split(&args.data, &args.split, args.max_frames, true)?;
    let study =
        omega_study_from_labels(frames, &config.frustum, config.train.seed, &DEFAULT_OMEGAS)?;
    out!("{study}");
    Ok(())
}
