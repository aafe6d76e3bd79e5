//! How many threads prepare frames beside the network (`FUSIONDET_PREPARE_THREADS`; beside a
//! GPU by default a quarter of the cores): the shipped DASANet writes the same result files,
//! byte for byte, with three threads preparing its five bundled val frames as with the CPU's
//! one, and a value out of range is refused before anything is written; the voxel family's
//! stage one on the network's thread (`FUSIONDET_STAGE_ONE_AHEAD=off`) writes the same files
//! as on the preparing thread (the default).

mod common;

use common::all_output;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

fn detect(out: &Path, preparers: Option<&str>) -> Output {
    common::detect_bundled_val("dasanet-car", out, "FUSIONDET_PREPARE_THREADS", preparers)
}

/// The result files (`<id>.txt`) of a result directory with their bytes.
fn result_files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "txt"))
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&p).unwrap())
        })
        .collect()
}

#[test]
fn three_preparers_write_the_same_results_as_one() {
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("one");
    let three = dir.path().join("three");
    let o = detect(&one, None);
    assert!(o.status.success(), "{}", all_output(&o));
    let o = detect(&three, Some("3"));
    assert!(o.status.success(), "{}", all_output(&o));
    let (one, three) = (result_files(&one), result_files(&three));
    assert_eq!(one.len(), 5, "{:?}", one.keys());
    assert!(
        one.values().any(|bytes| !bytes.is_empty()),
        "the shipped DASANet found boxes"
    );
    assert_eq!(one, three);
}

#[test]
fn a_number_of_threads_out_of_range_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = detect(&out, Some("0"));
    assert_refused(
        &o,
        &out,
        &["FUSIONDET_PREPARE_THREADS=\"0\"", "from 1 to 8"],
    );
}

/// `o` failed without a panic, saying each of `says`, and made no result directory `out`.
fn assert_refused(o: &Output, out: &Path, says: &[&str]) {
    let text = all_output(o);
    assert!(!o.status.success(), "{text}");
    assert!(says.iter().all(|s| text.contains(s)), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    assert!(!out.exists(), "the result directory was made");
}

/// Stage one on the preparing thread (the default) and on the network's thread
/// (`FUSIONDET_STAGE_ONE_AHEAD=off`) write the same result files, byte for byte, for both
/// voxel-family models.
#[test]
fn stage_one_on_either_thread_writes_the_same_results() {
    let dir = tempfile::tempdir().unwrap();
    for model in ["voxel-rcnn-car", "dasanet-car"] {
        let ahead = dir.path().join(format!("{model}-ahead"));
        let behind = dir.path().join(format!("{model}-behind"));
        let detect = |out: &Path, value: Option<&str>| {
            common::detect_bundled_val(model, out, "FUSIONDET_STAGE_ONE_AHEAD", value)
        };
        let o = detect(&ahead, None);
        assert!(o.status.success(), "{}", all_output(&o));
        let o = detect(&behind, Some("off"));
        assert!(o.status.success(), "{}", all_output(&o));
        let (ahead, behind) = (result_files(&ahead), result_files(&behind));
        assert_eq!(ahead.len(), 5, "{model}: {:?}", ahead.keys());
        assert!(ahead.values().any(|bytes| !bytes.is_empty()), "{model}");
        assert_eq!(ahead, behind, "{model}");
    }
}

#[test]
fn a_stage_one_setting_other_than_on_or_off_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = common::detect_bundled_val(
        "voxel-rcnn-car",
        &out,
        "FUSIONDET_STAGE_ONE_AHEAD",
        Some("yes"),
    );
    assert_refused(&o, &out, &["FUSIONDET_STAGE_ONE_AHEAD=\"yes\"", "`on`"]);
}
