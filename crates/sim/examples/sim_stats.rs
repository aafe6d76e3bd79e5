//! Simulates frames in memory and prints the realism report and timings:
//! `cargo run --release -p fusiondet-sim --example sim_stats -- [frames] [seed] [png-dir]`.

use fusiondet_sim::{DatasetStats, FrameStats, SimConfig, simulate_frame};
use rayon::prelude::*;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(20);
    let seed: u64 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(1);
    let png_dir = args.get(3);
    let cfg = SimConfig::default();
    let t = Instant::now();
    let stats: Vec<FrameStats> = (0..n)
        .into_par_iter()
        .map(|i| {
            let f = simulate_frame(seed, i, &cfg);
            if let Some(dir) = png_dir
                && i < 6
            {
                f.image.save(format!("{dir}/{}.png", f.id)).unwrap();
            }
            FrameStats::from_frame(&f)
        })
        .collect();
    let secs = t.elapsed().as_secs_f64();
    if let Ok(path) = std::env::var("SIM_RECORDS") {
        // One JSON line per frame, for offline analysis.
        let lines: Vec<String> = stats
            .iter()
            .map(|f| serde_json::to_string(f).unwrap())
            .collect();
        std::fs::write(path, lines.join("\n")).unwrap();
    }
    println!("{}", DatasetStats::from_frames(&stats).report());
    println!("{n} frames in {secs:.2} s: {:.2} frames/s", n as f64 / secs);
}
