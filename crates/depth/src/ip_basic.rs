//! IP-Basic's fast pipeline (Ku, Harakeh & Waslander, "In Defense of Classical Image
//! Processing: Fast Depth Completion on the CPU", CRV 2018), on inverted depth so that
//! dilation (a maximum) prefers the nearest surface:
//!
//! 1. invert: d → `max_depth` − d on valid pixels (d > 0.1 m);
//! 2. dilate with the 5×5 diamond;
//! 3. close with the full 5×5;
//! 4. fill empty pixels from a full 7×7 dilation;
//! 5. optionally extrapolate: each column's top value extended to the image top, then
//!    empty pixels filled from a full 31×31 dilation;
//! 6. 5×5 median;
//! 7. blur: a 5×5 Gaussian on the valid pixels only, or the bilateral filter (5, σ_color
//!    1.5, σ_space 2.0) over the whole image;
//! 8. re-invert the valid pixels; what is left at or below 0.1 m is empty (0).
//!
//! And its multiscale pipeline ([`Method::Multiscale`]), which dilates near returns more
//! than far ones and keeps the image above the scan empty unless extrapolating:
//!
//! 1. invert; dilate the returns ≤ 15 m with a 7×7 cross, 15–30 m with a 5×5 cross and
//!    > 30 m with a 3×3 cross, each range on its own, and merge far to near;
//! 2. close with the full 5×5; 5×5 median on valid pixels;
//! 3. the top mask: per column, the pixels above its topmost value are outside (a column
//!    without a value is inside, as `np.argmax` makes it in IP-Basic's code);
//! 4. fill empty pixels inside the mask from a full 9×9 dilation;
//! 5. optionally extrapolate: extend each column's top value upward, and the mask is
//!    dropped (everything is inside);
//! 6. six rounds of filling empty pixels inside the mask from a full 5×5 dilation;
//! 7. 5×5 median on the valid pixels inside the mask, then the Gaussian (kept on the
//!    pixels valid after the median) or the bilateral filter (5, σ_color 0.5, σ_space
//!    2.0; kept on those valid before it); re-invert.
//!
//! Both follow IP-Basic's published code (`depth_map_utils.py`) step for step, with
//! OpenCV's definitions of each filter (`image_ops`); `scripts/ip_basic_reference.py`
//! runs their code on our inputs for the comparison in docs/depth.md.

use crate::image_ops::{
    Kernel, bilateral, close, dilate, fill_where, gaussian5, median5, replace_where,
};
use crate::scratch;
use fusiondet_kitti::DepthMap;

/// Depths at or below this are "no measurement" (IP-Basic's threshold).
const VALID: f32 = 0.1;

/// The last smoothing step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Blur {
    /// 5×5 Gaussian, applied to valid pixels only.
    #[default]
    Gaussian,
    /// Bilateral filter (5, σ_color 1.5, σ_space 2.0) over the whole image.
    Bilateral,
}

/// Which of IP-Basic's pipelines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Method {
    /// `fill_in_fast`.
    #[default]
    Fast,
    /// `fill_in_multiscale`.
    Multiscale,
}

/// IP-Basic's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IpBasic {
    pub method: Method,
    /// Extend each column's top value upward and fill large holes (31×31).
    pub extrapolate: bool,
    pub blur: Blur,
    /// The depth inversion's reference, in metres (IP-Basic: 100).
    pub max_depth: f32,
}

impl Default for IpBasic {
    fn default() -> Self {
        IpBasic {
            method: Method::Fast,
            extrapolate: false,
            blur: Blur::Gaussian,
            max_depth: 100.0,
        }
    }
}

impl IpBasic {
    /// The setting that measured best here, on both the simulated dense truth and the
    /// held-out KITTI returns (docs/depth.md): the fast pipeline, the Gaussian, extrapolation.
    pub fn measured_best() -> IpBasic {
        IpBasic {
            method: Method::Fast,
            extrapolate: true,
            blur: Blur::Gaussian,
            max_depth: 100.0,
        }
    }
}

/// A depth completion method: sparse depth in, dense depth out (same size). IP-Basic
/// implements it; a learned model can too.
pub trait DepthCompleter {
    fn complete(&self, sparse: &DepthMap) -> DepthMap;
}

