//! The per-offset sparse convolution (gather → matrix multiply → scatter-add over every kernel
//! offset) as one custom operation on the flex CPU device, with its own backward pass.
//!
//! Why: built from burn's operations, each of a layer's up to 26 non-centre offsets is a
//! `select`, a `matmul` and a `select_assign`, and the backward pass of each `select` zeroes a
//! gradient the size of the whole input ([rows, C_in]) and scatters into it, after which
//! autodiff adds the 27 input gradients together: per layer, 27 input-sized buffers zeroed,
//! written and summed, where one is enough. Here the forward pass runs the same gathers, the
//! same flex matrix products and the same additions in the same order (so its output is
//! burn's to the bit), and the backward pass gathers the output gradient per offset, takes
//! the weight gradient as one product (gathered inputsᵀ · gathered gradient) and the input
//! gradient as one product scattered into a single [rows, C_in] buffer. Both use both cores:
//! the offsets' gathers and products run in parallel, and the additions run split by rows,
//! each row adding its offsets' rows in offset order (the rulebook's `RowPairs`), so the
//! result does not depend on how the work was split.
//!
//! The same `#[backend_extension]` route as [`crate::ragged`]: flex without autodiff runs the
//! fused forward pass, `Autodiff<Flex>` adds the backward step; other devices (and the
//! kernel-map layout) keep burn's operations ([`super::conv::SparseConv3d::forward`]).

use super::rulebook::HostRules;
use crate::matmul::{MatrixRef, product};
use crate::ragged::values;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use rayon::prelude::*;
use std::sync::Arc;

/// The custom operation (see the module's documentation).
#[backend_extension(Flex, Autodiff)]
pub trait SparseConvOps: Backend {
    /// `features` [input rows, C_in] convolved with `weight` [volume, C_in, C_out] over the
    /// pairs of `rules` → [output rows, C_out].
    fn sparse_conv_per_offset(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        rules: Arc<HostRules>,
    ) -> FloatTensor<Self>;
}

/// [`SparseConvOps::sparse_conv_per_offset`] on tensors on the flex device.
pub fn sparse_conv(features: Tensor<2>, weight: Tensor<3>, rules: &Arc<HostRules>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SparseConvOps>::sparse_conv_per_offset(
        features.into_dispatch(),
        weight.into_dispatch(),
        Arc::clone(rules),
    ))
}

fn matrix(values: Vec<f32>, shape: [usize; 2]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

/// Rows `rows` of the [_, c] matrix `data`, stacked: [rows.len(), c]. Appended row by row
/// into an unfilled buffer: zeroing it first, to split the copy over threads, cost more
/// than the copy (memory-bound either way). The networks' widths (voxel features of 4 and
/// 6 values, layers of 16 to 128 channels) are copied as fixed-size rows
/// ([`gather_fixed`]): a `memmove` call per row cost more than the copy itself.
fn gather_rows(data: &[f32], c: usize, rows: &[u32]) -> Vec<f32> {
    match c {
        4 => gather_fixed::<4>(data, rows),
        6 => gather_fixed::<6>(data, rows),
        16 => gather_fixed::<16>(data, rows),
        32 => gather_fixed::<32>(data, rows),
        48 => gather_fixed::<48>(data, rows),
        64 => gather_fixed::<64>(data, rows),
        128 => gather_fixed::<128>(data, rows),
        _ => {
            let mut out = Vec::with_capacity(rows.len() * c);
            for &r in rows {
                out.extend_from_slice(&data[r as usize * c..][..c]);
            }
            out
        }
    }
}

/// [`gather_rows`] for rows of `C` values, each copied as one array.
fn gather_fixed<const C: usize>(data: &[f32], rows: &[u32]) -> Vec<f32> {
    let (table, _) = data.as_chunks::<C>();
    let gathered: Vec<[f32; C]> = rows.iter().map(|&r| table[r as usize]).collect();
    gathered.into_flattened()
}

/// Offset k's [C_in, C_out] slice of the weight.
fn offset_weight(weight: &[f32], k: usize, [c_in, c_out]: [usize; 2]) -> MatrixRef<'_> {
    MatrixRef::new(&weight[k * c_in * c_out..][..c_in * c_out], [c_in, c_out])
}

fn weight_dims(weight: &FlexTensor) -> [usize; 3] {
    let shape = weight.layout().shape();
    assert_eq!(shape.num_dims(), 3, "a [volume, C_in, C_out] weight");
    [shape[0], shape[1], shape[2]]
}

