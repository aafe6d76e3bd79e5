//! ImageSets split files: parse or refuse, never panic; every id parsed is digits, once.
#![no_main]

use fusiondet_kitti::split::parse_split;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(ids) = parse_split(text, Path::new("val.txt")) {
        let unique: std::collections::HashSet<&String> = ids.iter().collect();
        assert_eq!(unique.len(), ids.len());
        assert!(ids.iter().all(|id| id.bytes().all(|b| b.is_ascii_digit())));
    }
});
