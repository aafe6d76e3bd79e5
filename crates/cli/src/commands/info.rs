//! `fusiondet info`: the network's configuration summary and per-module parameter table
//! by block (beside F-ConvNet at the same widths for a variant), with the paper's count and
//! our difference where a paper publishes one; for a refinement configuration, its first
//! stage's too and the total of both.

use fusiondet_models::info::{parameter_count, published_two_stage_parameters};
use fusiondet_models::render_info;
use fusiondet_pipeline::ExperimentConfig;
use fusiondet_workflows::{out, outln};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct InfoArgs {
    /// Experiment configuration (TOML, read as `train` reads it: `[detector]`, `[dataset]`,
    /// then the family's sections; a missing key takes its family's published Car value:
    /// F-ConvNet's for the frustum family, Voxel R-CNN's or DASANet's for theirs).
    #[arg(long)]
    pub config: PathBuf,
}

pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    let experiment = ExperimentConfig::from_file(&args.config)?;
    if let (Some(voxel), Some(dasanet)) = (&experiment.voxel_rcnn, &experiment.dasanet) {
        out!(
            "{}",
            fusiondet_pipeline::dasanet::info::render_info(&experiment.name, voxel, dasanet)?
        );
        return Ok(());
    }
    if let Some(section) = &experiment.voxel_rcnn {
        out!(
            "{}",
            fusiondet_pipeline::voxel_rcnn::info::render_info(&experiment.name, section)?
        );
        return Ok(());
    }
    let config = experiment.network();
    let Some(refine) = &experiment.refine else {
        outln!("{}", render_info(&config)?);
        return Ok(());
    };
    let first_path = &refine.first_stage;
    // A first stage that is not trained yet (e.g. `runs/fconvnet-people/model.bpk`) has no
    // configuration to count: the refinement stage's own table still answers.
    let first = match ExperimentConfig::for_checkpoint(first_path, None) {
        Ok(first) => first,
        Err(e) => {
            outln!("Refinement stage ({}):", args.config.display());
            outln!("{}", render_info(&config)?);
            outln!(
                "First stage not counted: {e}
(train it first, or point refine.first_stage at a trained checkpoint)"
            );
            return Ok(());
        }
    };
    outln!("First stage ({}):", first_path.display());
    outln!("{}", render_info(&first.network())?);
    outln!("Refinement stage ({}):", args.config.display());
    outln!("{}", render_info(&config)?);
    let (a, b) = (
        parameter_count(&first.model)?,
        parameter_count(&config.model)?,
    );
    outln!("Both stages: {} parameters ({a} + {b})", a + b);
    if let Some(p) = published_two_stage_parameters(&first.model, &config.model) {
        outln!("{}", p.compare(a + b));
    }
    Ok(())
}
