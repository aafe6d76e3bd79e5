//! The kernel-map layout of sparse convolution (what GPUs run, `RuleLayout::KernelMap`)
//! forced on the CPU with `FUSIONDET_SPARSE_RULES`: the shipped Voxel R-CNN and DASANet find
//! the same boxes on the bundled KITTI val frames as with the CPU's per-offset layout, within
//! the GPU parity tolerance of `fusiondet compare` (the two layouts sum in another order), and
//! a value the variable does not know is named and ignored.

mod common;

use common::{all_output, s};
use std::path::Path;
use std::process::Output;

fn detect(model: &str, out: &Path, layout: Option<&str>) -> Output {
    common::detect_bundled_val(model, out, "FUSIONDET_SPARSE_RULES", layout)
}

#[test]
fn the_kernel_map_layout_finds_the_cpus_boxes() {
    let dir = tempfile::tempdir().unwrap();
    for model in ["voxel-rcnn-car", "dasanet-car"] {
        let per_offset = dir.path().join(format!("{model}-per-offset"));
        let kernel_map = dir.path().join(format!("{model}-kernel-map"));
        let o = detect(model, &per_offset, None);
        assert!(o.status.success(), "{}", all_output(&o));
        let o = detect(model, &kernel_map, Some("kernel-map"));
        assert!(o.status.success(), "{}", all_output(&o));
        let o = common::run("compare", &[s(&per_offset), s(&kernel_map)]);
        let out = all_output(&o);
        assert!(o.status.success(), "{model}: {out}");
        assert!(out.contains("same boxes within 0.01 m"), "{model}: {out}");
        // Boxes were found, so the comparison compared something.
        let paired: usize = out
            .split("paired ")
            .nth(1)
            .and_then(|rest| rest.split_whitespace().next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{model}: no pair count in {out}"));
        assert!(paired > 0, "{model}: {out}");
    }
}

#[test]
fn an_unknown_layout_is_named_and_ignored() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = detect("voxel-rcnn-car", &out, Some("fastest"));
    let text = all_output(&o);
    assert!(o.status.success(), "{text}");
    assert!(
        text.contains("FUSIONDET_SPARSE_RULES=\"fastest\" is neither"),
        "{text}"
    );
}
