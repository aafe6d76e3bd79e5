//! Pseudo voxels per frame as DASANet's training and detection make them (issue 34):
//! for each frame of a split, the pseudo points in range, the voxels they fill with no
//! cap, and per rule (training: augmentation, without ground-truth pasting, and the voxel
//! cap's shuffle drawn from `SEED`; detection) the voxels kept and the in-range points no voxel mean includes.
//!
//! `cargo run --release -p fusiondet-pipeline --example dasanet_pseudo_voxels --
//! CONFIG.toml DATA_DIR SPLIT MAX_FRAMES SEED`

use fusiondet_dataset::rng::Sampler;
use fusiondet_dataset::{SensorFrame, split_ids};
use fusiondet_kitti::DatasetDir;
use fusiondet_pipeline::ExperimentConfig;
use fusiondet_pipeline::dasanet::detection_data;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [config, data_dir, split, max_frames, seed] = args.as_slice() else {
        return Err(
            "usage: dasanet_pseudo_voxels CONFIG.toml DATA_DIR SPLIT MAX_FRAMES SEED".into(),
        );
    };
    let config = ExperimentConfig::from_file(Path::new(config))?;
    let (Some(voxel), Some(dasanet)) = (&config.voxel_rcnn, &config.dasanet) else {
        return Err("not a DASANet configuration".into());
    };
    // No ground-truth database here: training's augmentation runs without pasting objects
    // (a few pasted boxes' points would not change the caps' effect on a frame).
    let mut voxel = voxel.clone();
    voxel.augment.sample_groups.clear();
    let data = detection_data(&voxel, dasanet)?;
    let seed: u64 = seed.parse()?;
    let ids = split_ids(Path::new(data_dir), split, max_frames.parse()?)?;
    let dir = DatasetDir::new(data_dir).training();
    let p = &dasanet.pseudo;
    println!(
        "{} (caps: training {}, detection {}; same_voxels_as_test {}), {} frames of {split}, seed {seed}",
        config.name,
        p.max_voxels_train,
        p.max_voxels_test,
        p.same_voxels_as_test,
        ids.len()
    );
    println!(
        "frame | in range | voxels uncapped | train: voxels, points left out | test: voxels, points left out"
    );
    for (k, id) in ids.iter().enumerate() {
        let frame = SensorFrame::load(&dir, id, true)?;
        let cloud = data.pseudo.cloud(&frame, None)?;
        let uncapped =
            data.voxel
                .voxelizer
                .voxelize_pseudo(&cloud, p.max_points_per_voxel, usize::MAX, None);
        let mut rng = Sampler::new(seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
        let train = data.sample_with_cloud(&frame, cloud.clone(), Some(&mut rng))?;
        let test = data.sample_with_cloud(&frame, cloud, None)?;
        let left_out = |v: &fusiondet_voxel::Voxels| {
            v.points_in_range - v.num_points.iter().map(|&n| n as usize).sum::<usize>()
        };
        println!(
            "{id} | {} | {} | {}, {} | {}, {}",
            uncapped.points_in_range,
            uncapped.len(),
            train.pseudo_voxels.len(),
            left_out(&train.pseudo_voxels),
            test.pseudo_voxels.len(),
            left_out(&test.pseudo_voxels),
        );
    }
    Ok(())
}
