//! Writing a dataset: argument checks, the output directory, frames in parallel
//! (each file atomic, the label last), then the split lists, the 2D detection files
//! and the statistics — so an interrupted run never leaves a dataset whose index
//! files claim frames that are not all there.

use crate::output_dir;
use crate::stats::{DatasetStats, FrameStats};
use crate::{SimConfig, Split, simulate_frame};
use fusiondet_kitti::detections2d::format_detections2d;
use fusiondet_kitti::{
    DatasetDir, FormatError, write_calib, write_objects, write_split, write_velodyne,
};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The image path prefix F-PointNet's detection files use.
pub const IMAGE_PREFIX: &str = "dataset/KITTI/object/training/image_2/";
/// Name of the statistics file written next to `training/`.
pub const STATS_FILE: &str = "sim_stats.json";
/// KITTI frame ids have six digits.
pub const MAX_FRAMES: usize = 1_000_000;

/// Why a dataset could not be written.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("{0}")]
    InvalidArgument(String),
    #[error(
        "{}: the output directory exists and is not empty; pass --force to overwrite the dataset in it, or choose another directory",
        .0.display()
    )]
    NotEmpty(PathBuf),
    #[error("{}: cannot create or use the output directory: {cause}", path.display())]
    Io {
        path: PathBuf,
        cause: std::io::Error,
    },
    /// A file could not be written (the message names it).
    #[error("{0}")]
    Format(FormatError),
}

impl From<FormatError> for SimError {
    fn from(e: FormatError) -> Self {
        SimError::Format(e)
    }
}

/// What to write.
#[derive(Debug, Clone)]
pub struct DatasetOptions {
    pub out: PathBuf,
    pub frames: usize,
    pub seed: u64,
    /// Overwrite a non-empty output directory (only the simulator's own files are removed).
    pub force: bool,
    pub config: SimConfig,
}

impl DatasetOptions {
    /// `frames` frames of the default scenes from `seed` into `out`, which must be new or
    /// empty.
    pub fn new(out: impl Into<PathBuf>, frames: usize, seed: u64) -> DatasetOptions {
        DatasetOptions {
            out: out.into(),
            frames,
            seed,
            force: false,
            config: SimConfig::default(),
        }
    }
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> SimError + '_ {
    move |cause| SimError::Io {
        path: path.to_path_buf(),
        cause,
    }
}

/// Checks the arguments before any work is done.
pub fn validate(opts: &DatasetOptions) -> Result<(), SimError> {
    if opts.frames == 0 {
        return Err(SimError::InvalidArgument(
            "--frames must be at least 1".to_string(),
        ));
    }
    if opts.frames > MAX_FRAMES {
        return Err(SimError::InvalidArgument(format!(
            "--frames must be at most {MAX_FRAMES} (KITTI frame ids have six digits)"
        )));
    }
    let f = opts.config.val_fraction;
    if !(0.0..=1.0).contains(&f) {
        return Err(SimError::InvalidArgument(format!(
            "--val-fraction must be between 0 and 1, got {f}"
        )));
    }
    Ok(())
}

/// Marks a directory as a data set `fusiondet simulate` wrote, with the frame count of that
/// run: `--force` replaces only such a data set, and only its frames. The simulator also
/// holds an advisory lock on it while writing, so two runs cannot mix their frames.
pub const MARKER_FILE: &str = ".fusiondet-sim";
/// The first line of a street data set's marker.
const MARKER_HEAD: &str = "fusiondet simulate";

/// Is `name` one of the files this simulator writes into `dir` (a subfolder name), for a
/// run of `frames` frames?
fn is_ours(dir: &str, name: &str, frames: usize) -> bool {
    // A temporary file of one of ours (a killed write's) is ours too.
    if let Some(target) = fusiondet_kitti::atomic::temp_target(name) {
        return is_ours(dir, target, frames);
    }
    let ext = output_dir::frame_file(name, frames);
    match dir {
        "velodyne" => ext == Some("bin"),
        "calib" | "label_2" => ext == Some("txt"),
        "image_2" | "depth_2" => ext == Some("png"),
        "ImageSets" => matches!(name, "train.txt" | "val.txt" | "trainval.txt"),
        "rgb_detections" => {
            matches!(name, "rgb_detection_train.txt" | "rgb_detection_val.txt")
        }
        "shards" => name.starts_with(crate::sharded::SIMULATE),
        _ => name == STATS_FILE,
    }
}

