//! Where a command may write: never into, onto or around what it reads. Every command that
//! writes checks its outputs here against its inputs, all resolved the same way (through
//! symbolic links and `..`, also where the path does not exist yet), so that no spelling of a
//! path (`velodyne/../velodyne`, a link to the data set, a relative path) lets an output
//! replace an input.
//!
//! The rule:
//! - an output **directory** may not equal, lie inside, or contain any input (file or
//!   directory); a data set is given as its root, so nothing is written into a data set;
//! - an output **file** may not equal an input file, nor lie inside an input directory where
//!   it exists already or has a frame file's name (`000001.txt`): a new, differently named
//!   file beside inputs (`--json results/eval.json`) is fine.

use std::path::{Component, Path, PathBuf};

/// `path` made absolute with links resolved, also when it does not exist yet: its longest
/// existing ancestor is resolved by the file system, and the rest is appended with `.`
/// dropped and `..` taking away the part before it.
pub fn resolve(path: &Path) -> PathBuf {
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|cwd| cwd.join(path))
            .unwrap_or_else(|_| path.to_path_buf())
    };
    // Walk forward, resolving the prefix while it exists; once a part is missing, the rest
    // is normalised by its words alone (nothing below a missing folder can be a link).
    let mut resolved = PathBuf::new();
    let mut exists = true;
    for component in absolute.components() {
        match component {
            Component::Prefix(_) | Component::RootDir => resolved.push(component),
            Component::CurDir => {}
            Component::ParentDir => {
                resolved.pop();
            }
            Component::Normal(part) => {
                resolved.push(part);
                if exists {
                    match resolved.canonicalize() {
                        Ok(real) => resolved = real,
                        Err(_) => exists = false,
                    }
                }
            }
        }
    }
    resolved
}

/// Whether `name` is a per-frame file name (`NNNNNN.txt`, `.png`, `.bin`).
pub fn is_frame_file_name(name: &str) -> bool {
    name.split_once('.').is_some_and(|(stem, ext)| {
        stem.len() == 6
            && stem.bytes().all(|b| b.is_ascii_digit())
            && matches!(ext, "txt" | "png" | "bin")
    })
}

/// What a command reads (files, folders, data set roots), each named by the flag that gave
/// it.
#[derive(Debug, Default, Clone)]
pub struct Inputs {
    entries: Vec<(String, PathBuf, PathBuf)>,
}

impl Inputs {
    pub fn new() -> Inputs {
        Inputs::default()
    }

    /// An input file or directory given by `flag` (ignored when `None`).
    pub fn with(mut self, flag: &str, path: Option<&Path>) -> Inputs {
        if let Some(path) = path {
            self.entries
                .push((flag.to_string(), path.to_path_buf(), resolve(path)));
        }
        self
    }
}

/// Why an output was refused: which output, which input, and what to do.
#[derive(Debug, thiserror::Error)]
#[error("{out_flag} {} {relation} {in_flag} {}, which this command reads; choose an output outside its inputs", out.display(), input.display())]
pub struct OverlapError {
    pub out_flag: String,
    pub out: PathBuf,
    pub relation: &'static str,
    pub in_flag: String,
    pub input: PathBuf,
}

/// Refuses an output directory `out` (given as `flag`) that equals, lies inside or contains
/// one of `inputs`.
pub fn check_output_dir(flag: &str, out: &Path, inputs: &Inputs) -> Result<(), OverlapError> {
    first_overlap(flag, out, inputs, |target, real| {
        if target == real {
            Some("is an input directory:")
        } else if target.starts_with(real) {
            Some("lies inside")
        } else {
            real.starts_with(target).then_some("contains")
        }
    })
}

/// Refuses an output file `out` (given as `flag`) that equals an input, or lies inside an
/// input directory where it exists already or has a frame file's name.
pub fn check_output_file(flag: &str, out: &Path, inputs: &Inputs) -> Result<(), OverlapError> {
    first_overlap(flag, out, inputs, |target, real| {
        let frame_name = target
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(is_frame_file_name);
        if target == real {
            Some("is the input")
        } else if real.is_dir() && target.starts_with(real) && (target.exists() || frame_name) {
            Some("would overwrite an input in")
        } else {
            real.starts_with(target).then_some("contains")
        }
    })
}

/// The first input that `relation(resolved output, resolved input)` says the output
/// touches, as the error naming both.
fn first_overlap(
    flag: &str,
    out: &Path,
    inputs: &Inputs,
    relation: impl Fn(&Path, &Path) -> Option<&'static str>,
) -> Result<(), OverlapError> {
    let target = resolve(out);
    for (in_flag, given, real) in &inputs.entries {
        if let Some(relation) = relation(&target, real) {
            return Err(OverlapError {
                out_flag: flag.to_string(),
                out: out.to_path_buf(),
                relation,
                in_flag: in_flag.clone(),
                input: given.clone(),
            });
        }
    }
    Ok(())
}

