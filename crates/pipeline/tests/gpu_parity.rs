//! CPU–GPU parity (cargo features `wgpu` and `cuda`): the shipped F-ConvNet, Voxel R-CNN and
//! DASANet Car models give the same boxes on burn's wgpu or CUDA backend as on the CPU for the
//! bundled KITTI val frames, within a stated tolerance (f32 kernels that sum in another order:
//! centres and sizes within 2 cm, headings within 0.02 rad, scores within 0.005), and the tiny
//! voxel-family configurations train to the same first-epoch loss. Where the backend finds no
//! adapter, driver or device the test says so and passes.
#![cfg(any(feature = "wgpu", feature = "cuda"))]

use burn::prelude::Device;
use fusiondet_pipeline::{
    ComputeDevice, Detector, ExperimentConfig, SideInputs, StageTimes, TrainOptions, train,
};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[cfg(feature = "wgpu")]
#[test]
fn shipped_models_give_the_same_boxes_on_wgpu_as_on_the_cpu() {
    parity(ComputeDevice::Wgpu, "wgpu");
}

#[cfg(feature = "cuda")]
#[test]
fn shipped_models_give_the_same_boxes_on_cuda_as_on_the_cpu() {
    parity(ComputeDevice::Cuda(0), "CUDA");
}

#[cfg(feature = "wgpu")]
#[test]
fn the_voxel_family_trains_to_the_same_first_losses_on_wgpu_as_on_the_cpu() {
    training_parity(ComputeDevice::Wgpu, "wgpu", VOXEL_FAMILY, true);
}

/// The frustum family's attention and SAF's parts on wgpu: CBAM's per-frustum sums and
/// gathers, LFA's gathers, the PointNet scales' pooling windows all add repeated rows by
/// their readers (`RowGather`).
#[cfg(feature = "wgpu")]
#[test]
fn the_frustum_family_trains_to_the_same_first_losses_on_wgpu_as_on_the_cpu() {
    training_parity(ComputeDevice::Wgpu, "wgpu", FRUSTUM_FAMILY, true);
}

#[cfg(feature = "cuda")]
#[test]
fn the_voxel_family_trains_to_the_same_first_losses_on_cuda_as_on_the_cpu() {
    training_parity(ComputeDevice::Cuda(0), "CUDA", VOXEL_FAMILY, false);
}

/// The voxel family's stage one on the threads that prepare frames (the default) and on
/// the network's thread give the same boxes to the bit on wgpu: the shipped Voxel R-CNN
/// and DASANet on the bundled val frames (stage one of the next frames on the preparing
/// threads' device streams while the network's thread takes a frame through stage two).
#[cfg(feature = "wgpu")]
#[test]
fn stage_one_on_the_preparing_threads_gives_the_same_boxes_on_wgpu() {
    use fusiondet_pipeline::SplitInputs;
    let gpu = ComputeDevice::Wgpu;
    if let Err(why) = gpu.check() {
        eprintln!("skipped: {why}; stage one ahead was not checked");
        return;
    }
    let device = gpu.device();
    let data = repo().join("data/kitti-sample");
    for model in ["voxel-rcnn-car", "dasanet-car"] {
        let path = repo().join(format!("models/{model}.bpk"));
        let config = ExperimentConfig::for_checkpoint(&path, None).unwrap();
        let detector = Detector::load(config, &path, &device).unwrap();
        let inputs = detector
            .load_split(&data, "val", 0, SideInputs::default())
            .unwrap();
        let run = |ahead: bool| {
            let timing = &mut StageTimes::default();
            let results = match (&detector, &inputs) {
                (Detector::VoxelRcnn(d), SplitInputs::Lidar { frames }) => {
                    d.detect_frames_with(&device, frames, ahead, timing)
                }
                (Detector::Dasanet(d), SplitInputs::Camera { frames, depth_dir }) => {
                    d.detect_frames_with(&device, frames, depth_dir.as_deref(), ahead, timing)
                }
                _ => unreachable!("{model}: a voxel-family model"),
            };
            results.unwrap().objects
        };
        let (ahead, behind) = (run(true), run(false));
        let boxes: usize = ahead.values().map(Vec::len).sum();
        assert!(boxes > 0, "{model}: no boxes");
        assert_eq!(ahead, behind, "{model}");
        eprintln!("{model}: {boxes} boxes, the same bits with stage one ahead and behind");
    }
}

