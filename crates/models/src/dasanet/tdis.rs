//! TDIS, the triple differential information supplement (DASANet, Section 3.2,
//! Eq. 1–7): the LiDAR RoI grid features F^S are supplemented with what the pseudo-point
//! features F^P add to them.
//!
//! - Eq. 1: F^D = F^P − F^S (C channels × N grid locations);
//! - Eq. 2: F^Sp(l) = Σ_ij W^Sp_l(i, j) F^D(i, j), one value per location (N of them);
//! - Eq. 3: F^T_Sp = F^S + A^Ch F^Sp (each location's value added on every channel);
//! - Eq. 4: F^Ch(k) = Σ_ij W^Ch_k(i, j) F^D(i, j), one value per channel (C of them);
//! - Eq. 5: F^T_Sp-Ch = F^T_Sp + F^Ch A^Sp (each channel's value added at every location);
//! - Eq. 6: F^Go = Σ_ij W^Go(i, j) F^D(i, j), one value;
//! - Eq. 7: F^T = F^T_Sp-Ch + F^Go A (added everywhere).
//!
//! Each of the N + C + 1 weighted sums is a dot product of the flattened F^D with one
//! C × N weight matrix, so the three are one matrix product of F^D [RoIs, N·C] with the
//! weights stacked as columns. The paper states no bias; none is added.
//!
//! With `tdis_form = "gated"` the sum S of the three added terms is scaled to F^S's size
//! and by a learned gate before it is added (see [`TdisForm`]); `plain` is the above.
//!
//! Layout: rows of [RoIs, N·C], location-major (element `j·C + i` is channel i at grid
//! location j), as the RoI grid pooling writes them.

use super::config::{TdisForm, TdisInit};
use burn::module::Param;
use burn::prelude::*;
use burn::tensor::Distribution;
use fusiondet_nn::inner_split;

/// Added to the mean squares of the gated form's RMS, so a RoI with no feature (all
/// zeros) divides by a number, not by zero.
const RMS_EPS: f32 = 1e-12;

#[derive(Module, Debug)]
pub struct Tdis {
    /// W^Sp: [N·C, N], column l is W^Sp_l flattened location-major.
    pub spatial: Param<Tensor<2>>,
    /// W^Ch: [N·C, C], column k is W^Ch_k.
    pub channel: Param<Tensor<2>>,
    /// W^Go: [N·C, 1].
    pub global: Param<Tensor<2>>,
    /// g of the gated form ([1], starts at 0); absent in the plain form, so plain
    /// checkpoints hold the same tensors as before the key existed.
    pub gate: Option<Param<Tensor<1>>>,
    /// `tdis_form = "bypass"`: F^T = F^S (a measurement of the row without TDIS).
    #[module(skip)]
    pub bypass: bool,
    #[module(skip)]
    pub channels: usize,
    #[module(skip)]
    pub locations: usize,
}

impl Tdis {
    /// Weights drawn uniformly in ±1/√(N·C), the fan-in bound burn's linear layers use,
    /// or zeros (see [`TdisInit`]); the gated form's gate shut.
    pub fn new(
        channels: usize,
        locations: usize,
        init: TdisInit,
        form: TdisForm,
        device: &Device,
    ) -> Self {
        let fan_in = channels * locations;
        let bound = 1.0 / (fan_in as f64).sqrt();
        let init = |cols: usize| {
            Param::from_tensor(match init {
                TdisInit::FanIn => {
                    Tensor::random([fan_in, cols], Distribution::Uniform(-bound, bound), device)
                }
                TdisInit::Zero => Tensor::zeros([fan_in, cols], device),
            })
        };
        Self {
            spatial: init(locations),
            channel: init(channels),
            global: init(1),
            gate: (form == TdisForm::Gated).then(|| Param::from_tensor(Tensor::zeros([1], device))),
            bypass: form == TdisForm::Bypass,
            channels,
            locations,
        }
    }

