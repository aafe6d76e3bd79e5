//! Rulebooks: for each kernel offset, the (input row, output row) pairs a sparse
//! convolution multiplies by that offset's weight. Built once per layer shape from the
//! sites, then shared by every layer of that shape (all submanifold layers of a backbone
//! stage share one).

use super::sites::SparseSites;
use burn::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

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

/// Everything a sparse convolution of one geometry needs on given input sites.
#[derive(Debug, Clone)]
pub struct Rulebook {
    pub geometry: ConvGeometry,
    /// Output sites = input sites (stride 1, same padding).
    pub submanifold: bool,
    pub input_rows: usize,
    pub output: Arc<SparseSites>,
    /// The offset whose pairs are every row onto itself (a submanifold kernel's centre):
    /// a plain matrix product, no gather or scatter.
    pub identity_offset: Option<usize>,
    /// The other offsets that have pairs, in offset order.
    pub rules: Vec<OffsetRule>,
}

impl Rulebook {
    /// A submanifold convolution's rulebook: output sites are the input sites, and an
    /// output reads only active inputs of its neighbourhood, so sparsity does not dilate.
    pub fn submanifold(sites: &Arc<SparseSites>, kernel: [usize; 3], device: &Device) -> Rulebook {
        let geometry = ConvGeometry::same(kernel);
        let volume = geometry.volume();
        let centre = volume / 2;
        // Offset k and its mirror `volume − 1 − k` pair the same sites the other way round
        // (o reads i at +d exactly when i reads o at −d), so only the offsets before the
        // centre are looked up: half the hash lookups.
        let half: Vec<(usize, Vec<i64>, Vec<i64>)> = (0..centre)
            .into_par_iter()
            .map(|k| {
                let d = geometry.offset(k);
                let p = geometry.padding.map(|p| p as i32);
                let (mut input, mut output) = (Vec::new(), Vec::new());
                for (o, c) in sites.coords().iter().enumerate() {
                    let at = [
                        c[0],
                        c[1] + d[0] - p[0],
                        c[2] + d[1] - p[1],
                        c[3] + d[2] - p[2],
                    ];
                    if let Some(i) = sites.row(at) {
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
        Rulebook {
            geometry,
            submanifold: true,
            input_rows: sites.len(),
            output: sites.clone(),
            identity_offset: (!sites.is_empty()).then_some(centre),
            rules: to_rules(pairs, device),
        }
    }

    /// A regular (strided) convolution's rulebook: an output site is active when any
    /// input site lies in its receptive field. Output sites are listed in batch-major
    /// (b, z, y, x) order, so the result does not depend on the order of the input rows.
    pub fn strided(sites: &SparseSites, geometry: ConvGeometry, device: &Device) -> Rulebook {
        let out_shape = geometry.output_shape(sites.spatial_shape());
        let volume = geometry.volume();
        // The output site offset `k` of input site `c` feeds, if any.
        let target = |c: &[i32; 4], k: usize| -> Option<[i32; 4]> {
            let d = geometry.offset(k);
            let mut o = [c[0], 0, 0, 0];
            for a in 0..3 {
                let n = c[a + 1] + geometry.padding[a] as i32 - d[a];
                let s = geometry.stride[a] as i32;
                if n < 0 || n % s != 0 || (n / s) as usize >= out_shape[a] {
                    return None;
                }
                o[a + 1] = n / s;
            }
            Some(o)
        };
        let mut outputs: Vec<[i32; 4]> = sites
            .coords()
            .par_iter()
            .flat_map_iter(|c| (0..volume).filter_map(move |k| target(c, k)))
            .collect();
        outputs.par_sort_unstable();
        outputs.dedup();
        let output = Arc::new(
            SparseSites::new(outputs, out_shape, sites.batch_size())
                .expect("output sites are in bounds and distinct by construction"),
        );
        let pairs: Vec<(usize, Vec<i64>, Vec<i64>)> = (0..volume)
            .into_par_iter()
            .map(|k| {
                let (mut input, mut out_rows) = (Vec::new(), Vec::new());
                for (i, c) in sites.coords().iter().enumerate() {
                    if let Some(o) = target(c, k) {
                        input.push(i as i64);
                        out_rows.push(output.row(o).expect("every target is an output") as i64);
                    }
                }
                (k, input, out_rows)
            })
            .collect();
        Rulebook {
            geometry,
            submanifold: false,
            input_rows: sites.len(),
            output,
            identity_offset: None,
            rules: to_rules(pairs, device),
        }
    }

    pub fn output_rows(&self) -> usize {
        self.output.len()
    }

    /// All (input, output) pairs, the identity offset's included: a convolution over
    /// these sites costs `pairs · C_in · C_out` multiply-adds.
    pub fn total_pairs(&self) -> usize {
        self.rules.iter().map(|r| r.pairs).sum::<usize>()
            + self.identity_offset.map_or(0, |_| self.input_rows)
    }
}

fn to_rules(pairs: Vec<(usize, Vec<i64>, Vec<i64>)>, device: &Device) -> Vec<OffsetRule> {
    pairs
        .into_iter()
        .filter(|(_, input, _)| !input.is_empty())
        .map(|(offset, input, output)| {
            let n = input.len();
            OffsetRule {
                offset,
                pairs: n,
                input: Tensor::from_data(TensorData::new(input, [n]), device),
                output: Tensor::from_data(TensorData::new(output, [n]), device),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(t: &Tensor<1, Int>) -> Vec<i64> {
        t.clone()
            .into_data()
            .convert::<i64>()
            .try_to_vec::<i64>()
            .unwrap()
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
        let book = Rulebook::submanifold(&sites, [3, 3, 3], &device);
        assert_eq!(book.identity_offset, Some(13));
        // Offset (1,1,2) = 14 reads x+1: row 0 reads row 1. Offset 12 reads x−1: row 1 reads row 0.
        let rules: Vec<(usize, Vec<i64>, Vec<i64>)> = book
            .rules
            .iter()
            .map(|r| (r.offset, rows(&r.input), rows(&r.output)))
            .collect();
        assert_eq!(rules, vec![(12, vec![0], vec![1]), (14, vec![1], vec![0])]);
        assert_eq!(book.total_pairs(), 4 + 2);
    }

    #[test]
    fn strided_outputs_cover_receptive_fields_in_order() {
        let device = Device::flex();
        let sites = SparseSites::new(vec![[0, 0, 0, 3], [0, 0, 0, 0]], [1, 1, 4], 1).unwrap();
        // Kernel 3 along x, stride 2, padding 1: output x=o reads inputs 2o−1, 2o, 2o+1.
        let book = Rulebook::strided(
            &sites,
            ConvGeometry::strided([1, 1, 3], [1, 1, 2], [0, 0, 1]),
            &device,
        );
        assert_eq!(book.output.spatial_shape(), [1, 1, 2]);
        // Input x=0 feeds output 0 (k=1); x=3 feeds output 1 (k=2) and output 2 (out of range).
        assert_eq!(book.output.coords(), &[[0, 0, 0, 0], [0, 0, 0, 1]]);
        let rules: Vec<(usize, Vec<i64>, Vec<i64>)> = book
            .rules
            .iter()
            .map(|r| (r.offset, rows(&r.input), rows(&r.output)))
            .collect();
        assert_eq!(rules, vec![(1, vec![1], vec![0]), (2, vec![0], vec![1])]);
    }
}
