//! SAF's local feature aggregation (LFA; He et al., Sensors 2022, after RandLA-Net).
//!
//! The frustum arrives with N₀ points in random order (the frustum sampler shuffles), so
//! "random sampling halves the points" is "keep the first half": after S halvings the
//! first N₀ / 2^S points remain, and those are the points the sub-frustums are cut from
//! (`frustum.sliced_points`). Before each halving every surviving point i gets
//!
//! `f_i = MaxPool_k MLP_local(p_k ⊕ (p_i − p_k) ⊕ ‖p_i − p_k‖ ⊕ p_i [⊕ g_k]) ⊕ MLP_point(p_i [⊕ g_i])`
//!
//! over its K nearest neighbours k among the points of the current stage (g the previous
//! stage's features; coordinates relative to the frustum's centroid). Optionally
//! (`position_scale_m`, `offset_scale_m`) positions and offsets are divided by their own
//! scales first, so that neither dominates the first layer. Only survivors get
//! features: the dropped half would feed nothing downstream. The slice PointNets then see
//! each pair's coordinates relative to its sub-frustum centre together with `f` of its point,
//! or with `γ ⊙ f` under `feature_gate = "zero"` (γ learned per channel, started at 0;
//! not in the paper, see [`LfaFeatureGate`]).
//!
//! The neighbour search runs on the host when the batch's tensors are built (a k-d tree
//! from `kiddo` over the frustum's distinct points: repeated samples are one neighbour),
//! the frustums in parallel.

use crate::config::{LfaConfig, LfaFeatureGate, ModelConfig};
use crate::error::ModelError;
use burn::module::Param;
use burn::prelude::*;
use burn::tensor::activation::relu;
use fusiondet_nn::buffers::{par_chunks_filled, par_chunks_written};
use fusiondet_nn::gather::RowGather;
use fusiondet_nn::ragged::{self, Neighbours, Runs};
use fusiondet_nn::{MlpLayer, host_max, mlp_stack};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZero;
use std::sync::Arc;

/// One stage's host-built indices.
#[derive(Debug, Clone)]
pub struct LfaStageIndex {
    /// Points of the stage per frustum (N_s).
    pub points: usize,
    /// [B · N_s / 2]: rows of the survivors in the stage's point rows (`index()` on the
    /// device), and their gather: burn's `select` on the CPU, a backward pass by each row's
    /// readers on a GPU (`RowGather`), where burn's walks every gathered row per column (and
    /// on lavapipe sums wrongly).
    pub keep: RowGather,
    /// [B · N_s / 2 · K]: rows of each survivor's K nearest neighbours, gathered likewise.
    pub neighbours: RowGather,
    /// The same rows on the host (with their transpose), for the first layer's host path
    /// in inference and its custom operation in training.
    pub neighbours_host: Arc<Neighbours>,
}

/// Everything LFA needs for a batch.
#[derive(Debug, Clone)]
pub struct LfaInputs {
    pub neighbours: usize,
    /// 1 / `position_scale_m` and 1 / `offset_scale_m` of the config.
    pub position_gain: f32,
    pub offset_gain: f32,
    /// [B · N₀, 3]: points relative to their frustum's centroid.
    pub coords: Tensor<2>,
    pub stages: Vec<LfaStageIndex>,
}

impl LfaInputs {
    /// `points` is the batch's [B · N₀ · 3] array; `n0` points per frustum.
    pub fn new(
        points: &[f32],
        batch_size: usize,
        n0: usize,
        config: &LfaConfig,
        device: &Device,
    ) -> Result<Self, ModelError> {
        let stages = config.stages.len();
        let k = config.neighbours;
        if !n0.is_multiple_of(1 << stages) || n0 >> stages < k {
            return Err(ModelError::Batch(format!(
                "LFA: {n0} points per frustum cannot be halved {stages} times keeping at least \
                 {k} neighbours; use frustum.points_per_frustum = a multiple of {}",
                1 << stages
            )));
        }
        let mut coords = Vec::with_capacity(points.len());
        for f in 0..batch_size {
            let frustum = &points[f * n0 * 3..(f + 1) * n0 * 3];
            let mut centroid = [0f64; 3];
            for p in frustum.chunks_exact(3) {
                for d in 0..3 {
                    centroid[d] += p[d] as f64 / n0 as f64;
                }
            }
            for p in frustum.chunks_exact(3) {
                for d in 0..3 {
                    coords.push(p[d] - centroid[d] as f32);
                }
            }
        }
        let mut stage_index = Vec::with_capacity(stages);
        let mut n = n0;
        for _ in 0..stages {
            let half = n / 2;
            let keep: Vec<u32> = (0..batch_size * half)
                .map(|r| ((r / half) * n + r % half) as u32)
                .collect();
            // The frustums' searches are independent: one per rayon task, collected in
            // frustum order (the same indices with any number of threads).
            let per_frustum: Vec<Vec<usize>> = (0..batch_size)
                .into_par_iter()
                .map(|f| {
                    // The stage's points of frustum f are the first n of its N₀ points.
                    let pts: Vec<[f32; 3]> = (0..n)
                        .map(|i| {
                            let r = (f * n0 + i) * 3;
                            [coords[r], coords[r + 1], coords[r + 2]]
                        })
                        .collect();
                    nearest_neighbours(&pts, half, k)
                })
                .collect();
            let mut neighbours = Vec::with_capacity(batch_size * half * k);
            for (f, knn) in per_frustum.into_iter().enumerate() {
                neighbours.extend(knn.into_iter().map(|j| (f * n + j) as u32));
            }
            stage_index.push(LfaStageIndex {
                points: n,
                keep: RowGather::new(&keep, batch_size * n, device),
                neighbours: RowGather::new(&neighbours, batch_size * n, device),
                neighbours_host: Arc::new(Neighbours::new(neighbours, k, batch_size * n)),
            });
            n = half;
        }
        Ok(Self {
            neighbours: k,
            position_gain: (1.0 / config.position_scale_m) as f32,
            offset_gain: (1.0 / config.offset_scale_m) as f32,
            coords: Tensor::from_data(TensorData::new(coords, [batch_size * n0, 3]), device),
            stages: stage_index,
        })
    }
}

