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

use crate::error::{PipelineError, Result};
use fusiondet_kitti::write_atomic;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunState {
    pub epochs_done: usize,
    /// Relative to the run directory.
    pub model: String,
    pub optimizer: String,
}

#[derive(Debug, Clone)]
pub struct RunDir {
    pub root: PathBuf,
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
    ) -> Result<Option<RunState>> {
        let non_empty = std::fs::read_dir(&self.root)
            .map(|mut d| d.next().is_some())
            .unwrap_or(false);
        if non_empty && !resume {
            return Err(self.err(
                &self.root,
                "the run directory is not empty; pass --resume to continue that run, or choose another --out",
            ));
        }
        std::fs::create_dir_all(self.checkpoints())
            .map_err(|e| self.err(&self.root, format!("cannot create: {e}")))?;
        if resume && self.config().exists() {
            let stored = std::fs::read_to_string(self.config())
                .map_err(|e| self.err(&self.config(), format!("cannot read: {e}")))?;
            if !compatible(&stored) {
                return Err(self.err(
                    &self.config(),
                    "this run was started with another configuration; resume with the same --config (the run's config.toml; only train.epochs may change), or start a new run",
                ));
            }
        }
        write_atomic(&self.config(), config_toml.as_bytes())?;
        if !resume || !self.state().exists() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(self.state())
            .map_err(|e| self.err(&self.state(), format!("cannot read: {e}")))?;
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
        Ok(Some(state))
    }

    /// Records a finished epoch whose checkpoint files are already written, then removes
    /// the checkpoints of earlier epochs.
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
                if !keep.contains(&path) {
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
        assert_eq!(run.open("a = 1\n", false, &same).unwrap(), None);
        let err = run.open("a = 1\n", false, &same).unwrap_err().to_string();
        assert!(err.contains("--resume"), "{err}");
        std::fs::write(run.config(), "a = 2\n").unwrap();
        let err = run.open("a = 1\n", true, &same).unwrap_err().to_string();
        assert!(err.contains("another configuration"), "{err}");
        std::fs::write(run.config(), "a = 1\n").unwrap();
        assert_eq!(run.open("a = 1\n", true, &same).unwrap(), None);
    }

    #[test]
    fn commit_keeps_only_the_named_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        run.open("x\n", false, &|_| true).unwrap();
        for e in 1..=2 {
            std::fs::write(run.root.join(run.epoch_model(e)), b"m").unwrap();
            std::fs::write(run.root.join(run.epoch_optimizer(e)), b"o").unwrap();
        }
        let state = RunState {
            epochs_done: 2,
            model: run.epoch_model(2),
            optimizer: run.epoch_optimizer(2),
        };
        run.commit(&state).unwrap();
        assert_eq!(std::fs::read_dir(run.checkpoints()).unwrap().count(), 2);
        assert_eq!(run.open("x\n", true, &|_| true).unwrap(), Some(state));
        std::fs::remove_file(run.root.join(run.epoch_optimizer(2))).unwrap();
        let err = run.open("x\n", true, &|_| true).unwrap_err().to_string();
        assert!(err.contains("missing"), "{err}");
    }
}
