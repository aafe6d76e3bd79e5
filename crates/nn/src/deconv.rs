//! Training's transposed 1D convolutions whose kernel equals their stride (the frustum FCN's
//! upsampling deconvolutions, strides 1, 2 and 4) as one point-wise product on the flex
//! CPU device.
//!
//! Why: with kernel = stride and no padding the output windows do not overlap, so
//! `out[b, o, l·k + j] = bias[o] + Σ_i x[b, i, l] · W[i, o, j]`: every input position is
//! one row [C_in] times the weight viewed as [C_in, C_out · k]. burn differentiates
//! `ConvTranspose1d` as a general transposed convolution (flex's 3D path, its backward a
//! convolution with the im2col copies and the narrow matrix kernels that brings); in the
//! published F-ConvNet step those passes took a tenth of the step. Here the product and its
//! gradients are [`crate::linear`]'s, and the layout changes around it are two small copies
//! (the maps are [batch, channels, slices] with a few dozen slices).
//!
//! Values are not bit for bit burn's (the sums run in another order), so inference keeps
//! `ConvTranspose1d::forward` and its pinned results; training's loss curve is the same to
//! float tolerance (test). [`crate::ragged::set_custom_ops`] turns it off with the other
//! custom operations.

use crate::linear::linear_rows;
use crate::ragged::custom_path;
use burn::nn::conv::ConvTranspose1d;
use burn::prelude::*;

/// `deconv.forward(x)` on [B, C_in, L] → [B, C_out, L · k]: in training on the flex device,
/// for a deconvolution whose kernel k is its stride (no padding, dilation 1, one group), as
/// one product (see the module's documentation); otherwise burn's.
pub fn deconv1d(deconv: &ConvTranspose1d, x: Tensor<3>) -> Tensor<3> {
    // The weight's shape, not `kernel_size`, is what burn's operation convolves with.
    let [c_in, c_out, kernel] = deconv.weight.dims();
    let [batch, channels, length] = x.dims();
    let non_overlapping = kernel == deconv.stride
        && deconv.padding == 0
        && deconv.padding_out == 0
        && deconv.dilation == 1
        && deconv.groups == 1
        && channels == c_in;
    if !(non_overlapping && custom_path(&x) && x.device().is_autodiff()) {
        return deconv.forward(x);
    }
    let rows = x.swap_dims(1, 2).reshape([batch * length, c_in]);
    let weight = deconv.weight.val().reshape([c_in, c_out * kernel]);
    let bias = deconv.bias.as_ref().map(|bias| {
        bias.val()
            .reshape([c_out, 1])
            .expand([c_out, kernel])
            .reshape([c_out * kernel])
    });
    linear_rows(rows, weight, bias)
        .reshape([batch, length, c_out, kernel])
        .permute([0, 2, 1, 3])
        .reshape([batch, c_out, length * kernel])
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;
    use burn::nn::conv::ConvTranspose1dConfig;
    use burn::tensor::TensorData;

    fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_to_vec_as::<f32>().unwrap()
    }

    /// Output and the input, weight and bias gradients of a fixed linear functional of the
    /// output, through [`deconv1d`] or burn's `ConvTranspose1d::forward`.
    fn run(deconv: &ConvTranspose1d, x: &Tensor<3>, custom: bool) -> Vec<Vec<f32>> {
        let device = x.device();
        let x = x.clone().require_grad();
        let out = if custom {
            assert!(custom_path(&x) && x.device().is_autodiff());
            deconv1d(deconv, x.clone())
        } else {
            deconv.forward(x.clone())
        };
        let probe = filled(out.dims(), 0.37, &device);
        let grads = (out.clone() * probe).sum().backward();
        let mut all = vec![
            to_vec(out),
            to_vec(x.grad(&grads).unwrap()),
            to_vec(deconv.weight.val().grad(&grads).unwrap()),
        ];
        if let Some(bias) = &deconv.bias {
            all.push(to_vec(bias.val().grad(&grads).unwrap()));
        }
        all
    }

    /// A tensor of `dims` with deterministic values in [-1, 1) (`phase` tells them apart).
    fn filled<const D: usize>(dims: [usize; D], phase: f32, device: &Device) -> Tensor<D> {
        let n = dims.iter().product::<usize>();
        let values: Vec<f32> = (0..n)
            .map(|i| ((i as f32 * 0.618 + phase).fract() * 2.0) - 1.0)
            .collect();
        Tensor::from_data(TensorData::new(values, dims), device)
    }

    /// Same values and gradients as burn's transposed convolution to float tolerance, for
    /// strides 1, 2 and 4, with and without a bias, one and several batch items.
    #[test]
    fn values_and_gradients_match_burns_transposed_convolution() {
        let device = Device::flex().autodiff();
        for (stride, bias, [batch, c_in, c_out, length]) in [
            (1, false, [2, 5, 3, 7]),
            (2, true, [3, 4, 6, 5]),
            (4, false, [1, 8, 2, 3]),
            (4, true, [4, 3, 5, 6]),
        ] {
            let mut deconv = ConvTranspose1dConfig::new([c_in, c_out], stride)
                .with_stride(stride)
                .with_bias(bias)
                .init(&device);
            if bias {
                // A bias that is not zero, so that its broadcast is checked.
                deconv.bias = Some(Param::from_tensor(filled([c_out], 0.11, &device)));
            }
            let x = filled([batch, c_in, length], 0.23, &device);
            let ours = run(&deconv, &x, true);
            let burns = run(&deconv, &x, false);
            assert_eq!(ours.len(), burns.len());
            for (part, (a, b)) in ours.iter().zip(&burns).enumerate() {
                assert_eq!(a.len(), b.len(), "stride {stride}, part {part}");
                for (i, (u, v)) in a.iter().zip(b).enumerate() {
                    assert!(
                        (u - v).abs() <= 1e-5 * (1.0 + v.abs()),
                        "stride {stride}, part {part}, value {i}: {u} against {v}"
                    );
                }
            }
        }
    }

    /// Other deconvolutions (kernel ≠ stride, padding) keep burn's operation, unchanged.
    #[test]
    fn overlapping_windows_keep_burns_operation() {
        let device = Device::flex().autodiff();
        let deconv = ConvTranspose1dConfig::new([3, 2], 3)
            .with_stride(2)
            .init(&device);
        let x = filled([2, 3, 4], 0.5, &device);
        assert_eq!(
            to_vec(deconv1d(&deconv, x.clone())),
            to_vec(deconv.forward(x))
        );
    }
}