/// The output directory, open for writing: its lock is held until dropped.
struct PreparedDir {
    ds: DatasetDir,
    _lock: std::fs::File,
}

/// Prepares the output directory ([`output_dir::claim`]): an earlier run's own files are
/// removed when `force` replaces it.
fn prepare_dir(opts: &DatasetOptions) -> Result<PreparedDir, SimError> {
    let root = &opts.out;
    let claimed = output_dir::claim(
        root,
        opts.force,
        MARKER_HEAD,
        &format!("a data set that `fusiondet simulate` wrote (it has no {MARKER_FILE})"),
    )?;
    let lock = claimed.lock;
    if let Some(frames) = claimed.earlier_frames {
        remove_earlier_run(root, frames)?;
    }
    write_marker(root, opts.frames)?;
    Ok(PreparedDir {
        ds: create_layout(root)?,
        _lock: lock,
    })
}

/// Writes the marker of a run of `frames` frames (before any frame, so that a killed run
/// can still be replaced with --force).
pub(crate) fn write_marker(root: &Path, frames: usize) -> Result<(), SimError> {
    output_dir::write_marker(root, MARKER_HEAD, frames)
}

/// The frame count recorded in `root`'s marker, if it is a data set the simulator wrote.
pub(crate) fn read_marker(root: &Path) -> Option<usize> {
    output_dir::marked_frames(
        &std::fs::read_to_string(root.join(MARKER_FILE)).ok()?,
        MARKER_HEAD,
    )
}

/// Creates the data set's folders under `root`.
pub(crate) fn create_layout(root: &Path) -> Result<DatasetDir, SimError> {
    let ds = DatasetDir::new(root);
    let training = ds.training();
    for sub in ["velodyne", "calib", "label_2", "image_2", "depth_2"] {
        let dir = training.root.join(sub);
        std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    }
    for dir in [root.join("ImageSets"), root.join("rgb_detections")] {
        std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    }
    Ok(ds)
}

/// Removes the files an earlier run of `frames` frames wrote under `root` (a sharded run's
/// records and per-shard data included).
pub(crate) fn remove_earlier_run(root: &Path, frames: usize) -> Result<(), SimError> {
    let dirs = [
        ("training/velodyne", "velodyne"),
        ("training/calib", "calib"),
        ("training/label_2", "label_2"),
        ("training/image_2", "image_2"),
        ("training/depth_2", "depth_2"),
        ("ImageSets", "ImageSets"),
        ("rgb_detections", "rgb_detections"),
        (fusiondet_kitti::shard::SHARDS_DIR, "shards"),
        ("", ""),
    ];
    output_dir::remove_own_files(root, &dirs, |kind, name| is_ours(kind, name, frames))
}

/// Writes one simulated frame's five files (the label last).
pub fn write_frame(ds: &DatasetDir, f: &crate::SimFrame) -> Result<(), SimError> {
    let t = ds.training();
    write_velodyne(&t.velodyne(&f.id), &f.points)?;
    write_calib(&t.calib(&f.id), &f.calib)?;
    fusiondet_kitti::image::write_png(&t.image(&f.id), &f.image)?;
    fusiondet_kitti::write_depth_png(&t.depth(&f.id), &f.depth)?;
    write_objects(&t.label(&f.id), &f.objects)?;
    Ok(())
}

/// Frames in flight between the simulating threads and the writers.
const QUEUE: usize = 6;
/// Writer threads: each file is fsynced, so writes wait on the disk rather than the CPU.
const WRITERS: usize = 4;

/// Simulates and writes a dataset; `progress(done, total)` is called after each frame
/// is on disk. Returns the realism statistics (also written to `sim_stats.json`).
pub fn write_dataset(
    opts: &DatasetOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<DatasetStats, SimError> {
    validate(opts)?;
    let prepared = prepare_dir(opts)?;
    let indices: Vec<usize> = (0..opts.frames).collect();
    let summaries = simulate_frames(opts, &prepared.ds, &indices, progress)?;
    write_index_files(&prepared.ds, &opts.out, summaries)
}

/// What the index files and statistics need of one written frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct FrameSummary {
    pub id: String,
    pub val: bool,
    /// The frame's lines of the 2D detection file.
    pub detections: String,
    pub stats: FrameStats,
}

