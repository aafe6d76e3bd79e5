//! Training's ragged operations as custom backend operations on the flex CPU device, each
//! with its own backward pass: the max over runs of rows that keeps its winning row
//! (backward scatters the gradient to it), LFA's neighbour sum (gather + add, backward
//! the transposed gather), and the gather + add of Voxel R-CNN's RoI grid pooling.
//!
//! Why: burn's generic form of these costs several passes over memory each way. The ragged
//! max-pool gathered every segment into a power-of-two window ([segments · width, C], up to
//! twice the rows), reshaped and reduced the middle axis with flex's element-by-element
//! scan, and its backward zeroed and scattered the window before scattering the window back
//! to the rows; the neighbour sum gathered, broadcast and added [M·K, C] matrices in about
//! ten passes and differentiated each. Here each is one pass forward and one backward.
//!
//! burn 0.22 routes a custom operation through `#[backend_extension]`: the trait below is
//! implemented for `Flex` (no graph: inference, or training's untracked parts) and for
//! `Autodiff<Flex, C>` (a node with a hand-written [`Backward`]); `Tensor::into_dispatch`
//! and `Tensor::from_dispatch` carry the workspace's `Tensor<D>` across. Any other device
//! (wgpu, CUDA) keeps burn's generic operations: [`custom_path`] says which applies.
//!
//! Ties and NaN follow flex's `max_dim_with_indices`, which training differentiated
//! before: a row replaces the running maximum only when it is larger, or NaN while the
//! maximum is not NaN, so among equal values the first row of the run wins (the gradient
//! goes to it) and the first NaN wins over everything after it.

use crate::buffers::par_chunks_filled;
use crate::row_pairs::{ROWS_PER_TASK, RowPairs};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use multiversion::multiversion;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

/// Whether the custom operations are used where they apply (the default).
static ENABLED: AtomicBool = AtomicBool::new(true);

/// `FUSIONDET_CUSTOM_OPS=off` in the environment turns the custom operations (these,
/// [`crate::conv2d`] and the others on the flex device, and training's batch norm on a GPU,
/// [`custom_device_path`]) off for the whole process, so that a training or detection through
/// the binary can be timed, or its results compared, against burn's generic operations;
/// `on` (or no variable) keeps them.
fn enabled_by_environment() -> bool {
    static FROM_ENV: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    crate::place::switch_on_unless_off(
        "FUSIONDET_CUSTOM_OPS",
        &FROM_ENV,
        "the custom operations stay on",
    )
}

/// Turns the custom operations off (or back on) for the whole process, so that burn's
/// generic operations run everywhere: for side-by-side benchmarks and for comparing
/// trainings of both paths. Set it before a computation starts, not during one.
pub fn set_custom_ops(enabled: bool) {
    ENABLED.store(enabled, Ordering::SeqCst);
}

/// Whether `x` takes the custom operations: on the flex CPU device, with or without
/// autodiff, unless [`set_custom_ops`] or the environment ([`enabled_by_environment`])
/// turned them off. Elsewhere callers use burn's generic operations.
pub fn custom_path<const D: usize>(x: &Tensor<D>) -> bool {
    ENABLED.load(Ordering::Relaxed)
        && enabled_by_environment()
        && x.device().without_autodiff() == Device::flex()
}

/// Whether `x` takes the custom operations written for GPUs that replace burn's generic ones
/// outright (training's batch norm, `batch_norm_device`): on a CubeCL device, unless
/// [`set_custom_ops`] or the environment turned the custom operations off.
pub fn custom_device_path<const D: usize>(x: &Tensor<D>) -> bool {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    let on_cube = crate::cube::cube_runtime(&x.device()).is_some();
    #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
    let on_cube = {
        let _ = x;
        false
    };
    on_cube && ENABLED.load(Ordering::Relaxed) && enabled_by_environment()
}

/// Runs of rows: run s covers rows `starts[s]..starts[s] + counts[s]` of a [rows, C]
/// tensor. Runs may be empty; they need not be disjoint or in order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Runs {
    pub starts: Vec<u32>,
    pub counts: Vec<u32>,
}

impl Runs {
    pub fn new(starts: &[usize], counts: &[usize]) -> Self {
        assert_eq!(starts.len(), counts.len(), "one start per run");
        let small = |v: &[usize]| -> Vec<u32> {
            v.iter()
                .map(|&x| u32::try_from(x).expect("row indices fit in 32 bits"))
                .collect()
        };
        Self {
            starts: small(starts),
            counts: small(counts),
        }
    }

    /// `blocks` runs of `width` consecutive rows each.
    pub fn blocks(blocks: usize, width: usize) -> Self {
        let starts: Vec<usize> = (0..blocks).map(|b| b * width).collect();
        Self::new(&starts, &vec![width; blocks])
    }

    pub fn len(&self) -> usize {
        self.counts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.counts.is_empty()
    }
}

/// LFA's neighbourhoods: query i's K neighbour rows `neighbours[i·K..(i+1)·K]` among the
/// stage's points, and that transposed (for each point, the (query, slot) rows that read
/// it, in row order) for the backward pass, built on the first backward step that needs it
/// (detection never does).
#[derive(Debug, Clone)]
pub struct Neighbours {
    pub k: usize,
    pub points: usize,
    pub neighbours: Vec<u32>,
    /// Per point, the rows that read it as (0, row) entries, in row order.
    readers: OnceLock<RowPairs>,
}

