//! A training run's directory and its resumable state.
//!
//! ```text
//! RUN_DIR/config.toml                 the experiment configuration (fixed for the run)
//! RUN_DIR/state.json                  epochs done + the checkpoint files holding them
//! RUN_DIR/checkpoints/epoch-NNNN.bpk  weights after epoch NNNN (1-based)
//! RUN_DIR/checkpoints/epoch-NNNN.optim.bpk   Adam's moments at that point
//! RUN_DIR/model.bpk                   the latest weights: what `detect` takes
//! RUN_DIR/metrics.jsonl               one JSON line per epoch
//! ```
//! `state.json` is replaced atomically only after both checkpoint files of an epoch are
//! complete, and older checkpoints are removed only after that: a kill at any moment
//! leaves a state that names complete files, losing at most the epoch in progress.
//!
//! A training holds `RUN_DIR/.lock` (an advisory lock) while it writes, so a second
//! `train` into the same directory is refused. Only the files above are ever removed:
//! older epochs' checkpoints, and temporary files a killed write left behind.

use crate::error::{PipelineError, Result};
use fusiondet_kitti::atomic::{remove_temp_files, try_lock_file};
use fusiondet_kitti::write_atomic;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunState {
    pub epochs_done: usize,
    /// Relative to the run directory.
    pub model: String,
    pub optimizer: String,
    /// A checksum of the optimizer file's bytes ([`file_checksum`]), so that a damaged
    /// optimizer state is refused on resume as damaged weights are (absent in runs
    /// written before it was kept).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optimizer_checksum: Option<String>,
}

/// A checksum of a file's bytes: 16 hex digits of SHA-256.
pub fn file_checksum(path: &Path) -> Result<String> {
    let bytes =
        fusiondet_kitti::error::read_regular(path, fusiondet_kitti::error::MAX_BINARY_BYTES)?;
    Ok(fusiondet_kitti::shard::fingerprint(&[&bytes]))
}

#[derive(Debug, Clone)]
pub struct RunDir {
    pub root: PathBuf,
}

/// The run directory's lock, held until dropped (see the module documentation).
#[derive(Debug)]
pub struct RunLock {
    _file: File,
}

/// The lock file's name; not counted as content when a new run checks for an empty
/// directory.
const LOCK_FILE: &str = ".lock";

/// Whether `name` (in `checkpoints/`) is one of a run's epoch checkpoint files.
fn is_epoch_checkpoint(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("epoch-") else {
        return false;
    };
    let digits = rest
        .strip_suffix(".optim.bpk")
        .or_else(|| rest.strip_suffix(".bpk"));
    digits.is_some_and(|d| d.len() >= 4 && d.bytes().all(|b| b.is_ascii_digit()))
}

/// Whether `name` is one of the run's own files (those a killed write may leave a
/// temporary file of).
fn is_run_file(name: &str) -> bool {
    ["config.toml", "state.json", "metrics.jsonl", "model.bpk"].contains(&name)
        || is_epoch_checkpoint(name)
}

