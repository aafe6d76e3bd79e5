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
//! Layout: rows of [RoIs, N·C], location-major (element `j·C + i` is channel i at grid
//! location j), as the RoI grid pooling writes them.

use super::config::TdisInit;
use burn::module::Param;
use burn::prelude::*;
use burn::tensor::Distribution;

#[derive(Module, Debug)]
pub struct Tdis {
    /// W^Sp: [N·C, N], column l is W^Sp_l flattened location-major.
    pub spatial: Param<Tensor<2>>,
    /// W^Ch: [N·C, C], column k is W^Ch_k.
    pub channel: Param<Tensor<2>>,
    /// W^Go: [N·C, 1].
    pub global: Param<Tensor<2>>,
    #[module(skip)]
    pub channels: usize,
    #[module(skip)]
    pub locations: usize,
}

impl Tdis {
    /// Weights drawn uniformly in ±1/√(N·C), the fan-in bound burn's linear layers use,
    /// or zeros (see [`TdisInit`]).
    pub fn new(channels: usize, locations: usize, init: TdisInit, device: &Device) -> Self {
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
            channels,
            locations,
        }
    }

    /// F^T [RoIs, N·C] from F^S and F^P, both [RoIs, N·C] location-major.
    pub fn forward(&self, lidar: Tensor<2>, pseudo: Tensor<2>) -> Tensor<2> {
        let [r, width] = lidar.dims();
        let (c, n) = (self.channels, self.locations);
        assert_eq!(width, n * c, "TDIS expects N·C = {n}·{c} features per RoI");
        let difference = pseudo - lidar.clone(); // Eq. 1
        let spatial = difference.clone().matmul(self.spatial.val()); // Eq. 2, [R, N]
        let channel = difference.clone().matmul(self.channel.val()); // Eq. 4, [R, C]
        let global = difference.matmul(self.global.val()); // Eq. 6, [R, 1]
        let supplemented = lidar.reshape([r, n, c])
            + spatial.reshape([r, n, 1]) // Eq. 3
            + channel.reshape([r, 1, c]) // Eq. 5
            + global.reshape([r, 1, 1]); // Eq. 7
        supplemented.reshape([r, n * c])
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
        let mut tdis = Tdis::new(c, n, TdisInit::FanIn, &d);
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
        let tdis = Tdis::new(4, 8, TdisInit::FanIn, &d);
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
        let tdis = Tdis::new(4, 8, TdisInit::Zero, &d);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &d);
        let out = tdis.forward(fs.clone(), fp.clone());
        let diff: f32 = (out - fs).abs().max().into_scalar();
        assert_eq!(diff, 0.0);

        let ad = Device::flex().autodiff();
        let tdis = Tdis::new(4, 8, TdisInit::Zero, &ad);
        let fs = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let fp = Tensor::<2>::random([3, 32], Distribution::Normal(0.0, 1.0), &ad);
        let grads = tdis.forward(fs, fp).sum().backward();
        let g: f32 = tdis.spatial.grad(&grads).unwrap().abs().sum().into_scalar();
        assert!(g > 0.0, "W^Sp got no gradient");
    }
}