/// Equal neighbourhoods are equal lists; the reader lists follow from them.
impl PartialEq for Neighbours {
    fn eq(&self, other: &Self) -> bool {
        (self.k, self.points, &self.neighbours) == (other.k, other.points, &other.neighbours)
    }
}

impl Eq for Neighbours {}

impl Neighbours {
    /// `neighbours`: [M · K] rows into `points` points.
    pub fn new(neighbours: Vec<u32>, k: usize, points: usize) -> Self {
        assert!(
            k > 0 && neighbours.len().is_multiple_of(k),
            "K rows per query"
        );
        for &p in &neighbours {
            assert!((p as usize) < points, "neighbour {p} past {points} points");
        }
        Self {
            k,
            points,
            neighbours,
            readers: OnceLock::new(),
        }
    }

    /// Per point, the rows that read it (see the field), built on first use.
    fn readers(&self) -> &RowPairs {
        self.readers
            .get_or_init(|| RowPairs::new(self.points, std::iter::once(self.neighbours.as_slice())))
    }

    pub fn queries(&self) -> usize {
        self.neighbours.len() / self.k
    }
}

/// The custom operations (see the module's documentation).
#[backend_extension(Flex, Autodiff)]
pub trait RaggedOps: Backend {
    /// Per-run max of `x` ([rows, C]) → [runs, C]; an empty run gives zeros.
    fn runs_max(x: FloatTensor<Self>, runs: Arc<Runs>) -> FloatTensor<Self>;

    /// `y[i·K + j] = (per_point[nb(i, j)] + per_query[i]) + distance[i·K + j] · w_d`,
    /// [M·K, C], from per_point [N, C], per_query [M, C], distance [M·K, 1] (a constant:
    /// it gets no gradient) and w_d [1, C].
    fn neighbour_sum(
        per_point: FloatTensor<Self>,
        per_query: FloatTensor<Self>,
        distance: FloatTensor<Self>,
        w_d: FloatTensor<Self>,
        neighbours: Arc<Neighbours>,
    ) -> FloatTensor<Self>;

    /// `y[r] = table[nb(r)] + per_row[r]`, [M·K, C], from table [N, C] and per_row
    /// [M·K, C]: the gather and addition of Voxel R-CNN's RoI grid pooling.
    fn gather_add(
        table: FloatTensor<Self>,
        per_row: FloatTensor<Self>,
        neighbours: Arc<Neighbours>,
    ) -> FloatTensor<Self>;
}

/// [`RaggedOps::runs_max`] on a `Tensor<2>` on the flex device (see [`custom_path`]).
pub fn runs_max(x: Tensor<2>, runs: &Arc<Runs>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as RaggedOps>::runs_max(
        x.into_dispatch(),
        Arc::clone(runs),
    ))
}

/// [`RaggedOps::neighbour_sum`] on tensors on the flex device (see [`custom_path`]).
pub fn neighbour_sum(
    per_point: Tensor<2>,
    per_query: Tensor<2>,
    distance: Tensor<2>,
    w_d: Tensor<2>,
    neighbours: &Arc<Neighbours>,
) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as RaggedOps>::neighbour_sum(
        per_point.into_dispatch(),
        per_query.into_dispatch(),
        distance.into_dispatch(),
        w_d.into_dispatch(),
        Arc::clone(neighbours),
    ))
}

/// [`RaggedOps::gather_add`] on tensors on the flex device (see [`custom_path`]).
pub fn gather_add(table: Tensor<2>, per_row: Tensor<2>, neighbours: &Arc<Neighbours>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as RaggedOps>::gather_add(
        table.into_dispatch(),
        per_row.into_dispatch(),
        Arc::clone(neighbours),
    ))
}

/// The f32 values of a flex tensor in row-major order, borrowed when it is contiguous.
pub(crate) fn values(x: &FlexTensor) -> std::borrow::Cow<'_, [f32]> {
    assert_eq!(x.dtype(), DType::F32, "the custom operations take f32");
    match x.as_slice::<f32>() {
        Some(s) => std::borrow::Cow::Borrowed(s),
        None => std::borrow::Cow::Owned(x.to_contiguous().as_slice::<f32>().unwrap().to_vec()),
    }
}

pub(crate) fn dims2(x: &FlexTensor) -> [usize; 2] {
    let shape = x.layout().shape();
    assert_eq!(shape.num_dims(), 2, "a [rows, C] tensor");
    [shape[0], shape[1]]
}

