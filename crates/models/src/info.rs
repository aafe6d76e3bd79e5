//! The per-module parameter table of `fusiondet info`.

use crate::config::FConvNetConfig;
use crate::error::ModelError;
use crate::model::FConvNet;
use burn::module::{ModuleVisitor, Param};
use burn::prelude::*;
use std::fmt;

/// Trainable parameters of a module: its float parameters minus the batch-norm running
/// statistics (`running_*` buffers), which burn's `num_params()` also counts.
pub fn trainable_params<M: Module>(module: &M) -> usize {
    struct Counter {
        path: Vec<String>,
        total: usize,
    }
    impl ModuleVisitor for Counter {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if !self.path.last().is_some_and(|n| n.starts_with("running_")) {
                self.total += param.lazy_shape().num_elements();
            }
        }
    }
    let mut counter = Counter {
        path: Vec::new(),
        total: 0,
    };
    module.visit(&mut counter);
    counter.total
}

/// Trainable parameter counts per module.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamTable {
    pub rows: Vec<(String, usize)>,
    /// Trainable parameters of the whole network.
    pub total: usize,
    /// Batch-norm running statistics (not trained, but stored in checkpoints).
    pub buffers: usize,
}

impl ParamTable {
    pub fn new(model: &FConvNet) -> Self {
        let mut rows = Vec::new();
        if let Some(lfa) = &model.lfa {
            for (k, stage) in lfa.stages.iter().enumerate() {
                rows.push((format!("lfa stage {}", k + 1), trainable_params(stage)));
            }
        }
        for (k, enc) in model.encoders.iter().enumerate() {
            let crate::pointnet::SliceEncoder::PointNet(p) = enc;
            let attention: usize = p.attention.iter().map(trainable_params).sum();
            rows.push((
                format!("pointnet scale {}", k + 1),
                trainable_params(enc) - attention,
            ));
            if attention > 0 {
                rows.push((format!("  attention (cbam) scale {}", k + 1), attention));
            }
        }
        let f = &model.fcn;
        rows.push(("fcn block1".into(), trainable_params(&f.block1)));
        rows.push(("fcn block2".into(), trainable_params(&f.block2)));
        rows.push(("fcn block3".into(), trainable_params(&f.block3)));
        rows.push(("fcn block4".into(), trainable_params(&f.block4)));
        rows.push(("deconv block2".into(), trainable_params(&f.deconv2)));
        rows.push(("deconv block3".into(), trainable_params(&f.deconv3)));
        rows.push(("deconv block4".into(), trainable_params(&f.deconv4)));
        rows.push(("head cls".into(), trainable_params(&model.heads.cls)));
        rows.push(("head reg".into(), trainable_params(&model.heads.reg)));
        let total = trainable_params(model);
        Self {
            rows,
            total,
            buffers: model.num_params() - total,
        }
    }
}

impl fmt::Display for ParamTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let width = self.rows.iter().map(|(n, _)| n.len()).max().unwrap_or(0);
        for (name, n) in &self.rows {
            writeln!(f, "{name:<width$}  {n:>10}")?;
        }
        writeln!(
            f,
            "batch-norm running statistics (stored, not trained): {}",
            self.buffers
        )?;
        write!(f, "parameters: {}", self.total)
    }
}

/// Trainable parameters of the network `config` describes (built on the CPU, not run).
pub fn parameter_count(config: &crate::config::ModelConfig) -> Result<usize, ModelError> {
    Ok(trainable_params(&FConvNet::new(config, &Device::flex())?))
}

/// The text `fusiondet info --config FILE` prints: a configuration summary and the table.
/// The network is built on the CPU device without running it.
pub fn render_info(config: &FConvNetConfig) -> Result<String, ModelError> {
    let m = &config.model;
    let model = FConvNet::new(m, &Device::flex())?;
    let table = ParamTable::new(&model);
    Ok(format!(
        "F-ConvNet: {:?} slice encoder{}, pointnet widths {:?}, fcn channels {:?}, deconv {} × 3, \
         {} heading bins, {} size clusters, regression {} per position\n{table}",
        m.slice_encoder,
        match &m.lfa {
            Some(l) => format!(
                " after LFA (K = {}, {} halvings, {} channels per point)",
                l.neighbours,
                l.stages.len(),
                l.out_channels()
            ),
            None => String::new(),
        },
        m.pointnet_widths,
        m.fcn_channels,
        m.deconv_channels,
        m.num_heading_bins,
        m.size_clusters.len(),
        m.regression_channels(),
    ))
}
