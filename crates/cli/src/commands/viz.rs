//! `fusiondet viz` (being written).

#[derive(clap::Args)]
pub struct VizArgs {}

pub fn run(_args: VizArgs) -> anyhow::Result<()> {
    anyhow::bail!("`fusiondet viz` is not available yet")
}
