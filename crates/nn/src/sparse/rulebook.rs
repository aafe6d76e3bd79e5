//! Rulebooks: for each kernel offset, the (input row, output row) pairs a sparse
//! convolution multiplies by that offset's weight. Built once per layer shape from the
//! sites, then shared by every layer of that shape (all submanifold layers of a backbone
//! stage share one). The pairs reach the device in one of two layouts ([`RuleLayout`]):
//! a list per offset for the CPU, one kernel map for GPUs.

use super::sites::{SparseSites, in_shape, linear_key};
use super::strided_sites::StridedOutputs;
use crate::row_pairs::RowPairs;
use burn::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, OnceLock};

/// Kernel, stride and padding of a 3D convolution, per axis in (z, y, x) order
/// (dilation 1). The output site `o` of offset `k` reads the input site `o·s − p + k`,
/// the cross-correlation of a dense `conv3d` with the same settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ConvGeometry {
    pub kernel: [usize; 3],
    pub stride: [usize; 3],
    pub padding: [usize; 3],
}

impl ConvGeometry {
    /// Stride 1 with "same" padding: the geometry of a submanifold convolution (odd kernel).
    pub fn same(kernel: [usize; 3]) -> ConvGeometry {
        assert!(
            kernel.iter().all(|k| k % 2 == 1),
            "a same-size kernel is odd: {kernel:?}"
        );
        ConvGeometry {
            kernel,
            stride: [1; 3],
            padding: kernel.map(|k| k / 2),
        }
    }

    pub fn strided(kernel: [usize; 3], stride: [usize; 3], padding: [usize; 3]) -> ConvGeometry {
        ConvGeometry {
            kernel,
            stride,
            padding,
        }
    }

    /// Kernel offsets, in (z, y, x) row-major order: the first axis of a sparse weight.
    pub fn volume(&self) -> usize {
        self.kernel.iter().product()
    }

    /// The dense output extent, `(n + 2p − k) / s + 1` per axis (as `conv3d`).
    pub fn output_shape(&self, input: [usize; 3]) -> [usize; 3] {
        std::array::from_fn(|a| {
            (input[a] + 2 * self.padding[a]).saturating_sub(self.kernel[a]) / self.stride[a] + 1
        })
    }

    /// Calls `f(k, o)` for every offset `k` by which input site `c` feeds an output site `o`
    /// inside `out_shape` (`o·s − p + d_k = c`), offsets ascending. Per axis only the offsets
    /// of the right residue modulo the stride are visited, one division each: testing all
    /// of a 3×3×3 kernel's 27 offsets with a division per axis was a strided rulebook's
    /// largest cost.
    pub(crate) fn for_each_target(
        &self,
        c: &[i32; 4],
        out_shape: [usize; 3],
        mut f: impl FnMut(usize, [i32; 4]),
    ) {
        let [kz, ky, kx] = self.kernel.map(|k| k as i32);
        let s = self.stride.map(|s| s as i32);
        let p = self.padding.map(|p| p as i32);
        // The first offset along axis `a` with (c + p − d) divisible by the stride.
        let first = |a: usize| (c[a + 1] + p[a]).rem_euclid(s[a]);
        // The output coordinate offset `d` reaches along axis `a`, if inside.
        let out = |a: usize, d: i32| {
            let n = c[a + 1] + p[a] - d;
            (n >= 0 && ((n / s[a]) as usize) < out_shape[a]).then_some(n / s[a])
        };
        for dz in (first(0)..kz).step_by(s[0] as usize) {
            let Some(oz) = out(0, dz) else { continue };
            for dy in (first(1)..ky).step_by(s[1] as usize) {
                let Some(oy) = out(1, dy) else { continue };
                for dx in (first(2)..kx).step_by(s[2] as usize) {
                    let Some(ox) = out(2, dx) else { continue };
                    let k = ((dz * ky + dy) * kx + dx) as usize;
                    f(k, [c[0], oz, oy, ox]);
                }
            }
        }
    }

    /// The output site input site `c` feeds at offset `k` (`o·s − p + d_k = c`), if inside
    /// `out_shape`: [`ConvGeometry::for_each_target`] for one offset.
    pub(crate) fn target(&self, c: &[i32; 4], k: usize, out_shape: [usize; 3]) -> Option<[i32; 4]> {
        let d = self.offset(k);
        let mut o = [c[0], 0, 0, 0];
        for a in 0..3 {
            let n = c[a + 1] + self.padding[a] as i32 - d[a];
            let s = self.stride[a] as i32;
            if n < 0 || n % s != 0 || (n / s) as usize >= out_shape[a] {
                return None;
            }
            o[a + 1] = n / s;
        }
        Some(o)
    }

