//! Where a command may write: never over the files it reads. `viz --out` onto the frame's
//! own image, or `eval --json` onto a label file, would destroy an input silently. A new
//! file beside the inputs (`--json results/eval.json`) is fine, unless its name is one a
//! frame's file would have (`000001.txt`), which a later read would take for input.

use anyhow::bail;
use std::path::{Path, PathBuf};

/// `path` made absolute with links resolved, also when it does not exist yet (its nearest
/// existing ancestor is resolved and the rest appended).
fn resolved(path: &Path) -> Option<PathBuf> {
    let mut missing = Vec::new();
    for ancestor in path.ancestors() {
        if let Ok(real) = ancestor.canonicalize() {
            return Some(
                missing
                    .iter()
                    .rev()
                    .fold(real, |p: PathBuf, part| p.join(part)),
            );
        }
        missing.push(ancestor.file_name()?.to_owned());
    }
    None
}

/// Whether `name` is a per-frame file name (`NNNNNN.txt`, `.png`, `.bin`).
fn is_frame_file(name: &str) -> bool {
    name.split_once('.').is_some_and(|(stem, ext)| {
        stem.len() == 6
            && stem.bytes().all(|b| b.is_ascii_digit())
            && matches!(ext, "txt" | "png" | "bin")
    })
}

/// Refuses an output file `out` (given as `flag`) inside one of the input folders (each
/// given as its flag and path) that exists already or has a frame file's name.
pub fn refuse_output_in_inputs(
    flag: &str,
    out: &Path,
    inputs: &[(&str, Option<&Path>)],
) -> anyhow::Result<()> {
    let Some(target) = resolved(out) else {
        return Ok(());
    };
    for (input_flag, dir) in inputs {
        let Some(dir) = dir.and_then(|d| d.canonicalize().ok()) else {
            continue;
        };
        let frame_name = target
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(is_frame_file);
        if target.starts_with(&dir) && (target.exists() || frame_name) {
            bail!(
                "{flag} {} would overwrite an input in {input_flag} {}; choose another \
                 path",
                out.display(),
                dir.display()
            );
        }
    }
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
        let inputs = [("--label-dir", Some(labels.as_path())), ("--other", None)];
        let err = refuse_output_in_inputs("--json", &labels.join("000001.txt"), &inputs)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--json") && err.contains("--label-dir"),
            "{err}"
        );
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
