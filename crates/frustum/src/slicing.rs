//! Cutting a frustum into sub-frustums along its depth axis (the frustum frame's z),
//! and the ragged (point, sub-frustum) membership lists.
//!
//! The strategy is pluggable: [`SliceStrategy`] turns a frustum's context (its 2D
//! box, class, focal length, depth range) into the depth intervals of every scale.
//! F-ConvNet's [`UniformSlicing`] ignores the box; SAF's [`DepthGuidedSlicing`] reads
//! `box2d.height()`, `focal_v` and the class's mean height to place one near-region
//! sub-frustum of length ω·L_depth (L_depth = f·H/h₀) and n − 1 sub-frustums over the
//! rest. Everything downstream (membership, centres, batching, targets) only sees the
//! [`ScaleLayout`]s, so nothing there assumes even spacing; every frustum must get the
//! same number of sub-frustums per scale (the batch arrays need fixed counts).

use crate::error::{FrustumError, Result};
use fusiondet_dataset::Class;
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

    /// The interval from `start` to `end`, its half length widened by the rounding of
    /// the centre so that both ends are inside (by [`Self::contains`] and by the
    /// `center ± half_length` bounds [`slice_pairs`] uses): intervals built from
    /// shared ends then leave no depth uncovered between them.
    pub fn spanning(start: f64, end: f64) -> SliceInterval {
        let mut iv = SliceInterval {
            center: 0.5 * (start + end),
            half_length: 0.5 * (end - start),
        };
        let inside = |iv: &SliceInterval, d: f64| {
            iv.contains(d) && iv.center - iv.half_length <= d && d <= iv.center + iv.half_length
        };
        // Finite ends are inside after a few ulps; NaN or infinite ends never are.
        while start.is_finite() && end.is_finite() && !(inside(&iv, start) && inside(&iv, end)) {
            iv.half_length = iv.half_length.next_up();
        }
        iv
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
    pub class: Class,
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

/// The configured slicing strategy (`kind = "uniform"` or `kind = "depth_guided"` in
/// TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Slicing {
    /// F-ConvNet: fixed stride and length per scale.
    Uniform(UniformSlicing),
    /// SAF: a near region sized from the 2D box, even sub-frustums behind it.
    DepthGuided(DepthGuidedSlicing),
}

impl Slicing {
    fn strategy(&self) -> &dyn SliceStrategy {
        match self {
            Slicing::Uniform(s) => s,
            Slicing::DepthGuided(s) => s,
        }
    }

    /// Per sub-frustum of one scale (`slices`, as laid out), the factor that multiplies
    /// a point's depth relative to the sub-frustum's centre; empty = 1 everywhere (the
    /// published models). Only depth-guided slicing with `compress_near_depth` has one:
    /// the near sub-frustum's is the regular half-length over its own when it is longer
    /// than the rest, 1 otherwise.
    pub fn relative_depth_gains(&self, slices: &[SliceInterval]) -> Vec<f64> {
        match self {
            Slicing::DepthGuided(d) if d.compress_near_depth && slices.len() >= 2 => {
                let regular = slices[slices.len() - 1].half_length;
                let near = slices[0].half_length;
                let mut gains = vec![1.0; slices.len()];
                if near > regular {
                    gains[0] = regular / near;
                }
                gains
            }
            _ => Vec::new(),
        }
    }
}