    /// The rows of `coords` by residue class modulo the stride of `c + p` (z, y, x), each
    /// class in row order: offset `k` reaches outputs from class
    /// [`ConvGeometry::offset_class`] only.
    fn residue_buckets(&self, coords: &[[i32; 4]]) -> Vec<Vec<u32>> {
        let s = self.stride.map(|s| s as i32);
        let mut buckets = vec![Vec::new(); self.stride.iter().product()];
        for (row, c) in coords.iter().enumerate() {
            let r: [i32; 3] =
                std::array::from_fn(|a| (c[a + 1] + self.padding[a] as i32).rem_euclid(s[a]));
            buckets[((r[0] * s[1] + r[1]) * s[2] + r[2]) as usize].push(row as u32);
        }
        buckets
    }

    /// The residue class (as [`ConvGeometry::residue_buckets`] numbers them) of the inputs
    /// offset `k` reaches outputs from: `c + p ≡ d_k` modulo the stride.
    fn offset_class(&self, k: usize) -> usize {
        let s = self.stride.map(|s| s as i32);
        let d = self.offset(k);
        let r: [i32; 3] = std::array::from_fn(|a| d[a] % s[a]);
        ((r[0] * s[1] + r[1]) * s[2] + r[2]) as usize
    }

    /// (dz, dy, dx) of offset index `k`.
    fn offset(&self, k: usize) -> [i32; 3] {
        let [_, ky, kx] = self.kernel;
        [
            (k / (ky * kx)) as i32,
            ((k / kx) % ky) as i32,
            (k % kx) as i32,
        ]
    }
}

/// How a rulebook's pairs are laid out for the device that runs the convolution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RuleLayout {
    /// A list of (input row, output row) pairs per kernel offset: per offset one gather, one
    /// matrix product and one scatter-add. The fewest multiply-adds, and the order of sums
    /// every CPU result of this project was made with.
    PerOffset,
    /// One kernel map, [output rows × kernel volume] input rows (a zero row where an offset
    /// has no input): the convolution is one gather and one matrix product whatever the
    /// kernel volume, the "implicit GEMM" form of spconv and TorchSparse. It multiplies the
    /// zeros of absent neighbours too (a submanifold layer over LiDAR voxels fills about a
    /// third of its 27 offsets), which a GPU does faster than it launches the 80-odd
    /// kernels a per-offset layer takes.
    KernelMap,
    /// The kernel map, run by the CubeCL kernels of `device_kernels` (which make its inverse,
    /// the output row that reads each input row at each offset, for a backward pass): no gathered copy, no zeros
    /// multiplied, no atomic additions in the backward pass. Only on a CubeCL device of a
    /// build with the `wgpu` or `cuda` feature; elsewhere it is [`RuleLayout::KernelMap`].
    /// The GPUs' default ([`RuleLayout::for_device`]).
    DeviceKernels,
}

impl RuleLayout {
    /// Per offset on burn's flex CPU backend (where sums keep the order of every pinned CPU
    /// result); the CubeCL kernels on wgpu and CUDA; the kernel map from burn's operations
    /// on any other backend. Why the kernels on GPUs (measured 2026-11-29): on lavapipe the
    /// kernel map's input gradients came out wrong at a backbone's size (off by up to their
    /// largest value over 20,000 sites; `pipeline::sparse_gradient_probe`); on an H200 they
    /// were right but its products ran in TF32 (gradients 2e-4 from the CPU's, the shipped
    /// Voxel R-CNN's boxes up to 0.47 m away) and its backward pass through burn's
    /// `select_assign` walks every gathered row per column: the kernels' training steps took
    /// 2.8 s against 5.2 s (published Voxel R-CNN) and 10.2 s against 23.9 s (DASANet), and
    /// their boxes matched the CPU's within the parity tolerance, at 8% fewer frames/s in
    /// detection (32.4 against 35.0 for the shipped Voxel R-CNN).
    /// `FUSIONDET_SPARSE_RULES=per-offset`, `kernel-map` or `kernels` overrides this for the
    /// whole process, so that the layouts can be timed side by side on one device.
    pub fn for_device(device: &Device) -> RuleLayout {
        static FORCED: OnceLock<Option<RuleLayout>> = OnceLock::new();
        let forced = FORCED.get_or_init(|| {
            let value = std::env::var("FUSIONDET_SPARSE_RULES").ok()?;
            let layout = [
                RuleLayout::PerOffset,
                RuleLayout::KernelMap,
                RuleLayout::DeviceKernels,
            ]
            .into_iter()
            .find(|layout| layout.name() == value);
            if layout.is_none() {
                eprintln!(
                    "warning: FUSIONDET_SPARSE_RULES={value:?} is neither \"per-offset\", \
                     \"kernel-map\" nor \"kernels\"; each device takes its default layout"
                );
            }
            layout
        });
        forced.unwrap_or_else(|| Self::default_for(device))
    }

