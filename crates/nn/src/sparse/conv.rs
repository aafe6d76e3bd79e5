//! Sparse 3D convolution, and the conv → batch norm → ReLU block every layer of a sparse
//! backbone is. Per the rulebook's layout: gather → matrix multiply → scatter-add one kernel
//! offset at a time (the CPU), or one gather through a kernel map and one matrix multiply
//! (GPUs, where launches cost more than the zeros it multiplies), or the kernel map's
//! CubeCL kernels ([`super::rulebook::RuleLayout::DeviceKernels`]).

use super::rulebook::{ConvGeometry, OffsetRule, RuleGather, Rulebook};
use crate::norm::{NormConfig, batch_norm};
use burn::module::{Module, Param};
use burn::nn::BatchNorm;
use burn::nn::Initializer;
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

/// A sparse 3D convolution without bias (it is always followed by batch norm).
///
/// The weight is [kernel volume, C_in, C_out], offsets in (z, y, x) row-major order: the
/// dense `conv3d` weight [C_out, C_in, kz, ky, kx] permuted. Initialised as PyTorch
/// initialises a convolution (Kaiming-uniform, bound 1/√fan_in).
#[derive(Module, Debug)]
pub struct SparseConv3d {
    pub weight: Param<Tensor<3>>,
    #[module(skip)]
    pub geometry: ConvGeometry,
    /// Submanifold (output sites = input sites) or regular.
    #[module(skip)]
    pub submanifold: bool,
}

impl SparseConv3d {
    /// A submanifold convolution: stride 1, same padding, no dilation of the sites.
    pub fn submanifold(channels: [usize; 2], kernel: [usize; 3], device: &Device) -> Self {
        Self::init(channels, ConvGeometry::same(kernel), true, device)
    }

    /// A regular convolution, whose output sites are every site some input reaches.
    pub fn regular(channels: [usize; 2], geometry: ConvGeometry, device: &Device) -> Self {
        Self::init(channels, geometry, false, device)
    }

    fn init(
        channels: [usize; 2],
        geometry: ConvGeometry,
        submanifold: bool,
        device: &Device,
    ) -> Self {
        let [c_in, c_out] = channels;
        let volume = geometry.volume();
        let weight = Initializer::KaimingUniform {
            gain: 1.0 / 3f64.sqrt(),
            fan_out_only: false,
        }
        .init_with(
            [volume, c_in, c_out],
            Some(c_in * volume),
            Some(c_out * volume),
            device,
        );
        Self {
            weight,
            geometry,
            submanifold,
        }
    }

    pub fn channels(&self) -> [usize; 2] {
        let [_, c_in, c_out] = self.weight.dims();
        [c_in, c_out]
    }

    /// `features` [input rows, C_in] on the rulebook's input sites → [output rows, C_out].
    pub fn forward(&self, features: Tensor<2>, rulebook: &Rulebook) -> Tensor<2> {
        assert_eq!(
            (rulebook.geometry, rulebook.submanifold),
            (self.geometry, self.submanifold),
            "a rulebook is built for one convolution shape"
        );
        let [rows, c_in] = features.dims();
        assert_eq!(
            rows, rulebook.input_rows,
            "features on the rulebook's input sites"
        );
        let [volume, _, c_out] = self.weight.dims();
        let weight = self.weight.val();
        let out_rows = rulebook.output_rows();
        match &rulebook.gather {
            RuleGather::PerOffset { host, .. } if crate::ragged::custom_path(&features) => {
                super::fused::sparse_conv(features, weight, host)
            }
            RuleGather::PerOffset {
                identity_offset,
                rules,
                ..
            } => per_offset_with_burns_ops(features, weight, *identity_offset, rules, out_rows),
            RuleGather::KernelMap { table, kernels } => {
                let device = features.device();
                if out_rows == 0 {
                    return Tensor::zeros([0, c_out], &device);
                }
                #[cfg(any(feature = "wgpu", feature = "cuda"))]
                if *kernels {
                    return super::device_kernels::sparse_conv(features, weight, table);
                }
                let _ = kernels;
                // Row `rows` is the zero row absent neighbours read; its gradient is dropped
                // with it.
                let padded = Tensor::cat(vec![features, Tensor::zeros([1, c_in], &device)], 0);
                padded
                    .select(0, table.as_ref().clone())
                    .reshape([out_rows, volume * c_in])
                    .matmul(weight.reshape([volume * c_in, c_out]))
            }
        }
    }
}

