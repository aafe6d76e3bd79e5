//! Whether a device differentiates the sparse convolution as the CPU does: one fixed
//! submanifold layer over 20,000 sites, its output and both gradients on the device against
//! the CPU's per-offset path; and how it adds repeated rows, which the backward pass of every
//! gather through burn's `select` does.
//!
//! Why: on wgpu over lavapipe (2026-11-29) the kernel map built from burn's operations gave
//! the right outputs and weight gradients but input gradients wrong by up to their largest
//! value over such a layer (burn's `select_assign` with `Add` over repeated rows, the
//! gather's backward, sums wrongly there), where layers of a few hundred sites agreed within
//! 1e-7; on an H200 the same additions were exact but took 172 ms (burn's kernel walks every
//! row per column) and the kernel map's gradients 2e-4 from the CPU's (TF32). A layer this
//! size is what a voxel backbone runs, so `bench` measures it on the device a model runs on,
//! in the layout it runs, beside the matrix-product probe ([`crate::matmul_precision`]).

use crate::matmul_precision::probe_values;
use burn::module::Param;
use burn::prelude::*;
use fusiondet_nn::sparse::{RuleLayout, Rulebook, SparseConv3d, SparseSites};
use std::sync::Arc;

/// The probe's grid ([z, y, x], a KITTI-like first stage) and about how many sites it holds.
const GRID: [usize; 3] = [40, 200, 176];
pub const PROBE_SITES: usize = 20_000;
const CHANNELS: [usize; 2] = [16, 16];

/// Each quantity's largest difference from the CPU's, relative to the CPU's largest value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SparseGradientError {
    pub output: f64,
    pub input_gradient: f64,
    pub weight_gradient: f64,
}

/// The probe on `device` in the layout the device's networks take
/// ([`RuleLayout::for_device`]), and that layout.
pub fn in_the_devices_layout(device: &Device) -> (RuleLayout, SparseGradientError) {
    let layout = RuleLayout::for_device(device);
    (layout, sparse_gradient_error(device, layout))
}

/// The probe on `device` in `layout` against the CPU's per-offset path.
pub fn sparse_gradient_error(device: &Device, layout: RuleLayout) -> SparseGradientError {
    let sites = Arc::new(probe_sites());
    let cpu = run(&sites, RuleLayout::PerOffset, &Device::flex().autodiff());
    let on_device = run(&sites, layout, &device.clone().autodiff());
    SparseGradientError {
        output: relative_difference(&on_device[0], &cpu[0]),
        input_gradient: relative_difference(&on_device[1], &cpu[1]),
        weight_gradient: relative_difference(&on_device[2], &cpu[2]),
    }
}

/// The largest |got − want| over the values, relative to the largest |want| (absolute where
/// every wanted value is zero).
pub(crate) fn relative_difference(got: &[f32], want: &[f32]) -> f64 {
    let scale = want.iter().fold(0f64, |m, v| m.max(v.abs() as f64));
    let worst = got
        .iter()
        .zip(want)
        .fold(0f64, |m, (x, y)| m.max((x - y).abs() as f64));
    if scale > 0.0 { worst / scale } else { worst }
}

/// Sites where a multiplicative hash of the linear index falls below the share that leaves
/// about [`PROBE_SITES`] of the grid's cells: no generator, the same probe everywhere.
fn probe_sites() -> SparseSites {
    let [nz, ny, nx] = GRID;
    let cells = (nz * ny * nx) as u64;
    let threshold = (u64::MAX / cells).saturating_mul(PROBE_SITES as u64);
    let coords = (0..cells)
        .filter(|&l| l.wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(17) < threshold)
        .map(|l| {
            let l = l as usize;
            [
                0,
                (l / (ny * nx)) as i32,
                (l / nx % ny) as i32,
                (l % nx) as i32,
            ]
        })
        .collect();
    SparseSites::new(coords, GRID, 1).expect("distinct sites inside the grid")
}

