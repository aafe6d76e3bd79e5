//! Frustum ConvNet (F-ConvNet, Wang & Jia, IROS 2019) in burn: the network, its loss,
//! inference decoding, checkpoints and the parameter table of `fusiondet info`.
//!
//! Module boundaries: [`pointnet`] (per-scale slice encoders over ragged point/slice pairs,
//! with FCAM's [`attention`] blocks),
//! [`fcn`] (the fully convolutional network over the slice sequence), [`heads`],
//! [`loss`]. The model code is backend-agnostic: tensors live on a [`burn::tensor::Device`]
//! chosen at run time (`Device::flex()` on the CPU, `.autodiff()` for training).
//!
//! ```no_run
//! use burn::prelude::*;
//! use fusiondet_models::{FConvNet, FConvNetConfig, decode};
//! # fn run(batch: &fusiondet_frustum::FrustumBatch) -> Result<(), fusiondet_models::ModelError> {
//! let config = FConvNetConfig::car();
//! let device = Device::flex();
//! let model = FConvNet::new(&config.model, &device)?.valid();
//! let inputs = model.inputs(batch, &device)?;
//! let output = model.forward_inputs(&inputs);
//! let predictions = decode(&output, &inputs, &config.model)?;
//! # Ok(()) }
//! ```

pub mod attention;
pub mod boxes;
pub mod checkpoint;
pub mod config;
pub mod dasanet;
pub mod decode;
#[cfg(all(test, feature = "wgpu"))]
mod device_test_support;
pub mod error;
pub mod family;
pub mod fcn;
pub mod heads;
pub mod info;
pub mod inputs;
pub mod lfa;
pub mod loss;
pub mod model;
pub mod pointnet;
pub mod synthetic;
pub mod voxel_rcnn;

pub use checkpoint::{
    load_checkpoint, read_checkpoint_config, read_checkpoint_kind, save_checkpoint,
};
pub use config::{
    AttentionConfig, CoordinateInit, FConvNetConfig, LfaConfig, LfaFeatureGate, LfaStageConfig,
    LossConfig, ModelConfig, SliceEncoderKind,
};
pub use decode::{FrustumPrediction, decode};
pub use error::ModelError;
pub use family::DetectorKind;
pub use info::{
    Block, ForwardMacs, ParamRow, ParamTable, Published, forward_macs, published_parameters,
    render_info,
};
pub use inputs::BatchInputs;
pub use loss::{LossComponents, LossOutput, LossTargets, fconvnet_loss};
pub use model::{FConvNet, FConvNetOutput};