pub(crate) fn flex_tensor(values: Vec<f32>, shape: [usize; 2]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

/// One step of flex's `max_dim_with_indices` scan: `v` replaces `best` when `best` is not
/// NaN and `v` is larger or NaN.
#[inline(always)]
fn replaces(best: f32, v: f32) -> bool {
    !best.is_nan() && (v.is_nan() || v > best)
}

/// One run's per-channel max into `dst` ([C]) over its rows `rows` ([count ≥ 1, C], the
/// first being row `first` of the input) and, with `arg`, each channel's winning row.
/// Compiled per instruction set and chosen at run time (`multiversion`, as batch norm's
/// kernels): the channels are independent, so the values are the baseline build's.
#[multiversion(targets = "simd")]
fn run_max(dst: &mut [f32], arg: Option<&mut [u32]>, rows: &[f32], first: u32) {
    let c = dst.len();
    dst.copy_from_slice(&rows[..c]);
    match arg {
        None => {
            for row in rows[c..].chunks_exact(c) {
                for (best, &v) in dst.iter_mut().zip(row) {
                    if replaces(*best, v) {
                        *best = v;
                    }
                }
            }
        }
        Some(arg) => {
            arg.fill(first);
            for (r, row) in rows[c..].chunks_exact(c).enumerate() {
                let r = first + 1 + r as u32;
                for ((best, at), &v) in dst.iter_mut().zip(arg.iter_mut()).zip(row) {
                    if replaces(*best, v) {
                        *best = v;
                        *at = r;
                    }
                }
            }
        }
    }
}

/// The per-run max of `x` and, when `with_argmax`, each (run, channel)'s winning row.
fn runs_max_forward(x: &FlexTensor, runs: &Runs, with_argmax: bool) -> (FlexTensor, Vec<u32>) {
    let [rows, c] = dims2(x);
    let data = values(x);
    let n = runs.len();
    let mut out = vec![0f32; n * c];
    let mut arg = if with_argmax {
        vec![u32::MAX; n * c]
    } else {
        Vec::new()
    };
    if c > 0 {
        let kernel = |dst: &mut [f32], arg: Option<&mut [u32]>, s: usize| {
            let (start, count) = (runs.starts[s] as usize, runs.counts[s] as usize);
            assert!(
                start + count <= rows,
                "run {start}+{count} past {rows} rows"
            );
            if count == 0 {
                return;
            }
            run_max(
                dst,
                arg,
                &data[start * c..(start + count) * c],
                start as u32,
            );
        };
        if with_argmax {
            out.par_chunks_mut(c)
                .zip(arg.par_chunks_mut(c))
                .enumerate()
                .for_each(|(s, (dst, arg))| kernel(dst, Some(arg), s));
        } else {
            out.par_chunks_mut(c)
                .enumerate()
                .for_each(|(s, dst)| kernel(dst, None, s));
        }
    }
    (flex_tensor(out, [n, c]), arg)
}

/// The gradient of the per-run max: each (run, channel)'s gradient added to its winning
/// row's, in run order (runs that share rows add up deterministically); rows that won
/// nothing get zero. Runs in order and disjoint (RoI grid pooling's, LFA's) own their rows,
/// so they are written in parallel; others in one pass in run order.
fn runs_max_backward(grad: &FlexTensor, argmax: &[u32], runs: &Runs, rows: usize) -> FlexTensor {
    let [n, c] = dims2(grad);
    assert_eq!(n, runs.len(), "a gradient row per run");
    let g = values(grad);
    let mut out = par_chunks_filled(rows * c, ROWS_PER_TASK * c, |_, _| {});
    // Run s's gradient into `dst`, the rows from `first` on.
    let add = |s: usize, dst: &mut [f32], first: usize| {
        for ch in 0..c {
            let at = argmax[s * c + ch];
            if at != u32::MAX {
                dst[(at as usize - first) * c + ch] += g[s * c + ch];
            }
        }
    };
    match rows_of_disjoint_runs(&mut out, runs, c) {
        Some(parts) => parts
            .into_par_iter()
            .with_min_len(64)
            .for_each(|(s, dst, first)| add(s, dst, first)),
        None => (0..n).for_each(|s| add(s, &mut out, 0)),
    }
    flex_tensor(out, [rows, c])
}

/// Each run's rows of `out` ([rows, c]) as (run, rows, first row), when the runs are in
/// order and disjoint; `None` otherwise.
fn rows_of_disjoint_runs<'a>(
    out: &'a mut [f32],
    runs: &Runs,
    c: usize,
) -> Option<Vec<(usize, &'a mut [f32], usize)>> {
    let ordered = (1..runs.len())
        .all(|s| runs.starts[s - 1] as u64 + runs.counts[s - 1] as u64 <= runs.starts[s] as u64);
    if !ordered || c == 0 {
        return None;
    }
    let mut parts = Vec::with_capacity(runs.len());
    let (mut rest, mut at) = (out, 0usize);
    for (s, (&start, &count)) in runs.starts.iter().zip(&runs.counts).enumerate() {
        let (start, count) = (start as usize, count as usize);
        let tail = std::mem::take(&mut rest);
        let (_, tail) = tail.split_at_mut((start - at) * c);
        let (mine, tail) = tail.split_at_mut(count * c);
        parts.push((s, mine, start));
        (rest, at) = (tail, start + count);
    }
    Some(parts)
}