impl DepthCompleter for IpBasic {
    fn complete(&self, sparse: &DepthMap) -> DepthMap {
        complete(sparse, self)
    }
}

fn invert_valid(map: &mut DepthMap, max_depth: f32) {
    for d in &mut map.data {
        if *d > VALID {
            *d = max_depth - *d;
        }
    }
}

/// Each column's topmost valid row (> 0.1), `None` for a column without one; found row
/// by row so the image is read in memory order.
fn column_tops(map: &DepthMap) -> Vec<Option<usize>> {
    let mut tops = vec![None; map.width];
    let mut open = map.width;
    for (y, row) in map.data.chunks_exact(map.width.max(1)).enumerate() {
        if open == 0 {
            break;
        }
        for (top, &d) in tops.iter_mut().zip(row) {
            if top.is_none() && d > VALID {
                *top = Some(y);
                open -= 1;
            }
        }
    }
    tops
}

/// Each column's topmost valid value copied to every pixel above it.
fn extend_columns_upward(map: &mut DepthMap) {
    let w = map.width;
    for (x, top) in column_tops(map).into_iter().enumerate() {
        if let Some(top) = top {
            let v = map.data[top * w + x];
            for y in 0..top {
                map.data[y * w + x] = v;
            }
        }
    }
}

/// IP-Basic's top mask: false above each column's topmost valid pixel. A column without
/// one is inside from the top (their `np.argmax` of an all-false column is row 0).
fn top_mask(map: &DepthMap) -> Vec<bool> {
    let tops = column_tops(map);
    let mut inside = vec![true; map.data.len()];
    for (y, row) in inside.chunks_exact_mut(map.width.max(1)).enumerate() {
        for (v, top) in row.iter_mut().zip(&tops) {
            *v = top.is_none_or(|top| y >= top);
        }
    }
    inside
}

/// IP-Basic's completion with `settings` (see the module documentation).
pub fn complete(sparse: &DepthMap, settings: &IpBasic) -> DepthMap {
    let mut map = match settings.method {
        Method::Fast => fast(sparse, settings),
        Method::Multiscale => multiscale(sparse, settings),
    };
    // What the blur spread into empty pixels (the bilateral filter leaves values like
    // 1e-8 there) is no measurement: IP-Basic's 16-bit output rounds it to 0, and so do we.
    for d in &mut map.data {
        if *d <= VALID {
            *d = 0.0;
        }
    }
    map
}

/// Multiscale step 1: the inverted depths with each range's returns dilated by its own
/// cross (≤ 15 m: 7×7, 15–30 m: 5×5, > 30 m: 3×3), merged far to near.
fn range_dilation(sparse: &DepthMap, max_depth: f32) -> DepthMap {
    let mut inverted = sparse.clone();
    invert_valid(&mut inverted, max_depth);
    let ranges = [
        (30.0f32, f32::INFINITY, Kernel::cross(3)),
        (15.0, 30.0, Kernel::cross(5)),
        (VALID, 15.0, Kernel::cross(7)),
    ];
    let mut map = inverted.clone();
    for (lo, hi, kernel) in ranges {
        let mut band = DepthMap::empty(sparse.width, sparse.height);
        for (i, &d) in sparse.data.iter().enumerate() {
            if d > lo && d <= hi {
                band.data[i] = inverted.data[i];
            }
        }
        let dilated = dilate(&band, &kernel);
        replace_where(&mut map, &dilated, |i, _| dilated.data[i] > VALID);
        scratch::recycle(dilated);
    }
    map
}