/// The K nearest distinct points (by index among `points`) of each of the first `queries`
/// points, nearest first; a point with fewer than K distinct neighbours repeats its last.
pub fn nearest_neighbours(points: &[[f32; 3]], queries: usize, k: usize) -> Vec<usize> {
    // Distinct coordinates, each represented by its first index (ordered by first use).
    let mut first: std::collections::HashMap<[u32; 3], usize> = Default::default();
    let mut distinct: Vec<[f32; 3]> = Vec::new();
    let mut distinct_index: Vec<usize> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        let key = p.map(f32::to_bits);
        first.entry(key).or_insert_with(|| {
            distinct.push(*p);
            distinct_index.push(i);
            distinct.len() - 1
        });
    }
    let mut out = Vec::with_capacity(queries * k);
    let take = k.min(distinct.len());
    let tree: ImmutableKdTree<f32, 3> =
        ImmutableKdTree::new_from_slice(&distinct).expect("finite coordinates build a k-d tree");
    for q in &points[..queries] {
        let found = tree
            .query(q)
            .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(take).expect("k ≥ 1"))
            .execute();
        let mut last = 0;
        for item in found.iter() {
            last = distinct_index[item.item as usize];
            out.push(last);
        }
        out.extend(std::iter::repeat_n(last, k - found.len()));
    }
    out
}

/// One stage: a local MLP over neighbour encodings (max-pooled) beside a point MLP.
#[derive(Module, Debug)]
pub struct LfaStage {
    pub local: Vec<MlpLayer>,
    pub point: Vec<MlpLayer>,
}

/// `x · gain`, skipping the product at the paper's gain of 1 (no work, same bits).
fn scaled(x: Tensor<2>, gain: f32) -> Tensor<2> {
    if gain == 1.0 { x } else { x.mul_scalar(gain) }
}

fn run(layers: &[MlpLayer], mut x: Tensor<2>) -> Tensor<2> {
    for layer in layers {
        x = layer.forward(x);
    }
    x
}

/// Local feature aggregation over the frustum's points.
#[derive(Module, Debug)]
pub struct Lfa {
    pub stages: Vec<LfaStage>,
    /// [C]: the per-channel scale γ of `feature_gate = "zero"` (absent in the paper's form).
    pub gate: Option<Param<Tensor<1>>>,
}

impl Lfa {
    pub fn new(config: &ModelConfig, lfa: &LfaConfig, device: &Device) -> Self {
        let mut prev = 0;
        let stages = lfa
            .stages
            .iter()
            .map(|s| {
                let stage = LfaStage {
                    local: mlp_stack(10 + prev, &s.local, &config.norm(), device),
                    point: mlp_stack(3 + prev, &s.point, &config.norm(), device),
                };
                prev = s.out_channels();
                stage
            })
            .collect();
        let gate = match lfa.feature_gate {
            LfaFeatureGate::None => None,
            LfaFeatureGate::Zero => Some(Param::from_tensor(Tensor::zeros([prev], device))),
        };
        Self { stages, gate }
    }

    /// Features of the surviving points, [B · N_S, C] (frustum-major, in sample order).
    pub fn forward(&self, inputs: &LfaInputs) -> Tensor<2> {
        let k = inputs.neighbours;
        let mut coords = inputs.coords.clone();
        let mut feats: Option<Tensor<2>> = None;
        for (stage, index) in self.stages.iter().zip(&inputs.stages) {
            let q = coords.clone().select(0, index.keep.index().clone()); // [M, 3]
            let (first, rest) = stage.local.split_first().expect("a local MLP has layers");
            let at = Neighbourhood {
                coords: &coords,
                q: &q,
                index,
                offset_gain: inputs.offset_gain,
                k,
            };
            let terms = || first_layer_terms(first, inputs, &coords, feats.as_ref(), &q);
            // The local MLP's last ReLU after the max over the K neighbours: it commutes
            // with the max, and then runs over M rows instead of M·K.
            let widest = stage.local.iter().map(MlpLayer::out_channels).max();
            let local = if rest.is_empty() && first.is_folded() && host_max::host_path(&q) {
                // One folded layer in inference on the CPU (LFA at the paper's widths):
                // the max is taken as the sums are formed, and the [M·K, C₁] sums are
                // never stored.
                terms().max_on_host(&at)
            } else if let Some(queries) = inference_chunk(&q, k, widest.unwrap_or(1)) {
                terms().local_in_chunks(first, rest, &at, queries)
            } else {
                max_over_neighbours(local_mlp(first, rest, terms().combine(&at)), k)
            };
            let local = relu(local);
            let mut point_in = vec![scaled(q.clone(), inputs.position_gain)];
            if let Some(g) = &feats {
                point_in.push(index.keep.gather(g.clone()));
            }
            let point = run(&stage.point, Tensor::cat(point_in, 1));
            feats = Some(Tensor::cat(vec![local, point], 1));
            coords = q;
        }
        let feats = feats.expect("LFA has at least one stage");
        match &self.gate {
            Some(gate) => {
                let c = gate.dims()[0];
                feats * gate.val().reshape([1, c])
            }
            None => feats,
        }
    }
}