impl SliceStrategy for Slicing {
    fn num_scales(&self) -> usize {
        self.strategy().num_scales()
    }
    fn slices_per_scale(&self, depth_range: [f64; 2]) -> Vec<usize> {
        self.strategy().slices_per_scale(depth_range)
    }
    fn max_points_per_scale(&self) -> Vec<usize> {
        self.strategy().max_points_per_scale()
    }
    fn layout(&self, ctx: &SliceContext<'_>) -> Vec<ScaleLayout> {
        self.strategy().layout(ctx)
    }
    fn validate(&self, depth_range: [f64; 2]) -> Result<()> {
        self.strategy().validate(depth_range)
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

/// Class mean heights H in metres, for the coarse depth L_depth = f·H/h₀. Car is
/// SAF's 1.56 m; Pedestrian and Cyclist are the KITTI training-label means
/// (F-ConvNet's mean sizes: 1.7626 m and 1.7370 m, to two decimals). Re-derive them
/// from your own labels when training on other data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MeanHeights {
    pub car: f64,
    pub pedestrian: f64,
    pub cyclist: f64,
}

impl Default for MeanHeights {
    fn default() -> Self {
        MeanHeights {
            car: 1.56,
            pedestrian: 1.76,
            cyclist: 1.74,
        }
    }
}

impl MeanHeights {
    /// The mean height of a class; `None` for classes without one (the frustum
    /// config only admits Car, Pedestrian and Cyclist).
    pub fn of(&self, class: Class) -> Option<f64> {
        match class {
            Class::Kitti(ObjectClass::Car) => Some(self.car),
            Class::Kitti(ObjectClass::Pedestrian) => Some(self.pedestrian),
            Class::Kitti(ObjectClass::Cyclist) => Some(self.cyclist),
            _ => None,
        }
    }
}

/// 2D boxes shorter than this (pixels) count as this tall in L_depth = f·H/h₀, so a
/// degenerate box gives a large but finite depth (which the near-region clamp caps).
pub const MIN_BOX_HEIGHT_PX: f64 = 1.0;

/// The near region never covers more than this fraction of the depth range, so an
/// overestimated L_depth (a box cut short by occlusion or the image border) still
/// leaves room for the n − 1 sub-frustums that localise the object.
pub const MAX_NEAR_FRACTION: f64 = 0.9;

/// Default ω, by [`mod@crate::omega_study`]'s rule (the largest candidate losing < 1 % of
/// the objects' own points to the near region) on the bundled KITTI frames: 8 cars,
/// 40 jittered 2D boxes each, lose nothing up to ω = 0.85 and 1–2 % at 0.9 (seeds 0
/// and 1). Eight cars are few: re-run the study on your training split.
pub const DEFAULT_OMEGA: f64 = 0.85;

/// SAF's coarse object depth from its 2D box: L_depth = f·H/h₀ with `focal_v` the
/// vertical focal length in pixels, `mean_height` H in metres and `box_height` h₀ in
/// pixels (at least [`MIN_BOX_HEIGHT_PX`]). This is camera depth (z); the frustum
/// depth of an off-axis object is larger by 1/cos φ. A near object's box is also
/// taller than f·H/z (faces at several depths show), e.g. 10.9 m for the car 13.3 m
/// away in KITTI frame 000003: the estimate mostly runs short, hence ω < 1.
pub fn coarse_depth(focal_v: f64, mean_height: f64, box_height: f64) -> f64 {
    focal_v * mean_height / box_height.max(MIN_BOX_HEIGHT_PX)
}

/// SAF's depth-guided sub-frustums (He et al., "Spatial Attention Frustum", Sensors
/// 2022). Scale s has n = T / 2^s sub-frustums (Car: T = 240 → 240/120/60/30). With
/// [d_min, d_max] the depth range, L_pc = d_max − d_min and a = ω·L_depth clamped to
/// [0, [`MAX_NEAR_FRACTION`]·L_pc]:
///
/// - sub-frustum 0, the "not interesting" near region, is exactly [d_min, d_min + a]
///   (centre d_min + a/2);
/// - sub-frustums k = 1 … n − 1 have step s = (L_pc − a)/n and length 2s, centred at
///   d_min + a + k·s, i.e. covering [d_min + a + (k − 1)·s, d_min + a + (k + 1)·s].
///
/// With the paper's counts (n − 1 intervals of length 2s at step s, n·s = L_pc − a)
/// this centre placement is the one where they tile the rest exactly: the first
/// starts where the near region ends, the last ends at d_max, and every depth but
/// the first and last step lies in two of them (F-ConvNet's 50 % overlap).
/// F-ConvNet's (k + ½)·s placement would leave the last s/2 before d_max uncovered
/// (about 1 m at the coarsest Car scale).
///
/// L_depth is a distance from the camera while the near region starts at d_min; the
/// two agree for d_min = 0, as in every preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthGuidedSlicing {
    /// T: sub-frustums at the finest scale; each coarser scale has half as many, so T
    /// must be divisible by 2^(scales − 1).
    pub slices: usize,
    /// ω: the near region's length as a fraction of L_depth, in [0, 1).
    pub omega: f64,
    /// Cap on points per sub-frustum, per scale (this also sets the number of scales).
    pub max_points: Vec<usize>,
    pub mean_heights: MeanHeights,
    /// Compress the depths of points relative to a near sub-frustum longer than the
    /// scale's regular ones by regular / near length, so that its relative depths span
    /// what every other sub-frustum's do (the PointNets' batch norm is shared by all
    /// sub-frustums of a scale). `false` = the paper (metres throughout).
    pub compress_near_depth: bool,
}