fn multiscale(sparse: &DepthMap, settings: &IpBasic) -> DepthMap {
    let mut map = range_dilation(sparse, settings.max_depth);
    advance(&mut map, |m| close(m, &Kernel::full(5)));
    merge_from(&mut map, median5, |_, d| d > VALID);
    let inside = top_mask(&map);
    fill_where(&mut map, &Kernel::full(9), |i, d| d <= VALID && inside[i]);
    // Extrapolating extends the columns and drops the mask; otherwise the mask is taken
    // again after the fill (the fill never reaches above it, so it is the same one). No
    // 31×31 fill here: only the fast pipeline has it.
    let inside = if settings.extrapolate {
        extend_columns_upward(&mut map);
        vec![true; map.data.len()]
    } else {
        top_mask(&map)
    };
    for _ in 0..6 {
        fill_where(&mut map, &Kernel::full(5), |i, d| d < VALID && inside[i]);
    }
    // Which pixels the median (and the bilateral filter after it) may replace: valid
    // ones inside, taken before the median as IP-Basic does.
    let valid: Vec<bool> = map
        .data
        .iter()
        .zip(&inside)
        .map(|(&d, &inside)| d > VALID && inside)
        .collect();
    merge_from(&mut map, median5, |i, _| valid[i]);
    match settings.blur {
        // The Gaussian goes to the pixels valid after the median…
        Blur::Gaussian => merge_from(&mut map, gaussian5, |i, d| d > VALID && inside[i]),
        // …the bilateral filter to those valid before it (IP-Basic reuses that mask).
        Blur::Bilateral => merge_from(&mut map, |m| bilateral(m, 5, 0.5, 2.0), |i, _| valid[i]),
    }
    invert_valid(&mut map, settings.max_depth);
    map
}

/// `map` becomes `step(map)`; the old buffer goes back for reuse.
fn advance(map: &mut DepthMap, step: impl FnOnce(&DepthMap) -> DepthMap) {
    let next = step(map);
    scratch::recycle(std::mem::replace(map, next));
}

/// [`replace_where`] from `step(map)`, whose buffer then goes back for reuse.
fn merge_from(
    map: &mut DepthMap,
    step: impl FnOnce(&DepthMap) -> DepthMap,
    keep: impl Fn(usize, f32) -> bool,
) {
    let source = step(map);
    replace_where(map, &source, keep);
    scratch::recycle(source);
}