/// The neighbour sum's forward (see [`RaggedOps::neighbour_sum`]); the same operations in
/// the same order as burn's tensor form, so the same bits.
fn neighbour_sum_forward(
    per_point: &FlexTensor,
    per_query: &FlexTensor,
    distance: &FlexTensor,
    w_d: &FlexTensor,
    nb: &Neighbours,
) -> FlexTensor {
    let [n, c] = dims2(per_point);
    let [m, cq] = dims2(per_query);
    assert_eq!(n, nb.points, "per-point rows");
    assert_eq!(m, nb.queries(), "per-query rows");
    assert_eq!(c, cq, "channels");
    assert_eq!(dims2(distance), [m * nb.k, 1], "a distance per neighbour");
    assert_eq!(dims2(w_d), [1, c], "a distance weight per channel");
    let (pp, pq, dist, wd) = (
        values(per_point),
        values(per_query),
        values(distance),
        values(w_d),
    );
    let k = nb.k;
    let y = par_chunks_filled(m * k * c, k * c, |i, rows| {
        let neighbours = &nb.neighbours[i * k..(i + 1) * k];
        let query = &pq[i * c..(i + 1) * c];
        for (j, (row, &p)) in rows.chunks_exact_mut(c).zip(neighbours).enumerate() {
            let d = dist[i * k + j];
            let point = &pp[p as usize * c..(p as usize + 1) * c];
            for (((out, &pk), &pi), &w) in row.iter_mut().zip(point).zip(query).zip(&*wd) {
                *out = (pk + pi) + d * w;
            }
        }
    });
    flex_tensor(y, [m * k, c])
}

/// Per point, the sum of the [·, c] rows of `g` that read it (in row order, from zero):
/// the gradient of a gather, [points, c].
fn reader_sums(g: &[f32], c: usize, nb: &Neighbours) -> FlexTensor {
    flex_tensor(nb.readers().sums(c, None, &[g]), [nb.points, c])
}

fn gather_add_forward(table: &FlexTensor, per_row: &FlexTensor, nb: &Neighbours) -> FlexTensor {
    let [n, c] = dims2(table);
    let [rows, c_rows] = dims2(per_row);
    assert_eq!(n, nb.points, "table rows");
    assert_eq!(rows, nb.neighbours.len(), "a per-row term per gathered row");
    assert_eq!(c, c_rows, "channels");
    let (t, pr) = (values(table), values(per_row));
    let y = par_chunks_filled(rows * c, c * ROWS_PER_TASK, |task, chunk| {
        for (i, dst) in chunk.chunks_exact_mut(c).enumerate() {
            let r = task * ROWS_PER_TASK + i;
            let src = &t[nb.neighbours[r] as usize * c..][..c];
            for ((o, &a), &b) in dst.iter_mut().zip(src).zip(&pr[r * c..][..c]) {
                *o = a + b;
            }
        }
    });
    flex_tensor(y, [rows, c])
}

/// The neighbour sum's input gradients from `grad` ([M·K, C]): per point the sum of its
/// readers' rows (in row order), per query the sum over its K rows, and w_d's the
/// distance-weighted sum over all rows.
fn neighbour_sum_backward(
    grad: &FlexTensor,
    distance: &[f32],
    nb: &Neighbours,
    need: [bool; 3],
) -> [Option<FlexTensor>; 3] {
    let [rows, c] = dims2(grad);
    let (m, k) = (nb.queries(), nb.k);
    assert_eq!(rows, m * k, "a gradient row per neighbour");
    let g = values(grad);
    let per_point = need[0].then(|| reader_sums(&g, c, nb));
    let per_query = need[1].then(|| {
        let out = par_chunks_filled(m * c, c, |i, dst| {
            for row in g[i * k * c..(i + 1) * k * c].chunks_exact(c) {
                for (o, &v) in dst.iter_mut().zip(row) {
                    *o += v;
                }
            }
        });
        flex_tensor(out, [m, c])
    });
    let w_d = need[2].then(|| {
        // Per query first (in parallel), then the queries in order: deterministic.
        let partial = par_chunks_filled(m * c, c, |i, dst| {
            for (j, row) in g[i * k * c..(i + 1) * k * c].chunks_exact(c).enumerate() {
                let d = distance[i * k + j];
                for (o, &v) in dst.iter_mut().zip(row) {
                    *o += d * v;
                }
            }
        });
        let mut out = vec![0f32; c];
        for row in partial.chunks_exact(c.max(1)).take(m) {
            for (o, &v) in out.iter_mut().zip(row) {
                *o += v;
            }
        }
        flex_tensor(out, [1, c])
    });
    [per_point, per_query, w_d]
}

impl RaggedOps for Flex {
    fn runs_max(x: FlexTensor, runs: Arc<Runs>) -> FlexTensor {
        runs_max_forward(&x, &runs, false).0
    }

    fn neighbour_sum(
        per_point: FlexTensor,
        per_query: FlexTensor,
        distance: FlexTensor,
        w_d: FlexTensor,
        neighbours: Arc<Neighbours>,
    ) -> FlexTensor {
        neighbour_sum_forward(&per_point, &per_query, &distance, &w_d, &neighbours)
    }

    fn gather_add(
        table: FlexTensor,
        per_row: FlexTensor,
        neighbours: Arc<Neighbours>,
    ) -> FlexTensor {
        gather_add_forward(&table, &per_row, &neighbours)
    }
}

