//! Inference decoding, the network's half: the best position of each frustum and its box
//! components read from the output tensors, in the box coder's terms
//! ([`FrustumPrediction::encoding`]); the coder's other half turns them into boxes.

use crate::config::ModelConfig;
use crate::error::ModelError;
use crate::heads::RegressionLayout;
use crate::inputs::BatchInputs;
use crate::model::FConvNetOutput;
use fusiondet_frustum::{BoxCoder, BoxEncoding};

/// The prediction of one frustum at its highest-scoring position.
#[derive(Debug, Clone, PartialEq)]
pub struct FrustumPrediction {
    /// Output position (slice of the output scale) with the highest object probability.
    pub position: usize,
    /// Softmax probability of "object" at that position.
    pub score: f32,
    /// Box centre (geometric), frustum frame: the position's slice centre + the offset.
    pub center: [f32; 3],
    /// Highest-scoring heading bin (bin k centred on k · 2π / bins).
    pub heading_bin: usize,
    /// Residual from the bin centre in radians (the normalised output × π / bins).
    pub heading_residual: f32,
    /// Highest-scoring size cluster.
    pub size_cluster: usize,
    /// (l, w, h) residual of that cluster over its mean size (size = mean · (1 + residual)).
    pub size_residual: [f32; 3],
}

impl FrustumPrediction {
    /// The prediction in the box coder's terms (the centre in the frustum frame), which
    /// [`BoxCoder::decode_encoding`] turns into a KITTI box.
    pub fn encoding(&self) -> BoxEncoding {
        BoxEncoding {
            center: self.center.map(f64::from),
            heading_bin: self.heading_bin,
            heading_residual: self.heading_residual as f64,
            size_cluster: self.size_cluster,
            size_residual: self.size_residual.map(f64::from),
        }
    }

    /// The heading angle in (−π, π].
    pub fn heading(&self, coder: &BoxCoder) -> f32 {
        coder.bin_to_heading_f32(self.heading_bin, self.heading_residual)
    }

    /// (l, w, h) in metres.
    pub fn size(&self, coder: &BoxCoder) -> [f32; 3] {
        let mean = coder.mean_sizes_f32()[self.size_cluster];
        std::array::from_fn(|d| mean[d] * (1.0 + self.size_residual[d]))
    }
}

fn read(t: &burn::tensor::Tensor<3>) -> Result<Vec<f32>, ModelError> {
    t.try_to_vec_as::<f32>()
        .map_err(|e| ModelError::Batch(format!("reading the network output back: {e:?}")))
}

fn argmax(v: &[f32]) -> usize {
    v.iter()
        .enumerate()
        .fold((0, f32::NEG_INFINITY), |best, (i, &x)| {
            if x > best.1 { (i, x) } else { best }
        })
        .0
}

/// One prediction per frustum of the batch.
pub fn decode(
    output: &FConvNetOutput,
    inputs: &BatchInputs,
    config: &ModelConfig,
) -> Result<Vec<FrustumPrediction>, ModelError> {
    let [b, p, _] = output.cls_logits.dims();
    let layout = RegressionLayout::new(config);
    let r = layout.len();
    if output.regression.dims() != [b, p, r] || b != inputs.batch_size || p != inputs.positions {
        return Err(ModelError::Batch(
            "output shapes do not match the inputs".into(),
        ));
    }
    let cls = read(&output.cls_logits)?;
    let reg = read(&output.regression)?;
    let half_bin = config.heading_bin_width() / 2.0;
    Ok((0..b)
        .map(|f| {
            // Highest object logit margin = highest softmax probability.
            let margins: Vec<f32> = (0..p)
                .map(|j| cls[(f * p + j) * 2 + 1] - cls[(f * p + j) * 2])
                .collect();
            let j = argmax(&margins);
            let score = 1.0 / (1.0 + (-margins[j]).exp());
            let row = &reg[(f * p + j) * r..(f * p + j + 1) * r];
            let pc = &inputs.position_centers[(f * p + j) * 3..(f * p + j) * 3 + 3];
            let heading_bin = argmax(&row[layout.heading_scores()]);
            let size_cluster = argmax(&row[layout.size_scores()]);
            let sr = layout.size_residuals().start + 3 * size_cluster;
            FrustumPrediction {
                position: j,
                score,
                center: std::array::from_fn(|d| pc[d] + row[d]),
                heading_bin,
                heading_residual: row[layout.heading_residuals().start + heading_bin] * half_bin,
                size_cluster,
                size_residual: [row[sr], row[sr + 1], row[sr + 2]],
            }
        })
        .collect())
}
