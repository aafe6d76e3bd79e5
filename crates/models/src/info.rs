//! The per-module parameter table of `fusiondet info`.

use crate::config::{FConvNetConfig, ModelConfig, SliceEncoderKind};
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

/// The named blocks of the frustum network, in data-flow order: what `info` groups its
/// rows by, so that a variant's extra parameters show where they sit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Block {
    /// SAF's local feature aggregation.
    Lfa,
    /// The per-scale slice PointNets (without attention).
    PointNets,
    /// FCAM's CBAM blocks inside the PointNets.
    Attention,
    /// FCN blocks 1–4 (convolutions and the merges with the coarser scales).
    Fcn,
    /// The three transposed convolutions.
    Deconv,
    /// Classification and box-regression heads.
    Heads,
}

impl Block {
    pub const ALL: [Block; 6] = [
        Block::Lfa,
        Block::PointNets,
        Block::Attention,
        Block::Fcn,
        Block::Deconv,
        Block::Heads,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Block::Lfa => "LFA",
            Block::PointNets => "PointNets",
            Block::Attention => "attention (CBAM)",
            Block::Fcn => "FCN",
            Block::Deconv => "FCN deconvolutions",
            Block::Heads => "heads",
        }
    }
}

/// One module's trainable parameters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamRow {
    pub block: Block,
    pub name: String,
    pub params: usize,
}

/// Trainable parameter counts per module.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamTable {
    pub rows: Vec<ParamRow>,
    /// Trainable parameters of the whole network.
    pub total: usize,
    /// Batch-norm running statistics (not trained, but stored in checkpoints).
    pub buffers: usize,
}

impl ParamTable {
    pub fn new(model: &FConvNet) -> Self {
        let mut rows = Vec::new();
        let mut row = |block, name: String, params| {
            rows.push(ParamRow {
                block,
                name,
                params,
            })
        };
        if let Some(lfa) = &model.lfa {
            for (k, stage) in lfa.stages.iter().enumerate() {
                row(
                    Block::Lfa,
                    format!("lfa stage {}", k + 1),
                    trainable_params(stage),
                );
            }
            if let Some(gate) = &lfa.gate {
                row(Block::Lfa, "lfa feature gate".into(), gate.dims()[0]);
            }
        }
        for (k, enc) in model.encoders.iter().enumerate() {
            let crate::pointnet::SliceEncoder::PointNet(p) = enc;
            let attention: usize = p.attention.iter().map(trainable_params).sum();
            row(
                Block::PointNets,
                format!("pointnet scale {}", k + 1),
                trainable_params(enc) - attention,
            );
            if attention > 0 {
                row(
                    Block::Attention,
                    format!("attention (cbam) scale {}", k + 1),
                    attention,
                );
            }
        }
        let f = &model.fcn;
        row(Block::Fcn, "fcn block1".into(), trainable_params(&f.block1));
        row(Block::Fcn, "fcn block2".into(), trainable_params(&f.block2));
        row(Block::Fcn, "fcn block3".into(), trainable_params(&f.block3));
        row(Block::Fcn, "fcn block4".into(), trainable_params(&f.block4));
        row(
            Block::Deconv,
            "deconv block2".into(),
            trainable_params(&f.deconv2),
        );
        row(
            Block::Deconv,
            "deconv block3".into(),
            trainable_params(&f.deconv3),
        );
        row(
            Block::Deconv,
            "deconv block4".into(),
            trainable_params(&f.deconv4),
        );
        row(
            Block::Heads,
            "head cls".into(),
            trainable_params(&model.heads.cls),
        );
        row(
            Block::Heads,
            "head reg".into(),
            trainable_params(&model.heads.reg),
        );
        let total = trainable_params(model);
        Self {
            rows,
            total,
            buffers: model.num_params() - total,
        }
    }