/// The backward step of [`RaggedOps::gather_add`]: the table's gradient sums each row's
/// readers; the per-row term's is the output gradient.
#[derive(Debug)]
struct GatherAddBackward;

impl Backward<Flex, 2> for GatherAddBackward {
    type State = Arc<Neighbours>;

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let neighbours = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let [table, per_row] = ops.parents;
        if let Some(table) = table {
            let [_, c] = dims2(&grad);
            grads.register::<Flex>(table.id, reader_sums(&values(&grad), c, &neighbours));
        }
        if let Some(per_row) = per_row {
            grads.register::<Flex>(per_row.id, grad);
        }
    }
}

/// The backward step of [`RaggedOps::runs_max`].
#[derive(Debug)]
struct RunsMaxBackward;

impl Backward<Flex, 1> for RunsMaxBackward {
    /// Each (run, channel)'s winning row (`u32::MAX` for an empty run), the runs and the
    /// input rows.
    type State = (Arc<Vec<u32>>, Arc<Runs>, usize);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (argmax, runs, rows) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        if let [Some(parent)] = ops.parents {
            let dx = runs_max_backward(&grad, &argmax, &runs, rows);
            grads.register::<Flex>(parent.id, dx);
        }
    }
}

/// The backward step of [`RaggedOps::neighbour_sum`].
#[derive(Debug)]
struct NeighbourSumBackward;

impl Backward<Flex, 3> for NeighbourSumBackward {
    /// The distances (constants) and the neighbourhoods.
    type State = (Arc<Vec<f32>>, Arc<Neighbours>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (distance, neighbours) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let need = ops.parents.each_ref().map(Option::is_some);
        let out = neighbour_sum_backward(&grad, &distance, &neighbours, need);
        for (parent, g) in ops.parents.into_iter().zip(out) {
            if let (Some(parent), Some(g)) = (parent, g) {
                grads.register::<Flex>(parent.id, g);
            }
        }
    }
}