/// The first directory at most `depth` levels below `root` that is a symbolic link (a
/// writer following it would write outside `root`).
pub fn linked_folder_below(root: &Path, depth: usize) -> Option<PathBuf> {
    if depth == 0 {
        return None;
    }
    let entries = std::fs::read_dir(root).ok()?;
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        if kind.is_symlink() && path.is_dir() {
            return Some(path);
        }
        if kind.is_dir()
            && let Some(found) = linked_folder_below(&path, depth - 1)
        {
            return Some(found);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn resolve_follows_links_and_parent_parts_also_where_missing() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().canonicalize().unwrap();
        std::fs::create_dir_all(root.join("a/velodyne")).unwrap();
        assert_eq!(
            resolve(&root.join("a/velodyne/../velodyne")),
            root.join("a/velodyne")
        );
        assert_eq!(resolve(&root.join("missing/../a/./x")), root.join("a/x"));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(root.join("a"), root.join("link")).unwrap();
            assert_eq!(
                resolve(&root.join("link/velodyne/new")),
                root.join("a/velodyne/new")
            );
        }
    }

    #[test]
    fn output_directories_around_inputs_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let training = dir.path().join("training");
        for sub in ["velodyne", "image_2", "depth_2"] {
            std::fs::create_dir_all(training.join(sub)).unwrap();
        }
        let inputs = Inputs::new().with("--data-dir", Some(&training));
        for bad in [
            training.join("velodyne"),
            training.join("velodyne/../velodyne"),
            training.join("depth_2"),
            training.join("new"),
            training.clone(),
            dir.path().to_path_buf(),
        ] {
            assert!(
                check_output_dir("--out-dir", &bad, &inputs).is_err(),
                "{bad:?}"
            );
        }
        let err = check_output_dir("--out-dir", &training.join("velodyne"), &inputs)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--out-dir") && err.contains("--data-dir"),
            "{err}"
        );
        check_output_dir("--out-dir", &dir.path().join("pseudo"), &inputs).unwrap();
    }

    #[test]
    fn output_files_may_not_replace_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let split = dir.path().join("val.txt");
        std::fs::write(&split, "000001\n").unwrap();
        let results = dir.path().join("results");
        std::fs::create_dir_all(&results).unwrap();
        std::fs::write(results.join("000001.txt"), "x").unwrap();
        let inputs = Inputs::new()
            .with("--split", Some(&split))
            .with("--results", Some(&results));
        assert!(check_output_file("--json", &split, &inputs).is_err());
        assert!(check_output_file("--json", &results.join("000001.txt"), &inputs).is_err());
        assert!(check_output_file("--json", &results.join("000002.txt"), &inputs).is_err());
        check_output_file("--json", &results.join("eval.json"), &inputs).unwrap();
        check_output_file("--json", &dir.path().join("eval.json"), &inputs).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn linked_folders_are_found() {
        let dir = tempfile::tempdir().unwrap();
        let other = dir.path().join("other");
        std::fs::create_dir_all(&other).unwrap();
        let sim = dir.path().join("sim");
        std::fs::create_dir_all(sim.join("training")).unwrap();
        assert_eq!(linked_folder_below(&sim, 3), None);
        std::os::unix::fs::symlink(&other, sim.join("training/velodyne")).unwrap();
        assert_eq!(
            linked_folder_below(&sim, 3),
            Some(sim.join("training/velodyne"))
        );
    }

    /// One piece of a path spelling: a folder name, a step up, or a link to one of the
    /// input folders.
    fn spelled(parts: &[u8], base: &Path, links: &[PathBuf]) -> PathBuf {
        let mut path = base.to_path_buf();
        for &p in parts {
            match p % 6 {
                0 => path.push(".."),
                1 => path.push("."),
                2 => path.push("velodyne"),
                3 => path.push("training"),
                4 => path = links[p as usize % links.len()].clone(),
                _ => path.push("fresh"),
            }
        }
        path
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// Whatever the spelling of an output directory (links, `..`, nesting), either it is
        /// refused, or writing a frame file into it changes no input file.
        #[test]
        fn no_accepted_output_directory_reaches_an_input(parts in proptest::collection::vec(any::<u8>(), 0..7)) {
            let dir = tempfile::tempdir().unwrap();
            let base = dir.path().canonicalize().unwrap();
            let training = base.join("data/training");
            std::fs::create_dir_all(training.join("velodyne")).unwrap();
            std::fs::write(training.join("velodyne/000000.bin"), b"scan").unwrap();
            let mut links = vec![training.clone()];
            #[cfg(unix)]
            {
                std::os::unix::fs::symlink(&training, base.join("to-training")).unwrap();
                std::os::unix::fs::symlink(training.join("velodyne"), base.join("to-velodyne")).unwrap();
                links.push(base.join("to-training"));
                links.push(base.join("to-velodyne"));
            }
            let out = spelled(&parts, &base, &links);
            // Spellings that climb out of the test's own folder are not written to.
            prop_assume!(resolve(&out).starts_with(&base));
            let inputs = Inputs::new().with("--data-dir", Some(&training));
            if check_output_dir("--out-dir", &out, &inputs).is_ok() && std::fs::create_dir_all(&out).is_ok() {
                let _ = std::fs::write(out.join("000000.bin"), b"pseudo");
                prop_assert_eq!(std::fs::read(training.join("velodyne/000000.bin")).unwrap(), b"scan".to_vec());
            }
        }
    }
}