/// (configuration, frames, batch size) of the voxel family's training parity: two batches of
/// 2 frames.
const VOXEL_FAMILY: &[(&str, usize, usize)] = &[("tiny-voxel-rcnn", 4, 2), ("tiny-dasanet", 4, 2)];

/// The frustum family's: FCAM's improved CBAM and SAF (depth-guided slicing, LFA, the
/// projection loss), two batches of the first simulated frame's 18 frustums (its cars, each
/// twice: `augment.copies`). Checked on wgpu (the CUDA test runs the voxel family only).
#[cfg(feature = "wgpu")]
const FRUSTUM_FAMILY: &[(&str, usize, usize)] = &[("tiny-fcam", 1, 9), ("tiny-saf", 1, 9)];

/// One backbone-sized sparse layer (20,000 sites) through the CubeCL kernels on wgpu
/// (its default layout): the output and both gradients within 1e-5 of the CPU's, relative
/// to their largest value. (burn's kernel map gave input gradients off by up to 1e0 here.)
#[cfg(feature = "wgpu")]
#[test]
fn the_sparse_kernels_differentiate_a_backbone_sized_layer_as_the_cpu_does() {
    use fusiondet_nn::sparse::RuleLayout;
    use fusiondet_pipeline::sparse_gradient_probe::sparse_gradient_error;
    let gpu = ComputeDevice::Wgpu;
    if let Err(why) = gpu.check() {
        eprintln!("skipped: {why}; the sparse kernels' gradients were not checked");
        return;
    }
    let error = sparse_gradient_error(&gpu.device(), RuleLayout::DeviceKernels);
    eprintln!("sparse kernels on wgpu against the CPU: {error:?}");
    for (what, e) in [
        ("output", error.output),
        ("input gradient", error.input_gradient),
        ("weight gradient", error.weight_gradient),
    ] {
        assert!(e < 1e-5, "{what}: {e}");
    }
}