/// The local MLP on a stage's first-layer sums [rows, C₁]: that layer's norm, then the other
/// layers, the last without its ReLU (which follows the max over the neighbours).
fn local_mlp(first: &MlpLayer, rest: &[MlpLayer], sums: Tensor<2>) -> Tensor<2> {
    let local = first.normalize(sums);
    match rest.split_last() {
        None => local,
        Some((last, hidden)) => last.forward_pre_activation(run(hidden, relu(local))),
    }
}

/// Queries a chunk where inference on a GPU would otherwise make a [M·K, C] tensor (C the
/// stage's widest local layer) past half the most one buffer binds (on wgpu a larger tensor
/// comes out wrong without an error: lavapipe binds 128 MiB, which the shipped SAF model's
/// first stage passes from 9 frustums a batch); `None` where it fits, in training (whose
/// batch norms take their statistics over all the rows) and off CubeCL.
fn inference_chunk(q: &Tensor<2>, k: usize, widest: usize) -> Option<usize> {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    {
        let device = q.device();
        if device.is_autodiff() {
            return None;
        }
        let budget = fusiondet_nn::cube::binding_limit(&device)? / 2;
        let per_query = (k * widest * std::mem::size_of::<f32>()).max(1) as u64;
        let [m, _] = q.dims();
        if m as u64 * per_query <= budget {
            return None;
        }
        Some(((budget / per_query) as usize).max(1))
    }
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    {
        let _ = (q, k, widest);
        None
    }
}

/// [M·K, C] → [M, C], the max over each query's K neighbours: on the host in inference
/// on the CPU (see `fusiondet_nn::host_max`), by the custom operation in training there
/// (`fusiondet_nn::ragged`: the winning neighbour kept, the gradient sent to it), else
/// burn's reduction.
fn max_over_neighbours(x: Tensor<2>, k: usize) -> Tensor<2> {
    if host_max::host_path(&x) {
        return host_max::blocks_max(x, k);
    }
    let [rows, c] = x.dims();
    if ragged::custom_path(&x) {
        return ragged::runs_max(x, &Arc::new(Runs::blocks(rows / k, k)));
    }
    x.reshape([rows / k, k, c])
        .max_dim(1)
        .reshape([rows / k, c])
}

/// The local MLP's first layer before its norm, for the encoding
/// `a·p_k ⊕ b·(p_i − p_k) ⊕ d_ik ⊕ a·p_i [⊕ g_k]` (a, b the position and offset gains,
/// d_ik = ‖b·(p_i − p_k)‖), as the parts of its sum over each query's K neighbours, without
/// building that [M·K, 10 + C_g] matrix. Its linear map splits by input rows,
/// W = [W_k; W_o; w_d; W_i; W_g], so
/// `y_ik = (p_k·(a W_k − b W_o) + g_k W_g)  +  (p_i·(b W_o + a W_i) + bias)  +  d_ik w_d`:
/// a term per point of the stage (N rows, then gathered for the neighbours), one per
/// query (M rows, broadcast over its K) and the distance term. The neighbours' features
/// g_k, the widest part of the encoding, are never gathered; the product is the same up
/// to float rounding.
fn first_layer_terms(
    layer: &MlpLayer,
    inputs: &LfaInputs,
    coords: &Tensor<2>,
    feats: Option<&Tensor<2>>,
    q: &Tensor<2>,
) -> FirstLayerTerms {
    let (a, b) = (inputs.position_gain, inputs.offset_gain);
    let (w, bias) = layer.affine();
    let [d_in, c1] = w.dims();
    let rows = |r: std::ops::Range<usize>| w.clone().slice([r, 0..c1]);
    let (w_k, w_o, w_d, w_i) = (rows(0..3), rows(3..6), rows(6..7), rows(7..10));
    let per_point_w = scaled(w_k, a) - scaled(w_o.clone(), b);
    let mut per_point = coords.clone().matmul(per_point_w);
    if let Some(g) = feats {
        per_point = per_point + g.clone().matmul(rows(10..d_in));
    }
    let mut per_query = q.clone().matmul(scaled(w_o, b) + scaled(w_i, a));
    if let Some(bias) = bias {
        per_query = per_query + bias.reshape([1, c1]);
    }
    FirstLayerTerms {
        per_point,
        per_query,
        w_d,
    }
}

/// Where the first local layer's sum is taken: the stage's points [N, 3], its queries
/// [M, 3], their neighbour rows, the offset gain and K.
#[derive(Clone, Copy)]
struct Neighbourhood<'a> {
    coords: &'a Tensor<2>,
    q: &'a Tensor<2>,
    index: &'a LfaStageIndex,
    offset_gain: f32,
    k: usize,
}

/// The first local layer's parts: [N, C₁] per point of the stage, [M, C₁] per query and
/// the distance's row of weights [1, C₁].
struct FirstLayerTerms {
    per_point: Tensor<2>,
    per_query: Tensor<2>,
    w_d: Tensor<2>,
}

