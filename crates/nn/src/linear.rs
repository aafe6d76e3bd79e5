//! Training's point-wise linear layers (`Linear` on [rows, channels]) on the flex CPU device:
//! the product and both gradient products through [`crate::matmul`], every value flex's own
//! to the bit (test).
//!
//! Why: burn differentiates `linear` with flex's `matmul`, which makes each output as a
//! zeroed byte buffer and copies it into aligned storage before the product overwrites it
//! (`FlexTensor::empty`), and takes the transposed operands of both gradients as views it may
//! copy first. In the published F-ConvNet training step (batch 32: ~8,000 points a frustum
//! batch through PointNets up to 512 wide) those two passes ran over every activation of
//! every layer three times a step. Here the forward product and the gradients
//! dX = dY·Wᵀ and dW = Xᵀ·dY write straight into new buffers, the transposes as strided views;
//! the bias is added and its gradient summed as burn does it (flex's `float_add`,
//! `float_sum_dim`).
//!
//! The same `#[backend_extension]` route as [`crate::conv2d`]: training (`Autodiff<Flex>`)
//! takes the operation below; inference and other devices keep `Linear::forward`.
//! [`crate::ragged::set_custom_ops`] turns it off with the other custom operations.

use crate::matmul::{MatrixRef, product};
use crate::ragged::{custom_device_path, custom_path, dims2, flex_tensor, values};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::Shape;

/// The custom operations: burn's `linear` on x [rows, in] with weight [in, out], without
/// and with a bias [out].
#[backend_extension(Flex, Autodiff)]
pub trait LinearRowOps: Backend {
    fn linear_rows(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self>;

    fn linear_rows_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

/// `layer.forward(x)` on [rows, in]; in training on the flex device through the custom
/// operation (see the module's documentation); on a GPU, a long input of few rows as
/// products over chunks of it ([`crate::inner_split`]), and in training many rows with the
/// weight gradient summed over chunks of rows ([`crate::linear_chunked`]).
pub fn linear(layer: &Linear, x: Tensor<2>) -> Tensor<2> {
    if let Some(y) = crate::inner_split::wide_linear(layer, &x) {
        return y;
    }
    // Training is told by the weights: an input may be a constant made off the autodiff
    // graph (RoI pooling's offsets from the device query).
    if layer.weight.device().is_autodiff() && custom_device_path(&x) {
        return crate::linear_chunked::device_linear(layer, x);
    }
    if !(custom_path(&x) && x.device().is_autodiff()) {
        return layer.forward(x);
    }
    linear_rows(
        x,
        layer.weight.val(),
        layer.bias.as_ref().map(|bias| bias.val()),
    )
}

/// x [rows, in] · `weight` [in, out] (+ `bias` [out]) through the custom operation, for
/// callers whose layer is not a `Linear` but is one product (a transposed convolution whose
/// kernel is its stride, [`crate::deconv`]). Only where [`custom_path`] holds.
pub(crate) fn linear_rows(x: Tensor<2>, weight: Tensor<2>, bias: Option<Tensor<1>>) -> Tensor<2> {
    let (x, weight) = (x.into_dispatch(), weight.into_dispatch());
    Tensor::from_dispatch(match bias {
        Some(bias) => <Dispatch as LinearRowOps>::linear_rows_bias(x, weight, bias.into_dispatch()),
        None => <Dispatch as LinearRowOps>::linear_rows(x, weight),
    })
}

/// x·W (+ b): the product written once, the bias added to it in place as flex's broadcast
/// `float_add` adds it (one rounding of the same two values).
fn forward(x: &FlexTensor, weight: &FlexTensor, bias: Option<&FlexTensor>) -> FlexTensor {
    let [rows, d_in] = dims2(x);
    let [w_in, d_out] = dims2(weight);
    assert_eq!(
        d_in, w_in,
        "x [rows, {d_in}] and a [{w_in}, {d_out}] weight"
    );
    let (x, w) = (values(x), values(weight));
    let mut out = product(
        MatrixRef::new(&x, [rows, d_in]),
        MatrixRef::new(&w, [d_in, d_out]),
    );
    if let Some(bias) = bias {
        let bias = values(bias);
        assert_eq!(bias.len(), d_out, "a bias of the output's width");
        for row in out.chunks_exact_mut(d_out.max(1)) {
            row.iter_mut().zip(bias.iter()).for_each(|(v, b)| *v += b);
        }
    }
    flex_tensor(out, [rows, d_out])
}

/// dX = dY·Wᵀ and dW = Xᵀ·dY, each where its node asks for it; dB as burn sums it.
fn register_grads(
    grads: &mut Gradients,
    nodes: [Option<burn::backend::autodiff::NodeId>; 3],
    (x, weight): (&FlexTensor, &FlexTensor),
    grad: FlexTensor,
) {
    let [node_x, node_weight, node_bias] = nodes;
    let ([rows, d_in], [_, d_out]) = (dims2(x), dims2(weight));
    let g = values(&grad);
    let dy = MatrixRef::new(&g, [rows, d_out]);
    if let Some(node) = node_x {
        let w = values(weight);
        let dx = product(dy, MatrixRef::new(&w, [d_in, d_out]).t());
        grads.register::<Flex>(node, flex_tensor(dx, [rows, d_in]));
    }
    if let Some(node) = node_weight {
        let xv = values(x);
        let dw = product(MatrixRef::new(&xv, [rows, d_in]).t(), dy);
        grads.register::<Flex>(node, flex_tensor(dw, [d_in, d_out]));
    }
    if let Some(node) = node_bias {
        drop(g);
        let db = Flex::float_reshape(Flex::float_sum_dim(grad, 0), Shape::new([d_out]));
        grads.register::<Flex>(node, db);
    }
}

/// The backward step: N = 2 parents (x, W) without a bias, 3 with one (x, W, b).
#[derive(Debug)]
struct LinearBackward<const N: usize>;

impl<const N: usize> Backward<Flex, N> for LinearBackward<N> {
    /// The input and the weight.
    type State = (FlexTensor, FlexTensor);

    fn backward(self, ops: Ops<Self::State, N>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, weight) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let mut nodes = [None; 3];
        for (node, parent) in nodes.iter_mut().zip(&ops.parents) {
            *node = parent.as_ref().map(|p| p.id);
        }
        register_grads(grads, nodes, (&x, &weight), grad);
    }
}

impl LinearRowOps for Flex {
    fn linear_rows(x: FlexTensor, weight: FlexTensor) -> FlexTensor {
        forward(&x, &weight, None)
    }

