//! F-PointNet's 2D detection files: parse or refuse, never panic.
#![no_main]

use fusiondet_kitti::detections2d::parse_detections2d;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = parse_detections2d(text, Path::new("rgb_detection_val.txt"));
    }
});