/// [`FirstLayerTerms`] as host values, with the distances and the sizes: what the host
/// forms of the sum read.
struct HostTerms {
    per_point: Vec<f32>,
    per_query: Vec<f32>,
    w_d: Vec<f32>,
    /// [M·K] (see [`Neighbourhood::distances`]).
    distance: Vec<f32>,
    m: usize,
    c1: usize,
    device: Device,
}

impl FirstLayerTerms {
    fn on_host(self, at: &Neighbourhood) -> HostTerms {
        let [m, c1] = self.per_query.dims();
        HostTerms {
            device: self.per_query.device(),
            per_point: host(self.per_point),
            per_query: host(self.per_query),
            w_d: host(self.w_d),
            distance: at.distances(),
            m,
            c1,
        }
    }

    /// `y_ik`, [M·K, C₁]: on the host in inference on the CPU, by the custom operation in
    /// training there, else by burn's operations.
    fn combine(self, at: &Neighbourhood) -> Tensor<2> {
        if host_max::host_path(&self.per_point) {
            self.combine_on_host(at)
        } else if ragged::custom_path(&self.per_point) {
            self.combine_custom(at)
        } else {
            self.combine_by_tensors(at)
        }
    }

    /// `max_k y_ik`, [M, C₁], in one pass on the host (inference on the flex device): each
    /// sum as [`combine_on_host`](Self::combine_on_host) forms it and the max as
    /// `host_max::blocks_max` scans it (neighbours in order, `flex_max`), so the same bits
    /// as that max over the stored sums.
    fn max_on_host(self, at: &Neighbourhood) -> Tensor<2> {
        let k = at.k;
        assert!(k > 0, "a query has neighbours");
        let h = self.on_host(at);
        let c1 = h.c1;
        let out = par_chunks_filled(h.m * c1, c1, |i, best| {
            let query = &h.per_query[i * c1..(i + 1) * c1];
            for (j, &nb) in at.neighbours()[i * k..(i + 1) * k].iter().enumerate() {
                let nb = nb as usize;
                let distance = h.distance[i * k + j];
                let point = &h.per_point[nb * c1..(nb + 1) * c1];
                let sums = point.iter().zip(query).zip(&h.w_d);
                for (best, ((&pk, &pi), &wd)) in best.iter_mut().zip(sums) {
                    let y = (pk + pi) + distance * wd;
                    *best = if j == 0 {
                        y
                    } else {
                        host_max::flex_max(*best, y)
                    };
                }
            }
        });
        Tensor::from_data(TensorData::new(out, [h.m, c1]), &h.device)
    }

    /// `y_ik = per_point_k + per_query_i + d_ik w_d`, [M·K, C₁], by burn's operations
    /// (differentiable, any backend).
    fn combine_by_tensors(self, at: &Neighbourhood) -> Tensor<2> {
        let [m, _] = self.per_query.dims();
        let neighbours = at.index.neighbours.index().clone();
        let per_point = at.index.neighbours.gather(self.per_point.clone());
        self.rows_of(at, 0..m, neighbours, per_point)
    }

    /// The sums of queries `queries` ([Q·K, C₁]), given those queries' neighbour rows [Q·K]
    /// and their per-point terms gathered [Q·K, C₁].
    fn rows_of(
        &self,
        at: &Neighbourhood,
        queries: std::ops::Range<usize>,
        neighbours: Tensor<1, Int>,
        per_point: Tensor<2>,
    ) -> Tensor<2> {
        let k = at.k;
        let [all, c1] = self.per_query.dims();
        let m = queries.len();
        // Whole tensors where the range is all the queries (no slice for autodiff to record).
        let rows = |t: &Tensor<2>, width: usize| {
            if m == all {
                t.clone()
            } else {
                t.clone().slice([queries.clone(), 0..width])
            }
        };
        // ‖p_i − p_k‖ of the scaled offsets, [Q·K, 1].
        let nb = at.coords.clone().select(0, neighbours); // [Q·K, 3]
        let qk = rows(at.q, 3)
            .reshape([m, 1, 3])
            .expand([m, k, 3])
            .reshape([m * k, 3]);
        let dist = scaled(qk - nb, at.offset_gain)
            .square()
            .sum_dim(1)
            .add_scalar(1e-12)
            .sqrt();
        let y = per_point.reshape([m, k, c1])
            + rows(&self.per_query, c1).reshape([m, 1, c1])
            + (dist * self.w_d.clone()).reshape([m, k, c1]);
        y.reshape([m * k, c1])
    }

    /// The stage's local features [M, C] (before their ReLU) through `first` and `rest`, the
    /// queries taken `queries` at a time so that no [queries·K, C] tensor passes what one
    /// buffer binds (inference only: each query's rows are the same whatever the chunk, and
    /// the norms use their running statistics).
    fn local_in_chunks(
        self,
        first: &MlpLayer,
        rest: &[MlpLayer],
        at: &Neighbourhood,
        queries: usize,
    ) -> Tensor<2> {
        let k = at.k;
        let [m, _] = self.per_query.dims();
        let index = at.index.neighbours.index();
        let parts: Vec<Tensor<2>> = (0..m)
            .step_by(queries.max(1))
            .map(|q0| {
                let rows = q0..(q0 + queries).min(m);
                let neighbours = index.clone().narrow(0, rows.start * k, rows.len() * k);
                let per_point = self.per_point.clone().select(0, neighbours.clone());
                let sums = self.rows_of(at, rows, neighbours, per_point);
                max_over_neighbours(local_mlp(first, rest, sums), k)
            })
            .collect();
        Tensor::cat(parts, 0)
    }

