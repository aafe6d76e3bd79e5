//! Writing an indoor data set in the prepared SUN RGB-D layout:
//!
//! ```text
//! OUT/points/<id>.bin  image/<id>.jpg  depth/<id>.png  calib/<id>.txt  det_2d/<id>.txt
//! OUT/label/<id>.txt   splits/train.txt  splits/val.txt  sim_stats.json  .fusiondet-sim
//! ```
//!
//! The output directory follows the street simulator's rule: a non-empty directory is
//! refused unless `force` is given and its marker says `fusiondet simulate --indoor` wrote it;
//! then only that run's own files are removed. Frames are simulated and written in parallel
//! (every file atomic, the label last), the split lists and statistics once all are on disk.

use super::stats::{DatasetStats, FrameStats};
use super::{IndoorConfig, IndoorFrame, simulate_indoor_frame};
use crate::dataset::{MARKER_FILE, MAX_FRAMES, STATS_FILE, SimError, io_err};
use crate::detector::Split;
use crate::output_dir;
use fusiondet_sunrgbd::{
    SunRgbdDir, write_calib, write_detections_2d, write_objects, write_points,
};
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The marker's first line for an indoor data set.
const MARKER_HEAD: &str = "fusiondet simulate --indoor";
/// JPEG quality of the colour images.
const JPEG_QUALITY: u8 = 92;

/// What to write.
#[derive(Debug, Clone)]
pub struct IndoorOptions {
    pub out: PathBuf,
    pub frames: usize,
    pub seed: u64,
    pub force: bool,
    pub config: IndoorConfig,
}

/// The raw depth PNG of a scene: `ROOT/depth/<id>.png`.
pub fn depth_path(dir: &SunRgbdDir, id: &str) -> PathBuf {
    dir.root.join("depth").join(format!("{id}.png"))
}

const SUBDIRS: [&str; 7] = [
    "points", "image", "depth", "calib", "label", "det_2d", "splits",
];

/// Is `name` in folder `dir` a file an indoor run of `frames` frames writes?
fn is_ours(dir: &str, name: &str, frames: usize) -> bool {
    if let Some(target) = fusiondet_kitti::atomic::temp_target(name) {
        return is_ours(dir, target, frames);
    }
    let ext = output_dir::frame_file(name, frames);
    match dir {
        "points" => ext == Some("bin"),
        "image" => ext == Some("jpg"),
        "depth" => ext == Some("png"),
        "calib" | "label" | "det_2d" => ext == Some("txt"),
        "splits" => matches!(name, "train.txt" | "val.txt"),
        _ => name == STATS_FILE,
    }
}

fn validate(opts: &IndoorOptions) -> Result<(), SimError> {
    let bad = |m: String| Err(SimError::InvalidArgument(m));
    if opts.frames == 0 {
        return bad("--frames must be at least 1".into());
    }
    if opts.frames > MAX_FRAMES {
        return bad(format!(
            "--frames must be at most {MAX_FRAMES} (scene ids have six digits)"
        ));
    }
    let f = opts.config.val_fraction;
    if !(0.0..=1.0).contains(&f) {
        return bad(format!("--val-fraction must be between 0 and 1, got {f}"));
    }
    if opts.config.points == 0 {
        return bad("--points must be at least 1".into());
    }
    let c = &opts.config.camera;
    if !(16..=4096).contains(&c.width) || !(16..=4096).contains(&c.height) {
        return bad(format!(
            "an image of {}×{} pixels is outside 16–4096 a side",
            c.width, c.height
        ));
    }
    Ok(())
}

/// Prepares the directory (module docs, [`output_dir::claim`]); the returned lock is held
/// while writing.
fn prepare_dir(opts: &IndoorOptions) -> Result<std::fs::File, SimError> {
    let root = &opts.out;
    let claimed = output_dir::claim(
        root,
        opts.force,
        MARKER_HEAD,
        &format!(
            "an indoor data set that `fusiondet simulate --indoor` wrote (its {MARKER_FILE} \
             says so)"
        ),
    )?;
    if let Some(frames) = claimed.earlier_frames {
        let dirs: Vec<(&str, &str)> = SUBDIRS.iter().chain([&""]).map(|&d| (d, d)).collect();
        output_dir::remove_own_files(root, &dirs, |kind, name| is_ours(kind, name, frames))?;
    }
    output_dir::write_marker(root, MARKER_HEAD, opts.frames)?;
    for sub in SUBDIRS {
        let dir = root.join(sub);
        std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    }
    Ok(claimed.lock)
}