    /// F^T [RoIs, N·C] from F^S and F^P, both [RoIs, N·C] location-major.
    pub fn forward(&self, lidar: Tensor<2>, pseudo: Tensor<2>) -> Tensor<2> {
        let [r, width] = lidar.dims();
        let (c, n) = (self.channels, self.locations);
        assert_eq!(width, n * c, "TDIS expects N·C = {n}·{c} features per RoI");
        if self.bypass {
            return lidar;
        }
        let difference = pseudo - lidar.clone(); // Eq. 1
        // Inner dimension N·C: split into chunks on a GPU (`fusiondet_nn::inner_split`).
        let spatial = inner_split::matmul(difference.clone(), self.spatial.val()); // Eq. 2, [R, N]
        let channel = inner_split::matmul(difference.clone(), self.channel.val()); // Eq. 4, [R, C]
        let global = inner_split::matmul(difference, self.global.val()); // Eq. 6, [R, 1]
        let Some(gate) = &self.gate else {
            let supplemented = lidar.reshape([r, n, c])
                + spatial.reshape([r, n, 1]) // Eq. 3
                + channel.reshape([r, 1, c]) // Eq. 5
                + global.reshape([r, 1, 1]); // Eq. 7
            return supplemented.reshape([r, n * c]);
        };
        // The same three terms (Eq. 3, 5, 7) as one supplement S, scaled to F^S's size.
        let supplement = (Tensor::<3>::zeros([r, n, c], &lidar.device())
            + spatial.reshape([r, n, 1])
            + channel.reshape([r, 1, c])
            + global.reshape([r, 1, 1]))
        .reshape([r, n * c]);
        let rms = |t: Tensor<2>| t.powi_scalar(2).mean_dim(1).add_scalar(RMS_EPS).sqrt();
        let scale = rms(lidar.clone()) / rms(supplement.clone()); // [R, 1]
        let g = gate.val().tanh().reshape([1, 1]);
        lidar + supplement * scale * g
    }

