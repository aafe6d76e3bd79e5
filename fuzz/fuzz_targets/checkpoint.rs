//! Checkpoints: any bytes in a `.bpk` file are refused or give a configuration and a
//! detector, never a panic or an unbounded allocation.
#![no_main]

use fusiondet_pipeline::{Detector, ExperimentConfig};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let path = dir.path().join("model.bpk");
    std::fs::write(&path, data).expect("the file is written");
    if fusiondet_models::read_checkpoint_kind(&path).is_err() {
        return;
    }
    if let Ok(config) = ExperimentConfig::for_checkpoint(&path, None) {
        let _ = Detector::load(config, &path, &burn::prelude::Device::flex());
    }
});