/// Encodes the colour image as JPEG.
pub fn encode_jpeg(image: &image::RgbImage) -> Vec<u8> {
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, JPEG_QUALITY)
        .encode_image(image)
        .expect("encoding into memory cannot fail");
    bytes
}

/// Writes one scene's files, the label last.
pub fn write_frame(dir: &SunRgbdDir, f: &IndoorFrame) -> Result<(), SimError> {
    write_points(&dir.points(&f.id), &f.points)?;
    fusiondet_kitti::write_atomic(&dir.image(&f.id), &encode_jpeg(&f.image))?;
    fusiondet_sunrgbd::depth::write_depth_png(&depth_path(dir, &f.id), &f.depth)?;
    write_calib(&dir.calib(&f.id), &f.calib)?;
    write_detections_2d(&dir.detections_2d(&f.id), &f.detections)?;
    write_objects(&dir.label(&f.id), &f.objects)?;
    Ok(())
}

/// Simulates and writes the data set; `progress(done, total)` after each scene. Returns the
/// statistics (also in `sim_stats.json`).
pub fn write_indoor_dataset(
    opts: &IndoorOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<DatasetStats, SimError> {
    validate(opts)?;
    let _lock = prepare_dir(opts)?;
    let dir = SunRgbdDir::new(&opts.out);
    let done = AtomicUsize::new(0);
    let summaries: Vec<(String, Split, FrameStats)> = (0..opts.frames)
        .into_par_iter()
        .map(|i| {
            let f = simulate_indoor_frame(opts.seed, i, &opts.config);
            write_frame(&dir, &f)?;
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, opts.frames);
            Ok((f.id.clone(), f.split, FrameStats::from_frame(&f)))
        })
        .collect::<Result<_, SimError>>()?;
    for (split, name) in [(Split::Train, "train"), (Split::Val, "val")] {
        let ids: Vec<String> = summaries
            .iter()
            .filter(|s| s.1 == split)
            .map(|s| s.0.clone())
            .collect();
        fusiondet_kitti::write_split(&dir.split(name), &ids)?;
    }
    let stats = DatasetStats::from_frames(summaries.into_iter().map(|s| s.2).collect());
    fusiondet_kitti::write_atomic(&opts.out.join(STATS_FILE), stats.to_json().as_bytes())?;
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn our_file_names() {
        assert!(is_ours("points", "000001.bin", 2));
        assert!(!is_ours("points", "000002.bin", 2));
        assert!(is_ours("image", ".000001.jpg.Xk3a9.tmp", 2));
        assert!(is_ours("det_2d", "000000.txt", 1));
        assert!(!is_ours("label", "notes.txt", 9));
        assert!(is_ours("", "sim_stats.json", 1));
        assert!(!is_ours("", "README.md", 1));
        assert_eq!(
            output_dir::marked_frames("fusiondet simulate --indoor\nframes: 4\n", MARKER_HEAD),
            Some(4)
        );
        // A street data set's marker is not an indoor one.
        assert_eq!(
            output_dir::marked_frames("fusiondet simulate\nframes: 4\n", MARKER_HEAD),
            None
        );
    }

    #[test]
    fn force_replaces_only_an_indoor_run_and_only_its_files() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        std::fs::create_dir_all(root.join("points")).unwrap();
        std::fs::write(root.join("points/000000.bin"), b"x").unwrap();
        let opts = IndoorOptions {
            out: root.to_path_buf(),
            frames: 1,
            seed: 0,
            force: true,
            config: IndoorConfig::default(),
        };
        // No marker: refused, nothing removed.
        let err = prepare_dir(&opts).unwrap_err().to_string();
        assert!(err.contains("only an indoor data set"), "{err}");
        assert!(root.join("points/000000.bin").exists());
        std::fs::write(
            root.join(MARKER_FILE),
            "fusiondet simulate --indoor\nframes: 3\n",
        )
        .unwrap();
        std::fs::write(root.join("points/000002.bin"), b"x").unwrap();
        std::fs::write(root.join("points/000003.bin"), b"not that run's").unwrap();
        std::fs::write(root.join("keep.txt"), b"mine").unwrap();
        drop(prepare_dir(&opts).unwrap());
        assert!(!root.join("points/000000.bin").exists());
        assert!(!root.join("points/000002.bin").exists());
        assert!(root.join("points/000003.bin").exists());
        assert!(root.join("keep.txt").exists());
        assert!(root.join("det_2d").is_dir());
        // Without --force a non-empty directory is refused.
        let err = prepare_dir(&IndoorOptions {
            force: false,
            ..opts
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("not empty"), "{err}");
    }
}