    fn default_for(device: &Device) -> RuleLayout {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if crate::cube::cube_runtime(device).is_some() {
            return RuleLayout::DeviceKernels;
        }
        if device.clone().without_autodiff() == Device::flex() {
            RuleLayout::PerOffset
        } else {
            RuleLayout::KernelMap
        }
    }

    /// The layout's name, as `FUSIONDET_SPARSE_RULES` spells it.
    pub fn name(self) -> &'static str {
        match self {
            RuleLayout::PerOffset => "per-offset",
            RuleLayout::KernelMap => "kernel-map",
            RuleLayout::DeviceKernels => "kernels",
        }
    }

    /// What this layout is on `device`: [`RuleLayout::DeviceKernels`] only where the
    /// kernels run (a CubeCL device, a GPU build), else [`RuleLayout::KernelMap`].
    fn on(self, device: &Device) -> RuleLayout {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        if self == RuleLayout::DeviceKernels && crate::cube::cube_runtime(device).is_some() {
            return self;
        }
        let _ = device;
        if self == RuleLayout::DeviceKernels {
            RuleLayout::KernelMap
        } else {
            self
        }
    }
}

/// The pairs of one kernel offset.
#[derive(Debug, Clone)]
pub struct OffsetRule {
    /// Index into the kernel volume (the weight's first axis).
    pub offset: usize,
    pub pairs: usize,
    /// [pairs] input rows to gather.
    pub input: Tensor<1, Int>,
    /// [pairs] output rows to add into.
    pub output: Tensor<1, Int>,
}

/// A per-offset rulebook's pairs as host index lists: what the fused flex operation reads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostRules {
    pub input_rows: usize,
    pub output_rows: usize,
    /// The offset that maps every input row onto the same output row (not in `rules`).
    pub identity_offset: Option<usize>,
    /// (offset, input rows, output rows) of the other offsets that have pairs, in offset
    /// order; within one offset no input row and no output row repeats.
    pub rules: Vec<(usize, Vec<u32>, Vec<u32>)>,
    /// The pairs of `rules` by output row (the forward pass's additions).
    pub by_output: RowPairs,
    /// The pairs of `rules` by input row (the input gradient's additions).
    pub by_input: RowPairs,
}

impl HostRules {
    pub fn new(
        input_rows: usize,
        output_rows: usize,
        identity_offset: Option<usize>,
        rules: Vec<(usize, Vec<u32>, Vec<u32>)>,
    ) -> HostRules {
        let by_output = RowPairs::new(output_rows, rules.iter().map(|(_, _, o)| o.as_slice()));
        let by_input = RowPairs::new(input_rows, rules.iter().map(|(_, i, _)| i.as_slice()));
        HostRules {
            input_rows,
            output_rows,
            identity_offset,
            rules,
            by_output,
            by_input,
        }
    }
}

/// A rulebook's pairs on the device, in one [`RuleLayout`].
#[derive(Debug, Clone)]
pub enum RuleGather {
    PerOffset {
        /// The offset whose pairs are every row onto itself (a submanifold kernel's
        /// centre): a plain matrix product, no gather or scatter.
        identity_offset: Option<usize>,
        /// The other offsets that have pairs, in offset order.
        rules: Vec<OffsetRule>,
        /// The same pairs on the host, for the fused flex operation
        /// ([`super::fused::sparse_conv`]).
        host: Arc<HostRules>,
    },
    KernelMap {
        /// [output rows · kernel volume]: row `o · volume + k` holds the input row output
        /// `o` reads at offset `k`, or `input_rows` (the zero row appended to the features)
        /// where it reads none. Boxed: a tensor handle is several times the size of the
        /// per-offset variant.
        table: Box<Tensor<1, Int>>,
        /// Whether the CubeCL kernels read it ([`RuleLayout::DeviceKernels`]; they make its
        /// inverse on the device when a backward pass needs it).
        kernels: bool,
    },
}

/// Everything a sparse convolution of one geometry needs on given input sites.
#[derive(Debug, Clone)]
pub struct Rulebook {
    pub geometry: ConvGeometry,
    /// Output sites = input sites (stride 1, same padding).
    pub submanifold: bool,
    pub input_rows: usize,
    pub output: Arc<SparseSites>,
    /// All (input, output) pairs, a submanifold kernel's centre included: counted as the
    /// host builds them, or from the table when first asked for where the device built it.
    pairs: OnceLock<usize>,
    pub gather: RuleGather,
}

impl Rulebook {
    /// A submanifold convolution's rulebook: output sites are the input sites, and an
    /// output reads only active inputs of its neighbourhood, so sparsity does not dilate.
    pub fn submanifold(sites: &Arc<SparseSites>, kernel: [usize; 3], device: &Device) -> Rulebook {
        Self::submanifold_in(sites, kernel, RuleLayout::for_device(device), device)
    }

