//! The image operations IP-Basic is made of, on f32 depth images, with OpenCV's border
//! rules (IP-Basic is written against OpenCV): dilation and erosion ignore pixels outside
//! the image, the median replicates the border, the Gaussian and bilateral filters
//! reflect it without repeating the edge (OpenCV's `BORDER_REFLECT_101`).
//!
//! Written here because no Rust image crate offers grey-level morphology and filters on
//! f32 images with these borders (`imageproc`'s work on 8-bit images); exactness against
//! the definitions matters more here than speed, and the tests check each on small
//! hand-made arrays.

use fusiondet_kitti::DepthMap;

/// A structuring element: the offsets (dx, dy) it covers.
#[derive(Debug, Clone, PartialEq)]
pub struct Kernel {
    offsets: Vec<(i32, i32)>,
    /// How dilation and erosion may run through 1-D windows instead of the offsets.
    shape: Shape,
}

/// Shapes with a fast exact decomposition into 1-D windows.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Shape {
    /// A k×k square: a row window, then a column window.
    Full(usize),
    /// A k×k cross: the larger of a row window and a column window of the same pixel.
    Cross(usize),
    /// A diamond of radius r: r rounds of the 3×3 cross (the L1 ball of radius r is r
    /// L1 balls of radius 1 added up; inside a rectangle every step between two pixels
    /// stays inside, so ignoring the outside keeps it exact).
    Diamond(usize),
}

impl Kernel {
    /// The full `k`×`k` square (`k` odd).
    pub fn full(k: usize) -> Kernel {
        let r = (k / 2) as i32;
        Kernel {
            offsets: (-r..=r)
                .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
                .collect(),
            shape: Shape::Full(k),
        }
    }

    /// The `k`×`k` diamond: offsets with |dx| + |dy| ≤ k / 2 (IP-Basic's 5×5 diamond).
    pub fn diamond(k: usize) -> Kernel {
        let r = (k / 2) as i32;
        Kernel {
            offsets: (-r..=r)
                .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
                .filter(|(dx, dy)| dx.abs() + dy.abs() <= r)
                .collect(),
            shape: Shape::Diamond(r as usize),
        }
    }

    /// The `k`×`k` cross: the centre row and column.
    pub fn cross(k: usize) -> Kernel {
        let r = (k / 2) as i32;
        Kernel {
            offsets: (-r..=r)
                .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
                .filter(|(dx, dy)| *dx == 0 || *dy == 0)
                .collect(),
            shape: Shape::Cross(k),
        }
    }
}

#[derive(Clone, Copy)]
enum Extremum {
    Max,
    Min,
}

impl Extremum {
    fn pick(self, a: f32, b: f32) -> f32 {
        match self {
            Extremum::Max => a.max(b),
            Extremum::Min => a.min(b),
        }
    }
    fn identity(self) -> f32 {
        match self {
            Extremum::Max => f32::NEG_INFINITY,
            Extremum::Min => f32::INFINITY,
        }
    }
}

/// Max (or min) over a 1-D window of radius `r` along rows or columns.
fn line_extremum(map: &DepthMap, r: usize, along_rows: bool, op: Extremum) -> DepthMap {
    let (w, h) = (map.width, map.height);
    let mut out = DepthMap::empty(w, h);
    for y in 0..h {
        for x in 0..w {
            let mut v = op.identity();
            if along_rows {
                for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                    v = op.pick(v, map.get(xx, y));
                }
            } else {
                for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                    v = op.pick(v, map.get(x, yy));
                }
            }
            out.set(x, y, v);
        }
    }
    out
}

