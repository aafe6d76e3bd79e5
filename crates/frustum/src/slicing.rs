//! Cutting a frustum into sub-frustums along its depth axis (the frustum frame's z),
//! and the ragged (point, sub-frustum) membership lists.
//!
//! The strategy is pluggable: [`SliceStrategy`] turns a frustum's context (its 2D
//! box, class, focal length, depth range) into the depth intervals of every scale.
//! F-ConvNet's [`UniformSlicing`] ignores the box; SAF's depth-guided slicing will be
//! another variant of [`Slicing`] that reads `box2d.height()`, `focal_v` and the
//! class's mean height from the same [`SliceContext`] to place one near-region
//! sub-frustum of length ω·L_depth (L_depth = f·H/h₀) and T − 1 sub-frustums over the
//! rest. Everything downstream (membership, centres, batching, targets) only sees the
//! [`ScaleLayout`]s and needs no change, as long as every frustum gets the same
//! number of sub-frustums per scale (the batch arrays need fixed counts).

use crate::error::{FrustumError, Result};
use fusiondet_kitti::{Box2d, ObjectClass};
use serde::{Deserialize, Serialize};

/// One sub-frustum: the depth interval `[center − half_length, center + half_length]`
/// along the frustum axis (both ends included).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SliceInterval {
    pub center: f64,
    pub half_length: f64,
}

impl SliceInterval {
    pub fn contains(&self, depth: f64) -> bool {
        (depth - self.center).abs() <= self.half_length
    }
}

/// The sub-frustums of one scale of one frustum.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleLayout {
    pub slices: Vec<SliceInterval>,
    /// At most this many points per sub-frustum.
    pub max_points: usize,
}

/// What a strategy may use to place the sub-frustums of one frustum.
#[derive(Debug, Clone, Copy)]
pub struct SliceContext<'a> {
    /// [min, max] depth of the frustum in metres.
    pub depth_range: [f64; 2],
    /// The class of the frustum's 2D box.
    pub class: ObjectClass,
    /// The frustum's (clipped) 2D box in pixels.
    pub box2d: &'a Box2d,
    /// Vertical focal length of P2 in pixels.
    pub focal_v: f64,
}

/// Places sub-frustums. Implementations must give every frustum the same number of
/// sub-frustums per scale ([`SliceStrategy::slices_per_scale`]) and return the
/// intervals of a scale sorted by centre.
pub trait SliceStrategy {
    fn num_scales(&self) -> usize;
    /// Sub-frustums per scale, finest first.
    fn slices_per_scale(&self, depth_range: [f64; 2]) -> Vec<usize>;
    /// Cap on points per sub-frustum, per scale.
    fn max_points_per_scale(&self) -> Vec<usize>;
    /// The intervals of every scale for one frustum.
    fn layout(&self, ctx: &SliceContext<'_>) -> Vec<ScaleLayout>;
    /// Checks the parameters against the depth range.
    fn validate(&self, depth_range: [f64; 2]) -> Result<()>;
}

/// The configured slicing strategy (`kind = "uniform"` in TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Slicing {
    /// F-ConvNet: fixed stride and length per scale.
    Uniform(UniformSlicing),
}

impl SliceStrategy for Slicing {
    fn num_scales(&self) -> usize {
        match self {
            Slicing::Uniform(s) => s.num_scales(),
        }
    }
    fn slices_per_scale(&self, depth_range: [f64; 2]) -> Vec<usize> {
        match self {
            Slicing::Uniform(s) => s.slices_per_scale(depth_range),
        }
    }
    fn max_points_per_scale(&self) -> Vec<usize> {
        match self {
            Slicing::Uniform(s) => s.max_points_per_scale(),
        }
    }
    fn layout(&self, ctx: &SliceContext<'_>) -> Vec<ScaleLayout> {
        match self {
            Slicing::Uniform(s) => s.layout(ctx),
        }
    }
    fn validate(&self, depth_range: [f64; 2]) -> Result<()> {
        match self {
            Slicing::Uniform(s) => s.validate(depth_range),
        }
    }
}

/// F-ConvNet's sliding sub-frustums: at scale `s`, sub-frustum `k` is centred at
/// depth `min + (k + ½)·stride[s]` and spans `length[s]` (twice the stride in the
/// paper: 50 % overlap). The count per scale is ⌈(max − min) / stride⌉, so the last
/// centre lies inside the range (as `np.arange(0, max, stride) + stride/2` does).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UniformSlicing {
    /// Metres between consecutive sub-frustum centres, per scale, finest first.
    pub strides: Vec<f64>,
    /// Length of each sub-frustum along depth, per scale.
    pub lengths: Vec<f64>,
    /// Cap on points per sub-frustum, per scale.
    pub max_points: Vec<usize>,
}