/// Simulates the frames `indices` and writes them into `ds`, returning their summaries in
/// the order of `indices`.
///
/// Frames are simulated in parallel (rayon) and handed to a few writer threads, so
/// that waiting for the disk (every file is written atomically and fsynced) overlaps
/// with simulating the next frames.
pub(crate) fn simulate_frames(
    opts: &DatasetOptions,
    ds: &DatasetDir,
    indices: &[usize],
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<FrameSummary>, SimError> {
    let done = AtomicUsize::new(0);
    let failed = std::sync::atomic::AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::sync_channel::<crate::SimFrame>(QUEUE);
    let rx = std::sync::Mutex::new(rx);
    let (summaries, write_result) = std::thread::scope(|scope| {
        let writers: Vec<_> = (0..WRITERS)
            .map(|_| {
                scope.spawn(|| -> Result<(), SimError> {
                    // After an error keep draining the queue (so no simulating thread
                    // blocks on a full queue) but write nothing more.
                    let mut result = Ok(());
                    loop {
                        let next = rx.lock().expect("writer queue").recv();
                        let Ok(frame) = next else {
                            return result;
                        };
                        if result.is_err() || failed.load(Ordering::Relaxed) {
                            continue;
                        }
                        if let Err(e) = write_frame(ds, &frame) {
                            failed.store(true, Ordering::Relaxed);
                            result = Err(e);
                            continue;
                        }
                        progress(done.fetch_add(1, Ordering::Relaxed) + 1, indices.len());
                    }
                })
            })
            .collect();
        let summaries: Vec<Option<FrameSummary>> = indices
            .par_iter()
            .map_with(tx, |tx, &i| {
                if failed.load(Ordering::Relaxed) {
                    return None;
                }
                let f = simulate_frame(opts.seed, i, &opts.config);
                let summary = FrameSummary {
                    id: f.id.clone(),
                    val: f.split == Split::Val,
                    detections: format_detections2d(&f.detections, IMAGE_PREFIX),
                    stats: FrameStats::from_frame(&f),
                };
                tx.send(f).ok()?;
                Some(summary)
            })
            .collect();
        // All senders are dropped here (map_with's clones end with the iterator).
        let mut result = Ok(());
        for w in writers {
            let r = w.join().expect("writer thread panicked");
            if result.is_ok() {
                result = r;
            }
        }
        (summaries, result)
    });
    write_result?;
    summaries
        .into_iter()
        .collect::<Option<Vec<_>>>()
        .ok_or_else(|| SimError::InvalidArgument("writing frames failed".to_string()))
}

/// Writes the split lists, the 2D detection files and the statistics of the frames
/// `summaries` (in frame order), once those frames are on disk: index files only ever list
/// frames that are complete.
pub(crate) fn write_index_files(
    ds: &DatasetDir,
    out: &Path,
    summaries: Vec<FrameSummary>,
) -> Result<DatasetStats, SimError> {
    let ids = |split: Option<bool>| -> Vec<String> {
        summaries
            .iter()
            .filter(|r| split.is_none_or(|val| r.val == val))
            .map(|r| r.id.clone())
            .collect()
    };
    write_split(&ds.split("train"), &ids(Some(false)))?;
    write_split(&ds.split("val"), &ids(Some(true)))?;
    write_split(&ds.split("trainval"), &ids(None))?;
    for (val, name) in [(false, "train"), (true, "val")] {
        let lines: String = summaries
            .iter()
            .filter(|r| r.val == val)
            .map(|r| r.detections.as_str())
            .collect();
        fusiondet_kitti::write_atomic(&ds.rgb_detections(name), lines.as_bytes())?;
    }
    let frame_stats: Vec<FrameStats> = summaries.into_iter().map(|r| r.stats).collect();
    let stats = DatasetStats::from_frames(&frame_stats);
    fusiondet_kitti::write_atomic(&out.join(STATS_FILE), stats.to_json().as_bytes())?;
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(out: &Path, frames: usize) -> DatasetOptions {
        DatasetOptions::new(out, frames, 1)
    }

    #[test]
    fn bad_arguments_are_refused_before_any_work() {
        let dir = tempfile::tempdir().unwrap();
        let err = write_dataset(&opts(dir.path(), 0), &|_, _| {}).unwrap_err();
        assert!(
            err.to_string().contains("--frames must be at least 1"),
            "{err}"
        );
        let mut o = opts(dir.path(), 1);
        o.config.val_fraction = 1.5;
        assert!(
            write_dataset(&o, &|_, _| {})
                .unwrap_err()
                .to_string()
                .contains("--val-fraction")
        );
        std::fs::write(dir.path().join("keep.txt"), "x").unwrap();
        let err = write_dataset(&opts(dir.path(), 1), &|_, _| {}).unwrap_err();
        assert!(matches!(err, SimError::NotEmpty(_)), "{err}");
        assert!(err.to_string().contains("--force"));
    }

    #[test]
    fn force_removes_only_the_earlier_runs_files() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        std::fs::create_dir_all(root.join("training/velodyne")).unwrap();
        std::fs::write(root.join(MARKER_FILE), "fusiondet simulate\nframes: 8\n").unwrap();
        std::fs::write(root.join("training/velodyne/000007.bin"), b"").unwrap();
        std::fs::write(
            root.join("training/velodyne/000012.bin"),
            b"not from that run",
        )
        .unwrap();
        std::fs::write(root.join("training/velodyne/notes.txt"), b"mine").unwrap();
        std::fs::write(root.join("keep.txt"), b"mine").unwrap();
        let mut o = opts(root, 1);
        o.force = true;
        // A linked label folder leads outside: the run is refused and nothing is removed,
        // here or there.
        #[cfg(unix)]
        {
            let outside = tempfile::tempdir().unwrap();
            std::fs::write(outside.path().join("000001.txt"), b"real labels").unwrap();
            let link = root.join("training/label_2");
            std::os::unix::fs::symlink(outside.path(), &link).unwrap();
            let err = prepare_dir(&o).err().expect("refused").to_string();
            assert!(err.contains("is a symbolic link"), "{err}");
            assert!(outside.path().join("000001.txt").exists());
            assert!(root.join("training/velodyne/000007.bin").exists());
            std::fs::remove_file(&link).unwrap();
        }
        drop(prepare_dir(&o).unwrap());
        assert!(!root.join("training/velodyne/000007.bin").exists());
        assert!(root.join("training/velodyne/000012.bin").exists());
        assert!(root.join("training/velodyne/notes.txt").exists());
        assert!(root.join("keep.txt").exists());
        assert!(root.join("training/image_2").is_dir());
        assert_eq!(read_marker(root), Some(1));
    }

    #[test]
    fn force_refuses_a_directory_the_simulator_did_not_write() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        std::fs::create_dir_all(root.join("training/label_2")).unwrap();
        std::fs::write(root.join("training/label_2/000000.txt"), b"real labels").unwrap();
        let mut o = opts(root, 2);
        o.force = true;
        let err = write_dataset(&o, &|_, _| {}).unwrap_err().to_string();
        assert!(
            err.contains("only a data set that `fusiondet simulate` wrote"),
            "{err}"
        );
        assert_eq!(
            std::fs::read(root.join("training/label_2/000000.txt")).unwrap(),
            b"real labels"
        );
    }

    #[test]
    fn a_second_simulator_is_refused_while_the_first_writes() {
        let dir = tempfile::tempdir().unwrap();
        let mut o = opts(dir.path(), 1);
        let first = prepare_dir(&o).unwrap();
        o.force = true;
        let err = prepare_dir(&o).err().unwrap().to_string();
        assert!(err.contains("another `fusiondet simulate`"), "{err}");
        drop(first);
        assert!(prepare_dir(&o).is_ok());
    }

    #[test]
    fn a_failed_write_stops_the_run_without_index_files() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        // A directory where frame 0's image should go makes its atomic rename fail.
        std::fs::create_dir_all(root.join("training/image_2/000000.png")).unwrap();
        std::fs::write(root.join(MARKER_FILE), "fusiondet simulate\nframes: 2\n").unwrap();
        let mut o = opts(root, 2);
        o.force = true;
        let err = write_dataset(&o, &|_, _| {}).unwrap_err().to_string();
        assert!(err.contains("000000.png"), "{err}");
        assert!(!root.join("ImageSets/trainval.txt").exists());
        assert!(!root.join("rgb_detections/rgb_detection_val.txt").exists());
        assert!(!root.join(STATS_FILE).exists());
    }

    #[test]
    fn our_file_names() {
        assert!(is_ours("velodyne", "000001.bin", 2));
        assert!(!is_ours("velodyne", "000002.bin", 2));
        assert!(!is_ours("velodyne", "000001.txt", 2));
        assert!(is_ours("image_2", ".000001.png.Xk3a9.tmp", 2));
        assert!(is_ours("", "sim_stats.json", 2));
        assert!(!is_ours("", "README.md", 2));
    }
}