impl Default for DepthGuidedSlicing {
    fn default() -> Self {
        DepthGuidedSlicing::saf_car()
    }
}

impl DepthGuidedSlicing {
    /// SAF's Car model: T = 240 (240/120/60/30 sub-frustums), at most 32/64/64/128
    /// points each, ω = [`DEFAULT_OMEGA`].
    pub fn saf_car() -> Self {
        DepthGuidedSlicing {
            slices: 240,
            omega: DEFAULT_OMEGA,
            max_points: vec![32, 64, 64, 128],
            mean_heights: MeanHeights::default(),
            compress_near_depth: false,
        }
    }

    /// L_depth of one frustum ([`coarse_depth`] with its class's mean height).
    ///
    /// # Panics
    /// For classes without a mean height (see [`MeanHeights::of`]).
    pub fn coarse_depth(&self, ctx: &SliceContext<'_>) -> f64 {
        let h = self
            .mean_heights
            .of(ctx.class)
            .unwrap_or_else(|| panic!("depth-guided slicing has no mean height for {}", ctx.class));
        coarse_depth(ctx.focal_v, h, ctx.box2d.height())
    }

    /// a = ω·L_depth clamped to [0, [`MAX_NEAR_FRACTION`]·L_pc]: the length of the
    /// near region, the same at every scale.
    pub fn near_length(&self, ctx: &SliceContext<'_>) -> f64 {
        let range = ctx.depth_range[1] - ctx.depth_range[0];
        let a = self.omega * self.coarse_depth(ctx);
        // `max` first: a NaN product (never from a validated config) becomes 0.
        a.max(0.0).min(MAX_NEAR_FRACTION * range)
    }

    /// The intervals of one scale with `n` sub-frustums, for a near region of length
    /// `near` (see the type's documentation). Neighbours are built from the same
    /// computed ends ([`SliceInterval::spanning`]), the last ending at exactly d_max,
    /// so every depth of the range lies in some interval despite rounding.
    pub fn scale_slices(depth_range: [f64; 2], near: f64, n: usize) -> Vec<SliceInterval> {
        let [lo, hi] = depth_range;
        let base = lo + near;
        let step = (hi - base) / n as f64;
        // e_j = d_min + a + j·s, with e_n = d_max exactly.
        let end = |j: usize| if j >= n { hi } else { base + j as f64 * step };
        let mut slices = Vec::with_capacity(n);
        slices.push(SliceInterval::spanning(lo, base));
        slices.extend((1..n).map(|k| SliceInterval::spanning(end(k - 1), end(k + 1))));
        slices
    }
}

impl SliceStrategy for DepthGuidedSlicing {
    fn num_scales(&self) -> usize {
        self.max_points.len()
    }

    fn slices_per_scale(&self, _depth_range: [f64; 2]) -> Vec<usize> {
        (0..self.num_scales() as u32)
            .map(|s| self.slices.checked_shr(s).unwrap_or(0))
            .collect()
    }

    fn max_points_per_scale(&self) -> Vec<usize> {
        self.max_points.clone()
    }

    fn layout(&self, ctx: &SliceContext<'_>) -> Vec<ScaleLayout> {
        let near = self.near_length(ctx);
        self.slices_per_scale(ctx.depth_range)
            .into_iter()
            .zip(&self.max_points)
            .map(|(n, &max_points)| ScaleLayout {
                slices: Self::scale_slices(ctx.depth_range, near, n),
                max_points,
            })
            .collect()
    }

