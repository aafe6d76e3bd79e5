//! Errors of training and detection; each says what to do next.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Format(#[from] fusiondet_kitti::FormatError),
    #[error(transparent)]
    Data(#[from] fusiondet_dataset::DataError),
    #[error(transparent)]
    Frustum(#[from] fusiondet_frustum::FrustumError),
    #[error(transparent)]
    Model(#[from] fusiondet_models::ModelError),
    #[error("{}: {message}", path.display())]
    Config { path: PathBuf, message: String },
    /// A configuration value out of range, at the line that sets it.
    #[error("{}:{line}: {message}", path.display())]
    ConfigAt {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{}: {message}", path.display())]
    RunDir { path: PathBuf, message: String },
    #[error("{0}")]
    Invalid(String),
    /// The user stopped a training (Ctrl-C); `epochs_done` epochs are committed.
    #[error("{}", interrupted_message(*epochs_done))]
    Interrupted { epochs_done: usize },
}

fn interrupted_message(epochs_done: usize) -> String {
    if epochs_done == 0 {
        "interrupted before the first epoch finished; nothing was kept".into()
    } else {
        format!("interrupted after epoch {epochs_done}; rerun with --resume to continue")
    }
}

pub type Result<T> = std::result::Result<T, PipelineError>;
