//! AnchorHeadSingle: per BEV cell and anchor, a class score, a 7-value box residual and a
//! direction bin, each from one 1×1 convolution over the BEV features.

use burn::module::Param;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;
use fusiondet_nn::conv2d::conv2d;

#[derive(Module, Debug)]
pub struct AnchorHead {
    pub cls: Conv2d,
    pub boxes: Conv2d,
    pub direction: Conv2d,
    #[module(skip)]
    pub anchors_per_location: usize,
    #[module(skip)]
    pub num_classes: usize,
    #[module(skip)]
    pub num_direction_bins: usize,
}

/// Predictions per anchor, anchors ordered (y, x, anchor of the cell) as the anchor grid.
#[derive(Debug, Clone)]
pub struct AnchorPredictions {
    /// [B, anchors, classes] logits.
    pub cls: Tensor<3>,
    /// [B, anchors, 7] residuals.
    pub boxes: Tensor<3>,
    /// [B, anchors, direction bins] logits.
    pub direction: Tensor<3>,
}

impl AnchorHead {
    pub fn new(
        channels: usize,
        anchors_per_location: usize,
        num_classes: usize,
        num_direction_bins: usize,
        device: &Device,
    ) -> Self {
        let conv = |out: usize| Conv2dConfig::new([channels, out], [1, 1]).init(device);
        let a = anchors_per_location;
        let mut cls = conv(a * num_classes);
        // Focal loss starts from a prior of 1% foreground (RetinaNet), so the first steps
        // are not swamped by the background anchors' loss.
        let prior = -((1.0f64 - 0.01) / 0.01).ln();
        cls.bias = Some(Param::from_tensor(Tensor::full(
            [a * num_classes],
            prior,
            device,
        )));
        let mut boxes = conv(a * 7);
        boxes.weight = Param::from_tensor(Tensor::random(
            [a * 7, channels, 1, 1],
            burn::tensor::Distribution::Normal(0.0, 0.001),
            device,
        ));
        Self {
            cls,
            boxes,
            direction: conv(a * num_direction_bins),
            anchors_per_location: a,
            num_classes,
            num_direction_bins,
        }
    }

    pub fn forward(&self, bev: Tensor<4>) -> AnchorPredictions {
        let [b, _, h, w] = bev.dims();
        let anchors = h * w * self.anchors_per_location;
        let flat = |x: Tensor<4>, per: usize| x.permute([0, 2, 3, 1]).reshape([b, anchors, per]);
        AnchorPredictions {
            cls: flat(conv2d(&self.cls, bev.clone()), self.num_classes),
            boxes: flat(conv2d(&self.boxes, bev.clone()), 7),
            direction: flat(conv2d(&self.direction, bev), self.num_direction_bins),
        }
    }

    /// Multiply-adds of one forward pass over `cells` BEV cells of `channels`.
    pub fn multiply_adds(&self, channels: usize, cells: usize) -> u64 {
        let a = self.anchors_per_location;
        (cells * channels * a * (self.num_classes + 7 + self.num_direction_bins)) as u64
    }
}