    /// Parameters of one block (0 where the network has none).
    pub fn block(&self, block: Block) -> usize {
        self.rows
            .iter()
            .filter(|r| r.block == block)
            .map(|r| r.params)
            .sum()
    }

    /// The row named `name`, if the network has it.
    pub fn row(&self, name: &str) -> Option<usize> {
        self.rows.iter().find(|r| r.name == name).map(|r| r.params)
    }
}

/// The table alone, or beside a baseline's (the extra parameters of each module).
struct TableView<'a> {
    table: &'a ParamTable,
    baseline: Option<&'a ParamTable>,
}

impl fmt::Display for TableView<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let t = self.table;
        let width = t
            .rows
            .iter()
            .map(|r| r.name.len() + 2)
            .chain(Block::ALL.iter().map(|b| b.name().len()))
            .max()
            .unwrap_or(0);
        let extra = |ours: usize, base: Option<usize>| match self.baseline {
            Some(_) => format!("  {:>+12}", ours as i64 - base.unwrap_or(0) as i64),
            None => String::new(),
        };
        match self.baseline {
            Some(_) => writeln!(
                f,
                "{:<width$}  {:>10}  {:>12}",
                "block / module", "parameters", "over F-ConvNet"
            )?,
            None => writeln!(f, "{:<width$}  {:>10}", "block / module", "parameters")?,
        }
        for block in Block::ALL {
            let rows: Vec<&ParamRow> = t.rows.iter().filter(|r| r.block == block).collect();
            if rows.is_empty() {
                continue;
            }
            let n = t.block(block);
            let base = self.baseline.map(|b| b.block(block));
            writeln!(f, "{:<width$}  {n:>10}{}", block.name(), extra(n, base))?;
            for r in rows {
                let base = self.baseline.and_then(|b| b.row(&r.name));
                writeln!(
                    f,
                    "  {:<w$}  {:>10}{}",
                    r.name,
                    r.params,
                    extra(r.params, base),
                    w = width - 2
                )?;
            }
        }
        writeln!(
            f,
            "batch-norm running statistics (stored, not trained): {}",
            t.buffers
        )?;
        write!(f, "parameters: {}", t.total)
    }
}

impl fmt::Display for ParamTable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        TableView {
            table: self,
            baseline: None,
        }
        .fmt(f)
    }
}

/// A parameter count a paper publishes for a network of this shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Published {
    pub params: usize,
    pub source: &'static str,
}

impl Published {
    /// `ours` against the paper's figure: the difference and its share of the paper's.
    pub fn compare(&self, ours: usize) -> String {
        let diff = ours as i64 - self.params as i64;
        format!(
            "paper: {} ({}); ours {diff:+} ({:+.2}%)",
            self.params,
            self.source,
            100.0 * diff as f64 / self.params as f64
        )
    }
}

/// The network without the variants' blocks: F-ConvNet at the same widths.
fn backbone_of(config: &ModelConfig) -> ModelConfig {
    ModelConfig {
        lfa: None,
        slice_encoder: SliceEncoderKind::PointNet,
        attention: Default::default(),
        ..config.clone()
    }
}

/// The paper's count for `config`'s network, where one is published: only for the
/// published F-ConvNet widths with KITTI's three classes (the one-hot and the size
/// clusters are part of the count), and only for the forms a paper counts. SAF's slicing
/// and projection loss add no parameters, so every network with LFA compares to SAF's
/// full model; the Pedestrian and Cyclist networks are the Car one (Tables 5 and 6 give
/// the same figures as Table 4).
pub fn published_parameters(config: &ModelConfig) -> Option<Published> {
    if backbone_of(config) != ModelConfig::car() {
        return None;
    }
    match (config.slice_encoder, &config.lfa) {
        (SliceEncoderKind::PointNet, None) => Some(Published {
            params: 3_316_777,
            source: "F-ConvNet as the SAF paper counts it, Tables 4-6; the FCAM paper quotes 3340089",
        }),
        (SliceEncoderKind::PointNet, Some(_)) => Some(Published {
            params: 3_724_013,
            source: "SAF, He et al., Sensors 2022, Tables 4-6",
        }),
        (SliceEncoderKind::ImprovedCbam, None) => Some(Published {
            params: 3_351_353,
            source: "FCAM, Sensors 2021",
        }),
        _ => None,
    }
}