    fn linear_rows_bias(x: FlexTensor, weight: FlexTensor, bias: FlexTensor) -> FlexTensor {
        forward(&x, &weight, Some(&bias))
    }
}

impl<C: CheckpointStrategy> LinearRowOps for Autodiff<Flex, C> {
    fn linear_rows(x: FloatTensor<Self>, weight: FloatTensor<Self>) -> FloatTensor<Self> {
        let (x, node_x) = x.into_parts();
        let (weight, node_weight) = weight.into_parts();
        let out = forward(&x, &weight, None);
        match LinearBackward::<2>
            .prepare::<C>([node_x, node_weight])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((x, weight), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }

    fn linear_rows_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let (x, node_x) = x.into_parts();
        let (weight, node_weight) = weight.into_parts();
        let (bias, node_bias) = bias.into_parts();
        let out = forward(&x, &weight, Some(&bias));
        match LinearBackward::<3>
            .prepare::<C>([node_x, node_weight, node_bias])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((x, weight), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;
    use burn::nn::LinearConfig;

    fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_to_vec_as::<f32>().unwrap()
    }

    /// Output and the input, weight and bias gradients of a fixed linear functional of the
    /// output, through [`linear`] or burn's `Linear::forward`. (Not through
    /// `set_custom_ops`: the switch is process-wide and other tests run beside this one.)
    fn run(layer: &Linear, x: &Tensor<2>, probe: &Tensor<2>, custom: bool) -> Vec<Vec<f32>> {
        let x = x.clone().require_grad();
        let out = if custom {
            assert!(custom_path(&x) && x.device().is_autodiff());
            linear(layer, x.clone())
        } else {
            layer.forward(x.clone())
        };
        let grads = (out.clone() * probe.clone()).sum().backward();
        let mut all = vec![
            to_vec(out),
            to_vec(x.grad(&grads).unwrap()),
            to_vec(layer.weight.val().grad(&grads).unwrap()),
        ];
        if let Some(b) = &layer.bias {
            all.push(to_vec(b.val().grad(&grads).unwrap()));
        }
        all
    }

    /// Forward values and every gradient equal burn's to the bit, with and without a bias,
    /// at PointNet-like widths below and above the size where the products go parallel,
    /// and with no rows at all.
    #[test]
    fn values_and_gradients_are_burns_bit_for_bit() {
        let device = Device::flex().autodiff();
        for (rows, d_in, d_out, bias) in [
            (37, 5, 3, true),
            (37, 5, 3, false),
            (700, 64, 128, true),
            (2048, 128, 256, false),
            (0, 16, 8, true),
        ] {
            let mut layer = LinearConfig::new(d_in, d_out).with_bias(bias).init(&device);
            let weight: Vec<f32> = (0..d_in * d_out)
                .map(|i| ((i * 37 % 101) as f32 - 50.0) / 97.0)
                .collect();
            layer.weight = Param::from_tensor(Tensor::from_data(
                TensorData::new(weight, [d_in, d_out]),
                &device,
            ));
            let x: Vec<f32> = (0..rows * d_in)
                .map(|i| ((i * 53 % 211) as f32 - 105.0) / 31.0)
                .collect();
            let x = Tensor::<2>::from_data(TensorData::new(x, [rows, d_in]), &device);
            let probe: Vec<f32> = (0..rows * d_out)
                .map(|i| ((i * 29 % 89) as f32 - 44.0) / 13.0)
                .collect();
            let probe = Tensor::<2>::from_data(TensorData::new(probe, [rows, d_out]), &device);
            let ours = run(&layer, &x, &probe, true);
            let burns = run(&layer, &x, &probe, false);
            let names = [
                "output",
                "input gradient",
                "weight gradient",
                "bias gradient",
            ];
            for ((a, b), name) in ours.iter().zip(&burns).zip(names) {
                assert_eq!(a.len(), b.len(), "{name} ({rows}x{d_in}->{d_out}): lengths");
                let same = a.iter().zip(b).all(|(p, q)| p.to_bits() == q.to_bits());
                assert!(same, "{name} ({rows}x{d_in}->{d_out}, bias {bias}) differs");
            }
        }
    }
}