    /// Multiply-adds per RoI: one dot product of length N·C per output value.
    pub fn multiply_adds_per_roi(&self) -> u64 {
        let (c, n) = (self.channels as u64, self.locations as u64);
        n * c * (n + c + 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t2(v: Vec<f32>, shape: [usize; 2], d: &Device) -> Tensor<2> {
        Tensor::from_data(TensorData::new(v, shape), d)
    }

    /// C = 2 channels, N = 3 locations, one RoI, every term of Eq. 1–7 by hand.
    #[test]
    fn equations_one_to_seven_term_by_term() {
        let d = Device::flex();
        let (c, n) = (2, 3);
        // F^S(i, j) and F^P(i, j) with channel i, location j; stored at j·C + i.
        let fs = [[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]];
        let fp = [[2.0f32, 2.0, 5.0], [3.0, 7.0, 6.0]];
        let flat = |f: &[[f32; 3]; 2]| -> Vec<f32> {
            (0..n)
                .flat_map(|j| (0..c).map(move |i| (i, j)))
                .map(|(i, j)| f[i][j])
                .collect()
        };
        let lidar = t2(flat(&fs), [1, n * c], &d);
        let pseudo = t2(flat(&fp), [1, n * c], &d);
        // Weights W(i, j) as small distinct numbers per output.
        let w = |o: usize, i: usize, j: usize| {
            0.1 * (o as f32 + 1.0) - 0.05 * i as f32 + 0.02 * j as f32
        };
        let column_major = |outs: usize, base: usize| {
            let mut v = vec![0.0f32; n * c * outs];
            for j in 0..n {
                for i in 0..c {
                    for o in 0..outs {
                        v[(j * c + i) * outs + o] = w(base + o, i, j);
                    }
                }
            }
            v
        };
        let mut tdis = Tdis::new(c, n, TdisInit::FanIn, TdisForm::Plain, &d);
        tdis.spatial = Param::from_tensor(t2(column_major(n, 0), [n * c, n], &d));
        tdis.channel = Param::from_tensor(t2(column_major(c, n), [n * c, c], &d));
        tdis.global = Param::from_tensor(t2(column_major(1, n + c), [n * c, 1], &d));

        // Eq. 1.
        let fd = |i: usize, j: usize| fp[i][j] - fs[i][j];
        let weighted = |o: usize| -> f32 {
            (0..c)
                .flat_map(|i| (0..n).map(move |j| (i, j)))
                .map(|(i, j)| w(o, i, j) * fd(i, j))
                .sum()
        };
        let f_sp: Vec<f32> = (0..n).map(weighted).collect(); // Eq. 2
        let f_ch: Vec<f32> = (0..c).map(|k| weighted(n + k)).collect(); // Eq. 4
        let f_go = weighted(n + c); // Eq. 6
        let out: Vec<f32> = tdis
            .forward(lidar, pseudo)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        for j in 0..n {
            for i in 0..c {
                // Eq. 3, 5, 7.
                let expected = fs[i][j] + f_sp[j] + f_ch[i] + f_go;
                let got = out[j * c + i];
                assert!(
                    (got - expected).abs() < 1e-5,
                    "({i}, {j}): {got} vs {expected}"
                );
            }
        }
    }

    /// Equal LiDAR and pseudo features leave F^S unchanged (F^D = 0).
    #[test]
    fn no_difference_no_supplement() {
        let d = Device::flex();
        let tdis = Tdis::new(4, 8, TdisInit::FanIn, TdisForm::Plain, &d);
        let x = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let out = tdis.forward(x.clone(), x.clone());
        let diff: f32 = (out - x).abs().max().into_scalar();
        assert!(diff < 1e-6);
        assert_eq!(tdis.multiply_adds_per_roi(), 32 * 13);
    }

    /// Zero-started TDIS passes F^S through whatever F^P is, and its weights still get a
    /// gradient (F^D) from the first backward pass.
    #[test]
    fn zero_init_starts_as_identity_and_learns() {
        let d = Device::flex();
        let tdis = Tdis::new(4, 8, TdisInit::Zero, TdisForm::Plain, &d);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let out = tdis.forward(fs.clone(), fp.clone());
        let diff: f32 = (out - fs).abs().max().into_scalar();
        assert_eq!(diff, 0.0);

        let ad = Device::flex().autodiff();
        let tdis = Tdis::new(4, 8, TdisInit::Zero, TdisForm::Plain, &ad);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let grads = tdis.forward(fs, fp).sum().backward();
        let g: f32 = tdis.spatial.grad(&grads).unwrap().abs().sum().into_scalar();
        assert!(g > 0.0, "W^Sp got no gradient");
    }

    /// RMS(F^T − F^S) / RMS(F^S) per RoI.
    fn ratios(tdis: &Tdis, fs: &Tensor<2>, fp: &Tensor<2>) -> Vec<f32> {
        let rms = |t: Tensor<2>| t.powi_scalar(2).mean_dim(1).sqrt();
        let out = tdis.forward(fs.clone(), fp.clone());
        (rms(out - fs.clone()) / rms(fs.clone()))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap()
    }

    /// The gated form starts as the identity; with its gate open and weights far larger
    /// than any training would reach, the supplement is still |tanh g| times F^S's size,
    /// where the plain form's is hundreds of times F^S.
    #[test]
    fn the_gated_supplement_is_tanh_g_times_the_lidar_features() {
        let d = Device::flex();
        let mut tdis = Tdis::new(4, 8, TdisInit::FanIn, TdisForm::Gated, &d);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        assert!(ratios(&tdis, &fs, &fp).iter().all(|&q| q == 0.0));

        let big = |t: &Param<Tensor<2>>| Param::from_tensor(t.val().mul_scalar(1000.0));
        tdis.spatial = big(&tdis.spatial);
        tdis.channel = big(&tdis.channel);
        tdis.global = big(&tdis.global);
        let mut plain = Tdis::new(4, 8, TdisInit::FanIn, TdisForm::Plain, &d);
        plain.spatial = tdis.spatial.clone();
        plain.channel = tdis.channel.clone();
        plain.global = tdis.global.clone();
        assert!(ratios(&plain, &fs, &fp).iter().all(|&q| q > 100.0));

        tdis.gate = Some(Param::from_tensor(Tensor::from_data(
            TensorData::new(vec![0.5f32], [1]),
            &d,
        )));
        for q in ratios(&tdis, &fs, &fp) {
            assert!((q - 0.5f32.tanh()).abs() < 1e-4, "{q}");
        }
    }

    /// A shut gate still gets a gradient (from the fan-in supplement), so the gated form
    /// can open.
    #[test]
    fn the_shut_gate_learns() {
        let ad = Device::flex().autodiff();
        let tdis = Tdis::new(4, 8, TdisInit::FanIn, TdisForm::Gated, &ad);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let w = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let grads = (tdis.forward(fs, fp) * w).sum().backward();
        let gate = tdis.gate.as_ref().unwrap();
        let g: f32 = gate.grad(&grads).unwrap().abs().sum().into_scalar();
        assert!(g > 0.0, "the gate got no gradient");
    }

    /// On wgpu (over lavapipe in CI) TDIS at N·C = 64 · 128 = 8,192 takes its products in
    /// two chunks of the inner dimension (`fusiondet_nn::inner_split`): the output and the
    /// gradients of F^S, F^P and the three weights are the CPU's plain products' within f32
    /// rounding.
    #[cfg(feature = "wgpu")]
    #[test]
    fn on_wgpu_the_split_products_are_the_cpus() {
        use crate::device_test_support::{assert_close, upstream};
        let Some(gpu) = fusiondet_nn::cube::working_wgpu_device("TDIS's split products") else {
            return;
        };
        let (c, n, r) = (128, 64, 6);
        assert_eq!(
            fusiondet_nn::inner_split::inner_chunks(r, n * c, n),
            Some(2)
        );
        let cpu = Device::flex().autodiff();
        let tdis = Tdis::new(c, n, TdisInit::FanIn, TdisForm::Plain, &cpu);
        let values = |a: usize| -> Vec<f32> {
            (0..r * n * c)
                .map(|i| ((i * a % 193) as f32 - 96.0) / 64.0)
                .collect()
        };
        let run = |device: &Device| {
            let tdis = tdis.clone().fork(device);
            let fs = t2(values(37), [r, n * c], device).require_grad();
            let fp = t2(values(59), [r, n * c], device).require_grad();
            let y = tdis.forward(fs.clone(), fp.clone());
            let grads = (y.clone() * upstream(y.dims(), device)).sum().backward();
            let vec = |t: Tensor<2>| t.try_into_vec_as::<f32>().unwrap();
            vec![
                vec(y),
                vec(fs.grad(&grads).unwrap()),
                vec(fp.grad(&grads).unwrap()),
                vec(tdis.spatial.grad(&grads).unwrap()),
                vec(tdis.channel.grad(&grads).unwrap()),
                vec(tdis.global.grad(&grads).unwrap()),
            ]
        };
        let want = run(&cpu);
        for (i, (got, want)) in run(&gpu.autodiff()).iter().zip(&want).enumerate() {
            assert_close(got, want, 1e-4, &format!("quantity {i}"));
        }
    }

    /// The bypass form hands F^S through untouched, whatever F^P and the weights are.
    #[test]
    fn bypass_is_the_identity() {
        let d = Device::flex();
        let tdis = Tdis::new(4, 8, TdisInit::FanIn, TdisForm::Bypass, &d);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let out = tdis.forward(fs.clone(), fp.clone());
        let diff: f32 = (out - fs.clone()).abs().max().into_scalar();
        assert_eq!(diff, 0.0);
        let plain = Tdis::new(4, 8, TdisInit::FanIn, TdisForm::Plain, &d);
        let moved: f32 = (plain.forward(fs.clone(), fp) - fs)
            .abs()
            .max()
            .into_scalar();
        assert!(moved > 0.0);
    }
}
