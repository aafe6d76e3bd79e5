//! CPU–GPU parity (cargo feature `wgpu`): the shipped F-ConvNet and Voxel R-CNN Car models
//! give the same boxes on burn's wgpu backend as on the CPU for the bundled KITTI val frames,
//! within a stated tolerance (f32 kernels that sum in another order: centres and sizes within
//! 2 cm, headings within 0.02 rad, scores within 0.005). Where no wgpu adapter is found the
//! test says so and passes.
#![cfg(feature = "wgpu")]

use burn::prelude::Device;
use fusiondet_pipeline::{ComputeDevice, Detector, ExperimentConfig, SideInputs, StageTimes};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The wgpu device, if an adapter can be had (creating one panics where none exists).
fn wgpu_device() -> Option<Device> {
    let device = ComputeDevice::Wgpu.device();
    let probe = device.clone();
    let works = std::panic::catch_unwind(move || {
        let t = burn::tensor::Tensor::<1>::from_floats([1.0, 2.0, 3.0], &probe);
        t.sum().into_scalar::<f32>()
    });
    match works {
        Ok(sum) if (sum - 6.0).abs() < 1e-6 => Some(device),
        _ => None,
    }
}

#[test]
fn shipped_models_give_the_same_boxes_on_wgpu_as_on_the_cpu() {
    let Some(gpu) = wgpu_device() else {
        eprintln!("skipped: no wgpu adapter on this machine; parity was not checked");
        return;
    };
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
        let (cpu, wgpu) = (run(&ComputeDevice::Cpu.device()), run(&gpu));
        let mut compared = 0;
        for (id, a) in &cpu {
            let b = &wgpu[id];
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
        eprintln!("{model}: {compared} boxes equal on CPU and wgpu within the tolerance");
    }
}
