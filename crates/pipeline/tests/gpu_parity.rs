//! CPU–GPU parity (cargo features `wgpu` and `cuda`): the shipped F-ConvNet and Voxel R-CNN
//! Car models give the same boxes on burn's wgpu or CUDA backend as on the CPU for the bundled
//! KITTI val frames, within a stated tolerance (f32 kernels that sum in another order: centres
//! and sizes within 2 cm, headings within 0.02 rad, scores within 0.005). Where the backend
//! finds no adapter, driver or device the test says so and passes.
#![cfg(any(feature = "wgpu", feature = "cuda"))]

use burn::prelude::Device;
use fusiondet_pipeline::{ComputeDevice, Detector, ExperimentConfig, SideInputs, StageTimes};
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

/// Compares every box of both models on `gpu` with the CPU's, or skips (passing) where
/// [`ComputeDevice::check`] finds the device unusable.
fn parity(gpu: ComputeDevice, name: &str) {
    if let Err(why) = gpu.check() {
        eprintln!("skipped: {why}; {name} parity was not checked");
        return;
    }
    let gpu = gpu.device();
    let data = repo().join("data/kitti-sample");
    for model in ["fconvnet-car", "voxel-rcnn-car"] {
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