impl UniformSlicing {
    /// Lengths twice the strides (F-ConvNet).
    pub fn with_double_lengths(strides: &[f64], max_points: &[usize]) -> Self {
        UniformSlicing {
            strides: strides.to_vec(),
            lengths: strides.iter().map(|s| 2.0 * s).collect(),
            max_points: max_points.to_vec(),
        }
    }

    fn count(stride: f64, depth_range: [f64; 2]) -> usize {
        // The tolerance keeps 70 / 0.25 at 280 despite rounding.
        ((depth_range[1] - depth_range[0]) / stride - 1e-9)
            .ceil()
            .max(0.0) as usize
    }
}

impl SliceStrategy for UniformSlicing {
    fn num_scales(&self) -> usize {
        self.strides.len()
    }

    fn slices_per_scale(&self, depth_range: [f64; 2]) -> Vec<usize> {
        self.strides
            .iter()
            .map(|&s| Self::count(s, depth_range))
            .collect()
    }

    fn max_points_per_scale(&self) -> Vec<usize> {
        self.max_points.clone()
    }

    fn layout(&self, ctx: &SliceContext<'_>) -> Vec<ScaleLayout> {
        let lo = ctx.depth_range[0];
        self.strides
            .iter()
            .zip(&self.lengths)
            .zip(&self.max_points)
            .map(|((&stride, &length), &max_points)| ScaleLayout {
                slices: (0..Self::count(stride, ctx.depth_range))
                    .map(|k| SliceInterval {
                        center: lo + (k as f64 + 0.5) * stride,
                        half_length: 0.5 * length,
                    })
                    .collect(),
                max_points,
            })
            .collect()
    }

    fn validate(&self, depth_range: [f64; 2]) -> Result<()> {
        let n = self.strides.len();
        if n == 0 {
            return Err(FrustumError::Config("`slicing.strides` is empty".into()));
        }
        if self.lengths.len() != n || self.max_points.len() != n {
            return Err(FrustumError::Config(format!(
                "`slicing`: {n} strides but {} lengths and {} max_points; give one of each per scale",
                self.lengths.len(),
                self.max_points.len()
            )));
        }
        for (s, (&stride, &length)) in self.strides.iter().zip(&self.lengths).enumerate() {
            if !(stride.is_finite() && stride > 0.0 && length.is_finite() && length > 0.0) {
                return Err(FrustumError::Config(format!(
                    "`slicing` scale {s}: stride {stride} and length {length} must be positive"
                )));
            }
        }
        if let Some(s) = self.max_points.iter().position(|&m| m == 0) {
            return Err(FrustumError::Config(format!(
                "`slicing.max_points` scale {s} is 0"
            )));
        }
        if self.slices_per_scale(depth_range).contains(&0) {
            return Err(FrustumError::Config(
                "`slicing`: a scale has no sub-frustum in the depth range".into(),
            ));
        }
        Ok(())
    }
}

