//! `fusiondet simulate` (being written).

#[derive(clap::Args)]
pub struct SimulateArgs {}

pub fn run(_args: SimulateArgs) -> anyhow::Result<()> {
    anyhow::bail!("`fusiondet simulate` is not available yet")
}
