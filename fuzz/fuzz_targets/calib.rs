//! Calibration files: parse or refuse, never panic; what parses round-trips exactly and
//! gives a camera model.
#![no_main]

use fusiondet_kitti::calib::{format_calib, parse_calib};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("calib/000000.txt");
    if let Ok(calib) = parse_calib(text, path) {
        let back = parse_calib(&format_calib(&calib), path).expect("what we write, we read");
        assert_eq!(back, calib);
        // A calibration that passed the reader can build a camera (or say why not).
        let _ = calib.camera_model();
    }
});