/// (output, input gradient, weight gradient) of the layer on `device` in `layout`.
fn run(sites: &Arc<SparseSites>, layout: RuleLayout, device: &Device) -> [Vec<f32>; 3] {
    let [c_in, c_out] = CHANNELS;
    let mut conv = SparseConv3d::submanifold(CHANNELS, [3; 3], device);
    // Weights of a Kaiming-uniform scale (1/√(27 · 16) ≈ 0.05), fixed.
    let weight: Vec<f32> = probe_values(27 * c_in * c_out, 1)
        .into_iter()
        .map(|v| v * 0.05)
        .collect();
    conv.weight = Param::from_tensor(Tensor::from_data(
        TensorData::new(weight, [27, c_in, c_out]),
        device,
    ));
    let book = Rulebook::submanifold_in(sites, [3; 3], layout, device);
    let rows = sites.len();
    let x = Tensor::<2>::from_data(
        TensorData::new(probe_values(rows * c_in, 2), [rows, c_in]),
        device,
    )
    .require_grad();
    let upstream = Tensor::<2>::from_data(
        TensorData::new(probe_values(rows * c_out, 3), [rows, c_out]),
        device,
    );
    let out = conv.forward(x.clone(), &book);
    let grads = (out.clone() * upstream).sum().backward();
    [
        values(out),
        values(x.grad(&grads).expect("the features are tracked")),
        values(conv.weight.grad(&grads).expect("the weight is tracked")),
    ]
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.try_into_vec_as::<f32>().expect("f32 values")
}

/// Rows the repeated-row probe adds into, and how many rows it adds into each.
const TARGET_ROWS: usize = 20_001;
const ADDS_PER_ROW: usize = 27;

/// What the gather's backward does everywhere a network reads rows more than once through
/// burn's `select` (the losses' row picks; RoI pooling, STCA, the BEV, LFA, CBAM and the
/// PointNet scales take `fusiondet_nn::gather::RowGather` on GPUs, the sparse convolution its
/// kernels): burn's
/// `select_assign` with `Add`, here 540,027 rows of 16 values added into 20,001 rows, 27 into
/// each, in a fixed scattered order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RepeatedRowAddition {
    /// The largest difference from the CPU's sums relative to their largest value: about
    /// 1e-7 where additions into one row do not collide.
    pub error: f64,
    /// Seconds of one such addition on the device, its upload and read-back included, after
    /// a first run that compiled it: burn's GPU kernel gives each column one thread that walks
    /// every added row, so this tells whether gathers' backward passes hold a training step.
    pub seconds: f64,
}

/// The repeated-row probe on `device` against the CPU.
pub fn repeated_row_addition(device: &Device) -> RepeatedRowAddition {
    let c = 16;
    let n = TARGET_ROWS * ADDS_PER_ROW;
    // A stride coprime to the row count visits every row ADDS_PER_ROW times, scattered.
    let index: Vec<i64> = (0..n).map(|i| ((i * 7919) % TARGET_ROWS) as i64).collect();
    let rows = probe_values(n * c, 4);
    let sums = |device: &Device| {
        let index = Tensor::<1, Int>::from_data(TensorData::new(index.clone(), [n]), device);
        let rows = Tensor::<2>::from_data(TensorData::new(rows.clone(), [n, c]), device);
        values(Tensor::<2>::zeros([TARGET_ROWS, c], device).select_assign(
            0,
            index,
            rows,
            burn::tensor::IndexingUpdateOp::Add,
        ))
    };
    let want = sums(&Device::flex());
    sums(device);
    let started = std::time::Instant::now();
    let got = sums(device);
    let seconds = started.elapsed().as_secs_f64();
    RepeatedRowAddition {
        error: relative_difference(&got, &want),
        seconds,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernel map on the CPU against the per-offset path: the same sums in another order,
    /// so every quantity agrees within f32 rounding, and the probe holds about the sites it
    /// says.
    #[test]
    fn the_cpus_kernel_map_differentiates_as_its_per_offset_layout() {
        let sites = probe_sites().len();
        assert!(
            (PROBE_SITES * 9 / 10..PROBE_SITES * 11 / 10).contains(&sites),
            "{sites}"
        );
        let error = sparse_gradient_error(&Device::flex(), RuleLayout::KernelMap);
        for (what, e) in [
            ("output", error.output),
            ("input gradient", error.input_gradient),
            ("weight gradient", error.weight_gradient),
        ] {
            assert!(e < 1e-5, "{what}: {e}");
        }
    }

    /// On the CPU the repeated-row additions are the CPU's own: the same sums, bit for bit.
    #[test]
    fn the_cpu_adds_repeated_rows_as_itself() {
        assert_eq!(repeated_row_addition(&Device::flex()).error, 0.0);
    }
}
