//! The ω study (see `fusiondet_frustum::omega_study`) over a KITTI-layout directory.
//!
//! `cargo run -p fusiondet-frustum --release --example omega_study -- [DIR] [car|people] [SEED] [COPIES]`
//!
//! DIR is a `training` directory (calib, velodyne, label_2; default: the bundled
//! sample frames); every frame with a label file is used. The frustums are the
//! preset's training frustums: COPIES (default 5) jittered 2D boxes per object.

use fusiondet_frustum::{
    DEFAULT_OMEGAS, DepthGuidedSlicing, FrustumConfig, InMemoryFrames, Slicing,
    omega_study_from_labels,
};
use fusiondet_kitti::FrameDir;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = args.first().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training")
    });
    let config = match args.get(1).map(String::as_str) {
        None | Some("car") => FrustumConfig::saf_car(),
        Some("people") => FrustumConfig {
            slicing: Slicing::DepthGuided(DepthGuidedSlicing::saf_car()),
            ..FrustumConfig::pedestrian_cyclist()
        },
        Some(other) => return Err(format!("unknown preset `{other}` (car or people)").into()),
    };
    let seed: u64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(0);
    let mut config = config;
    if let Some(c) = args.get(3) {
        config.augment.copies = c.parse()?;
    }
    let mut ids: Vec<String> = std::fs::read_dir(dir.join("label_2"))?
        .filter_map(|e| {
            let name = e.ok()?.file_name().into_string().ok()?;
            name.strip_suffix(".txt").map(str::to_string)
        })
        .collect();
    ids.sort();
    let frames = InMemoryFrames::load(&FrameDir::new(dir), &ids, true)?;
    let study = omega_study_from_labels(frames, &config, seed, &DEFAULT_OMEGAS)?;
    println!("{} frames, classes {:?}", ids.len(), config.classes);
    println!("{study}");
    Ok(())
}