/// Point indices sorted by depth (ties by index), shared by all scales of a frustum.
pub fn depth_order(depths: &[f64]) -> Vec<u32> {
    // Sorts (key, index) pairs where the key orders like `f64::total_cmp` (the same
    // bit trick): no indirect comparator, ties by index.
    let mut keyed: Vec<(i64, u32)> = depths
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let bits = d.to_bits() as i64;
            (bits ^ ((((bits >> 63) as u64) >> 1) as i64), i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// The (point, sub-frustum) pairs of one scale: every point whose depth lies within
/// a sub-frustum's interval, at most `max_points` per sub-frustum (the lowest point
/// indices, i.e. the first in sampled order), sorted by sub-frustum and then point.
/// `order` is [`depth_order`] of `depths`.
pub fn slice_pairs(
    depths: &[f64],
    order: &[u32],
    slices: &[SliceInterval],
    max_points: usize,
) -> (Vec<u32>, Vec<u32>) {
    let mut pair_point = Vec::with_capacity(2 * depths.len());
    let mut pair_slice = Vec::with_capacity(2 * depths.len());
    let mut members: Vec<u32> = Vec::new();
    for (k, s) in slices.iter().enumerate() {
        let (lo, hi) = (s.center - s.half_length, s.center + s.half_length);
        let a = order.partition_point(|&i| depths[i as usize] < lo);
        let b = order.partition_point(|&i| depths[i as usize] <= hi);
        if b <= a {
            continue;
        }
        members.clear();
        members.extend_from_slice(&order[a..b]);
        if members.len() > max_points {
            members.select_nth_unstable(max_points);
            members.truncate(max_points);
        }
        members.sort_unstable();
        pair_point.extend_from_slice(&members);
        pair_slice.extend(std::iter::repeat_n(k as u32, members.len()));
    }
    (pair_point, pair_slice)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(b: &Box2d) -> SliceContext<'_> {
        SliceContext {
            depth_range: [0.0, 70.0],
            class: ObjectClass::Car,
            box2d: b,
            focal_v: 721.0,
        }
    }

    fn car() -> UniformSlicing {
        UniformSlicing::with_double_lengths(&[0.25, 0.5, 1.0, 2.0], &[32, 64, 64, 128])
    }

    #[test]
    fn car_layout_has_published_counts_and_centres() {
        let b = Box2d::default();
        let layout = car().layout(&ctx(&b));
        let counts: Vec<usize> = layout.iter().map(|l| l.slices.len()).collect();
        assert_eq!(counts, [280, 140, 70, 35]);
        assert_eq!(car().slices_per_scale([0.0, 70.0]), counts);
        assert_eq!(
            layout[1].slices[0],
            SliceInterval {
                center: 0.25,
                half_length: 0.5
            }
        );
        assert_eq!(
            layout[3].slices[34],
            SliceInterval {
                center: 69.0,
                half_length: 2.0
            }
        );
        // Non-multiple ranges round up like np.arange.
        assert_eq!(car().slices_per_scale([0.0, 69.9]), [280, 140, 70, 35]);
        assert_eq!(car().slices_per_scale([0.0, 70.1]), [281, 141, 71, 36]);
    }

    #[test]
    fn pairs_are_exactly_the_points_within_each_interval_capped_by_index() {
        // 500 points at pseudo-random depths, some exactly on interval ends.
        let depths: Vec<f64> = (0..500)
            .map(|i| {
                if i % 50 == 0 {
                    0.25 * (i / 50) as f64
                } else {
                    ((i * 7919) % 1000) as f64 * 0.007
                }
            })
            .collect();
        let order = depth_order(&depths);
        let slices: Vec<SliceInterval> = (0..14)
            .map(|k| SliceInterval {
                center: 0.25 + 0.5 * k as f64,
                half_length: 0.5,
            })
            .collect();
        for cap in [3, 64, 1000] {
            let (pp, ps) = slice_pairs(&depths, &order, &slices, cap);
            assert_eq!(pp.len(), ps.len());
            assert!(ps.windows(2).all(|w| w[0] <= w[1]), "sorted by slice");
            for (k, s) in slices.iter().enumerate() {
                let expect: Vec<u32> = (0..depths.len() as u32)
                    .filter(|&i| s.contains(depths[i as usize]))
                    .take(cap)
                    .collect();
                let got: Vec<u32> = pp
                    .iter()
                    .zip(&ps)
                    .filter(|(_, q)| **q == k as u32)
                    .map(|(p, _)| *p)
                    .collect();
                assert_eq!(got, expect, "slice {k} cap {cap}");
            }
        }
    }

    #[test]
    fn depth_order_sorts_by_depth_then_index() {
        let d = [3.0, -1.0, 0.0, -0.0, 3.0, 1e-300, -2.5, 70.0];
        let order = depth_order(&d);
        let mut expect: Vec<u32> = (0..d.len() as u32).collect();
        expect.sort_by(|&a, &b| d[a as usize].total_cmp(&d[b as usize]).then(a.cmp(&b)));
        assert_eq!(order, expect);
        assert_eq!(order, [6, 1, 3, 2, 5, 0, 4, 7]);
    }

    #[test]
    fn validation_names_the_problem() {
        let mut s = car();
        s.lengths.pop();
        assert!(
            s.validate([0.0, 70.0])
                .unwrap_err()
                .to_string()
                .contains("3 lengths")
        );
        let mut s = car();
        s.strides[2] = 0.0;
        assert!(
            s.validate([0.0, 70.0])
                .unwrap_err()
                .to_string()
                .contains("scale 2")
        );
        assert!(car().validate([0.0, 70.0]).is_ok());
    }
}
