//! TCA, the three-dimension coordinate attention of STCA (DASANet, Section 3.3,
//! Eq. 8–14): coordinate attention (Hou et al., CVPR 2021) extended from two axes to
//! three, over the concatenated Siamese encoder maps F^C of every RoI.
//!
//! - Eq. 8–10: α^X, α^Y, α^Z — averages over the planes across each axis, per channel;
//! - Eq. 11–13: g = σ(Conv^g(δ(Conv(α)))), with one Conv_XY shared by the x and y axes
//!   (objects on the road look alike along both), its own Conv_Z, both to C/16 channels,
//!   and one Conv^g back to C channels per axis; δ is ReLU, σ the sigmoid;
//! - Eq. 14: F^A = F^C + F^C · g^X · g^Y · g^Z.
//!
//! The 1×1 convolutions over a 1-D profile are linear layers on [profile cells, C]
//! (with bias, as convolutions have). Layout: [RoIs, L, W, H, C] (x, y, z, channel),
//! channel fastest.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::{relu, sigmoid};

#[derive(Module, Debug)]
pub struct CoordinateAttention3d {
    /// Conv_XY, shared by the x and y profiles (C → C/16).
    pub squeeze_xy: Linear,
    /// Conv_Z (C → C/16).
    pub squeeze_z: Linear,
    /// Conv^g_X, Conv^g_Y, Conv^g_Z (C/16 → C).
    pub excite_x: Linear,
    pub excite_y: Linear,
    pub excite_z: Linear,
}

/// The width of the squeezed profiles: C/16, at least 1.
pub fn reduced_channels(channels: usize, reduction: usize) -> usize {
    (channels / reduction).max(1)
}

impl CoordinateAttention3d {
    pub fn new(channels: usize, reduction: usize, device: &Device) -> Self {
        let mid = reduced_channels(channels, reduction);
        let linear = |a, b| LinearConfig::new(a, b).init(device);
        Self {
            squeeze_xy: linear(channels, mid),
            squeeze_z: linear(channels, mid),
            excite_x: linear(mid, channels),
            excite_y: linear(mid, channels),
            excite_z: linear(mid, channels),
        }
    }

    /// One axis' gate [R, cells, C] from its profile [R, cells, C] (Eq. 11–13).
    fn gate(squeeze: &Linear, excite: &Linear, profile: Tensor<3>) -> Tensor<3> {
        let [r, n, c] = profile.dims();
        let x = relu(squeeze.forward(profile.reshape([r * n, c])));
        sigmoid(excite.forward(x)).reshape([r, n, c])
    }

    /// F^A from F^C, both [R, L, W, H, C].
    pub fn forward(&self, features: Tensor<5>) -> Tensor<5> {
        let [r, l, w, h, c] = features.dims();
        // Eq. 8–10: mean over the two other axes.
        let alpha_x = features.clone().mean_dims(&[2, 3]).reshape([r, l, c]);
        let alpha_y = features.clone().mean_dims(&[1, 3]).reshape([r, w, c]);
        let alpha_z = features.clone().mean_dims(&[1, 2]).reshape([r, h, c]);
        let g_x = Self::gate(&self.squeeze_xy, &self.excite_x, alpha_x).reshape([r, l, 1, 1, c]);
        let g_y = Self::gate(&self.squeeze_xy, &self.excite_y, alpha_y).reshape([r, 1, w, 1, c]);
        let g_z = Self::gate(&self.squeeze_z, &self.excite_z, alpha_z).reshape([r, 1, 1, h, c]);
        // Eq. 14.
        features.clone() + features * g_x * g_y * g_z
    }

