//! The first check of `--data` and `--data-dir`: the folder has the layout the command
//! reads, else an error that draws the layout and names a parent or child folder that has
//! it (the usual slip is one level too deep or too shallow).

use anyhow::bail;
use std::path::{Path, PathBuf};

/// A data set root as `train`, `detect`, `bench` and `gt-database` read it.
const ROOT_LAYOUT: &str = "\
expected a KITTI-format data set root:
  ROOT/
    ImageSets/{train,val}.txt              frame ids (or give --split a file)
    training/velodyne/NNNNNN.bin           LiDAR scans
    training/calib/NNNNNN.txt
    training/image_2/NNNNNN.png
    training/label_2/NNNNNN.txt            labels (training, evaluation)
    rgb_detections/rgb_detection_<split>.txt   2D detections (frustum models)
or a prepared SUN RGB-D directory (points/, calib/, label/, det_2d/, splits/)";

/// A frames folder as `viz`, `view`, `depth-complete` and `pseudo-points` read it.
const FRAMES_LAYOUT: &str = "\
expected the frames folder of a KITTI-format data set (ROOT/training):
  training/
    velodyne/NNNNNN.bin
    calib/NNNNNN.txt
    image_2/NNNNNN.png
    label_2/NNNNNN.txt   (optional)
or a prepared SUN RGB-D directory (points/, calib/, label/, det_2d/, splits/)";

fn is_root(dir: &Path) -> bool {
    dir.join("training").is_dir() || is_sun_rgbd(dir)
}

fn is_frames(dir: &Path) -> bool {
    dir.join("velodyne").is_dir()
        || dir.join("calib").is_dir() && !dir.join("points").is_dir()
        || is_sun_rgbd(dir)
}

fn is_sun_rgbd(dir: &Path) -> bool {
    dir.join("points").is_dir() && dir.join("calib").is_dir()
}

/// The folders one level up and down (two up: `training/velodyne` given for a root).
fn neighbours(dir: &Path) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = dir
        .ancestors()
        .skip(1)
        .take(2)
        .map(Path::to_path_buf)
        .collect();
    if let Ok(entries) = std::fs::read_dir(dir) {
        let mut children: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        children.sort();
        out.extend(children);
    }
    out.retain(|p| !p.as_os_str().is_empty());
    out
}

fn check(flag: &str, dir: &Path, fits: fn(&Path) -> bool, layout: &str) -> anyhow::Result<()> {
    if !dir.is_dir() {
        bail!("{flag} {}: no such directory", dir.display());
    }
    if fits(dir) {
        return Ok(());
    }
    let hint = match neighbours(dir).into_iter().find(|p| fits(p)) {
        Some(p) => format!("\ndid you mean {flag} {}?", p.display()),
        None => String::new(),
    };
    bail!(
        "{flag} {}: not the folder this reads; {layout}{hint}",
        dir.display()
    )
}

/// Checks a data set root (`--data`).
pub fn check_root(flag: &str, dir: &Path) -> anyhow::Result<()> {
    check(flag, dir, is_root, ROOT_LAYOUT)
}

/// Checks a frames folder (`--data-dir`, `ROOT/training`).
pub fn check_frames(flag: &str, dir: &Path) -> anyhow::Result<()> {
    check(flag, dir, is_frames, FRAMES_LAYOUT)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_level_off_is_named() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("sim");
        for d in ["training/velodyne", "training/calib", "ImageSets"] {
            std::fs::create_dir_all(root.join(d)).unwrap();
        }
        check_root("--data", &root).unwrap();
        check_frames("--data-dir", &root.join("training")).unwrap();
        let err = check_root("--data", &root.join("training"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("ImageSets/{train,val}.txt"), "{err}");
        assert!(
            err.ends_with(&format!("did you mean --data {}?", root.display())),
            "{err}"
        );
        let err = check_frames("--data-dir", &root).unwrap_err().to_string();
        assert!(
            err.ends_with(&format!(
                "did you mean --data-dir {}?",
                root.join("training").display()
            )),
            "{err}"
        );
        let err = check_root("--data", tmp.path()).unwrap_err().to_string();
        assert!(
            err.ends_with(&format!("did you mean --data {}?", root.display())),
            "{err}"
        );
        let err = check_root("--data", &root.join("nope"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("no such directory"), "{err}");
    }
}
