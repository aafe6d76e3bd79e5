//! `fusiondet info`: the network's configuration summary and per-module parameter table.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct InfoArgs {
    /// Model configuration: TOML with `[model]` and `[loss]` tables (missing keys take the
    /// published F-ConvNet Car values; other tables are ignored).
    #[arg(long)]
    pub config: PathBuf,
}

pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    let config = fusiondet_models::FConvNetConfig::from_toml_file(&args.config)?;
    println!("{}", fusiondet_models::render_info(&config)?);
    Ok(())
}