fn fast(sparse: &DepthMap, settings: &IpBasic) -> DepthMap {
    let mut map = sparse.clone();
    invert_valid(&mut map, settings.max_depth);
    advance(&mut map, |m| dilate(m, &Kernel::diamond(5)));
    advance(&mut map, |m| close(m, &Kernel::full(5)));
    fill_where(&mut map, &Kernel::full(7), |_, d| d < VALID);
    if settings.extrapolate {
        extend_columns_upward(&mut map);
        fill_where(&mut map, &Kernel::full(31), |_, d| d < VALID);
    }
    advance(&mut map, median5);
    match settings.blur {
        Blur::Bilateral => advance(&mut map, |m| bilateral(m, 5, 1.5, 2.0)),
        Blur::Gaussian => merge_from(&mut map, gaussian5, |_, d| d > VALID),
    }
    invert_valid(&mut map, settings.max_depth);
    map
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane seen by the camera, depth = a + b·x + c·y, sampled every `step` pixels.
    fn plane(w: usize, h: usize, step: usize) -> (DepthMap, DepthMap) {
        let depth = |x: usize, y: usize| 20.0 + 0.01 * x as f32 - 0.02 * y as f32;
        let mut dense = DepthMap::empty(w, h);
        let mut sparse = DepthMap::empty(w, h);
        for y in 0..h {
            for x in 0..w {
                dense.set(x, y, depth(x, y));
                if x % step == 0 && y % step == 0 {
                    sparse.set(x, y, depth(x, y));
                }
            }
        }
        (sparse, dense)
    }

    const SETTINGS: [(Method, Blur); 4] = [
        (Method::Fast, Blur::Gaussian),
        (Method::Fast, Blur::Bilateral),
        (Method::Multiscale, Blur::Gaussian),
        (Method::Multiscale, Blur::Bilateral),
    ];

    #[test]
    fn a_sparsely_sampled_plane_is_recovered() {
        let (sparse, dense) = plane(60, 40, 3);
        for (method, blur) in SETTINGS {
            let settings = IpBasic {
                method,
                blur,
                ..Default::default()
            };
            let out = complete(&sparse, &settings);
            // Every pixel is filled (multiscale: every pixel at or below the top row).
            assert_eq!(
                out.valid_count(),
                60 * 40,
                "{method:?} {blur:?}: every pixel filled"
            );
            // Away from the border (where dilation reaches from one side only).
            let mut worst = 0f32;
            for y in 4..36 {
                for x in 4..56 {
                    worst = worst.max((out.get(x, y) - dense.get(x, y)).abs());
                }
            }
            // Dilation takes the nearest of the neighbours within 2 pixels of sampling:
            // the error is bounded by the plane's change over a few pixels.
            assert!(worst < 0.1, "{method:?} {blur:?}: {worst} m");
        }
    }

    #[test]
    fn blurring_leaves_no_near_zero_depths_behind() {
        // Two sampled patches far apart: the bilateral filter spreads tiny values into
        // the empty pixels between them, which must come out as empty, not as 1e-8 m.
        let mut sparse = DepthMap::empty(40, 10);
        for y in 0..10 {
            for x in (0..6).chain(34..40) {
                sparse.set(x, y, 12.0);
            }
        }
        for blur in [Blur::Gaussian, Blur::Bilateral] {
            let out = complete(
                &sparse,
                &IpBasic {
                    blur,
                    ..Default::default()
                },
            );
            assert!(
                out.data.iter().all(|&d| d == 0.0 || d > VALID),
                "{blur:?}: a near-zero depth is left"
            );
            assert_eq!(out.get(20, 5), 0.0, "{blur:?}: the gap stays empty");
        }
    }

    #[test]
    fn multiscale_dilates_near_returns_wider_and_keeps_the_sky_empty() {
        // One return at 10 m and one at 50 m, alone in their neighbourhoods.
        let mut sparse = DepthMap::empty(40, 20);
        sparse.set(10, 10, 10.0);
        sparse.set(30, 10, 50.0);
        let mut banded = range_dilation(&sparse, 100.0);
        invert_valid(&mut banded, 100.0);
        // 7×7 cross for the near return (13 pixels), 3×3 for the far one (5 pixels).
        let near = (0..40 * 20)
            .filter(|&i| (banded.data[i] - 10.0).abs() < 1e-3)
            .count();
        let far = (0..40 * 20)
            .filter(|&i| (banded.data[i] - 50.0).abs() < 1e-3)
            .count();
        assert_eq!((near, far), (13, 5));
        // Above the scan (rows 0..10 of columns with no return higher up) stays empty.
        let (s, _) = plane(30, 30, 2);
        let mut low = s.clone();
        for y in 0..15 {
            for x in 0..30 {
                low.set(x, y, 0.0);
            }
        }
        let out = complete(
            &low,
            &IpBasic {
                method: Method::Multiscale,
                ..Default::default()
            },
        );
        assert_eq!(out.get(10, 3), 0.0);
        assert!(out.get(10, 20) > 0.0);
    }

    #[test]
    fn extrapolation_fills_the_sky_above_the_scan() {
        let (mut sparse, _) = plane(40, 40, 2);
        for y in 0..20 {
            for x in 0..40 {
                sparse.set(x, y, 0.0);
            }
        }
        let without = complete(&sparse, &IpBasic::default());
        assert!(
            without.get(10, 0) == 0.0,
            "no extrapolation: the top stays empty"
        );
        let with = complete(
            &sparse,
            &IpBasic {
                extrapolate: true,
                ..Default::default()
            },
        );
        assert_eq!(with.valid_count(), 40 * 40);
        // The top takes the column's topmost measured depth.
        assert!((with.get(10, 0) - sparse.get(10, 20)).abs() < 0.2);
    }

    #[test]
    fn the_nearer_surface_wins_where_two_meet() {
        // A near object (5 m) in front of a far wall (40 m), both sampled.
        let mut sparse = DepthMap::empty(30, 10);
        for y in (0..10).step_by(2) {
            for x in (0..30).step_by(2) {
                sparse.set(x, y, if (10..20).contains(&x) { 5.0 } else { 40.0 });
            }
        }
        for (method, blur) in SETTINGS {
            let out = complete(
                &sparse,
                &IpBasic {
                    method,
                    blur,
                    ..Default::default()
                },
            );
            assert!(
                (out.get(15, 5) - 5.0).abs() < 0.01,
                "{method:?}: {}",
                out.get(15, 5)
            );
            assert!(
                (out.get(2, 5) - 40.0).abs() < 0.01,
                "{method:?}: {}",
                out.get(2, 5)
            );
        }
        // An empty input stays empty.
        assert_eq!(
            complete(&DepthMap::empty(8, 8), &IpBasic::default()).valid_count(),
            0
        );
    }
}