/// The per-offset convolution from burn's operations (select, matmul, select_assign with
/// add), which every backend differentiates: the centre offset's product (or zeros), then
/// each other offset's gathered product added into its output rows.
pub(super) fn per_offset_with_burns_ops(
    features: Tensor<2>,
    weight: Tensor<3>,
    identity_offset: Option<usize>,
    rules: &[OffsetRule],
    out_rows: usize,
) -> Tensor<2> {
    let [_, c_in, c_out] = weight.dims();
    let offset_weight = |k: usize| {
        weight
            .clone()
            .slice([k..k + 1, 0..c_in, 0..c_out])
            .reshape([c_in, c_out])
    };
    let mut out = match identity_offset {
        Some(k) => features.clone().matmul(offset_weight(k)),
        None => Tensor::zeros([out_rows, c_out], &features.device()),
    };
    for rule in rules {
        let products = features
            .clone()
            .select(0, rule.input.clone())
            .matmul(offset_weight(rule.offset));
        out = out.select_assign(0, rule.output.clone(), products, IndexingUpdateOp::Add);
    }
    out
}

/// Sparse convolution → batch norm over the active rows → ReLU.
#[derive(Module, Debug)]
pub struct SparseConvBlock {
    pub conv: SparseConv3d,
    pub norm: BatchNorm,
}

impl SparseConvBlock {
    pub fn new(conv: SparseConv3d, norm: &NormConfig, device: &Device) -> Self {
        let [_, c_out] = conv.channels();
        Self {
            norm: batch_norm(c_out, norm, device),
            conv,
        }
    }

    pub fn forward(&self, features: Tensor<2>, rulebook: &Rulebook) -> Tensor<2> {
        crate::norm::norm_rows_relu(&self.norm, self.conv.forward(features, rulebook))
    }
}

#[cfg(test)]
mod tests {
    use super::super::rulebook::RuleLayout;
    use super::super::sites::SparseSites;
    use super::*;
    use burn::tensor::module::conv3d;
    use burn::tensor::ops::ConvOptions;
    use std::sync::Arc;

    /// A test-only generator (nn sits below the project's `dataset::rng`): splitmix64.
    struct SplitMix(u64);

    impl SplitMix {
        fn new(seed: u64) -> Self {
            SplitMix(seed)
        }
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn below(&mut self, n: usize) -> usize {
            (self.unit() * n as f64) as usize
        }
    }

    fn values(t: Tensor<2>) -> Vec<f32> {
        t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
    }

    /// `count` distinct random sites in a `shape` grid, batch items 0 and 1.
    fn random_sites(shape: [usize; 3], count: usize, rng: &mut SplitMix) -> SparseSites {
        let mut coords = Vec::new();
        while coords.len() < count {
            let c = [
                rng.below(2) as i32,
                rng.below(shape[0]) as i32,
                rng.below(shape[1]) as i32,
                rng.below(shape[2]) as i32,
            ];
            if !coords.contains(&c) {
                coords.push(c);
            }
        }
        SparseSites::new(coords, shape, 2).unwrap()
    }

    fn random_tensor<const D: usize>(
        shape: [usize; D],
        rng: &mut SplitMix,
        device: &Device,
    ) -> Tensor<D> {
        let n = shape.iter().product();
        let data: Vec<f32> = (0..n).map(|_| rng.unit() as f32 * 2.0 - 1.0).collect();
        Tensor::from_data(TensorData::new(data, shape), device)
    }