    /// [`Rulebook::submanifold`] in a given layout.
    pub fn submanifold_in(
        sites: &Arc<SparseSites>,
        kernel: [usize; 3],
        layout: RuleLayout,
        device: &Device,
    ) -> Rulebook {
        Self::submanifold_built(sites, kernel, layout, device, TableBuild::for_process())
    }

    /// [`Rulebook::submanifold_in`], the kernels' tables built where `build` says.
    pub(crate) fn submanifold_built(
        sites: &Arc<SparseSites>,
        kernel: [usize; 3],
        layout: RuleLayout,
        device: &Device,
        build: TableBuild,
    ) -> Rulebook {
        let geometry = ConvGeometry::same(kernel);
        let volume = geometry.volume();
        if let Some(gather) = device_tables(sites, None, &geometry, layout, device, build) {
            return Rulebook {
                geometry,
                submanifold: true,
                input_rows: sites.len(),
                output: sites.clone(),
                pairs: OnceLock::new(),
                gather,
            };
        }
        let centre = volume / 2;
        // Offset k and its mirror `volume − 1 − k` pair the same sites the other way round
        // (o reads i at +d exactly when i reads o at −d), so only the offsets before the
        // centre are searched.
        let half: Vec<(usize, Vec<i64>, Vec<i64>)> = (0..centre)
            .into_par_iter()
            .map(|k| {
                let shift = geometry.offset(k);
                let shift: [i32; 3] =
                    std::array::from_fn(|a| shift[a] - geometry.padding[a] as i32);
                let read = neighbours_at(sites, shift);
                let (mut input, mut output) = (Vec::new(), Vec::new());
                for (o, &i) in read.iter().enumerate() {
                    if i != NONE {
                        input.push(i as i64);
                        output.push(o as i64);
                    }
                }
                (k, input, output)
            })
            .collect();
        let mut pairs = Vec::with_capacity(volume - 1);
        for (k, input, output) in &half {
            pairs.push((volume - 1 - k, output.clone(), input.clone()));
        }
        pairs.extend(half);
        pairs.sort_by_key(|(k, _, _)| *k);
        let identity = (!sites.is_empty()).then_some(centre);
        Rulebook {
            geometry,
            submanifold: true,
            input_rows: sites.len(),
            output: sites.clone(),
            pairs: OnceLock::from(count_pairs(&pairs) + identity.map_or(0, |_| sites.len())),
            gather: gather(
                pairs,
                identity,
                sites.len(),
                sites.len(),
                volume,
                layout,
                device,
            ),
        }
    }

    /// A regular (strided) convolution's rulebook: an output site is active when any
    /// input site lies in its receptive field. Output sites are listed in batch-major
    /// (b, z, y, x) order, so the result does not depend on the order of the input rows.
    pub fn strided(sites: &SparseSites, geometry: ConvGeometry, device: &Device) -> Rulebook {
        Self::strided_in(sites, geometry, RuleLayout::for_device(device), device)
    }

    /// [`Rulebook::strided`] in a given layout.
    pub fn strided_in(
        sites: &SparseSites,
        geometry: ConvGeometry,
        layout: RuleLayout,
        device: &Device,
    ) -> Rulebook {
        Self::strided_built(sites, geometry, layout, device, TableBuild::for_process())
    }

    /// [`Rulebook::strided_in`], the kernels' tables built where `build` says.
    pub(crate) fn strided_built(
        sites: &SparseSites,
        geometry: ConvGeometry,
        layout: RuleLayout,
        device: &Device,
        build: TableBuild,
    ) -> Rulebook {
        let out_shape = geometry.output_shape(sites.spatial_shape());
        let volume = geometry.volume();
        let StridedOutputs {
            coords: outputs,
            rows: row_of_output,
        } = StridedOutputs::new(sites, &geometry);
        let output = Arc::new(SparseSites::from_sorted(
            outputs,
            out_shape,
            sites.batch_size(),
        ));
        if let Some(gather) = device_tables(sites, Some(&output), &geometry, layout, device, build)
        {
            return Rulebook {
                geometry,
                submanifold: false,
                input_rows: sites.len(),
                output,
                pairs: OnceLock::new(),
                gather,
            };
        }
        // Per offset, the pairs in input row order. An offset reaches an output from the
        // inputs of one residue class modulo the stride only (`c + p − d ≡ 0`), so the
        // inputs are bucketed by class first (in row order) and each offset walks its own
        // bucket: an eighth of the inputs per offset at stride 2, not all of them.
        let buckets = geometry.residue_buckets(sites.coords());
        let pairs: OffsetPairs = (0..volume)
            .into_par_iter()
            .map(|k| {
                let (mut input, mut out_rows) = (Vec::new(), Vec::new());
                for &i in &buckets[geometry.offset_class(k)] {
                    let c = &sites.coords()[i as usize];
                    if let Some(o) = geometry.target(c, k, out_shape) {
                        input.push(i as i64);
                        out_rows.push(row_of_output.row(linear_key(o, out_shape)) as i64);
                    }
                }
                (k, input, out_rows)
            })
            .collect();
        let output_rows = output.len();
        Rulebook {
            geometry,
            submanifold: false,
            input_rows: sites.len(),
            output,
            pairs: OnceLock::from(count_pairs(&pairs)),
            gather: gather(
                pairs,
                None,
                sites.len(),
                output_rows,
                volume,
                layout,
                device,
            ),
        }
    }