fn morph(map: &DepthMap, kernel: &Kernel, op: Extremum) -> DepthMap {
    if map.data.is_empty() {
        return map.clone();
    }
    match kernel.shape {
        Shape::Full(k) => {
            let rows = line_extremum(map, k / 2, true, op);
            line_extremum(&rows, k / 2, false, op)
        }
        Shape::Cross(k) => {
            let mut out = line_extremum(map, k / 2, true, op);
            let columns = line_extremum(map, k / 2, false, op);
            for (a, b) in out.data.iter_mut().zip(&columns.data) {
                *a = op.pick(*a, *b);
            }
            out
        }
        Shape::Diamond(r) => {
            let cross = Kernel::cross(3);
            let mut out = map.clone();
            for _ in 0..r {
                out = morph(&out, &cross, op);
            }
            out
        }
    }
}

/// The definition: the extremum over every offset of the kernel inside the image (what
/// the decompositions above are tested against).
#[cfg(test)]
fn morph_by_offsets(map: &DepthMap, kernel: &Kernel, op: Extremum) -> DepthMap {
    let (w, h) = (map.width as i32, map.height as i32);
    let mut out = DepthMap::empty(map.width, map.height);
    for y in 0..h {
        for x in 0..w {
            let mut v = op.identity();
            for &(dx, dy) in &kernel.offsets {
                let (xx, yy) = (x + dx, y + dy);
                if (0..w).contains(&xx) && (0..h).contains(&yy) {
                    v = op.pick(v, map.get(xx as usize, yy as usize));
                }
            }
            out.set(x as usize, y as usize, v);
        }
    }
    out
}

/// Grey-level dilation: the maximum over the kernel (pixels outside are ignored).
pub fn dilate(map: &DepthMap, kernel: &Kernel) -> DepthMap {
    morph(map, kernel, Extremum::Max)
}

/// Grey-level erosion: the minimum over the kernel (pixels outside are ignored).
pub fn erode(map: &DepthMap, kernel: &Kernel) -> DepthMap {
    morph(map, kernel, Extremum::Min)
}

/// Closing: dilation, then erosion with the same kernel.
pub fn close(map: &DepthMap, kernel: &Kernel) -> DepthMap {
    erode(&dilate(map, kernel), kernel)
}

/// Replaces `map`'s pixels where `keep(pixel index, old value)` holds by `source`'s.
pub fn replace_where(map: &mut DepthMap, source: &DepthMap, keep: impl Fn(usize, f32) -> bool) {
    for (i, (d, s)) in map.data.iter_mut().zip(&source.data).enumerate() {
        if keep(i, *d) {
            *d = *s;
        }
    }
}

/// The 5×5 median, the border replicated. Rows whose whole 5-row window is empty (the
/// image above a scan) are left empty without looking: the median of zeros.
pub fn median5(map: &DepthMap) -> DepthMap {
    let (w, h) = (map.width as i64, map.height as i64);
    let mut out = DepthMap::empty(map.width, map.height);
    let row_has_data: Vec<bool> = map
        .data
        .chunks(map.width.max(1))
        .map(|row| row.iter().any(|&d| d != 0.0))
        .collect();
    let mut window = [0f32; 25];
    for y in 0..h {
        if !(y - 2..=y + 2).any(|yy| row_has_data[yy.clamp(0, h - 1) as usize]) {
            continue;
        }
        for x in 0..w {
            let mut n = 0;
            for dy in -2..=2i64 {
                for dx in -2..=2i64 {
                    let xx = (x + dx).clamp(0, w - 1) as usize;
                    let yy = (y + dy).clamp(0, h - 1) as usize;
                    window[n] = map.get(xx, yy);
                    n += 1;
                }
            }
            let (_, median, _) = window.select_nth_unstable_by(12, f32::total_cmp);
            out.set(x as usize, y as usize, *median);
        }
    }
    out
}

/// OpenCV's `BORDER_REFLECT_101` index: …, 2, 1 | 0, 1, 2, … | n−2, n−3, ….
fn reflect101(i: i64, n: i64) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n - 1);
    let m = i.rem_euclid(period);
    (if m < n { m } else { period - m }) as usize
}

