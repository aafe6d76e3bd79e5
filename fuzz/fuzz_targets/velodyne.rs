//! LiDAR scans: any bytes parse or are refused, never panic; what parses encodes back to
//! the same bytes.
#![no_main]

use fusiondet_kitti::velodyne::{encode_velodyne, parse_velodyne};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(points) = parse_velodyne(data, Path::new("velodyne/000000.bin")) {
        assert_eq!(encode_velodyne(&points), data);
    }
});