impl<C: CheckpointStrategy> RaggedOps for Autodiff<Flex, C> {
    fn runs_max(x: FloatTensor<Self>, runs: Arc<Runs>) -> FloatTensor<Self> {
        let (x, node) = x.into_parts();
        match RunsMaxBackward
            .prepare::<C>([node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let rows = dims2(&x)[0];
                let (out, argmax) = runs_max_forward(&x, &runs, true);
                prep.finish((Arc::new(argmax), runs, rows), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(runs_max_forward(&x, &runs, false).0),
        }
    }

    fn neighbour_sum(
        per_point: FloatTensor<Self>,
        per_query: FloatTensor<Self>,
        distance: FloatTensor<Self>,
        w_d: FloatTensor<Self>,
        neighbours: Arc<Neighbours>,
    ) -> FloatTensor<Self> {
        assert!(
            !distance.is_tracked(),
            "the neighbour distances are constants (they get no gradient)"
        );
        let distance = distance.into_primitive();
        let (per_point, a) = per_point.into_parts();
        let (per_query, b) = per_query.into_parts();
        let (w_d, c) = w_d.into_parts();
        let out = neighbour_sum_forward(&per_point, &per_query, &distance, &w_d, &neighbours);
        match NeighbourSumBackward
            .prepare::<C>([a, b, c])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let distance = Arc::new(values(&distance).into_owned());
                prep.finish((distance, neighbours), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }

    fn gather_add(
        table: FloatTensor<Self>,
        per_row: FloatTensor<Self>,
        neighbours: Arc<Neighbours>,
    ) -> FloatTensor<Self> {
        let (table, a) = table.into_parts();
        let (per_row, b) = per_row.into_parts();
        let out = gather_add_forward(&table, &per_row, &neighbours);
        match GatherAddBackward
            .prepare::<C>([a, b])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(neighbours, out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SegmentPool;

    fn tensor(values: &[f32], shape: [usize; 2], device: &Device) -> Tensor<2> {
        Tensor::from_data(TensorData::new(values.to_vec(), shape), device)
    }

    fn bits(t: Tensor<2>) -> Vec<u32> {
        t.try_into_vec_as::<f32>()
            .unwrap()
            .iter()
            .map(|v| v.to_bits())
            .collect()
    }

    /// Values with many ties (zeros of both signs, repeated halves) and negatives.
    fn tied(n: usize, seed: usize) -> Vec<f32> {
        (0..n)
            .map(|i| match ((i + seed) * 7919) % 11 {
                0 => 0.0,
                1 => -0.0,
                r => (r as f32 - 6.0) * 0.5,
            })
            .collect()
    }

    /// Weights of a loss Σ w · out, so that every output element has its own gradient.
    fn weights(n: usize, c: usize, device: &Device) -> Tensor<2> {
        let w: Vec<f32> = (0..n * c).map(|i| 0.25 + (i % 13) as f32 * 0.5).collect();
        tensor(&w, [n, c], device)
    }

    /// The pooled values and the input gradient of Σ w · pool(x), by a pooling function.
    fn pooled_and_grad(
        values: &[f32],
        shape: [usize; 2],
        pool: impl Fn(Tensor<2>) -> Tensor<2>,
    ) -> (Vec<u32>, Vec<u32>) {
        let device = Device::flex().autodiff();
        let x = tensor(values, shape, &device).require_grad();
        let out = pool(x.clone());
        let [n, c] = out.dims();
        let grads = (out.clone() * weights(n, c, &device)).sum().backward();
        (bits(out), bits(x.grad(&grads).unwrap()))
    }

    /// The custom max-pool gives burn's generic bucket path's values and gradients bit for
    /// bit: ragged and uneven segments, empty ones, runs longer than a power of two, ties.
    #[test]
    fn runs_max_matches_the_generic_pool_in_values_and_gradients() {
        let c = 5;
        for counts in [
            vec![2usize, 0, 3, 1, 7, 0, 16, 5],
            vec![1; 9],
            vec![0, 0, 4],
            vec![33, 2, 17],
        ] {
            let mut starts = vec![0usize];
            for &n in &counts {
                starts.push(starts.last().unwrap() + n);
            }
            let rows = *starts.last().unwrap();
            let x = tied(rows * c, counts.len());
            let device = Device::flex().autodiff();
            let pool = SegmentPool::new(&counts, &starts, &device);
            let generic = pooled_and_grad(&x, [rows, c], |t| pool.max_pool_generic(t));
            let runs = Arc::new(Runs::new(&starts[..counts.len()], &counts));
            let custom = pooled_and_grad(&x, [rows, c], |t| {
                assert!(custom_path(&t));
                runs_max(t, &runs)
            });
            assert_eq!(custom.0, generic.0, "values, counts {counts:?}");
            assert_eq!(custom.1, generic.1, "gradients, counts {counts:?}");
            // The pool takes the custom path itself on the flex device.
            let through_pool = pooled_and_grad(&x, [rows, c], |t| pool.max_pool(t));
            assert_eq!(through_pool, custom);
        }
    }

    /// Many disjoint runs in order, with unread rows between them (the parallel backward):
    /// the same gradient as the one-pass definition, and unread rows zero.
    #[test]
    fn disjoint_runs_backward_as_the_one_pass_definition() {
        let c = 3;
        let (mut starts, mut counts, mut at) = (Vec::new(), Vec::new(), 0usize);
        for s in 0..400usize {
            at += s % 3; // a gap of 0–2 unread rows
            starts.push(at);
            counts.push(s % 4);
            at += s % 4;
        }
        let rows = at + 2;
        let runs = Runs::new(&starts, &counts);
        let x = FlexTensor::from_data(TensorData::new(tied(rows * c, 3), [rows, c]));
        let (_, argmax) = runs_max_forward(&x, &runs, true);
        let g: Vec<f32> = (0..400 * c).map(|i| 0.5 + (i % 7) as f32).collect();
        let grad = FlexTensor::from_data(TensorData::new(g.clone(), [400, c]));
        assert!(rows_of_disjoint_runs(&mut vec![0.0; rows * c], &runs, c).is_some());
        let parallel = runs_max_backward(&grad, &argmax, &runs, rows);
        let mut expected = vec![0f32; rows * c];
        for (i, &at) in argmax.iter().enumerate() {
            if at != u32::MAX {
                expected[at as usize * c + i % c] += g[i];
            }
        }
        assert_eq!(values(&parallel).into_owned(), expected);
        assert!(expected.iter().filter(|&&v| v == 0.0).count() > rows); // unread rows stay zero
        // Out of order: the one-pass path.
        let shuffled = Runs::new(&[4, 0], &[2, 3]);
        assert!(rows_of_disjoint_runs(&mut vec![0.0; rows * c], &shuffled, c).is_none());
    }

    /// Among equal values the first row of the run gets the gradient; the first NaN wins
    /// over everything after it (its value and its gradient), as in flex's indexed max.
    #[test]
    fn ties_go_to_the_first_row_and_nan_to_the_first_nan() {
        let nan = f32::NAN;
        // One run of 4 rows, 3 channels: channel 0 ties at 2.0 (rows 1, 3); channel 1
        // has NaN at rows 2 and 3 after a larger value; channel 2 is all equal.
        let x = [
            1.0, 5.0, 7.0, //
            2.0, 6.0, 7.0, //
            0.0, nan, 7.0, //
            2.0, nan, 7.0,
        ];
        let (values, grad) = pooled_and_grad(&x, [4, 3], |t| {
            runs_max(t, &Arc::new(Runs::new(&[0], &[4])))
        });
        let values: Vec<f32> = values.into_iter().map(f32::from_bits).collect();
        assert_eq!(values[0], 2.0);
        assert!(values[1].is_nan());
        assert_eq!(values[2], 7.0);
        let grad: Vec<f32> = grad.into_iter().map(f32::from_bits).collect();
        // Loss weights of the three outputs: 0.25, 0.75, 1.25.
        let mut expected = vec![0.0; 12];
        expected[3] = 0.25; // row 1, channel 0
        expected[7] = 0.75; // row 2, channel 1 (the first NaN)
        expected[2] = 1.25; // row 0, channel 2
        assert_eq!(grad, expected);
        // The generic pool agrees.
        let device = Device::flex().autodiff();
        let pool = SegmentPool::new(&[4], &[0, 4], &device);
        let generic = pooled_and_grad(&x, [4, 3], |t| pool.max_pool_generic(t));
        assert_eq!(
            generic
                .1
                .into_iter()
                .map(f32::from_bits)
                .collect::<Vec<_>>(),
            expected
        );
    }

    /// Without autodiff (the flex device itself) the same values; empty runs give zeros
    /// and runs may overlap (their gradients add).
    #[test]
    fn plain_flex_values_and_overlapping_runs() {
        let x: Vec<f32> = (0..12).map(|i| (i % 5) as f32).collect();
        let runs = Arc::new(Runs::new(&[0, 2, 3, 0], &[3, 0, 3, 2]));
        let plain = runs_max(tensor(&x, [6, 2], &Device::flex()), &runs);
        let (ad, grad) = pooled_and_grad(&x, [6, 2], |t| runs_max(t, &runs));
        assert_eq!(bits(plain.clone()), ad);
        assert_eq!(
            plain.try_into_vec_as::<f32>().unwrap(),
            vec![4.0, 3.0, 0.0, 0.0, 3.0, 4.0, 2.0, 3.0]
        );
        let grad: Vec<f32> = grad.into_iter().map(f32::from_bits).collect();
        // burn's own max per run (select + max_dim), the runs concatenated.
        let generic = {
            let device = Device::flex().autodiff();
            let x = tensor(&x, [6, 2], &device).require_grad();
            let sel = |s: usize, n: usize| {
                let rows: Vec<i64> = (s..s + n).map(|r| r as i64).collect();
                Tensor::<1, Int>::from_data(TensorData::new(rows, [n]), &device)
            };
            let zero = Tensor::<2>::zeros([1, 2], &device);
            let out = Tensor::cat(
                vec![
                    x.clone().select(0, sel(0, 3)).max_dim(0),
                    zero,
                    x.clone().select(0, sel(3, 3)).max_dim(0),
                    x.clone().select(0, sel(0, 2)).max_dim(0),
                ],
                0,
            );
            let g = (out * weights(4, 2, &device)).sum().backward();
            x.grad(&g).unwrap().try_into_vec_as::<f32>().unwrap()
        };
        assert_eq!(grad, generic);
        // Row 1 wins channel 1 of runs 0 and 3 (loss weights 0.75 and 3.75): both add.
        assert_eq!(grad[3], 4.5);
    }

    /// The neighbour sum against burn's gather + broadcast + add, values and the three
    /// gradients, with points read by several queries, by none, and twice by one query.
    #[test]
    fn neighbour_sum_matches_burns_tensor_form() {
        let (n, m, k, c) = (11, 6, 4, 7);
        let nb: Vec<u32> = (0..m * k)
            .map(|r| {
                if r % 9 == 4 {
                    3
                } else {
                    ((r * 5) % (n - 2)) as u32
                }
            })
            .collect();
        let neighbours = Arc::new(Neighbours::new(nb.clone(), k, n));
        let pp = tied(n * c, 1);
        let pq: Vec<f32> = (0..m * c).map(|i| (i % 7) as f32 * 0.3 - 1.0).collect();
        let dist: Vec<f32> = (0..m * k).map(|i| (i % 5) as f32 * 0.7 + 0.1).collect();
        let wd: Vec<f32> = (0..c).map(|i| i as f32 * 0.2 - 0.5).collect();
        let run = |custom: bool| {
            let device = Device::flex().autodiff();
            let per_point = tensor(&pp, [n, c], &device).require_grad();
            let per_query = tensor(&pq, [m, c], &device).require_grad();
            let w_d = tensor(&wd, [1, c], &device).require_grad();
            let distance = tensor(&dist, [m * k, 1], &device);
            let y = if custom {
                neighbour_sum(
                    per_point.clone(),
                    per_query.clone(),
                    distance,
                    w_d.clone(),
                    &neighbours,
                )
            } else {
                let rows: Vec<i64> = nb.iter().map(|&r| r as i64).collect();
                let index = Tensor::<1, Int>::from_data(TensorData::new(rows, [m * k]), &device);
                (per_point.clone().select(0, index).reshape([m, k, c])
                    + per_query.clone().reshape([m, 1, c])
                    + (distance * w_d.clone()).reshape([m, k, c]))
                .reshape([m * k, c])
            };
            let grads = (y.clone() * weights(m * k, c, &device)).sum().backward();
            let grad = |t: &Tensor<2>| t.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap();
            (
                y.try_into_vec_as::<f32>().unwrap(),
                grad(&per_point),
                grad(&per_query),
                grad(&w_d),
            )
        };
        let (custom, generic) = (run(true), run(false));
        assert_eq!(bits_of(&custom.0), bits_of(&generic.0), "values");
        for (name, a, b) in [
            ("per point", &custom.1, &generic.1),
            ("per query", &custom.2, &generic.2),
            ("w_d", &custom.3, &generic.3),
        ] {
            assert_eq!(a.len(), b.len());
            for (x, y) in a.iter().zip(b.iter()) {
                assert!(
                    (x - y).abs() <= 1e-5 * (1.0 + y.abs()),
                    "{name}: {x} vs {y}"
                );
            }
        }
        // Points 9 and 10 are read by no query: zero gradient.
        assert!(custom.1[9 * c..].iter().all(|&g| g == 0.0));
        // Without autodiff the same values.
        let device = Device::flex();
        let plain = neighbour_sum(
            tensor(&pp, [n, c], &device),
            tensor(&pq, [m, c], &device),
            tensor(&dist, [m * k, 1], &device),
            tensor(&wd, [1, c], &device),
            &neighbours,
        );
        assert_eq!(
            bits_of(&plain.try_into_vec_as::<f32>().unwrap()),
            bits_of(&custom.0)
        );
    }

    /// The gather + add against burn's `select` and `+`: values and both gradients the
    /// same to the bit, over more rows than one task's share, with table rows nobody reads.
    #[test]
    fn gather_add_matches_select_and_add_to_the_bit() {
        let (n, m, k, c) = (40, 130, 4, 5);
        let nb: Vec<u32> = (0..m * k).map(|r| ((r * 7) % (n - 3)) as u32).collect();
        let neighbours = Arc::new(Neighbours::new(nb.clone(), k, n));
        let table = tied(n * c, 2);
        let per_row: Vec<f32> = (0..m * k * c)
            .map(|i| (i % 11) as f32 * 0.3 - 1.4)
            .collect();
        let run = |custom: bool| {
            let device = Device::flex().autodiff();
            let t = tensor(&table, [n, c], &device).require_grad();
            let r = tensor(&per_row, [m * k, c], &device).require_grad();
            let y = if custom {
                gather_add(t.clone(), r.clone(), &neighbours)
            } else {
                let rows: Vec<i64> = nb.iter().map(|&r| r as i64).collect();
                let index = Tensor::<1, Int>::from_data(TensorData::new(rows, [m * k]), &device);
                t.clone().select(0, index) + r.clone()
            };
            let grads = (y.clone() * weights(m * k, c, &device)).sum().backward();
            let grad = |x: &Tensor<2>| x.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap();
            [y.try_into_vec_as::<f32>().unwrap(), grad(&t), grad(&r)].map(|v| bits_of(&v))
        };
        let (custom, generic) = (run(true), run(false));
        for (name, a, b) in ["values", "table gradient", "per-row gradient"]
            .into_iter()
            .zip(&custom)
            .zip(&generic)
            .map(|((name, a), b)| (name, a, b))
        {
            assert_eq!(a, b, "{name}");
        }
        // The last three table rows are read by nobody: zero gradient.
        assert!(custom[1][(n - 3) * c..].iter().all(|&g| g == 0));
        let device = Device::flex();
        let plain = gather_add(
            tensor(&table, [n, c], &device),
            tensor(&per_row, [m * k, c], &device),
            &neighbours,
        );
        assert_eq!(bits_of(&plain.try_into_vec_as::<f32>().unwrap()), custom[0]);
    }

    fn bits_of(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn the_transposed_neighbourhood_lists_each_points_readers_in_row_order() {
        let nb = Neighbours::new(vec![2, 0, 2, 1, 2, 2], 2, 4);
        assert_eq!(nb.queries(), 3);
        let readers =
            |p: usize| -> Vec<u32> { nb.readers().of(p).iter().map(|&(_, r)| r).collect() };
        assert_eq!(
            [0, 1, 2, 3].map(readers),
            [vec![1], vec![3], vec![0, 2, 4, 5], vec![]]
        );
    }

    /// Detection runs the forward pass only: it must not pay for the reader lists.
    #[test]
    fn the_reader_lists_are_built_by_the_first_backward_step_only() {
        let neighbours = Arc::new(Neighbours::new(vec![2, 0, 2, 1, 2, 2], 2, 4));
        let table =
            || Tensor::<2>::from_data(TensorData::new(vec![1f32; 8], [4, 2]), &Device::flex());
        let per_row = |d: &Device| Tensor::<2>::zeros([6, 2], d);
        let _ = gather_add(table(), per_row(&Device::flex()), &neighbours);
        assert!(
            neighbours.readers.get().is_none(),
            "built by a forward pass"
        );
        assert_eq!(*neighbours, Neighbours::new(vec![2, 0, 2, 1, 2, 2], 2, 4));
        let device = Device::flex().autodiff();
        let t =
            Tensor::<2>::from_data(TensorData::new(vec![1f32; 8], [4, 2]), &device).require_grad();
        let out = gather_add(t.clone(), per_row(&device), &neighbours);
        assert!(
            neighbours.readers.get().is_none(),
            "built by a training forward pass"
        );
        let grads = out.sum().backward();
        let g = t.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap();
        assert!(neighbours.readers.get().is_some());
        assert_eq!(g, [1.0, 1.0, 1.0, 1.0, 4.0, 4.0, 0.0, 0.0]);
    }

    #[test]
    fn other_devices_are_not_the_custom_path() {
        assert!(custom_path(&Tensor::<2>::zeros([1, 1], &Device::flex())));
        assert!(custom_path(&Tensor::<2>::zeros(
            [1, 1],
            &Device::flex().autodiff()
        )));
    }
}