    /// Rows [N, C] on `sites` scattered into a dense [B, C, Z, Y, X] grid, by index
    /// arithmetic the sparse code does not use.
    fn densify(features: Tensor<2>, sites: &SparseSites) -> Tensor<5> {
        let [_, c] = features.dims();
        let [z, y, x] = sites.spatial_shape();
        let b = sites.batch_size();
        let index: Vec<i64> = sites
            .coords()
            .iter()
            .map(|s| {
                (((s[0] as usize * z + s[1] as usize) * y + s[2] as usize) * x + s[3] as usize)
                    as i64
            })
            .collect();
        let n = index.len();
        let device = features.device();
        Tensor::<2>::zeros([b * z * y * x, c], &device)
            .select_assign(
                0,
                Tensor::from_data(TensorData::new(index, [n]), &device),
                features,
                IndexingUpdateOp::Add,
            )
            .reshape([b, z, y, x, c])
            .permute([0, 4, 1, 2, 3])
    }

    /// The dense tensor's values at `sites`, as rows [N, C].
    fn sample(dense: Tensor<5>, sites: &SparseSites) -> Tensor<2> {
        let [b, c, z, y, x] = dense.dims();
        let index: Vec<i64> = sites
            .coords()
            .iter()
            .map(|s| {
                (((s[0] as usize * z + s[1] as usize) * y + s[2] as usize) * x + s[3] as usize)
                    as i64
            })
            .collect();
        let n = index.len();
        let device = dense.device();
        dense
            .permute([0, 2, 3, 4, 1])
            .reshape([b * z * y * x, c])
            .select(0, Tensor::from_data(TensorData::new(index, [n]), &device))
    }

    fn dense_weight(conv: &SparseConv3d) -> Tensor<5> {
        let [c_in, c_out] = conv.channels();
        let [kz, ky, kx] = conv.geometry.kernel;
        conv.weight
            .val()
            .permute([2, 1, 0])
            .reshape([c_out, c_in, kz, ky, kx])
    }