impl RunDir {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        RunDir { root: root.into() }
    }
    pub fn config(&self) -> PathBuf {
        self.root.join("config.toml")
    }
    pub fn state(&self) -> PathBuf {
        self.root.join("state.json")
    }
    pub fn metrics(&self) -> PathBuf {
        self.root.join("metrics.jsonl")
    }
    pub fn model(&self) -> PathBuf {
        self.root.join("model.bpk")
    }
    pub fn checkpoints(&self) -> PathBuf {
        self.root.join("checkpoints")
    }
    pub fn epoch_model(&self, epoch: usize) -> String {
        format!("checkpoints/epoch-{epoch:04}.bpk")
    }
    pub fn epoch_optimizer(&self, epoch: usize) -> String {
        format!("checkpoints/epoch-{epoch:04}.optim.bpk")
    }

    fn err(&self, path: &Path, message: impl Into<String>) -> PipelineError {
        PipelineError::RunDir {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// Prepares the directory for a new run (it must be absent or empty) or checks it
    /// for a resumed one (`compatible` must accept its stored config; the stored file is
    /// then replaced by `config_toml`, e.g. with more epochs). Returns the state to
    /// resume from, if any.
    pub fn open(
        &self,
        config_toml: &str,
        resume: bool,
        compatible: &dyn Fn(&str) -> bool,
    ) -> Result<(RunLock, Option<RunState>)> {
        // Checked before the lock file is made, so that a directory that is not ours gets
        // nothing written into it; and again under the lock, against a run started between.
        self.check_contents(resume)?;
        let lock = self.lock()?;
        self.check_contents(resume)?;
        std::fs::create_dir_all(self.checkpoints())
            .map_err(|e| self.err(&self.root, format!("cannot create: {e}")))?;
        self.remove_stale_temp_files();
        if resume && self.config().exists() {
            let stored = fusiondet_kitti::error::read_text(&self.config())?;
            if !compatible(&stored) {
                return Err(self.err(
                    &self.config(),
                    "this run was started with another configuration; resume with the same --config (the run's config.toml; only train.epochs may change), or start a new run",
                ));
            }
        }
        write_atomic(&self.config(), config_toml.as_bytes())?;
        if !resume || !self.state().exists() {
            return Ok((lock, None));
        }
        let text = fusiondet_kitti::error::read_text(&self.state())?;
        let state: RunState = serde_json::from_str(&text).map_err(|e| {
            self.err(
                &self.state(),
                format!("corrupt state ({e}); remove it to restart the run"),
            )
        })?;
        for file in [&state.model, &state.optimizer] {
            if !self.root.join(file).is_file() {
                return Err(self.err(&self.root.join(file), "named by state.json but missing"));
            }
        }
        if let Some(stored) = &state.optimizer_checksum {
            let path = self.root.join(&state.optimizer);
            let found = file_checksum(&path)?;
            if found != *stored {
                return Err(self.err(
                    &path,
                    format!(
                        "the optimizer state is damaged (its checksum is {found}, the run wrote \
                         {stored}); restore the file, or resume from an earlier epoch by \
                         starting a new run"
                    ),
                ));
            }
        }
        Ok((lock, Some(state)))
    }

    /// A new run needs an empty (or absent) directory; a resumed one a directory that
    /// holds a run (its `config.toml`), or nothing yet.
    fn check_contents(&self, resume: bool) -> Result<()> {
        let non_empty = std::fs::read_dir(&self.root)
            .map(|d| d.flatten().any(|e| e.file_name() != LOCK_FILE))
            .unwrap_or(false);
        if non_empty && !resume {
            return Err(self.err(
                &self.root,
                "the run directory is not empty; pass --resume to continue that run, or choose another --out",
            ));
        }
        if non_empty && !self.config().is_file() {
            return Err(self.err(
                &self.root,
                "not a training run (it has no config.toml), so there is nothing to resume and \
                 its files are not ours to replace; choose another --out",
            ));
        }
        Ok(())
    }

    /// Takes the run directory's lock, creating the directory if needed.
    pub fn lock(&self) -> Result<RunLock> {
        std::fs::create_dir_all(&self.root)
            .map_err(|e| self.err(&self.root, format!("cannot create: {e}")))?;
        let path = self.root.join(LOCK_FILE);
        match try_lock_file(&path) {
            Ok(Some(file)) => Ok(RunLock { _file: file }),
            Ok(None) => Err(self.err(
                &self.root,
                "another fusiondet process is training into this run directory; wait for it \
                 to finish or choose another --out",
            )),
            Err(e) => Err(self.err(&path, format!("cannot lock the run directory: {e}"))),
        }
    }

    /// Removes temporary files that killed writes of the run's own files left behind (only
    /// under the lock: no writer of this run is running).
    fn remove_stale_temp_files(&self) {
        for dir in [self.root.clone(), self.checkpoints()] {
            remove_temp_files(&dir, is_run_file);
        }
    }

    /// Records a finished epoch whose checkpoint files are already written, then removes
    /// the checkpoints of earlier epochs (files of other names under `checkpoints/` stay).
    pub fn commit(&self, state: &RunState) -> Result<()> {
        let json = serde_json::to_string_pretty(state).expect("state serialises");
        write_atomic(&self.state(), json.as_bytes())?;
        let keep = [
            self.root.join(&state.model),
            self.root.join(&state.optimizer),
        ];
        if let Ok(entries) = std::fs::read_dir(self.checkpoints()) {
            for entry in entries.flatten() {
                let path = entry.path();
                let ours = entry.file_name().to_str().is_some_and(is_epoch_checkpoint);
                if ours && !keep.contains(&path) {
                    let _ = std::fs::remove_file(path);
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_run_refuses_non_empty_dirs_and_resume_checks_config() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path().join("run"));
        let same = |stored: &str| stored == "a = 1\n";
        assert_eq!(run.open("a = 1\n", false, &same).unwrap().1, None);
        let err = run.open("a = 1\n", false, &same).unwrap_err().to_string();
        assert!(err.contains("--resume"), "{err}");
        std::fs::write(run.config(), "a = 2\n").unwrap();
        let err = run.open("a = 1\n", true, &same).unwrap_err().to_string();
        assert!(err.contains("another configuration"), "{err}");
        std::fs::write(run.config(), "a = 1\n").unwrap();
        assert_eq!(run.open("a = 1\n", true, &same).unwrap().1, None);
    }

    #[test]
    fn commit_keeps_the_named_checkpoint_and_files_not_its_own() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        drop(run.open("x\n", false, &|_| true).unwrap());
        for e in 1..=2 {
            std::fs::write(run.root.join(run.epoch_model(e)), b"m").unwrap();
            std::fs::write(run.root.join(run.epoch_optimizer(e)), b"o").unwrap();
        }
        let users = run.checkpoints().join("best.bpk");
        std::fs::write(&users, b"a copy the user made").unwrap();
        let optimizer = run.root.join(run.epoch_optimizer(2));
        let state = RunState {
            epochs_done: 2,
            model: run.epoch_model(2),
            optimizer: run.epoch_optimizer(2),
            optimizer_checksum: Some(file_checksum(&optimizer).unwrap()),
        };
        run.commit(&state).unwrap();
        assert_eq!(std::fs::read_dir(run.checkpoints()).unwrap().count(), 3);
        assert!(users.is_file());
        assert_eq!(
            run.open("x\n", true, &|_| true).unwrap().1,
            Some(state.clone())
        );
        // A flipped bit in the optimizer state is refused on resume, naming the file.
        std::fs::write(&optimizer, b"O").unwrap();
        let err = run.open("x\n", true, &|_| true).unwrap_err().to_string();
        assert!(
            err.contains("optimizer state is damaged") && err.contains("epoch-0002.optim.bpk"),
            "{err}"
        );
        std::fs::write(&optimizer, b"o").unwrap();
        std::fs::remove_file(run.root.join(run.epoch_optimizer(2))).unwrap();
        let err = run.open("x\n", true, &|_| true).unwrap_err().to_string();
        assert!(err.contains("missing"), "{err}");
    }

    #[test]
    fn a_second_writer_is_refused_while_the_first_holds_the_run() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path().join("run"));
        let (held, _) = run.open("x\n", false, &|_| true).unwrap();
        let err = run.open("x\n", true, &|_| true).unwrap_err().to_string();
        assert!(err.contains("another fusiondet process"), "{err}");
        drop(held);
        assert!(run.open("x\n", true, &|_| true).is_ok());
    }

    #[test]
    fn resume_refuses_a_directory_that_is_not_a_run() {
        let dir = tempfile::tempdir().unwrap();
        let users = dir.path().join("model.bpk");
        std::fs::write(&users, b"the user's model").unwrap();
        let err = RunDir::new(dir.path())
            .open("x\n", true, &|_| true)
            .unwrap_err()
            .to_string();
        assert!(err.contains("not a training run"), "{err}");
        assert_eq!(std::fs::read(&users).unwrap(), b"the user's model");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().flatten().collect();
        assert_eq!(names.len(), 1, "nothing written beside it");
    }

    #[test]
    fn temporary_files_of_killed_writes_are_removed_on_open() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        drop(run.open("x\n", false, &|_| true).unwrap());
        let stale = [
            run.root.join("model.bpk.4242-2.tmp"),
            run.root.join(".state.json.k3Jx9a.tmp"),
            run.checkpoints().join("epoch-0003.bpk.4242-0.tmp"),
            run.checkpoints().join("epoch-0003.optim.bpk.4242-1.tmp"),
        ];
        let kept = [
            run.root.join("notes.tmp"),
            run.checkpoints().join("best.bpk.4242-0.tmp"),
        ];
        for path in stale.iter().chain(&kept) {
            std::fs::write(path, b"t").unwrap();
        }
        drop(run.open("x\n", true, &|_| true).unwrap());
        assert!(stale.iter().all(|p| !p.exists()));
        assert!(kept.iter().all(|p| p.exists()));
    }
}