    fn validate(&self, _depth_range: [f64; 2]) -> Result<()> {
        let bad = |m: String| Err(FrustumError::Config(m));
        let scales = self.max_points.len();
        if scales == 0 {
            return bad(
                "`slicing.max_points` is empty; give one cap per scale, e.g. [32, 64, 64, 128]"
                    .into(),
            );
        }
        if let Some(s) = self.max_points.iter().position(|&m| m == 0) {
            return bad(format!("`slicing.max_points` scale {s} is 0"));
        }
        let t = self.slices;
        let halvings = 1usize.checked_shl(scales as u32 - 1).unwrap_or(0);
        if halvings == 0 || !t.is_multiple_of(halvings) {
            return bad(format!(
                "`slicing.slices` = {t} must be divisible by {halvings}: each of the {scales} \
                 scales has half the sub-frustums of the previous one (e.g. 240 → 240/120/60/30)"
            ));
        }
        if t / halvings < 2 {
            return bad(format!(
                "`slicing.slices` = {t} leaves {} sub-frustum(s) at the coarsest scale; it needs \
                 the near region plus at least one more, so use slices >= {}",
                t / halvings,
                2 * halvings
            ));
        }
        if !(self.omega.is_finite() && (0.0..1.0).contains(&self.omega)) {
            return bad(format!(
                "`slicing.omega` = {} must be in [0, 1): the near region ω·L_depth has to end \
                 before the object's estimated depth L_depth",
                self.omega
            ));
        }
        let m = self.mean_heights;
        for (name, h) in [
            ("car", m.car),
            ("pedestrian", m.pedestrian),
            ("cyclist", m.cyclist),
        ] {
            if !(h.is_finite() && h > 0.0) {
                return bad(format!(
                    "`slicing.mean_heights.{name}` = {h} must be a positive height in metres"
                ));
            }
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
            class: ObjectClass::Car.into(),
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

    fn saf_ctx(b: &Box2d, class: ObjectClass, range: [f64; 2]) -> SliceContext<'_> {
        let class = Class::Kitti(class);
        SliceContext {
            depth_range: range,
            class,
            box2d: b,
            focal_v: 720.0,
        }
    }

    fn tall(h: f64) -> Box2d {
        Box2d {
            x1: 500.0,
            y1: 150.0,
            x2: 600.0,
            y2: 150.0 + h,
        }
    }

    fn saf(omega: f64) -> DepthGuidedSlicing {
        DepthGuidedSlicing {
            omega,
            ..DepthGuidedSlicing::saf_car()
        }
    }

    #[test]
    fn depth_guided_has_the_published_counts_and_caps() {
        let s = DepthGuidedSlicing::saf_car();
        s.validate([0.0, 75.0]).unwrap();
        assert_eq!(s.slices_per_scale([0.0, 75.0]), [240, 120, 60, 30]);
        assert_eq!(s.max_points_per_scale(), [32, 64, 64, 128]);
        // The counts do not depend on the box (the batch arrays need fixed counts).
        for h in [0.0, 3.0, 30.0, 300.0] {
            let b = tall(h);
            let layout = s.layout(&saf_ctx(&b, ObjectClass::Car, [0.0, 75.0]));
            let counts: Vec<usize> = layout.iter().map(|l| l.slices.len()).collect();
            assert_eq!(counts, [240, 120, 60, 30], "box height {h}");
            let caps: Vec<usize> = layout.iter().map(|l| l.max_points).collect();
            assert_eq!(caps, [32, 64, 64, 128]);
        }
    }

    /// With `compress_near_depth`, a near sub-frustum longer than the regular ones gets
    /// gain regular / near (its relative depths then span a regular one's), every other
    /// sub-frustum 1; a short near one keeps 1; the published slicings have no gains.
    #[test]
    fn compressed_near_depth_gains_by_hand() {
        let b = tall(52.0); // L_depth = 21.6 m
        let ctx = saf_ctx(&b, ObjectClass::Car, [0.0, 75.0]);
        let gains_of = |s: DepthGuidedSlicing| {
            let slicing = Slicing::DepthGuided(s.clone());
            s.layout(&ctx)
                .iter()
                .map(|l| slicing.relative_depth_gains(&l.slices))
                .collect::<Vec<_>>()
        };
        assert!(gains_of(saf(0.55)).iter().all(Vec::is_empty));
        let compressed = |omega| DepthGuidedSlicing {
            compress_near_depth: true,
            ..saf(omega)
        };
        // ω = 0.5: near 10.8 m (half 5.4); at 240 slices the step is 64.2 / 240 m and the
        // regular half-length one step; at 30, 64.2 / 30.
        for (scale, gains) in gains_of(compressed(0.5)).iter().enumerate() {
            let n = 240 >> scale;
            let step = (75.0 - 10.8) / n as f64;
            assert_eq!(gains.len(), n);
            assert!(
                (gains[0] - step / 5.4).abs() < 1e-9,
                "scale {scale}: {}",
                gains[0]
            );
            assert!(gains[1..].iter().all(|&g| g == 1.0));
        }
        // ω = 0: an empty near region is not stretched.
        for gains in gains_of(compressed(0.0)) {
            assert!(gains.iter().all(|&g| g == 1.0));
        }
        let uniform = Slicing::Uniform(car());
        let layout = uniform.layout(&saf_ctx(&b, ObjectClass::Car, [0.0, 70.0]));
        assert!(uniform.relative_depth_gains(&layout[0].slices).is_empty());
    }

    #[test]
    fn coarse_depth_by_hand() {
        // 720 px · 1.56 m / 52 px = 21.6 m.
        assert!((coarse_depth(720.0, 1.56, 52.0) - 21.6).abs() < 1e-12);
        let s = saf(0.5);
        let (car, ped, cyc) = (tall(52.0), tall(88.0), tall(72.0));
        let l = |b, c| s.coarse_depth(&saf_ctx(b, c, [0.0, 75.0]));
        assert!((l(&car, ObjectClass::Car) - 21.6).abs() < 1e-12);
        // 720 · 1.76 / 88 = 14.4 and 720 · 1.74 / 72 = 17.4.
        assert!((l(&ped, ObjectClass::Pedestrian) - 14.4).abs() < 1e-12);
        assert!((l(&cyc, ObjectClass::Cyclist) - 17.4).abs() < 1e-12);
        // The near region is ω · L_depth.
        let near = s.near_length(&saf_ctx(&car, ObjectClass::Car, [0.0, 75.0]));
        assert!((near - 10.8).abs() < 1e-12);
    }

    #[test]
    fn near_interval_is_exactly_dmin_to_dmin_plus_omega_l_depth() {
        for range in [[0.0, 75.0], [2.0, 75.0], [0.0, 40.0]] {
            let b = tall(52.0); // L_depth = 21.6 m
            for omega in [0.0, 0.25, 0.5, 0.9] {
                let s = saf(omega);
                let layout = s.layout(&saf_ctx(&b, ObjectClass::Car, range));
                let a = omega * 21.6;
                for scale in &layout {
                    let near = scale.slices[0];
                    assert!((near.center - near.half_length - range[0]).abs() < 1e-12);
                    assert!(
                        (near.center + near.half_length - (range[0] + a)).abs() < 1e-12,
                        "{near:?} vs a = {a} in {range:?}"
                    );
                }
            }
        }
        // Exact in floating point for a representable case: L_depth = 720·1.5/54 = 20, ω = 0.5.
        let s = DepthGuidedSlicing {
            omega: 0.5,
            mean_heights: MeanHeights {
                car: 1.5,
                ..MeanHeights::default()
            },
            ..DepthGuidedSlicing::saf_car()
        };
        let b = tall(54.0);
        let layout = s.layout(&saf_ctx(&b, ObjectClass::Car, [2.0, 75.0]));
        assert_eq!(
            layout[0].slices[0],
            SliceInterval {
                center: 7.0,
                half_length: 5.0
            }
        );
    }

    #[test]
    fn the_rest_follows_the_step_and_length_formula() {
        let b = tall(52.0); // L_depth = 21.6 m
        let s = saf(0.5); // a = 10.8 m
        for range in [[0.0, 75.0], [2.0, 70.0]] {
            let layout = s.layout(&saf_ctx(&b, ObjectClass::Car, range));
            let a = 10.8;
            let rest = range[1] - range[0] - a;
            for scale in &layout {
                let n = scale.slices.len();
                let step = rest / n as f64;
                for (k, iv) in scale.slices.iter().enumerate().skip(1) {
                    // Length 2·(L_pc − a)/n, step (L_pc − a)/n, centre d_min + a + k·step.
                    assert!((2.0 * iv.half_length - 2.0 * rest / n as f64).abs() < 1e-12);
                    let c = range[0] + a + k as f64 * step;
                    assert!((iv.center - c).abs() < 1e-9, "scale {n} slice {k}");
                    assert!(iv.center > range[0] && iv.center < range[1]);
                }
                assert!(
                    scale.slices.windows(2).all(|w| w[0].center < w[1].center),
                    "sorted by centre"
                );
                for w in scale.slices[1..].windows(2) {
                    assert!((w[1].center - w[0].center - step).abs() < 1e-9);
                }
                // The n − 1 intervals tile [d_min + a, d_max] exactly.
                let first = scale.slices[1];
                let last = scale.slices[n - 1];
                assert!((first.center - first.half_length - (range[0] + a)).abs() < 1e-9);
                assert!((last.center + last.half_length - range[1]).abs() < 1e-9);
            }
            // Car at the finest scale over 0–75 m: step (75 − 10.8)/240 = 0.2675 m.
            if range == [0.0, 75.0] {
                assert!((layout[0].slices[1].half_length - 0.2675).abs() < 1e-12);
                assert!((layout[3].slices[1].half_length - 2.14).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn spanning_intervals_hold_both_ends() {
        for (start, end) in [
            (0.0, 75.0),
            (2.0, 12.0),
            (16.848, 17.0903),
            (74.6, 75.0),
            (0.1 + 0.2, 0.7),
            (1e-300, 3.3),
            (5.0, 5.0),
        ] {
            let iv = SliceInterval::spanning(start, end);
            for d in [start, end] {
                assert!(iv.contains(d), "{d} not in {iv:?}");
                let (order, depths) = (vec![0u32], vec![d]);
                let (pp, _) = slice_pairs(&depths, &order, &[iv], 1);
                assert_eq!(pp, [0], "{d} not paired with {iv:?}");
            }
            assert!((iv.half_length - 0.5 * (end - start)).abs() < 1e-12);
        }
        // Non-finite ends do not hang.
        assert!(SliceInterval::spanning(0.0, f64::NAN).half_length.is_nan());
        assert!(
            SliceInterval::spanning(0.0, f64::INFINITY)
                .half_length
                .is_infinite()
        );
    }

    #[test]
    fn every_depth_is_covered_near_once_and_beyond_twice() {
        let b = tall(40.0);
        let range = [0.0, 75.0];
        let s = saf(0.6);
        let ctx = saf_ctx(&b, ObjectClass::Car, range);
        let a = s.near_length(&ctx);
        // Both ends of the range, for awkward ranges and every ω, are covered.
        for range in [[0.0, 75.0], [2.0, 70.0], [0.3, 40.1]] {
            for omega in [0.0, 0.1, 0.35, 0.6, 0.95] {
                let ctx = saf_ctx(&b, ObjectClass::Car, range);
                for scale in saf(omega).layout(&ctx) {
                    for d in range {
                        assert!(
                            scale.slices.iter().any(|iv| iv.contains(d)),
                            "{d} of {range:?} uncovered at ω {omega}"
                        );
                    }
                }
            }
        }
        for scale in s.layout(&ctx) {
            let step = scale.slices[1].half_length;
            for i in 0..=7500 {
                let d = i as f64 * 0.01;
                let hits = scale.slices.iter().filter(|iv| iv.contains(d)).count();
                // The near region, and the first and last step of the rest, lie in
                // one interval; every other depth in two.
                let single = d < a + step - 1e-9 || d > range[1] - step + 1e-9;
                let expect = if single { 1 } else { 2 };
                // On an interval end (shared, both included) rounding decides
                // whether the intervals meeting there count.
                let on_end = scale
                    .slices
                    .iter()
                    .any(|iv| ((d - iv.center).abs() - iv.half_length).abs() < 1e-9);
                assert!(
                    hits == expect || (on_end && hits.abs_diff(expect) <= 1),
                    "depth {d}: {hits} intervals, expected {expect} (n = {})",
                    scale.slices.len()
                );
                assert!(
                    hits >= 1,
                    "depth {d} uncovered (n = {})",
                    scale.slices.len()
                );
            }
        }
    }

    #[test]
    fn near_region_is_clamped() {
        let range = [0.0, 75.0];
        let s = saf(0.9);
        // A zero-height box counts as 1 px: L_depth = 720 · 1.56 m, clamped to 0.9 · 75.
        for h in [0.0, 0.3, -2.0, f64::NAN] {
            let b = tall(h);
            let ctx = saf_ctx(&b, ObjectClass::Car, range);
            assert!((s.coarse_depth(&ctx) - 720.0 * 1.56).abs() < 1e-9, "h {h}");
            assert_eq!(s.near_length(&ctx), MAX_NEAR_FRACTION * 75.0);
            let layout = s.layout(&ctx);
            for scale in &layout {
                let near = scale.slices[0];
                assert!((near.center + near.half_length - 67.5).abs() < 1e-12);
                let last = scale.slices.last().unwrap();
                assert!((last.center + last.half_length - 75.0).abs() < 1e-9);
                assert!(last.center < 75.0);
            }
        }
        // The clamp follows the depth range: 0.9 · (40 − 2) from d_min = 2.
        let b = tall(1.0);
        let ctx = saf_ctx(&b, ObjectClass::Car, [2.0, 40.0]);
        assert!((s.near_length(&ctx) - 0.9 * 38.0).abs() < 1e-12);
        // ω = 0: an empty near region at d_min, the rest covers the whole range.
        let ctx = saf_ctx(&b, ObjectClass::Car, range);
        let layout = saf(0.0).layout(&ctx);
        assert_eq!(
            layout[0].slices[0],
            SliceInterval {
                center: 0.0,
                half_length: 0.0
            }
        );
        assert!((layout[0].slices[1].half_length - 75.0 / 240.0).abs() < 1e-12);
        // A class without a mean height has no depth-guided layout.
        let r = std::panic::catch_unwind(|| {
            s.coarse_depth(&saf_ctx(&b, ObjectClass::Van, range));
        });
        assert!(r.is_err());
    }

    #[test]
    fn depth_guided_validation_says_what_to_fix() {
        let err = |s: DepthGuidedSlicing| s.validate([0.0, 75.0]).unwrap_err().to_string();
        let e = err(DepthGuidedSlicing {
            slices: 250,
            ..DepthGuidedSlicing::saf_car()
        });
        assert!(
            e.contains("`slicing.slices` = 250 must be divisible by 8"),
            "{e}"
        );
        let e = err(DepthGuidedSlicing {
            slices: 8,
            ..DepthGuidedSlicing::saf_car()
        });
        assert!(e.contains("use slices >= 16"), "{e}");
        // Two scales need an even count.
        let two = DepthGuidedSlicing {
            slices: 6,
            max_points: vec![32, 64],
            ..DepthGuidedSlicing::saf_car()
        };
        two.validate([0.0, 75.0]).unwrap();
        assert_eq!(two.slices_per_scale([0.0, 75.0]), [6, 3]);
        for omega in [1.0, -0.1, f64::NAN] {
            let e = err(saf(omega));
            assert!(e.contains("`slicing.omega`") && e.contains("[0, 1)"), "{e}");
        }
        let e = err(DepthGuidedSlicing {
            mean_heights: MeanHeights {
                cyclist: 0.0,
                ..MeanHeights::default()
            },
            ..DepthGuidedSlicing::saf_car()
        });
        assert!(e.contains("`slicing.mean_heights.cyclist` = 0"), "{e}");
        let e = err(DepthGuidedSlicing {
            max_points: vec![],
            ..DepthGuidedSlicing::saf_car()
        });
        assert!(e.contains("`slicing.max_points` is empty"), "{e}");
        let e = err(DepthGuidedSlicing {
            max_points: vec![32, 0, 64, 128],
            ..DepthGuidedSlicing::saf_car()
        });
        assert!(e.contains("scale 1 is 0"), "{e}");
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