/// The first training step (`first_step_loss` of an epoch of two batches from the first
/// `frames` frames) of tiny configurations on the CPU and on `gpu` from the same seed: the
/// same initial weights and data, so the loss — for the voxel family both stages, RoIs from
/// the device's own proposals and RoI grid query — agrees within 1e-4 (relative). With `both_steps`, the epoch's mean over its
/// two steps too, within 1e-3: the second step runs on weights the first step's gradients
/// moved, so wrong gradients part it (on lavapipe burn's kernel map, whose input gradients
/// are wrong at this size, gave means 0.6% and 13% apart; the sparse kernels, wgpu's
/// default, within 1e-4). Not asked of CUDA yet: its TF32 products may move Adam's first
/// updates on near-zero gradients, which a GPU run has not measured.
fn training_parity(
    gpu: ComputeDevice,
    name: &str,
    configs: &[(&str, usize, usize)],
    both_steps: bool,
) {
    if let Err(why) = gpu.check() {
        eprintln!("skipped: {why}; {name} training parity was not checked");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("sim");
    fusiondet_sim::write_dataset(&fusiondet_sim::DatasetOptions::new(&data, 8, 5), &|_, _| {})
        .unwrap();
    for &(config_name, frames, batch_size) in configs {
        let mut config =
            ExperimentConfig::from_file(&repo().join(format!("configs/{config_name}.toml")))
                .unwrap();
        config.train.epochs = 1;
        config.train.batch_size = batch_size;
        config.train.max_frames = frames;
        if let Some(voxel) = config.voxel_rcnn.as_mut() {
            voxel.augment = fusiondet_voxel::AugmentConfig::none();
        }
        // (first-step loss, two-step mean) of a run.
        let losses = |device: ComputeDevice, label: &str| {
            let run = dir.path().join(format!("{config_name}-{label}"));
            let mut options = TrainOptions::new(config.clone(), &data, &run);
            options.device = device;
            train(&options).unwrap();
            let metrics = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
            let first: serde_json::Value =
                serde_json::from_str(metrics.lines().next().unwrap()).unwrap();
            assert_eq!(first["batches"], 2, "{config_name}: two batches");
            (
                first["first_step_loss"].as_f64().unwrap(),
                first["loss_total"].as_f64().unwrap(),
            )
        };
        let (cpu, on_gpu) = (losses(ComputeDevice::Cpu, "cpu"), losses(gpu, name));
        eprintln!(
            "{config_name}: first-step loss cpu {}, {name} {}; two-step mean cpu {}, {name} {}",
            cpu.0, on_gpu.0, cpu.1, on_gpu.1
        );
        assert!(
            (cpu.0 - on_gpu.0).abs() <= 1e-4 * cpu.0.abs().max(1.0),
            "{config_name}: first-step loss cpu {} vs {name} {}",
            cpu.0,
            on_gpu.0
        );
        if both_steps {
            assert!(
                (cpu.1 - on_gpu.1).abs() <= 1e-3 * cpu.1.abs().max(1.0),
                "{config_name}: two-step mean cpu {} vs {name} {}",
                cpu.1,
                on_gpu.1
            );
        }
    }
}

/// Compares every box of the nine shipped models on `gpu` with the CPU's on the bundled val
/// frames (SAF's LFA among them passes lavapipe's 128 MiB binding limit unless it takes its
/// queries in chunks), or skips (passing) where
/// [`ComputeDevice::check`] finds the device unusable.
fn parity(gpu: ComputeDevice, name: &str) {
    if let Err(why) = gpu.check() {
        eprintln!("skipped: {why}; {name} parity was not checked");
        return;
    }
    let gpu = gpu.device();
    let data = repo().join("data/kitti-sample");
    for model in [
        "fconvnet-car",
        "saf-car",
        "fcam-car",
        "voxel-rcnn-car",
        "dasanet-car",
        "fconvnet-people",
        "saf-people",
        "fconvnet-refine-car",
        "fconvnet-refine-people",
    ] {
        let path = repo().join(format!("models/{model}.bpk"));
        let config = ExperimentConfig::for_checkpoint(&path, None).unwrap();
        let run = |device: &Device| {
            let detector = Detector::load(config.clone(), &path, device).unwrap();
            let inputs = detector
                .load_split(&data, "val", 0, SideInputs::default())
                .unwrap();
            detector
                .detect(device, &inputs, &mut StageTimes::default())
                .unwrap()
                .objects
        };
        let (cpu, on_gpu) = (run(&ComputeDevice::Cpu.device()), run(&gpu));
        let mut compared = 0;
        for (id, a) in &cpu {
            let b = &on_gpu[id];
            assert_eq!(a.len(), b.len(), "{model} {id}: box counts differ");
            for (x, y) in a.iter().zip(b) {
                let (p, q) = (&x.box3d, &y.box3d);
                let far = [
                    p.x - q.x,
                    p.y - q.y,
                    p.z - q.z,
                    p.l - q.l,
                    p.w - q.w,
                    p.h - q.h,
                ]
                .iter()
                .any(|d| d.abs() > 0.02);
                assert!(!far, "{model} {id}: {p:?} vs {q:?}");
                let turn = fusiondet_geometry::normalize_angle(p.ry - q.ry).abs();
                assert!(turn < 0.02, "{model} {id}: heading {} vs {}", p.ry, q.ry);
                let ds = (x.score.unwrap() - y.score.unwrap()).abs();
                assert!(
                    ds < 0.005,
                    "{model} {id}: score {:?} vs {:?}",
                    x.score,
                    y.score
                );
                compared += 1;
            }
        }
        eprintln!("{model}: {compared} boxes equal on CPU and {name} within the tolerance");
    }
}