/// The 5×5 Gaussian with OpenCV's default sigma for that size (0.3·((5−1)/2 − 1) + 0.8
/// = 1.1), separable, the border reflected.
pub fn gaussian5(map: &DepthMap) -> DepthMap {
    let sigma = 1.1f64;
    let raw: Vec<f64> = (-2..=2i32)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    let weights: Vec<f32> = raw.iter().map(|v| (v / sum) as f32).collect();
    let (w, h) = (map.width as i64, map.height as i64);
    let pass = |src: &DepthMap, along_rows: bool| {
        let mut out = DepthMap::empty(src.width, src.height);
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0f32;
                let (i, n) = if along_rows { (x, w) } else { (y, h) };
                let interior = i >= 2 && i + 2 < n;
                for (k, weight) in weights.iter().enumerate() {
                    let o = k as i64 - 2;
                    // Away from the border the reflection is the identity.
                    let j = if interior {
                        (i + o) as usize
                    } else {
                        reflect101(i + o, n)
                    };
                    let v = if along_rows {
                        src.get(j, y as usize)
                    } else {
                        src.get(x as usize, j)
                    };
                    acc += weight * v;
                }
                out.set(x as usize, y as usize, acc);
            }
        }
        out
    };
    pass(&pass(map, true), false)
}