    pub fn output_rows(&self) -> usize {
        self.output.len()
    }

    /// All (input, output) pairs, the identity offset's included: a convolution over
    /// these sites costs `pairs · C_in · C_out` multiply-adds (in the per-offset layout).
    /// Where the device built the table, the first call reads it back (a wait for the
    /// device; `info` and benchmarks ask, a forward pass does not).
    pub fn total_pairs(&self) -> usize {
        *self.pairs.get_or_init(|| match &self.gather {
            RuleGather::KernelMap { table, .. } => table
                .clone()
                .into_data()
                .convert::<i64>()
                .iter::<i64>()
                .filter(|&row| (0..self.input_rows as i64).contains(&row))
                .count(),
            RuleGather::PerOffset { .. } => unreachable!("a per-offset rulebook counts its pairs"),
        })
    }
}

/// Where the tables of [`RuleLayout::DeviceKernels`] are built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum TableBuild {
    /// On the device by search (`rulebook_device`), where the grid's indices fit an i32.
    Device,
    /// On the host from the pairs, then uploaded (the device build's reference in tests).
    Host,
}

impl TableBuild {
    /// On the device, unless `FUSIONDET_RULEBOOK_TABLES=host` asks for the host for the whole
    /// process (so that `scripts/gpu-check.sh` times both side by side on one GPU).
    fn for_process() -> TableBuild {
        static FORCED: OnceLock<TableBuild> = OnceLock::new();
        *FORCED.get_or_init(|| match std::env::var("FUSIONDET_RULEBOOK_TABLES").as_deref() {
            Err(_) | Ok("device") => TableBuild::Device,
            Ok("host") => TableBuild::Host,
            Ok(value) => {
                eprintln!(
                    "warning: FUSIONDET_RULEBOOK_TABLES={value:?} is neither \"device\" nor \"host\"; \
                     the sparse kernels' tables are built on the device"
                );
                TableBuild::Device
            }
        })
    }
}

/// The kernels' table built on the device, where `layout` is
/// [`RuleLayout::DeviceKernels`] on `device` and `build` asks for it; `output` is `None` for a
/// submanifold layer (its outputs are its inputs).
fn device_tables(
    input: &SparseSites,
    output: Option<&SparseSites>,
    geometry: &ConvGeometry,
    layout: RuleLayout,
    device: &Device,
    build: TableBuild,
) -> Option<RuleGather> {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if build == TableBuild::Device && layout.on(device) == RuleLayout::DeviceKernels {
        let table = super::rulebook_device::kernel_map(input, output, geometry, device)?;
        return Some(RuleGather::KernelMap {
            table: Box::new(table),
            kernels: true,
        });
    }
    let _ = (input, output, geometry, layout, device, build);
    None
}

/// A row that is not there.
const NONE: u32 = u32::MAX;

/// For every site o (by row), the row of the active site at o + `shift` (z, y, x), or
/// [`NONE`]. A shift adds one constant to every in-bounds site's linear index, and the
/// shifted indices ascend with the originals, so one walk through the sites by index,
/// a second cursor advancing alongside, finds them all: sequential reads, no hashing.
fn neighbours_at(sites: &SparseSites, shift: [i32; 3]) -> Vec<u32> {
    let shape = sites.spatial_shape();
    let delta =
        (shift[0] as i64 * shape[1] as i64 + shift[1] as i64) * shape[2] as i64 + shift[2] as i64;
    let by_key = sites.by_key();
    let coords = sites.coords();
    let mut read = vec![NONE; sites.len()];
    let mut cursor = 0;
    for &(key, o) in by_key {
        let c = coords[o as usize];
        if !in_shape(std::array::from_fn(|a| c[a + 1] + shift[a]), shape) {
            // Its index shifted would wrap into another row of the grid.
            continue;
        }
        let wanted = (key as i64 + delta) as u64;
        while cursor < by_key.len() && by_key[cursor].0 < wanted {
            cursor += 1;
        }
        if cursor < by_key.len() && by_key[cursor].0 == wanted {
            read[o as usize] = by_key[cursor].1;
        }
    }
    read
}

/// (offset, input rows, output rows) of every offset but a submanifold kernel's centre.
type OffsetPairs = Vec<(usize, Vec<i64>, Vec<i64>)>;