    /// Multiply-adds per RoI on an L × W × H grid of C channels: the profile layers plus
    /// the three gate products of Eq. 14.
    pub fn multiply_adds_per_roi(&self, [l, w, h]: [usize; 3]) -> u64 {
        let [c, mid] = self.squeeze_xy.weight.dims();
        let profile = (l + w + h) * 2 * c * mid;
        (profile + 3 * l * w * h * c) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;

    fn linear_with(weight: Vec<f32>, bias: Vec<f32>, [a, b]: [usize; 2], d: &Device) -> Linear {
        let mut layer = LinearConfig::new(a, b).init(d);
        layer.weight = Param::from_tensor(Tensor::from_data(TensorData::new(weight, [a, b]), d));
        layer.bias = Some(Param::from_tensor(Tensor::from_data(
            TensorData::new(bias, [b]),
            d,
        )));
        layer
    }

    fn sigmoid_f(x: f64) -> f64 {
        1.0 / (1.0 + (-x).exp())
    }

    /// A 2 × 3 × 2 grid of C = 2 channels, squeezed to one channel (C/16 floored up to 1),
    /// with chosen weights: every term of Eq. 8–14 computed by hand.
    #[test]
    fn equations_eight_to_fourteen_term_by_term() {
        let d = Device::flex();
        let (l, w, h, c) = (2usize, 3usize, 2usize, 2usize);
        let value = |i: usize, j: usize, k: usize, ch: usize| {
            (i as f64 + 1.0) * 0.5 - j as f64 * 0.3
                + k as f64 * 0.7
                + if ch == 0 { 0.2 } else { -0.4 }
        };
        let mut data = Vec::new();
        for i in 0..l {
            for j in 0..w {
                for k in 0..h {
                    for ch in 0..c {
                        data.push(value(i, j, k, ch) as f32);
                    }
                }
            }
        }
        let input = Tensor::<5>::from_data(TensorData::new(data, [1, l, w, h, c]), &d);
        let mut tca = CoordinateAttention3d::new(c, 16, &d);
        // Conv_XY = (0.5, −0.25) · α + 0.1; Conv_Z = (0.3, 0.6) · α − 0.2.
        tca.squeeze_xy = linear_with(vec![0.5, -0.25], vec![0.1], [2, 1], &d);
        tca.squeeze_z = linear_with(vec![0.3, 0.6], vec![-0.2], [2, 1], &d);
        // Conv^g: channel ch gets a·m + b.
        let excite: [([f64; 2], [f64; 2]); 3] = [
            ([1.0, -1.0], [0.0, 0.5]),
            ([0.4, 0.8], [-0.3, 0.2]),
            ([-0.6, 1.2], [0.1, 0.0]),
        ];
        let to32 = |v: [f64; 2]| v.map(|x| x as f32).to_vec();
        tca.excite_x = linear_with(to32(excite[0].0), to32(excite[0].1), [1, 2], &d);
        tca.excite_y = linear_with(to32(excite[1].0), to32(excite[1].1), [1, 2], &d);
        tca.excite_z = linear_with(to32(excite[2].0), to32(excite[2].1), [1, 2], &d);

        // Eq. 8–10.
        let alpha_x = |i: usize, ch: usize| {
            (0..w)
                .flat_map(|j| (0..h).map(move |k| value(i, j, k, ch)))
                .sum::<f64>()
                / (w * h) as f64
        };
        let alpha_y = |j: usize, ch: usize| {
            (0..l)
                .flat_map(|i| (0..h).map(move |k| value(i, j, k, ch)))
                .sum::<f64>()
                / (l * h) as f64
        };
        let alpha_z = |k: usize, ch: usize| {
            (0..l)
                .flat_map(|i| (0..w).map(move |j| value(i, j, k, ch)))
                .sum::<f64>()
                / (l * w) as f64
        };
        // Eq. 11–13.
        let squeeze =
            |a0: f64, a1: f64, wt: [f64; 2], b: f64| (wt[0] * a0 + wt[1] * a1 + b).max(0.0);
        let gate =
            |m: f64, axis: usize, ch: usize| sigmoid_f(excite[axis].0[ch] * m + excite[axis].1[ch]);
        let g_x = |i: usize, ch: usize| {
            gate(
                squeeze(alpha_x(i, 0), alpha_x(i, 1), [0.5, -0.25], 0.1),
                0,
                ch,
            )
        };
        let g_y = |j: usize, ch: usize| {
            gate(
                squeeze(alpha_y(j, 0), alpha_y(j, 1), [0.5, -0.25], 0.1),
                1,
                ch,
            )
        };
        let g_z = |k: usize, ch: usize| {
            gate(
                squeeze(alpha_z(k, 0), alpha_z(k, 1), [0.3, 0.6], -0.2),
                2,
                ch,
            )
        };

        let out: Vec<f32> = tca.forward(input).into_data().try_to_vec::<f32>().unwrap();
        let mut n = 0;
        for i in 0..l {
            for j in 0..w {
                for k in 0..h {
                    for ch in 0..c {
                        // Eq. 14.
                        let f = value(i, j, k, ch);
                        let expected = f + f * g_x(i, ch) * g_y(j, ch) * g_z(k, ch);
                        assert!(
                            (out[n] as f64 - expected).abs() < 1e-5,
                            "({i},{j},{k},{ch}): {} vs {expected}",
                            out[n]
                        );
                        n += 1;
                    }
                }
            }
        }
    }

    #[test]
    fn zero_features_stay_zero_and_shapes_hold() {
        let d = Device::flex();
        let tca = CoordinateAttention3d::new(32, 16, &d);
        assert_eq!(tca.squeeze_xy.weight.dims(), [32, 2]);
        let out = tca.forward(Tensor::zeros([3, 4, 5, 2, 32], &d));
        assert_eq!(out.dims(), [3, 4, 5, 2, 32]);
        assert_eq!(out.abs().max().into_scalar::<f32>(), 0.0);
    }
}
