//! Where a command may write a single output file (`eval --json`, `viz --out`, `view
//! --out`): never over the files it reads. The rule, shared with every command that writes
//! a directory, is [`fusiondet_kitti::paths`]'s; this is the commands' way of listing their
//! inputs by flag.

use fusiondet_kitti::paths::{Inputs, check_output_file};
use std::path::Path;

/// Refuses an output file `out` (given as `flag`) that is one of the inputs (each given as
/// its flag and path, a file or a folder), or lies in an input folder where it exists
/// already or has a frame file's name.
pub fn refuse_output_in_inputs(
    flag: &str,
    out: &Path,
    inputs: &[(&str, Option<&Path>)],
) -> anyhow::Result<()> {
    let inputs = inputs
        .iter()
        .fold(Inputs::new(), |all, (input_flag, path)| {
            all.with(input_flag, *path)
        });
    check_output_file(flag, out, &inputs)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_inside_inputs_are_refused_and_others_pass() {
        let dir = tempfile::tempdir().unwrap();
        let labels = dir.path().join("label_2");
        std::fs::create_dir_all(&labels).unwrap();
        std::fs::write(labels.join("000001.txt"), "x").unwrap();
        let split = dir.path().join("val.txt");
        std::fs::write(&split, "000001\n").unwrap();
        let inputs = [
            ("--label-dir", Some(labels.as_path())),
            ("--split", Some(split.as_path())),
            ("--other", None),
        ];
        let err = refuse_output_in_inputs("--json", &labels.join("000001.txt"), &inputs)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--json") && err.contains("--label-dir"),
            "{err}"
        );
        // The split file read, also spelled through `..`.
        let err = refuse_output_in_inputs("--json", &labels.join("../val.txt"), &inputs)
            .unwrap_err()
            .to_string();
        assert!(err.contains("--split"), "{err}");
        // Through a link to the folder, and a frame's name that does not exist yet.
        #[cfg(unix)]
        {
            let link = dir.path().join("link");
            std::os::unix::fs::symlink(&labels, &link).unwrap();
            assert!(refuse_output_in_inputs("--json", &link.join("000001.txt"), &inputs).is_err());
        }
        assert!(refuse_output_in_inputs("--json", &labels.join("000002.txt"), &inputs).is_err());
        // A new file of another name beside the inputs, or outside them, is fine.
        refuse_output_in_inputs("--json", &labels.join("eval.json"), &inputs).unwrap();
        refuse_output_in_inputs("--json", &dir.path().join("out/e.json"), &inputs).unwrap();
    }
}
