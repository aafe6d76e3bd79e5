//! Writes a simulated dataset without the CLI (same files as `fusiondet simulate`):
//! `cargo run --release -p fusiondet-sim --example write_dataset -- OUT [frames] [seed]`.

use fusiondet_sim::{DatasetOptions, SimConfig, write_dataset};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let out = args
        .get(1)
        .expect("usage: write_dataset OUT [frames] [seed]");
    let frames = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
    let seed = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(0);
    let opts = DatasetOptions {
        out: out.into(),
        frames,
        seed,
        force: true,
        config: SimConfig::default(),
    };
    match write_dataset(&opts, &|_, _| {}) {
        Ok(stats) => print!("{}", stats.report()),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