/// The paper's count for a refinement model's two stages (first stage and refinement
/// stage both F-ConvNet): SAF's Table 4, "Backbone + Refine".
pub fn published_two_stage_parameters(
    first: &ModelConfig,
    refine: &ModelConfig,
) -> Option<Published> {
    let plain = |c: &ModelConfig| *c == ModelConfig::car();
    (plain(first) && plain(refine)).then_some(Published {
        params: 6_633_554,
        source: "F-ConvNet with its refinement stage, SAF paper Table 4",
    })
}

/// Trainable parameters of the network `config` describes (built on the CPU, not run).
pub fn parameter_count(config: &crate::config::ModelConfig) -> Result<usize, ModelError> {
    Ok(trainable_params(&FConvNet::new(config, &Device::flex())?))
}

/// The text `fusiondet info --config FILE` prints: a configuration summary, the table by
/// block (beside F-ConvNet at the same widths for a variant, so that its extra
/// parameters show where they sit) and, where a paper publishes a count for this
/// network, that count and our difference. The network is built on the CPU device
/// without running it.
pub fn render_info(config: &FConvNetConfig) -> Result<String, ModelError> {
    let m = &config.model;
    let device = Device::flex();
    let table = ParamTable::new(&FConvNet::new(m, &device)?);
    let backbone = backbone_of(m);
    let baseline = if backbone != *m {
        Some(ParamTable::new(&FConvNet::new(&backbone, &device)?))
    } else {
        None
    };
    let view = TableView {
        table: &table,
        baseline: baseline.as_ref(),
    };
    let paper = match published_parameters(m) {
        Some(p) => format!("\n{}", p.compare(table.total)),
        None => String::new(),
    };
    Ok(format!(
        "F-ConvNet: {:?} slice encoder{}, pointnet widths {:?}, fcn channels {:?}, deconv {} × 3, \
         {} heading bins, {} size clusters, regression {} per position\n{view}{paper}",
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

/// Multiply-adds of one F-ConvNet forward pass over a batch, by part. Counted from the layer
/// shapes and the batch's real (point, sub-frustum) pairs, as the ragged PointNets run them:
/// a `Linear` is in × out per row, a convolution in × out × kernel per output position, a
/// transposed one in × out × stride per input position. Batch norm, ReLU, pooling and
/// concatenation are left out (they are not multiply-adds); so are SAF's LFA and FCAM's
/// attention blocks, which `counted_all` then reports as false.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForwardMacs {
    pub pointnets: [u64; 4],
    pub fcn: u64,
    pub heads: u64,
    /// False when the network has blocks this count leaves out (LFA, attention).
    pub counted_all: bool,
}

impl ForwardMacs {
    pub fn total(&self) -> u64 {
        self.pointnets.iter().sum::<u64>() + self.fcn + self.heads
    }
}

/// [`ForwardMacs`] of `config`'s network on `batch`.
pub fn forward_macs(
    config: &crate::config::ModelConfig,
    batch: &fusiondet_frustum::FrustumBatch,
) -> Result<ForwardMacs, ModelError> {
    if batch.scales.len() != 4 || config.pointnet_widths.len() != 4 {
        return Err(ModelError::Batch(
            "multiply-adds are counted for four scales".into(),
        ));
    }
    let b = batch.batch_size as u64;
    let mut pointnets = [0u64; 4];
    for (k, scale) in batch.scales.iter().enumerate() {
        let mut c_in = config.pointnet_input_channels() as u64;
        let mut per_row = 0;
        for &w in &config.pointnet_widths[k] {
            per_row += c_in * w as u64;
            c_in = w as u64;
        }
        pointnets[k] = per_row * scale.pair_point.len() as u64;
    }
    let c: Vec<u64> = config.fcn_channels.iter().map(|&x| x as u64).collect();
    let s = |k: usize| config.scale_feature_channels(k) as u64;
    let d = config.deconv_channels as u64;
    // Output lengths: block 1 keeps scale 1's slices, each down block halves (rounding up).
    let l1 = batch.scales[0].slices_per_frustum as u64;
    let l2 = l1.div_ceil(2);
    let l3 = l2.div_ceil(2);
    let l4 = l3.div_ceil(2);
    let down = |c_in: u64, c_out: u64, s_next: u64, l: u64| {
        l * (c_in * c_out * 3 + c_out * c_out * 3 + (c_out + s_next) * c_out)
    };
    let fcn = b
        * (l1 * s(0) * c[0] * 3
            + down(c[0], c[1], s(1), l2)
            + down(c[1], c[2], s(2), l3)
            + down(c[2], c[3], s(3), l4)
            + l2 * c[1] * d
            + l3 * c[2] * d * 2
            + l4 * c[3] * d * 4);
    let heads = b * l2 * config.head_channels() as u64 * (2 + config.regression_channels() as u64);
    Ok(ForwardMacs {
        pointnets,
        fcn,
        heads,
        counted_all: config.lfa.is_none() && !config.slice_encoder.uses_attention(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{SyntheticSpec, synthetic_batch};

    /// The count's arithmetic against the shapes of the network burn builds: every weight
    /// element is one multiply-add per output position (per input position for the
    /// transposed convolutions, whose weights hold stride taps each).
    #[test]
    fn forward_macs_match_the_built_layers() {
        let config = crate::config::ModelConfig::car();
        let batch = synthetic_batch(&SyntheticSpec::car(2), 3);
        let macs = forward_macs(&config, &batch).unwrap();
        assert!(macs.counted_all);
        let model = FConvNet::new(&config, &Device::flex()).unwrap();
        let elems = |t: &Tensor<3>| t.dims().iter().product::<usize>() as u64;
        let f = &model.fcn;
        let lens: Vec<u64> = batch
            .scales
            .iter()
            .map(|s| s.slices_per_frustum as u64)
            .collect();
        let down = |blk: &crate::fcn::DownBlock, l: u64| {
            (elems(&blk.down.conv.weight.val())
                + elems(&blk.conv.conv.weight.val())
                + elems(&blk.merge.conv.weight.val()))
                * l
        };
        let fcn = 2
            * (elems(&f.block1.conv.weight.val()) * lens[0]
                + down(&f.block2, lens[1])
                + down(&f.block3, lens[2])
                + down(&f.block4, lens[3])
                + elems(&f.deconv2.deconv.weight.val()) * lens[1]
                + elems(&f.deconv3.deconv.weight.val()) * lens[2]
                + elems(&f.deconv4.deconv.weight.val()) * lens[3]);
        assert_eq!(macs.fcn, fcn);
        let heads = (trainable_params(&model.heads.cls) + trainable_params(&model.heads.reg)
            - 2
            - config.regression_channels()) as u64;
        assert_eq!(macs.heads, 2 * lens[1] * heads);
        for (k, enc) in model.encoders.iter().enumerate() {
            let crate::pointnet::SliceEncoder::PointNet(p) = enc;
            let weights: u64 = p
                .layers
                .iter()
                .map(|l| l.linear.weight.val().dims().iter().product::<usize>() as u64)
                .sum();
            assert_eq!(
                macs.pointnets[k],
                weights * batch.scales[k].pair_point.len() as u64
            );
        }
        let mut saf = config.clone();
        saf.lfa = Some(crate::config::LfaConfig::default());
        assert!(!forward_macs(&saf, &batch).unwrap().counted_all);
    }
}