fn count_pairs(pairs: &OffsetPairs) -> usize {
    pairs.iter().map(|(_, input, _)| input.len()).sum()
}

/// The pairs in `layout`, on the device: `identity` is the offset that pairs every input
/// row with the same output row (not listed in `pairs`).
fn gather(
    pairs: OffsetPairs,
    identity: Option<usize>,
    input_rows: usize,
    output_rows: usize,
    volume: usize,
    layout: RuleLayout,
    device: &Device,
) -> RuleGather {
    match layout.on(device) {
        RuleLayout::PerOffset => {
            let pairs: OffsetPairs = pairs
                .into_iter()
                .filter(|(_, input, _)| !input.is_empty())
                .collect();
            let host_rows = |rows: &[i64]| rows.iter().map(|&r| r as u32).collect::<Vec<u32>>();
            let host = HostRules::new(
                input_rows,
                output_rows,
                identity,
                pairs
                    .iter()
                    .map(|(offset, input, output)| (*offset, host_rows(input), host_rows(output)))
                    .collect(),
            );
            RuleGather::PerOffset {
                identity_offset: identity,
                rules: pairs
                    .into_iter()
                    .map(|(offset, input, output)| {
                        let n = input.len();
                        OffsetRule {
                            offset,
                            pairs: n,
                            input: Tensor::from_data(TensorData::new(input, [n]), device),
                            output: Tensor::from_data(TensorData::new(output, [n]), device),
                        }
                    })
                    .collect(),
                host: Arc::new(host),
            }
        }
        layout @ (RuleLayout::KernelMap | RuleLayout::DeviceKernels) => {
            // Built column by column (one offset a task), then laid out row by row (rows
            // split over tasks): on a GPU machine these tables are the host's work of every
            // frame (a serial fill held the published Voxel R-CNN's rulebooks at 35 ms a frame
            // on an H200's host). i32: what the kernels read, uploaded without a conversion.
            // Per offset, its (input rows, output rows).
            let mut by_offset: Vec<Option<(&[i64], &[i64])>> = vec![None; volume];
            for (k, input, output) in &pairs {
                by_offset[*k] = Some((input, output));
            }
            let column = |k: usize| {
                let mut column = vec![input_rows as i32; output_rows];
                if identity == Some(k) {
                    for (row, v) in column.iter_mut().enumerate() {
                        *v = row as i32;
                    }
                }
                if let Some((input, output)) = by_offset[k] {
                    for (&o, &n) in output.iter().zip(input) {
                        column[o as usize] = n as i32;
                    }
                }
                column
            };
            // The table: output o reads `table[o · volume + k]` at offset k, `input_rows` for
            // none (the zero row).
            let columns: Vec<Vec<i32>> = (0..volume).into_par_iter().map(column).collect();
            let table = interleave(&columns, output_rows);
            let n = table.len();
            RuleGather::KernelMap {
                table: Box::new(Tensor::from_data(TensorData::new(table, [n]), device)),
                kernels: layout == RuleLayout::DeviceKernels,
            }
        }
    }
}

