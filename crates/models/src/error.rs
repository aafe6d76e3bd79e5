use std::path::PathBuf;

/// Errors of the network crate.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("invalid model configuration: {0}")]
    InvalidConfig(String),
    #[error("cannot parse configuration: {0}")]
    ConfigParse(String),
    /// The batch does not fit the network (scale count, slice lengths, targets, ...).
    #[error("batch does not fit the network: {0}")]
    Batch(String),
    /// A loss term is NaN or infinite; training must stop without writing a checkpoint.
    #[error(
        "non-finite loss: {component} = {value} (total {total}); stopping before the weights are updated"
    )]
    NonFiniteLoss {
        component: &'static str,
        value: f32,
        total: f32,
    },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("checkpoint {}: {message}", path.display())]
    Checkpoint { path: PathBuf, message: String },
    /// The checkpoint was written by a network with another architecture.
    #[error(
        "checkpoint {} was written for another model configuration ({differences}); \
         use the configuration it was trained with",
        path.display()
    )]
    ConfigMismatch { path: PathBuf, differences: String },
}