/// OpenCV's bilateral filter with diameter `d`: weights exp(−r²/2σ_space²) over the
/// disc of radius d/2 times exp(−Δ²/2σ_color²) on the depth difference, the border
/// reflected.
pub fn bilateral(map: &DepthMap, d: usize, sigma_color: f32, sigma_space: f32) -> DepthMap {
    let r = (d / 2) as i64;
    let (w, h) = (map.width as i64, map.height as i64);
    let color = -0.5 / (sigma_color * sigma_color);
    let space = -0.5 / (sigma_space * sigma_space);
    let taps: Vec<(i64, i64, f32)> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|(dx, dy)| dx * dx + dy * dy <= r * r)
        .map(|(dx, dy)| (dx, dy, ((dx * dx + dy * dy) as f32 * space).exp()))
        .collect();
    let mut out = DepthMap::empty(map.width, map.height);
    for y in 0..h {
        for x in 0..w {
            let centre = map.get(x as usize, y as usize);
            let (mut acc, mut norm) = (0f32, 0f32);
            for &(dx, dy, ws) in &taps {
                let v = map.get(reflect101(x + dx, w), reflect101(y + dy, h));
                let diff = v - centre;
                let weight = ws * (diff * diff * color).exp();
                acc += weight * v;
                norm += weight;
            }
            out.set(x as usize, y as usize, acc / norm);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(w: usize, h: usize, data: &[f32]) -> DepthMap {
        DepthMap {
            width: w,
            height: h,
            data: data.to_vec(),
        }
    }

    #[test]
    fn kernels_have_the_right_shapes() {
        assert_eq!(Kernel::full(5).offsets.len(), 25);
        assert_eq!(Kernel::diamond(5).offsets.len(), 13);
        assert_eq!(Kernel::cross(5).offsets.len(), 9);
        assert!(!Kernel::diamond(5).offsets.contains(&(2, 1)));
    }

    #[test]
    fn a_single_value_dilates_into_the_kernel_shape() {
        let mut m = DepthMap::empty(7, 7);
        m.set(3, 3, 5.0);
        let d = dilate(&m, &Kernel::diamond(5));
        for y in 0..7 {
            for x in 0..7 {
                let inside = (x as i32 - 3).abs() + (y as i32 - 3).abs() <= 2;
                assert_eq!(d.get(x, y), if inside { 5.0 } else { 0.0 }, "({x}, {y})");
            }
        }
        assert_eq!(dilate(&m, &Kernel::full(3)).valid_count(), 9);
    }

    #[test]
    fn fast_decompositions_equal_the_definition() {
        // Random values (fixed seed) on an odd-sized image, every kernel in use, both
        // extrema: the 1-D decompositions give exactly the offsets' answer, borders too.
        let mut rng = fusiondet_dataset::rng::Sampler::new(5);
        let data: Vec<f32> = (0..23 * 17)
            .map(|_| {
                if rng.chance(0.3) {
                    rng.range(1.0, 90.0) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let m = map(23, 17, &data);
        for kernel in [
            Kernel::full(3),
            Kernel::full(5),
            Kernel::full(9),
            Kernel::cross(3),
            Kernel::cross(5),
            Kernel::cross(7),
            Kernel::diamond(5),
        ] {
            for op in [Extremum::Max, Extremum::Min] {
                assert_eq!(
                    morph(&m, &kernel, op),
                    morph_by_offsets(&m, &kernel, op),
                    "{kernel:?}"
                );
            }
        }
    }

    #[test]
    fn erosion_ignores_the_outside_and_closing_fills_a_gap() {
        let m = map(5, 1, &[1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!(
            erode(&m, &Kernel::full(3)).data,
            vec![1.0, 1.0, 2.0, 3.0, 4.0]
        );
        assert_eq!(
            dilate(&m, &Kernel::full(3)).data,
            vec![2.0, 3.0, 4.0, 5.0, 5.0]
        );
        // A one-pixel hole between equal depths is closed; the ends keep their values.
        let gap = map(5, 1, &[4.0, 4.0, 0.0, 4.0, 4.0]);
        assert_eq!(close(&gap, &Kernel::full(3)).data, vec![4.0; 5]);
    }

    #[test]
    fn median_takes_the_middle_of_25_with_a_replicated_border() {
        let data: Vec<f32> = (0..25).map(|v| v as f32).collect();
        let m = map(5, 5, &data);
        assert_eq!(median5(&m).get(2, 2), 12.0);
        // The corner's window replicates row 0 and column 0: values 0,0,0,1,2 / …
        let mut corner: Vec<f32> = (-2..=2i32)
            .flat_map(|dy| (-2..=2i32).map(move |dx| (dy.max(0) * 5 + dx.max(0)) as f32))
            .collect();
        corner.sort_by(f32::total_cmp);
        assert_eq!(median5(&m).get(0, 0), corner[12]);
        // A lone spike disappears.
        let mut spike = DepthMap::empty(5, 5);
        spike.set(2, 2, 9.0);
        assert_eq!(median5(&spike).valid_count(), 0);
    }

    #[test]
    fn gaussian_keeps_constants_and_sums_to_one() {
        let flat = map(6, 4, &[3.0; 24]);
        for v in gaussian5(&flat).data {
            assert!((v - 3.0).abs() < 1e-6);
        }
        // An impulse in the middle spreads into the normalised 2-D kernel.
        let mut impulse = DepthMap::empty(9, 9);
        impulse.set(4, 4, 1.0);
        let g = gaussian5(&impulse);
        let total: f32 = g.data.iter().sum();
        assert!((total - 1.0).abs() < 1e-6, "{total}");
        assert!(g.get(4, 4) > g.get(5, 4) && g.get(5, 4) > g.get(6, 4));
        assert_eq!(g.get(7, 4), 0.0);
        assert_eq!(reflect101(-1, 5), 1);
        assert_eq!(reflect101(5, 5), 3);
    }

    #[test]
    fn bilateral_smooths_within_a_surface_and_keeps_an_edge() {
        let mut data = vec![10.0f32; 10 * 5];
        for y in 0..5 {
            for x in 5..10 {
                data[y * 10 + x] = 20.0;
            }
        }
        let m = map(10, 5, &data);
        let b = bilateral(&m, 5, 1.5, 2.0);
        // A 10 m step is 6.7 sigma_color: the sides do not mix.
        assert!((b.get(4, 2) - 10.0).abs() < 1e-3, "{}", b.get(4, 2));
        assert!((b.get(5, 2) - 20.0).abs() < 1e-3, "{}", b.get(5, 2));
        // Small noise on a flat surface is averaged.
        let mut noisy = map(5, 5, &[10.0; 25]);
        noisy.set(2, 2, 10.5);
        assert!(bilateral(&noisy, 5, 1.5, 2.0).get(2, 2) < 10.5);
    }
}