/// Columns of `rows` values each, as one row-major [rows · columns] list; rows in parallel.
fn interleave(columns: &[Vec<i32>], rows: usize) -> Vec<i32> {
    let width = columns.len();
    let mut out = vec![0i32; rows * width];
    if width > 0 {
        out.par_chunks_mut(width)
            .enumerate()
            .for_each(|(row, values)| {
                for (v, column) in values.iter_mut().zip(columns) {
                    *v = column[row];
                }
            });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sparse::test_data::ints;

    /// A per-offset rulebook's identity offset and (offset, inputs, outputs) lists.
    fn per_offset(book: &Rulebook) -> (Option<usize>, OffsetPairs) {
        match &book.gather {
            RuleGather::PerOffset {
                identity_offset,
                rules,
                ..
            } => (
                *identity_offset,
                rules
                    .iter()
                    .map(|r| (r.offset, ints(&r.input), ints(&r.output)))
                    .collect(),
            ),
            RuleGather::KernelMap { .. } => panic!("a per-offset rulebook"),
        }
    }

    fn kernel_map(book: &Rulebook) -> Vec<i64> {
        match &book.gather {
            RuleGather::KernelMap { table, .. } => ints(table),
            RuleGather::PerOffset { .. } => panic!("a kernel-map rulebook"),
        }
    }

    #[test]
    fn the_cpu_takes_the_per_offset_layout() {
        // (Unless FUSIONDET_SPARSE_RULES says otherwise, which tests do not set.)
        assert_eq!(
            RuleLayout::for_device(&Device::flex().autodiff()),
            RuleLayout::PerOffset
        );
    }

    #[test]
    fn output_shapes_match_voxel_rcnn_backbone() {
        let grid = [41, 1600, 1408];
        let s2 = ConvGeometry::strided([3; 3], [2; 3], [1; 3]);
        let conv2 = s2.output_shape(grid);
        assert_eq!(conv2, [21, 800, 704]);
        let conv3 = s2.output_shape(conv2);
        assert_eq!(conv3, [11, 400, 352]);
        let conv4 = ConvGeometry::strided([3; 3], [2; 3], [0, 1, 1]).output_shape(conv3);
        assert_eq!(conv4, [5, 200, 176]);
        let out = ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3]).output_shape(conv4);
        assert_eq!(out, [2, 200, 176]);
    }

    #[test]
    fn submanifold_pairs_neighbours_only() {
        let device = Device::flex();
        // Two sites side by side in x, one far away, one in another batch item.
        let sites = Arc::new(
            SparseSites::new(
                vec![[0, 1, 1, 1], [0, 1, 1, 2], [0, 3, 3, 3], [1, 1, 1, 1]],
                [5, 5, 5],
                2,
            )
            .unwrap(),
        );
        let book = Rulebook::submanifold_in(&sites, [3, 3, 3], RuleLayout::PerOffset, &device);
        let (identity, rules) = per_offset(&book);
        assert_eq!(identity, Some(13));
        // Offset (1,1,2) = 14 reads x+1: row 0 reads row 1. Offset 12 reads x−1: row 1 reads row 0.
        assert_eq!(rules, vec![(12, vec![0], vec![1]), (14, vec![1], vec![0])]);
        assert_eq!(book.total_pairs(), 4 + 2);

        // The same pairs as a kernel map: 27 entries per output row, 4 (the zero row) where
        // the offset reads nothing.
        let book = Rulebook::submanifold_in(&sites, [3, 3, 3], RuleLayout::KernelMap, &device);
        assert_eq!(book.total_pairs(), 4 + 2);
        let table = kernel_map(&book);
        assert_eq!(table.len(), 4 * 27);
        let mut expected = vec![4i64; 4 * 27];
        for o in 0..4 {
            expected[o * 27 + 13] = o as i64;
        }
        expected[27 + 12] = 0;
        expected[14] = 1;
        assert_eq!(table, expected);
    }

    #[test]
    fn strided_outputs_cover_receptive_fields_in_order() {
        let device = Device::flex();
        let sites = SparseSites::new(vec![[0, 0, 0, 3], [0, 0, 0, 0]], [1, 1, 4], 1).unwrap();
        // Kernel 3 along x, stride 2, padding 1: output x=o reads inputs 2o−1, 2o, 2o+1.
        let geometry = ConvGeometry::strided([1, 1, 3], [1, 1, 2], [0, 0, 1]);
        let book = Rulebook::strided_in(&sites, geometry, RuleLayout::PerOffset, &device);
        assert_eq!(book.output.spatial_shape(), [1, 1, 2]);
        // Input x=0 feeds output 0 (k=1); x=3 feeds output 1 (k=2) and output 2 (out of range).
        assert_eq!(book.output.coords(), &[[0, 0, 0, 0], [0, 0, 0, 1]]);
        let (identity, rules) = per_offset(&book);
        assert_eq!(identity, None);
        assert_eq!(rules, vec![(1, vec![1], vec![0]), (2, vec![0], vec![1])]);

        // As a kernel map: output 0 reads input 1 at k=1, output 1 input 0 at k=2, and the
        // zero row (2) elsewhere.
        let book = Rulebook::strided_in(&sites, geometry, RuleLayout::KernelMap, &device);
        assert_eq!(kernel_map(&book), vec![2, 1, 2, 2, 2, 0]);
        assert_eq!(book.total_pairs(), 2);
    }

    /// The pairs of every offset as a direct search finds them (a hash map of the sites,
    /// each output's receptive field looked up): what the rulebooks must list, in order.
    fn reference_pairs(
        sites: &SparseSites,
        geometry: ConvGeometry,
        submanifold: bool,
    ) -> OffsetPairs {
        let index: std::collections::HashMap<[i32; 4], usize> = sites
            .coords()
            .iter()
            .enumerate()
            .map(|(r, &c)| (c, r))
            .collect();
        let out_shape = geometry.output_shape(sites.spatial_shape());
        let outputs: Vec<[i32; 4]> = if submanifold {
            sites.coords().to_vec()
        } else {
            let mut all: Vec<[i32; 4]> = Vec::new();
            for c in sites.coords() {
                for k in 0..geometry.volume() {
                    let d = geometry.offset(k);
                    let n: [i32; 3] =
                        std::array::from_fn(|a| c[a + 1] + geometry.padding[a] as i32 - d[a]);
                    let s = geometry.stride.map(|s| s as i32);
                    if (0..3).all(|a| {
                        n[a] >= 0 && n[a] % s[a] == 0 && ((n[a] / s[a]) as usize) < out_shape[a]
                    }) {
                        all.push([c[0], n[0] / s[0], n[1] / s[1], n[2] / s[2]]);
                    }
                }
            }
            all.sort();
            all.dedup();
            all
        };
        let out_index: std::collections::HashMap<[i32; 4], usize> =
            outputs.iter().enumerate().map(|(r, &c)| (c, r)).collect();
        let centre = submanifold.then_some(geometry.volume() / 2);
        (0..geometry.volume())
            .filter(|&k| Some(k) != centre)
            .map(|k| {
                let d = geometry.offset(k);
                let (mut input, mut output) = (Vec::new(), Vec::new());
                if submanifold {
                    for (o, c) in outputs.iter().enumerate() {
                        let at = [0, 1, 2].map(|a| c[a + 1] + d[a] - geometry.padding[a] as i32);
                        if let Some(&i) = index.get(&[c[0], at[0], at[1], at[2]]) {
                            input.push(i as i64);
                            output.push(o as i64);
                        }
                    }
                } else {
                    for (i, c) in sites.coords().iter().enumerate() {
                        let n: [i32; 3] =
                            std::array::from_fn(|a| c[a + 1] + geometry.padding[a] as i32 - d[a]);
                        let s = geometry.stride.map(|s| s as i32);
                        if (0..3).all(|a| n[a] >= 0 && n[a] % s[a] == 0) {
                            let o = [c[0], n[0] / s[0], n[1] / s[1], n[2] / s[2]];
                            if let Some(&o) = out_index.get(&o) {
                                input.push(i as i64);
                                output.push(o as i64);
                            }
                        }
                    }
                }
                // A submanifold kernel's offsets after the centre list their pairs as their
                // mirrors before it found them: by input row (the build's order since the
                // first CPU results).
                if submanifold && Some(k) > centre {
                    let mut by_input: Vec<(i64, i64)> = input.into_iter().zip(output).collect();
                    by_input.sort();
                    (input, output) = by_input.into_iter().unzip();
                }
                (k, input, output)
            })
            .filter(|(_, input, _)| !input.is_empty())
            .collect()
    }

    /// Random clustered sites in random row order (a pseudo-random walk, seeded): grids
    /// whose edges the clusters touch, two batch items.
    fn random_sites(seed: u64, shape: [usize; 3], count: usize) -> SparseSites {
        let mut state = seed;
        let mut next = move |n: usize| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as usize) % n
        };
        let mut seen = std::collections::HashSet::new();
        let mut coords = Vec::new();
        let mut at = [0i32; 4];
        while coords.len() < count {
            if next(8) == 0 {
                at = [
                    next(2) as i32,
                    next(shape[0]) as i32,
                    next(shape[1]) as i32,
                    next(shape[2]) as i32,
                ];
            } else {
                let a = 1 + next(3);
                at[a] = (at[a] + next(3) as i32 - 1).clamp(0, shape[a - 1] as i32 - 1);
            }
            if seen.insert(at) {
                coords.push(at);
            }
        }
        SparseSites::new(coords, shape, 2).unwrap()
    }

    /// The index walk finds exactly the pairs a direct search finds, in the same order,
    /// for submanifold and strided geometries, with sites in random row order and at the
    /// grid's edges (where a shifted index would wrap into another row).
    #[test]
    fn rulebooks_list_the_pairs_a_direct_search_finds() {
        let device = Device::flex();
        let strided = [
            ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
            ConvGeometry::strided([3; 3], [2; 3], [0, 1, 1]),
            ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3]),
            ConvGeometry::strided([2, 3, 3], [1, 2, 2], [0, 1, 1]),
        ];
        for (seed, shape) in [(1, [5, 9, 7]), (2, [1, 4, 30]), (3, [11, 6, 6])] {
            let count = shape.iter().product::<usize>() / 3;
            let sites = Arc::new(random_sites(seed, shape, count));
            for kernel in [[3; 3], [1, 3, 5], [5, 1, 3]] {
                let book = Rulebook::submanifold_in(&sites, kernel, RuleLayout::PerOffset, &device);
                let (_, rules) = per_offset(&book);
                assert_eq!(
                    rules,
                    reference_pairs(&sites, ConvGeometry::same(kernel), true),
                    "submanifold {kernel:?} on {shape:?}"
                );
            }
            for geometry in strided {
                let book = Rulebook::strided_in(&sites, geometry, RuleLayout::PerOffset, &device);
                let (_, rules) = per_offset(&book);
                assert_eq!(
                    rules,
                    reference_pairs(&sites, geometry, false),
                    "strided {geometry:?} on {shape:?}"
                );
                let mut sorted = book.output.coords().to_vec();
                sorted.sort();
                assert_eq!(sorted, book.output.coords(), "outputs in batch-major order");
                for (row, &c) in book.output.coords().iter().enumerate() {
                    assert_eq!(book.output.row(c), Some(row));
                }
            }
        }
    }
}