    /// The same sum in one pass on the host, in parallel over the queries, for inference
    /// on the flex CPU device: the tensor form gathers, broadcasts and adds [M·K, C₁]
    /// matrices in about ten passes, and those element-wise passes were most of LFA's
    /// time. The same operations in the same order, so the same bits.
    fn combine_on_host(self, at: &Neighbourhood) -> Tensor<2> {
        let k = at.k;
        let h = self.on_host(at);
        let c1 = h.c1;
        // Every value is written (a query's K rows of C₁), so the [M·K, C₁] buffer, the
        // largest of LFA's inference, is not zeroed first.
        let y = par_chunks_written(h.m * k * c1, k * c1, |i, rows| {
            let neighbours = &at.neighbours()[i * k..(i + 1) * k];
            let query = &h.per_query[i * c1..(i + 1) * c1];
            for (j, (row, &nb)) in rows.chunks_exact_mut(c1).zip(neighbours).enumerate() {
                let nb = nb as usize;
                let distance = h.distance[i * k + j];
                let point = &h.per_point[nb * c1..(nb + 1) * c1];
                let sums = point.iter().zip(query).zip(&h.w_d);
                for (out, ((&pk, &pi), &wd)) in row.iter_mut().zip(sums) {
                    out.write((pk + pi) + distance * wd);
                }
            }
        });
        Tensor::from_data(TensorData::new(y, [h.m * k, c1]), &h.device)
    }

    /// The same sum as one custom operation on the flex device with its own backward
    /// (`fusiondet_nn::ragged::neighbour_sum`), for training there: the distances are
    /// computed on the host (the points are inputs, constants of the graph), the gather,
    /// broadcast and adds are one pass each way. The same bits as the tensor form.
    fn combine_custom(self, at: &Neighbourhood) -> Tensor<2> {
        let device = self.per_query.device();
        let rows = at.index.neighbours_host.neighbours.len();
        let distance = Tensor::from_data(TensorData::new(at.distances(), [rows, 1]), &device);
        ragged::neighbour_sum(
            self.per_point,
            self.per_query,
            distance,
            self.w_d,
            &at.index.neighbours_host,
        )
    }
}

/// A tensor's f32 values on the host.
fn host(t: Tensor<2>) -> Vec<f32> {
    t.into_data()
        .try_into_vec::<f32>()
        .expect("f32 on the host")
}