    fn assert_close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}: lengths");
        let scale = b.iter().fold(1f32, |m, v| m.max(v.abs()));
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-5 * scale,
                "{what}[{i}]: sparse {x} vs dense {y}"
            );
        }
    }

    /// Forward and gradients of a sparse convolution equal a dense `conv3d` of the
    /// densified input on every output site (inactive inputs are zeros in the dense grid).
    fn check_against_dense(
        shape: [usize; 3],
        active: usize,
        make: impl Fn(&Device) -> SparseConv3d,
        seed: u64,
    ) {
        for layout in [RuleLayout::PerOffset, RuleLayout::KernelMap] {
            check_layout_against_dense(shape, active, &make, seed, layout);
        }
    }

    fn check_layout_against_dense(
        shape: [usize; 3],
        active: usize,
        make: impl Fn(&Device) -> SparseConv3d,
        seed: u64,
        layout: RuleLayout,
    ) {
        let device = Device::flex().autodiff();
        let mut rng = SplitMix::new(seed);
        let sites = Arc::new(random_sites(shape, active, &mut rng));
        let conv = make(&device);
        let [c_in, c_out] = conv.channels();
        let book = if conv.submanifold {
            Rulebook::submanifold_in(&sites, conv.geometry.kernel, layout, &device)
        } else {
            Rulebook::strided_in(&sites, conv.geometry, layout, &device)
        };
        let x = random_tensor([sites.len(), c_in], &mut rng, &device).require_grad();
        let sparse_out = conv.forward(x.clone(), &book);
        let upstream = random_tensor([book.output_rows(), c_out], &mut rng, &device);
        let sparse_grads = (sparse_out.clone() * upstream.clone()).sum().backward();

        let x_dense = x.clone().detach().require_grad();
        let w_dense = dense_weight(&conv).detach().require_grad();
        let g = conv.geometry;
        let dense_out = conv3d(
            densify(x_dense.clone(), &sites),
            w_dense.clone(),
            None,
            ConvOptions::new(g.stride, g.padding, [1; 3], 1),
        );
        assert_eq!(
            dense_out.dims()[2..],
            book.output.spatial_shape(),
            "output extent"
        );
        let dense_at_sites = sample(dense_out.clone(), &book.output);
        let dense_grads = (dense_at_sites.clone() * upstream).sum().backward();

        assert_close(
            &values(sparse_out.clone().inner()),
            &values(dense_at_sites.inner()),
            &format!("{layout:?} forward"),
        );
        if !conv.submanifold {
            // A regular convolution's output sites are exactly where the dense output can
            // be non-zero: everything outside them is zero.
            let total: f32 = dense_out.inner().abs().sum().into_scalar();
            let on_sites: f32 = sparse_out.inner().abs().sum().into_scalar();
            assert!(
                (total - on_sites).abs() <= 1e-4 * total.max(1.0),
                "mass off the output sites"
            );
        }
        let gx_sparse = x.grad(&sparse_grads).unwrap();
        let gx_dense = x_dense.grad(&dense_grads).unwrap();
        assert_close(
            &values(gx_sparse),
            &values(gx_dense),
            &format!("{layout:?} input gradient"),
        );
        let gw_sparse = conv
            .weight
            .val()
            .grad(&sparse_grads)
            .unwrap()
            .permute([2, 1, 0]);
        let gw_dense = w_dense.grad(&dense_grads).unwrap();
        let [kz, ky, kx] = g.kernel;
        assert_close(
            &values(gw_sparse.reshape([c_out * c_in, kz * ky * kx])),
            &values(gw_dense.reshape([c_out * c_in, kz * ky * kx])),
            &format!("{layout:?} weight gradient"),
        );
    }

    #[test]
    fn submanifold_3x3x3_equals_dense() {
        check_against_dense(
            [5, 7, 6],
            40,
            |d| SparseConv3d::submanifold([3, 4], [3; 3], d),
            1,
        );
    }

    #[test]
    fn strided_3x3x3_with_padding_equals_dense() {
        check_against_dense(
            [7, 8, 9],
            50,
            |d| SparseConv3d::regular([4, 5], ConvGeometry::strided([3; 3], [2; 3], [1; 3]), d),
            2,
        );
    }

    #[test]
    fn stride_one_regular_dilates_sites_and_equals_dense() {
        check_against_dense(
            [4, 5, 5],
            12,
            |d| SparseConv3d::regular([2, 3], ConvGeometry::strided([3; 3], [1; 3], [1; 3]), d),
            3,
        );
    }

    #[test]
    fn x_conv4_padding_0_1_1_equals_dense() {
        check_against_dense(
            [11, 6, 8],
            60,
            |d| SparseConv3d::regular([3, 3], ConvGeometry::strided([3; 3], [2; 3], [0, 1, 1]), d),
            4,
        );
    }

    #[test]
    fn output_layer_3_1_1_stride_2_1_1_equals_dense() {
        check_against_dense(
            [5, 6, 7],
            45,
            |d| {
                SparseConv3d::regular(
                    [4, 6],
                    ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3]),
                    d,
                )
            },
            5,
        );
    }

    #[test]
    fn block_normalises_only_active_rows() {
        let device = Device::flex().autodiff();
        let mut rng = SplitMix::new(9);
        let sites = Arc::new(random_sites([4, 4, 4], 20, &mut rng));
        let norm = NormConfig {
            bias_before_norm: false,
            momentum: 0.01,
            epsilon: 1e-3,
        };
        let block = SparseConvBlock::new(
            SparseConv3d::submanifold([2, 3], [3; 3], &device),
            &norm,
            &device,
        );
        let book = Rulebook::submanifold(&sites, [3; 3], &device);
        let x = random_tensor([sites.len(), 2], &mut rng, &device);
        let y = block.forward(x, &book).inner();
        assert_eq!(y.dims(), [20, 3]);
        // Before the ReLU each channel had zero mean over the 20 rows: some rows are
        // positive and some are clamped to zero in every channel.
        let v = values(y);
        for c in 0..3 {
            let col: Vec<f32> = v.iter().skip(c).step_by(3).copied().collect();
            assert!(
                col.iter().any(|&a| a > 0.0) && col.contains(&0.0),
                "channel {c}: {col:?}"
            );
        }
    }
}