/// The forward pass: each offset's gathered product (offsets in parallel), then per output
/// row the centre offset's product (or zero) plus the other offsets' products in offset
/// order (rows in parallel).
fn forward(features: &FlexTensor, weight: &FlexTensor, rules: &HostRules) -> FlexTensor {
    let [_, c_in, c_out] = weight_dims(weight);
    let (x, w) = (values(features), values(weight));
    assert_eq!(
        x.len(),
        rules.input_rows * c_in,
        "features on the input sites"
    );
    let (centre, products) = rayon::join(
        || {
            rules.identity_offset.map(|k| {
                product(
                    MatrixRef::rows(&x, c_in),
                    offset_weight(&w, k, [c_in, c_out]),
                )
            })
        },
        || {
            rules
                .rules
                .par_iter()
                .map(|(k, input, _)| {
                    let gathered = gather_rows(&x, c_in, input);
                    product(
                        MatrixRef::rows(&gathered, c_in),
                        offset_weight(&w, *k, [c_in, c_out]),
                    )
                })
                .collect::<Vec<_>>()
        },
    );
    let out = match centre {
        // The centre product's own buffer (no copy), the other offsets added in.
        Some(mut out) => {
            rules.by_output.add_into(&mut out, c_out, None, &products);
            out
        }
        None => rules.by_output.sums(c_out, None, &products),
    };
    matrix(out, [rules.output_rows, c_out])
}

/// The backward pass: (input gradient, weight gradient), each where asked for. Per offset
/// (offsets in parallel), dW_k = x[inputs]ᵀ · g[outputs] and g[outputs] · W_kᵀ; then per
/// input row (rows in parallel) dx[i] = the centre offset's g · W_kᵀ plus the other
/// offsets' rows for i, in offset order.
fn backward(
    features: &FlexTensor,
    weight: &FlexTensor,
    rules: &HostRules,
    grad: &FlexTensor,
    [want_x, want_w]: [bool; 2],
) -> (Option<FlexTensor>, Option<FlexTensor>) {
    let dims @ [volume, c_in, c_out] = weight_dims(weight);
    let (x, w, g) = (values(features), values(weight), values(grad));
    // (dW_k, g[outputs] · W_kᵀ) of one offset.
    let offset_grads = |k: usize, x_rows: &[f32], g_rows: &[f32]| {
        let dw_k = want_w.then(|| {
            product(
                MatrixRef::rows(x_rows, c_in).t(),
                MatrixRef::rows(g_rows, c_out),
            )
        });
        let dx_k = want_x.then(|| {
            product(
                MatrixRef::rows(g_rows, c_out),
                offset_weight(&w, k, [c_in, c_out]).t(),
            )
        });
        (dw_k, dx_k)
    };
    let (centre, others) = rayon::join(
        || rules.identity_offset.map(|k| (k, offset_grads(k, &x, &g))),
        || {
            rules
                .rules
                .par_iter()
                .map(|(k, input, output)| {
                    let x_rows = gather_rows(&x, c_in, input);
                    let g_rows = gather_rows(&g, c_out, output);
                    offset_grads(*k, &x_rows, &g_rows)
                })
                .collect::<Vec<_>>()
        },
    );
    let dw = want_w.then(|| {
        let mut dw = vec![0f32; volume * c_in * c_out];
        let offsets = centre.iter().map(|(k, (dw_k, _))| (*k, dw_k));
        let offsets = offsets.chain(
            rules
                .rules
                .iter()
                .zip(&others)
                .map(|((k, ..), (dw_k, _))| (*k, dw_k)),
        );
        for (k, dw_k) in offsets {
            let dw_k = dw_k.as_ref().expect("weight gradients asked for");
            dw[k * c_in * c_out..][..c_in * c_out].copy_from_slice(dw_k);
        }
        FlexTensor::from_data(TensorData::new(dw, dims))
    });
    let dx = want_x.then(|| {
        fn asked(dx_k: &Option<Vec<f32>>) -> &[f32] {
            dx_k.as_deref().expect("input gradients asked for")
        }
        let centre = centre.as_ref().map(|(_, (_, dx_k))| asked(dx_k));
        let products: Vec<&[f32]> = others.iter().map(|(_, dx_k)| asked(dx_k)).collect();
        let dx = rules.by_input.sums(c_in, centre, &products);
        matrix(dx, [rules.input_rows, c_in])
    });
    (dx, dw)
}

impl SparseConvOps for Flex {
    fn sparse_conv_per_offset(
        features: FlexTensor,
        weight: FlexTensor,
        rules: Arc<HostRules>,
    ) -> FlexTensor {
        forward(&features, &weight, &rules)
    }
}

/// The backward step of [`SparseConvOps::sparse_conv_per_offset`].
#[derive(Debug)]
struct SparseConvBackward;

impl Backward<Flex, 2> for SparseConvBackward {
    /// The features, the weight and the pairs.
    type State = (FlexTensor, FlexTensor, Arc<HostRules>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (features, weight, rules) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let [node_x, node_w] = ops.parents;
        let want = [node_x.is_some(), node_w.is_some()];
        let (dx, dw) = backward(&features, &weight, &rules, &grad, want);
        for (node, g) in [(node_x, dx), (node_w, dw)] {
            if let (Some(node), Some(g)) = (node, g) {
                grads.register::<Flex>(node.id, g);
            }
        }
    }
}