impl Neighbourhood<'_> {
    /// The K neighbour rows of each query, [M·K].
    fn neighbours(&self) -> &[u32] {
        &self.index.neighbours_host.neighbours
    }

    /// `‖b·(p_i − p_k)‖` per (query, neighbour), [M·K], by the tensor form's operations in
    /// its order (so its bits).
    fn distances(&self) -> Vec<f32> {
        let (offset_gain, k) = (self.offset_gain, self.k);
        let (coords, q) = (host(self.coords.clone()), host(self.q.clone()));
        let neighbours = &self.index.neighbours_host.neighbours;
        let mut out = vec![0f32; neighbours.len()];
        out.par_chunks_mut(k)
            .zip(neighbours.par_chunks(k))
            .enumerate()
            .for_each(|(i, (dst, neighbours))| {
                let p_i = &q[i * 3..i * 3 + 3];
                for (d_out, &nb) in dst.iter_mut().zip(neighbours) {
                    let p_k = &coords[nb as usize * 3..nb as usize * 3 + 3];
                    let mut squares = 0f32;
                    for d in 0..3 {
                        let offset = p_i[d] - p_k[d];
                        let offset = if offset_gain == 1.0 {
                            offset
                        } else {
                            offset * offset_gain
                        };
                        squares += offset * offset;
                    }
                    *d_out = (squares + 1e-12).sqrt();
                }
            });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::LfaStageConfig;

    #[test]
    fn neighbours_are_the_nearest_distinct_points() {
        // A line of points 0, 1, 2, ... with point 5 repeated at the end.
        let mut pts: Vec<[f32; 3]> = (0..10).map(|i| [i as f32, 0.0, 0.0]).collect();
        pts.push([5.0, 0.0, 0.0]);
        let nn = nearest_neighbours(&pts, 4, 3);
        assert_eq!(&nn[0..3], &[0, 1, 2]);
        assert_eq!(nn[3], 1);
        let mut second: Vec<usize> = nn[4..6].to_vec();
        second.sort();
        assert_eq!(second, [0, 2]);
        // Point 3's neighbours: 3, then 2 and 4 (either order); never the duplicate 10.
        assert_eq!(nn[9], 3);
        assert!(!nn.contains(&10));
    }

    #[test]
    fn too_few_distinct_points_repeat_the_last_neighbour() {
        let pts = vec![[1.0, 2.0, 3.0]; 8];
        assert_eq!(nearest_neighbours(&pts, 2, 4), vec![0; 8]);
    }

    /// Dividing positions and offsets by one scale s is the same as running the raw LFA on
    /// the frustum shrunk by s (neighbours are the same; every input is linear in the
    /// coordinates); unequal scales change the features.
    #[test]
    fn input_scales_divide_positions_and_offsets() {
        let device = Device::flex();
        let n0 = 32;
        let points: Vec<f32> = (0..2 * n0 * 3)
            .map(|i| ((i * 53) % 97) as f32 * 0.25 - 6.0)
            .collect();
        let raw = LfaConfig {
            neighbours: 4,
            ..LfaConfig::default()
        };
        let model = ModelConfig {
            lfa: Some(raw.clone()),
            ..ModelConfig::default()
        };
        let lfa = Lfa::new(&model, &raw, &device);
        let features = |config: &LfaConfig, pts: &[f32]| {
            let inputs = LfaInputs::new(pts, 2, n0, config, &device).unwrap();
            lfa.forward(&inputs)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        let both = LfaConfig {
            position_scale_m: 4.0,
            offset_scale_m: 4.0,
            ..raw.clone()
        };
        let shrunk: Vec<f32> = points.iter().map(|p| p / 4.0).collect();
        let (a, b) = (features(&both, &points), features(&raw, &shrunk));
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() <= 1e-4 * (1.0 + y.abs()), "{x} vs {y}");
        }
        let offsets_only = LfaConfig {
            offset_scale_m: 0.25,
            ..raw.clone()
        };
        let c = features(&offsets_only, &points);
        let d = features(&raw, &points);
        assert!(c.iter().zip(&d).any(|(x, y)| (x - y).abs() > 1e-3));
    }

    /// LFA with the encoding built whole: `[a·p_k, b·(p_i − p_k), d_ik, a·p_i, g_k]`
    /// concatenated and run through the local MLP.
    fn forward_by_concatenation(lfa: &Lfa, inputs: &LfaInputs) -> Tensor<2> {
        let k = inputs.neighbours;
        let (a, b) = (inputs.position_gain, inputs.offset_gain);
        let mut coords = inputs.coords.clone();
        let mut feats: Option<Tensor<2>> = None;
        for (stage, index) in lfa.stages.iter().zip(&inputs.stages) {
            let q = coords.clone().select(0, index.keep.index().clone());
            let m = q.dims()[0];
            let nb = coords.clone().select(0, index.neighbours.index().clone());
            let qk = q
                .clone()
                .reshape([m, 1, 3])
                .expand([m, k, 3])
                .reshape([m * k, 3]);
            let rel = (qk.clone() - nb.clone()).mul_scalar(b);
            let dist = rel.clone().square().sum_dim(1).add_scalar(1e-12).sqrt();
            let mut local_in = vec![nb.mul_scalar(a), rel, dist, qk.mul_scalar(a)];
            let mut point_in = vec![q.clone().mul_scalar(a)];
            if let Some(g) = &feats {
                local_in.push(g.clone().select(0, index.neighbours.index().clone()));
                point_in.push(g.clone().select(0, index.keep.index().clone()));
            }
            let local = run(&stage.local, Tensor::cat(local_in, 1));
            let c = local.dims()[1];
            let local = local.reshape([m, k, c]).max_dim(1).reshape([m, c]);
            let point = run(&stage.point, Tensor::cat(point_in, 1));
            feats = Some(Tensor::cat(vec![local, point], 1));
            coords = q;
        }
        feats.unwrap()
    }

    /// The first local layer evaluated in parts (per point, per query, distance) computes
    /// what the layer does on the whole encoding: with unit and non-unit input scales,
    /// one- and two-layer local MLPs, batch statistics (training) and a folded norm.
    #[test]
    fn split_first_layer_matches_the_concatenated_encoding() {
        let n0 = 64;
        let points: Vec<f32> = (0..3 * n0 * 3)
            .map(|i| ((i * 53) % 97) as f32 * 0.21 - 9.0)
            .collect();
        for (scales, stages) in [
            ((1.0, 1.0), LfaConfig::default().stages),
            (
                (5.0, 0.5),
                vec![
                    LfaStageConfig {
                        local: vec![8],
                        point: vec![8],
                    },
                    LfaStageConfig {
                        local: vec![8, 16, 12],
                        point: vec![4],
                    },
                ],
            ),
        ] {
            let config = LfaConfig {
                neighbours: 4,
                stages,
                position_scale_m: scales.0,
                offset_scale_m: scales.1,
                ..LfaConfig::default()
            };
            let model = ModelConfig {
                lfa: Some(config.clone()),
                ..ModelConfig::default()
            };
            let compare = |lfa: &Lfa, device: &Device| {
                let inputs = LfaInputs::new(&points, 3, n0, &config, device).unwrap();
                let split = lfa.forward(&inputs).try_into_vec_as::<f32>().unwrap();
                let whole = forward_by_concatenation(lfa, &inputs)
                    .try_into_vec_as::<f32>()
                    .unwrap();
                assert_eq!(split.len(), whole.len());
                for (x, y) in split.iter().zip(&whole) {
                    assert!((x - y).abs() <= 1e-4 * (1.0 + y.abs()), "{x} vs {y}");
                }
            };
            let train = Device::flex().autodiff();
            compare(&Lfa::new(&model, &config, &train), &train);
            let device = Device::flex();
            let mut lfa = Lfa::new(&model, &config, &device);
            compare(&lfa, &device);
            for stage in &mut lfa.stages {
                stage.local.iter_mut().for_each(MlpLayer::fold_norm);
            }
            compare(&lfa, &device);
        }
    }

    /// The first layer's host sum and its custom operation give the tensor sum's bits, and
    /// the host max taken while summing the bits of the max over those sums, at unit and
    /// other offset gains, over a real stage index.
    #[test]
    fn host_first_layer_sum_gives_the_tensor_bits() {
        let device = Device::flex();
        let (n0, k, c1) = (64, 4, 5);
        let points: Vec<f32> = (0..2 * n0 * 3)
            .map(|i| ((i * 37) % 89) as f32 * 0.17 - 7.0)
            .collect();
        let config = LfaConfig {
            neighbours: k,
            ..LfaConfig::default()
        };
        let inputs = LfaInputs::new(&points, 2, n0, &config, &device).unwrap();
        let index = &inputs.stages[0];
        let q = inputs.coords.clone().select(0, index.keep.index().clone());
        let m = q.dims()[0];
        let values = |rows: usize, seed: usize| {
            let v: Vec<f32> = (0..rows * c1)
                .map(|i| (((i + seed) * 7919) % 1000) as f32 / 333.0 - 1.5)
                .collect();
            Tensor::<2>::from_data(TensorData::new(v, [rows, c1]), &device)
        };
        let terms = || FirstLayerTerms {
            per_point: values(2 * n0, 1),
            per_query: values(m, 2),
            w_d: values(1, 3),
        };
        let bits = |t: Tensor<2>| {
            t.try_into_vec_as::<f32>()
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        for offset_gain in [1.0, 0.37] {
            let at = Neighbourhood {
                coords: &inputs.coords,
                q: &q,
                index,
                offset_gain,
                k,
            };
            let by_tensors = bits(terms().combine_by_tensors(&at));
            let on_host = bits(terms().combine_on_host(&at));
            let custom = terms().combine_custom(&at);
            assert_eq!(custom.dims(), [m * k, c1]);
            assert_eq!(by_tensors, on_host, "offset gain {offset_gain}");
            assert_eq!(by_tensors, bits(custom), "offset gain {offset_gain}");
            // The max taken while summing: the bits of the max over the stored sums.
            let fused = terms().max_on_host(&at);
            assert_eq!(fused.dims(), [m, c1]);
            assert_eq!(
                bits(fused),
                bits(host_max::blocks_max(terms().combine_on_host(&at), k)),
                "offset gain {offset_gain}"
            );
        }
    }

    /// `feature_gate = "zero"` starts LFA's output at zero (the PointNets see only the
    /// coordinates, as in F-ConvNet); the gate gets a gradient from the first step, LFA's
    /// own weights once the gate has moved.
    #[test]
    fn a_zero_gate_starts_lfa_shut_and_learns_to_open() {
        let device = Device::flex().autodiff();
        let n0 = 32;
        let points: Vec<f32> = (0..2 * n0 * 3)
            .map(|i| ((i * 53) % 97) as f32 * 0.25 - 6.0)
            .collect();
        let config = LfaConfig {
            neighbours: 4,
            feature_gate: LfaFeatureGate::Zero,
            ..LfaConfig::default()
        };
        let model = ModelConfig {
            lfa: Some(config.clone()),
            ..ModelConfig::default()
        };
        let mut lfa = Lfa::new(&model, &config, &device);
        let inputs = LfaInputs::new(&points, 2, n0, &config, &device).unwrap();
        let out = lfa.forward(&inputs);
        assert_eq!(out.dims(), [2 * n0 / 4, config.out_channels()]);
        let largest: f32 = out.clone().abs().max().into_scalar();
        assert_eq!(largest, 0.0);
        let grads = out.sum().backward();
        let gate = lfa.gate.as_ref().unwrap();
        let gate_grad = gate.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap();
        assert!(gate_grad.iter().any(|&g| g != 0.0));
        let weight = |lfa: &Lfa| lfa.stages[0].point[0].linear.weight.clone();
        let shut: f32 = weight(&lfa)
            .grad(&grads)
            .map_or(0.0, |g| g.abs().max().into_scalar());
        assert_eq!(shut, 0.0);
        // Opened a little, the gate passes f scaled and LFA's weights learn.
        let c = config.out_channels();
        lfa.gate = Some(Param::from_tensor(
            Tensor::ones([c], &device).mul_scalar(0.5),
        ));
        let out = lfa.forward(&inputs);
        let largest: f32 = out.clone().abs().max().into_scalar();
        assert!(largest > 0.0);
        let grads = out.sum().backward();
        let open: f32 = weight(&lfa).grad(&grads).unwrap().abs().max().into_scalar();
        assert!(open > 0.0);
        // The paper's form has no gate.
        let paper = Lfa::new(&model, &LfaConfig::default(), &device);
        assert!(paper.gate.is_none());
    }

    #[test]
    fn input_scales_must_be_positive() {
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let model = ModelConfig {
                lfa: Some(LfaConfig {
                    offset_scale_m: v,
                    ..LfaConfig::default()
                }),
                ..ModelConfig::default()
            };
            let e = model.validate().unwrap_err().to_string();
            assert!(
                e.contains("lfa.offset_scale_m") && e.contains("positive"),
                "{e}"
            );
        }
    }

    #[test]
    fn survivors_and_neighbours_stay_in_their_frustum() {
        let device = Device::flex();
        let n0 = 64;
        let points: Vec<f32> = (0..2 * n0 * 3)
            .map(|i| ((i * 37) % 101) as f32 * 0.1)
            .collect();
        let config = LfaConfig {
            neighbours: 4,
            ..LfaConfig::default()
        };
        let inputs = LfaInputs::new(&points, 2, n0, &config, &device).unwrap();
        let mut n = n0;
        for stage in &inputs.stages {
            let keep = stage.keep.index().clone().try_into_vec_as::<i64>().unwrap();
            let nb = stage
                .neighbours
                .index()
                .clone()
                .try_into_vec_as::<i64>()
                .unwrap();
            assert_eq!(keep.len(), n);
            assert_eq!(nb.len(), n * 4);
            for (row, &r) in keep.iter().enumerate() {
                let f = row / (n / 2);
                assert_eq!(r as usize, f * n + row % (n / 2));
                for &j in &nb[row * 4..row * 4 + 4] {
                    assert_eq!(j as usize / n, f, "neighbour in another frustum");
                }
            }
            n /= 2;
        }
        // The frustums are searched in parallel: one thread gives the same indices.
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| LfaInputs::new(&points, 2, n0, &config, &device).unwrap());
        for (a, b) in inputs.stages.iter().zip(&one_thread.stages) {
            let ints = |t: &Tensor<1, Int>| t.clone().try_into_vec_as::<i64>().unwrap();
            assert_eq!(ints(a.neighbours.index()), ints(b.neighbours.index()));
            assert_eq!(ints(a.keep.index()), ints(b.keep.index()));
        }
        let bad = LfaInputs::new(&points[..2 * 6 * 3], 2, 6, &config, &device);
        assert!(bad.unwrap_err().to_string().contains("halved"));
    }
    /// In training on a GPU the features' gathers differentiate by their readers
    /// (`RowGather`): the output and every stage's first-layer weight gradient on wgpu are
    /// the CPU's (its custom operations) within rounding.
    #[cfg(feature = "wgpu")]
    #[test]
    fn training_gradients_on_wgpu_match_the_cpu() {
        use crate::device_test_support::{assert_close, upstream};
        let Some(gpu) = fusiondet_nn::cube::working_wgpu_device("LFA's gathers on a GPU") else {
            return;
        };
        let n0 = 64;
        let points: Vec<f32> = (0..3 * n0 * 3)
            .map(|i| ((i * 53) % 97) as f32 * 0.21 - 9.0)
            .collect();
        let config = LfaConfig {
            neighbours: 4,
            ..LfaConfig::default()
        };
        let model = ModelConfig {
            lfa: Some(config.clone()),
            ..ModelConfig::default()
        };
        let cpu = Device::flex().autodiff();
        let lfa = Lfa::new(&model, &config, &cpu);
        let run = |device: &Device| {
            let lfa = lfa.clone().fork(device);
            let inputs = LfaInputs::new(&points, 3, n0, &config, device).unwrap();
            let y = lfa.forward(&inputs);
            let grads = (y.clone() * upstream(y.dims(), device)).sum().backward();
            let mut out = vec![y.try_into_vec_as::<f32>().unwrap()];
            for stage in &lfa.stages {
                let weight = &stage.local[0].linear.weight;
                out.push(
                    weight
                        .grad(&grads)
                        .unwrap()
                        .try_into_vec_as::<f32>()
                        .unwrap(),
                );
            }
            out
        };
        let want = run(&cpu);
        assert!(
            want[1..].iter().all(|g| g.iter().any(|&v| v != 0.0)),
            "gradients reach LFA"
        );
        let got = run(&gpu.autodiff());
        for (i, (got, want)) in got.iter().zip(&want).enumerate() {
            assert_close(got, want, 1e-3, &format!("quantity {i}"));
        }
    }

    /// In inference on a GPU a stage whose [M·K, C] sums would pass half of what one buffer
    /// binds takes its queries in chunks (lavapipe binds 128 MiB, and a larger tensor comes
    /// out wrong there without an error): 13 frustums of 4,096 points at the paper's widths
    /// (218 MB of sums a stage) give the CPU's features.
    #[cfg(feature = "wgpu")]
    #[test]
    fn inference_past_the_binding_limit_matches_the_cpu_on_wgpu() {
        use crate::device_test_support::assert_close;
        let Some(gpu) = fusiondet_nn::cube::working_wgpu_device("LFA's chunked inference") else {
            return;
        };
        let (frustums, n0) = (13, 4096);
        let points: Vec<f32> = (0..frustums * n0 * 3)
            .map(|i| ((i * 7919) % 1000) as f32 / 100.0 - 5.0)
            .collect();
        let config = LfaConfig::paper();
        let model = ModelConfig {
            lfa: Some(config.clone()),
            ..ModelConfig::default()
        };
        let cpu = Device::flex();
        let lfa = Lfa::new(&model, &config, &cpu);
        let run = |device: &Device| {
            let lfa = lfa.clone().fork(device);
            let inputs = LfaInputs::new(&points, frustums, n0, &config, device).unwrap();
            lfa.forward(&inputs).try_into_vec_as::<f32>().unwrap()
        };
        let queries = Tensor::<2>::zeros([frustums * n0 / 2, 3], &gpu);
        let sums = (frustums * n0 / 2 * config.neighbours * 128 * 4) as u64;
        let limit = fusiondet_nn::cube::binding_limit(&gpu).unwrap();
        assert_eq!(
            inference_chunk(&queries, config.neighbours, 128).is_some(),
            sums > limit / 2,
            "chunks exactly where the sums pass half the limit ({limit} bytes)"
        );
        assert_close(&run(&gpu), &run(&cpu), 1e-5, "LFA's features");
    }
}
