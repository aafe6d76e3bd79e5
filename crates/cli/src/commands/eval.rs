//! `fusiondet eval` (being written).

#[derive(clap::Args)]
pub struct EvalArgs {}

pub fn run(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("`fusiondet eval` is not available yet")
}