impl<C: CheckpointStrategy> SparseConvOps for Autodiff<Flex, C> {
    fn sparse_conv_per_offset(
        features: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        rules: Arc<HostRules>,
    ) -> FloatTensor<Self> {
        let (features, a) = features.into_parts();
        let (weight, b) = weight.into_parts();
        let out = forward(&features, &weight, &rules);
        match SparseConvBackward
            .prepare::<C>([a, b])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((features, weight, rules), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::conv::per_offset_with_burns_ops;
    use super::super::rulebook::{ConvGeometry, RuleGather, RuleLayout, Rulebook};
    use super::super::sites::SparseSites;
    use super::super::test_data::{sites, values};
    use super::*;

    fn tensor<const D: usize>(shape: [usize; D], salt: usize, device: &Device) -> Tensor<D> {
        let v = values(shape.iter().product(), salt);
        Tensor::from_data(TensorData::new(v, shape), device)
    }

    fn flat<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    fn close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}");
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-5 * (1.0 + y.abs()),
                "{what}[{i}]: {x} vs {y}"
            );
        }
    }

    /// The fused operation against the same convolution from burn's operations: the
    /// forward pass identical to the bit, the input and weight gradients within rounding,
    /// for a submanifold rulebook (with a centre offset), a strided one (none), and sites
    /// so sparse that most offsets have no pairs.
    #[test]
    fn fused_sparse_conv_matches_burns_operations() {
        let device = Device::flex().autodiff();
        let cases = [
            ([6, 7, 8], 60, ConvGeometry::same([3; 3]), true, [3, 5]),
            (
                [6, 7, 8],
                60,
                ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
                false,
                [4, 2],
            ),
            ([9, 9, 9], 5, ConvGeometry::same([3; 3]), true, [2, 3]),
            // More rows than one task's share: sums split over threads.
            ([10, 14, 14], 1200, ConvGeometry::same([3; 3]), true, [3, 2]),
            (
                [10, 14, 14],
                1200,
                ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
                false,
                [2, 3],
            ),
            // The widths whose rows are gathered as fixed-size arrays.
            (
                [10, 14, 14],
                400,
                ConvGeometry::same([3; 3]),
                true,
                [16, 48],
            ),
            (
                [10, 14, 14],
                400,
                ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
                false,
                [32, 64],
            ),
            ([8, 8, 8], 100, ConvGeometry::same([3; 3]), true, [6, 128]),
        ];
        for (case, (shape, count, geometry, submanifold, [c_in, c_out])) in
            cases.into_iter().enumerate()
        {
            let sites = sites(shape, count, case as u64 + 1);
            let book = if submanifold {
                Rulebook::submanifold_in(&sites, geometry.kernel, RuleLayout::PerOffset, &device)
            } else {
                Rulebook::strided_in(&sites, geometry, RuleLayout::PerOffset, &device)
            };
            let RuleGather::PerOffset {
                identity_offset,
                rules,
                host,
            } = &book.gather
            else {
                panic!("a per-offset rulebook")
            };
            assert_eq!(identity_offset.is_some(), submanifold);
            let volume = geometry.volume();
            let upstream = tensor([book.output_rows(), c_out], 3, &device);
            let run = |fused: bool| {
                let x = tensor([sites.len(), c_in], 1, &device).require_grad();
                let w = tensor([volume, c_in, c_out], 2, &device).require_grad();
                let out = if fused {
                    sparse_conv(x.clone(), w.clone(), host)
                } else {
                    let rows = book.output_rows();
                    per_offset_with_burns_ops(x.clone(), w.clone(), *identity_offset, rules, rows)
                };
                let grads = (out.clone() * upstream.clone()).sum().backward();
                (
                    flat(out),
                    flat(x.grad(&grads).unwrap()),
                    flat(w.grad(&grads).unwrap()),
                )
            };
            let (fused, burns) = (run(true), run(false));
            assert_eq!(fused.0, burns.0, "case {case}: forward");
            close(&fused.1, &burns.1, &format!("case {case}: input gradient"));
            close(&fused.2, &burns.2, &format!("case {case}: weight gradient"));
        }
    }

    /// Without autodiff (detection) the operation is the forward pass alone, and a rulebook
    /// over no sites gives an empty output.
    #[test]
    fn inference_and_empty_sites() {
        let device = Device::flex();
        let empty = Arc::new(SparseSites::new(Vec::new(), [4, 4, 4], 1).unwrap());
        let book = Rulebook::submanifold_in(&empty, [3; 3], RuleLayout::PerOffset, &device);
        let RuleGather::PerOffset { host, .. } = &book.gather else {
            panic!("a per-offset rulebook")
        };
        let out = sparse_conv(
            Tensor::zeros([0, 2], &device),
            tensor([27, 2, 3], 0, &device),
            host,
        );
        assert_eq!(out.dims(), [0, 3]);
    }
}
