//! Label and result files: any text parses or is refused, never panics; what parses
//! formats and parses back to the same objects (to the written precision).
#![no_main]

use fusiondet_kitti::label::{format_objects, parse_objects};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("label_2/000000.txt");
    if let Ok(objects) = parse_objects(text, path) {
        let written = format_objects(&objects);
        let back = parse_objects(&written, path).expect("what we write, we read");
        assert_eq!(back.len(), objects.len());
        assert_eq!(
            format_objects(&back),
            written,
            "formatting is a fixed point"
        );
    }
});
