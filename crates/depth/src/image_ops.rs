//! The image operations IP-Basic is made of, on f32 depth images, with OpenCV's border
//! rules (IP-Basic is written against OpenCV): dilation and erosion ignore pixels outside
//! the image, the median replicates the border, the Gaussian and bilateral filters
//! reflect it without repeating the edge (OpenCV's `BORDER_REFLECT_101`).
//!
//! Written here because no Rust image crate offers grey-level morphology and filters on
//! f32 images with these borders (`imageproc`'s work on 8-bit images). Each operation is
//! arranged for speed on one core without CPU-specific flags (passes over whole rows that
//! the compiler vectorizes; see each function) and gives exactly what its definition gives:
//! the tests compare every fast path with the straightforward definition, also kept here,
//! on random maps with borders and empty pixels, and on small hand-made arrays. Depth maps
//! hold no NaN, which lets a max or min be written as a comparison.

use crate::scratch;
use fusiondet_kitti::DepthMap;

/// A structuring element: the offsets (dx, dy) it covers.
#[derive(Debug, Clone, PartialEq)]
pub struct Kernel {
    offsets: Vec<(i32, i32)>,
    /// How dilation and erosion may run through 1-D windows instead of the offsets.
    shape: Shape,
}

/// Shapes with a fast exact decomposition.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Shape {
    /// A k×k square: a row window, then a column window.
    Full(usize),
    /// A k×k cross: the centre row and column.
    Cross(usize),
    /// A diamond of radius r: |dx| + |dy| ≤ r.
    Diamond(usize),
}

impl Shape {
    /// The kernel as runs: for each row offset dy, the half width a of the offsets
    /// (−a..=a, dy) it covers. Every kernel here is a union of such centred runs.
    fn runs(self) -> Vec<(i64, usize)> {
        match self {
            Shape::Full(k) => {
                let r = (k / 2) as i64;
                (-r..=r).map(|dy| (dy, k / 2)).collect()
            }
            Shape::Cross(k) => {
                let r = (k / 2) as i64;
                (-r..=r)
                    .map(|dy| (dy, if dy == 0 { k / 2 } else { 0 }))
                    .collect()
            }
            Shape::Diamond(r) => {
                let r = r as i64;
                (-r..=r).map(|dy| (dy, (r - dy.abs()) as usize)).collect()
            }
        }
    }
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

#[derive(Clone, Copy, Debug)]
enum Extremum {
    Max,
    Min,
}

impl Extremum {
    fn identity(self) -> f32 {
        match self {
            Extremum::Max => f32::NEG_INFINITY,
            Extremum::Min => f32::INFINITY,
        }
    }
    /// `dst[i] = pick(dst[i], src[i])` over two slices (to the shorter's length).
    fn fold_into(self, dst: &mut [f32], src: &[f32]) {
        let n = dst.len().min(src.len());
        let mut dst = dst[..n].chunks_exact_mut(8);
        let mut src = src[..n].chunks_exact(8);
        for (d, s) in (&mut dst).zip(&mut src) {
            let (a, b): ([f32; 8], [f32; 8]) = ((*d).try_into().unwrap(), s.try_into().unwrap());
            d.copy_from_slice(&std::array::from_fn::<f32, 8, _>(|k| self.pick(a[k], b[k])));
        }
        for (d, s) in dst.into_remainder().iter_mut().zip(src.remainder()) {
            *d = self.pick(*d, *s);
        }
    }

    /// The larger (smaller) of two depths, written as a comparison so LLVM emits the
    /// vector max (min) instruction: equal to `f32::max` (`min`) on NaN-free depths.
    #[inline(always)]
    fn pick(self, a: f32, b: f32) -> f32 {
        match self {
            Extremum::Max => {
                if a > b {
                    a
                } else {
                    b
                }
            }
            Extremum::Min => {
                if a < b {
                    a
                } else {
                    b
                }
            }
        }
    }

    /// `seq[i] = pick(seq[i], seq[i + offset])` for `i < count`, in place: each step of
    /// 8 reads its inputs before writing, and writes only below what later steps read.
    /// (Blocks of whole arrays: written as in-place selects, LLVM turns them into stores
    /// of only the changed elements, one at a time, and nothing is vectorized.)
    fn fold_ahead(self, seq: &mut [f32], offset: usize, count: usize) {
        match self {
            Extremum::Max => fold_ahead_with(seq, offset, count, |a, b| if a > b { a } else { b }),
            Extremum::Min => fold_ahead_with(seq, offset, count, |a, b| if a < b { a } else { b }),
        }
    }
}

#[inline(always)]
fn fold_ahead_with(seq: &mut [f32], offset: usize, count: usize, pick: impl Fn(f32, f32) -> f32) {
    const STEP: usize = 8;
    let whole = count / STEP * STEP;
    for i in (0..whole).step_by(STEP) {
        let a: [f32; STEP] = seq[i..i + STEP].try_into().expect("a step");
        let b: [f32; STEP] = seq[i + offset..i + offset + STEP]
            .try_into()
            .expect("a step");
        seq[i..i + STEP]
            .copy_from_slice(&std::array::from_fn::<f32, STEP, _>(|k| pick(a[k], b[k])));
    }
    for i in whole..count {
        seq[i] = pick(seq[i], seq[i + offset]);
    }
}

/// Reduces `seq` in place so that `seq[i]` becomes the extremum of the window
/// `seq[i..i + len]` (for `i + len <= seq.len()`), by doubling: windows of 2, 4, 8, …
/// (each the extremum of two overlapping halves, exact because max and min are
/// idempotent), then two overlapping windows of the largest power of two ≤ `len`.
/// O(log len) passes of whole slices, so the 31×31 costs 5 passes per axis instead of 31.
/// `unit` is the length of one element (1 along a row, the width along columns).
fn window_extremum(seq: &mut [f32], unit: usize, len: usize, op: Extremum) {
    let n = seq.len() / unit;
    let mut span = 1;
    while span * 2 <= len && span < n {
        // seq[i] = pick(seq[i], seq[i + span]): reading ahead of the write, so in place.
        op.fold_ahead(seq, span * unit, (n - span) * unit);
        span *= 2;
    }
    let rest = len - span;
    if rest > 0 && rest < n {
        op.fold_ahead(seq, rest * unit, (n - rest) * unit);
    }
}

/// Max (or min) over a 1-D window of radius `r` along rows, into `out` (the outside of
/// the image is the operation's identity: ignored). `pad` is scratch.
fn row_extremum(map: &DepthMap, r: usize, op: Extremum, out: &mut [f32], pad: &mut Vec<f32>) {
    let w = map.width;
    pad.clear();
    pad.resize(w + 2 * r, op.identity());
    for (src, dst) in map.data.chunks_exact(w).zip(out.chunks_exact_mut(w)) {
        pad[r..r + w].copy_from_slice(src);
        pad[..r].fill(op.identity());
        pad[r + w..].fill(op.identity());
        window_extremum(pad, 1, 2 * r + 1, op);
        dst.copy_from_slice(&pad[..w]);
    }
}

/// Max (or min) over a 1-D window of radius `r` along the columns of the `w`-wide image
/// `data`, whole rows at a time.
fn column_extremum(
    w: usize,
    data: &[f32],
    r: usize,
    op: Extremum,
    out: &mut [f32],
    pad: &mut Vec<f32>,
) {
    let h = data.len() / w;
    pad.clear();
    pad.resize((h + 2 * r) * w, op.identity());
    pad[r * w..(r + h) * w].copy_from_slice(data);
    window_extremum(pad, w, 2 * r + 1, op);
    out.copy_from_slice(&pad[..h * w]);
}

/// The extremum over `runs` (see [`Shape::runs`]) of the `w`-wide image `src`, into
/// `out`, one output row at a time: the centre row copied, then each offset's source row
/// folded in, shifted and cut at the image's edges (the outside ignored). This is the
/// definition itself, arranged so that each fold is a vector pass over a row held in L1;
/// it costs one fold per offset, so large squares go through [`window_extremum`].
fn morph_by_runs(w: usize, src: &[f32], runs: &[(i64, usize)], op: Extremum, out: &mut [f32]) {
    let h = src.len() / w;
    for (y, dst) in out.chunks_exact_mut(w).enumerate() {
        dst.copy_from_slice(&src[y * w..(y + 1) * w]);
        for &(dy, a) in runs {
            let yy = y as i64 + dy;
            if !(0..h as i64).contains(&yy) {
                continue;
            }
            let row = &src[yy as usize * w..(yy as usize + 1) * w];
            for dx in 0..=a.min(w - 1) {
                if dx == 0 {
                    if dy != 0 {
                        op.fold_into(dst, row);
                    }
                    continue;
                }
                // Offset +dx: dst[x] takes row[x + dx]; offset −dx: dst[x + dx] takes row[x].
                op.fold_into(&mut dst[..w - dx], &row[dx..]);
                op.fold_into(&mut dst[dx..], &row[..w - dx]);
            }
        }
    }
}

/// Radii up to this fold offset by offset; larger squares use the doubling windows.
const DIRECT_RADIUS: usize = 4;

fn morph(map: &DepthMap, kernel: &Kernel, op: Extremum) -> DepthMap {
    if map.data.is_empty() {
        return map.clone();
    }
    let w = map.width;
    let mut out = scratch::map(w, map.height);
    let mut rows = scratch::take(map.data.len());
    match kernel.shape {
        Shape::Full(k) if k / 2 > DIRECT_RADIUS => {
            let mut pad = scratch::take(0);
            row_extremum(map, k / 2, op, &mut rows, &mut pad);
            column_extremum(w, &rows, k / 2, op, &mut out.data, &mut pad);
            scratch::give(pad);
        }
        // Separable: the row run, then the column of rows.
        Shape::Full(k) => {
            let r = k / 2;
            morph_by_runs(w, &map.data, &[(0, r)], op, &mut rows);
            let column: Vec<(i64, usize)> = (-(r as i64)..=r as i64).map(|dy| (dy, 0)).collect();
            morph_by_runs(w, &rows, &column, op, &mut out.data);
        }
        shape => morph_by_runs(w, &map.data, &shape.runs(), op, &mut out.data),
    }
    scratch::give(rows);
    out
}

/// The straightforward 1-D window (each pixel scans its window), kept as the definition
/// the doubling in [`window_extremum`] is tested against.
#[cfg(test)]
fn line_extremum_by_scan(map: &DepthMap, r: usize, along_rows: bool, op: Extremum) -> DepthMap {
    let (w, h) = (map.width, map.height);
    let mut out = DepthMap::empty(w, h);
    for y in 0..h {
        for x in 0..w {
            let mut v = op.identity();
            if along_rows {
                for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                    v = match op {
                        Extremum::Max => v.max(map.get(xx, y)),
                        Extremum::Min => v.min(map.get(xx, y)),
                    };
                }
            } else {
                for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                    v = match op {
                        Extremum::Max => v.max(map.get(x, yy)),
                        Extremum::Min => v.min(map.get(x, yy)),
                    };
                }
            }
            out.set(x, y, v);
        }
    }
    out
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
                    let d = map.get(xx as usize, yy as usize);
                    v = match op {
                        Extremum::Max => v.max(d),
                        Extremum::Min => v.min(d),
                    };
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
    let dilated = dilate(map, kernel);
    let closed = erode(&dilated, kernel);
    scratch::recycle(dilated);
    closed
}

/// Replaces `map`'s pixels where `keep(pixel index, old value)` holds by `source`'s.
/// Runs in blocks of 8 that are read, chosen and stored whole (as an in-place select
/// per pixel it would not vectorize; see `fold_ahead`).
pub fn replace_where(map: &mut DepthMap, source: &DepthMap, keep: impl Fn(usize, f32) -> bool) {
    let n = map.data.len().min(source.data.len());
    let mut dst = map.data[..n].chunks_exact_mut(8);
    let mut src = source.data[..n].chunks_exact(8);
    for (c, (d, s)) in (&mut dst).zip(&mut src).enumerate() {
        let (a, b): ([f32; 8], [f32; 8]) = ((*d).try_into().unwrap(), s.try_into().unwrap());
        let chosen: [f32; 8] =
            std::array::from_fn(|k| if keep(c * 8 + k, a[k]) { b[k] } else { a[k] });
        d.copy_from_slice(&chosen);
    }
    let base = n / 8 * 8;
    for (k, (d, s)) in dst
        .into_remainder()
        .iter_mut()
        .zip(src.remainder())
        .enumerate()
    {
        if keep(base + k, *d) {
            *d = *s;
        }
    }
}

/// `replace_where(map, &dilate(map, kernel), keep)`: the pixels where `keep(index, old
/// value)` holds take the maximum over the kernel around them (of the map as it was).
/// IP-Basic's hole fills replace only the empty pixels, often a few; when those are few
/// enough that visiting each one's kernel costs less than dilating the whole image, only
/// they are computed (the definition, offset by offset), else the whole dilation is.
pub fn fill_where(map: &mut DepthMap, kernel: &Kernel, keep: impl Fn(usize, f32) -> bool) {
    let targets: Vec<usize> = (0..map.data.len())
        .filter(|&i| keep(i, map.data[i]))
        .collect();
    // A whole dilation costs a few passes per offset row; a visit, one read per offset.
    let whole = map.data.len() * 4;
    if targets.len() * kernel.offsets.len() > whole {
        let dilated = dilate(map, kernel);
        for &i in &targets {
            map.data[i] = dilated.data[i];
        }
        scratch::recycle(dilated);
        return;
    }
    let (w, h) = (map.width as i64, map.height as i64);
    let values: Vec<f32> = targets
        .iter()
        .map(|&i| {
            let (x, y) = ((i as i64) % w, (i as i64) / w);
            let mut v = f32::NEG_INFINITY;
            for &(dx, dy) in &kernel.offsets {
                let (xx, yy) = (x + dx as i64, y + dy as i64);
                if (0..w).contains(&xx) && (0..h).contains(&yy) {
                    v = v.max(map.data[(yy * w + xx) as usize]);
                }
            }
            v
        })
        .collect();
    for (&i, v) in targets.iter().zip(values) {
        map.data[i] = v;
    }
}

/// The 5×5 median, the border replicated (OpenCV's `medianBlur(src, 5)`), by a
/// selection network run over whole rows ([`crate::median`]). Rows whose whole 5-row
/// window is empty (the image above a scan) are left empty without looking: the median
/// of zeros.
pub fn median5(map: &DepthMap) -> DepthMap {
    crate::median::median5(map)
}

/// The definition: each pixel's 25 values (border replicated) sorted, the 13th taken.
#[cfg(test)]
pub(crate) fn median5_by_sorting(map: &DepthMap) -> DepthMap {
    let (w, h) = (map.width as i64, map.height as i64);
    let mut out = DepthMap::empty(map.width, map.height);
    let mut window = [0f32; 25];
    for y in 0..h {
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
            window.sort_by(f32::total_cmp);
            out.set(x as usize, y as usize, window[12]);
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

/// The 5×5 Gaussian of `GaussianBlur(src, (5, 5), 0)`: with sigma 0 and a size up to 7,
/// OpenCV takes its fixed binomial kernel [1, 4, 6, 4, 1] / 16, not the sigma formula
/// (`getGaussianKernel`). Separable, the border reflected (`BORDER_REFLECT_101`).
const GAUSS5: [f32; 3] = [0.375, 0.25, 0.0625];

/// One 5-tap pass: centre, then the symmetric pairs (OpenCV's order for symmetric kernels).
#[inline(always)]
fn gauss_tap(m2: f32, m1: f32, c: f32, p1: f32, p2: f32) -> f32 {
    GAUSS5[0] * c + GAUSS5[1] * (m1 + p1) + GAUSS5[2] * (m2 + p2)
}

/// The 5×5 Gaussian (see [`GAUSS5`]): rows through a reflected-padded row, then columns
/// as whole rows at a time.
pub fn gaussian5(map: &DepthMap) -> DepthMap {
    let (w, h) = (map.width, map.height);
    if map.data.is_empty() {
        return map.clone();
    }
    let mut rows = scratch::take(w * h);
    let mut pad = vec![0f32; w + 4];
    for (src, dst) in map.data.chunks_exact(w).zip(rows.chunks_exact_mut(w)) {
        for (i, p) in pad.iter_mut().enumerate() {
            *p = src[reflect101(i as i64 - 2, w as i64)];
        }
        for (x, d) in dst.iter_mut().enumerate() {
            *d = gauss_tap(pad[x], pad[x + 1], pad[x + 2], pad[x + 3], pad[x + 4]);
        }
    }
    let mut out = scratch::map(w, h);
    let row = |y: i64| {
        let y = reflect101(y, h as i64);
        &rows[y * w..(y + 1) * w]
    };
    for (y, dst) in out.data.chunks_exact_mut(w).enumerate() {
        let y = y as i64;
        let (m2, m1, c, p1, p2) = (row(y - 2), row(y - 1), row(y), row(y + 1), row(y + 2));
        for x in 0..w {
            dst[x] = gauss_tap(m2[x], m1[x], c[x], p1[x], p2[x]);
        }
    }
    scratch::give(rows);
    out
}

/// The definition: the 2-D kernel (outer product of [1, 4, 6, 4, 1] / 16) summed over
/// reflected offsets, in f64.
#[cfg(test)]
fn gaussian5_by_definition(map: &DepthMap) -> DepthMap {
    let k = [1.0, 4.0, 6.0, 4.0, 1.0f64].map(|v| v / 16.0);
    let (w, h) = (map.width as i64, map.height as i64);
    let mut out = DepthMap::empty(map.width, map.height);
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0f64;
            for dy in -2..=2i64 {
                for dx in -2..=2i64 {
                    let v = map.get(reflect101(x + dx, w), reflect101(y + dy, h)) as f64;
                    acc += k[(dx + 2) as usize] * k[(dy + 2) as usize] * v;
                }
            }
            out.set(x as usize, y as usize, acc as f32);
        }
    }
    out
}

/// Bins of OpenCV's colour-weight table for one channel (`kExpNumBinsPerChannel`).
const EXP_BINS: usize = 1 << 12;

/// OpenCV's bilateral filter on a float image (`bilateralFilter(src, d, σ_color,
/// σ_space)`), as OpenCV computes it: space weights exp(−r²/2σ_space²) over the disc
/// of radius d/2 (centre excluded, added with weight 1 at the end), the colour weight
/// exp(−Δ²/2σ_color²) read from a 4096-bin table over the image's value range with
/// linear interpolation (not evaluated per tap), the border reflected
/// (`BORDER_REFLECT_101`). A constant image is returned as is.
pub fn bilateral(map: &DepthMap, d: usize, sigma_color: f32, sigma_space: f32) -> DepthMap {
    let (w, h) = (map.width, map.height);
    if map.data.is_empty() {
        return map.clone();
    }
    let (lo, hi) = map
        .data
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if ((lo - hi) as f64).abs() < f32::EPSILON as f64 {
        return map.clone();
    }
    let r = (d / 2).max(1);
    let color = -0.5 / (sigma_color as f64 * sigma_color as f64);
    let space = -0.5 / (sigma_space as f64 * sigma_space as f64);
    let scale_index = EXP_BINS as f32 / (hi - lo);
    let mut lut = vec![0f32; EXP_BINS + 2];
    let mut last = 1f32;
    for (i, e) in lut.iter_mut().enumerate() {
        if last > 0.0 {
            let v = (i as f32 / scale_index) as f64;
            *e = (v * v * color).exp() as f32;
            last = *e;
        }
    }
    // Each bin with its step to the next: one read per tap (the same f32 difference
    // OpenCV takes at run time, so the interpolation is unchanged).
    let steps: Vec<[f32; 2]> = (0..=EXP_BINS)
        .map(|i| [lut[i], lut[i + 1] - lut[i]])
        .collect();
    let ri = r as i64;
    let taps: Vec<(usize, usize, f32)> = (-ri..=ri)
        .flat_map(|dy| (-ri..=ri).map(move |dx| (dx, dy)))
        .filter_map(|(dx, dy)| {
            let dist = ((dx * dx + dy * dy) as f64).sqrt();
            (dist <= r as f64 && (dx, dy) != (0, 0)).then(|| {
                let ws = (dist * dist * space).exp() as f32;
                ((dx + ri) as usize, (dy + ri) as usize, ws)
            })
        })
        .collect();
    // The image with a reflected border of r, so the taps need no index checks.
    let pw = w + 2 * r;
    let mut pad = vec![0f32; pw * (h + 2 * r)];
    for (py, prow) in pad.chunks_exact_mut(pw).enumerate() {
        let y = reflect101(py as i64 - ri, h as i64);
        for (px, p) in prow.iter_mut().enumerate() {
            *p = map.data[y * w + reflect101(px as i64 - ri, w as i64)];
        }
    }
    let mut out = DepthMap::empty(w, h);
    let (mut sum, mut wsum) = (vec![0f32; w], vec![0f32; w]);
    for y in 0..h {
        sum.fill(0.0);
        wsum.fill(0.0);
        let centre = &pad[(y + r) * pw + r..(y + r) * pw + r + w];
        for &(tx, ty, ws) in &taps {
            let src = &pad[(y + ty) * pw + tx..(y + ty) * pw + tx + w];
            for x in 0..w {
                let v = src[x];
                let alpha = (v - centre[x]).abs() * scale_index;
                // alpha ≥ 0: truncation is the floor; it is at most EXP_BINS but for
                // rounding, and the clamp lets the compiler drop the bounds check.
                let idx = (alpha as u32 as usize).min(EXP_BINS);
                let frac = alpha - idx as f32;
                let [base, step] = steps[idx];
                let weight = ws * (base + frac * step);
                sum[x] += v * weight;
                wsum[x] += weight;
            }
        }
        let dst = &mut out.data[y * w..(y + 1) * w];
        for x in 0..w {
            dst[x] = (sum[x] + centre[x]) / (wsum[x] + 1.0);
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
            Kernel::full(7),
            Kernel::full(9),
            Kernel::full(31),
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

    /// Random depths (about half empty, some repeated) on a `w`×`h` image.
    fn random_map(w: usize, h: usize, seed: u64) -> DepthMap {
        let mut rng = fusiondet_dataset::rng::Sampler::new(seed);
        let data: Vec<f32> = (0..w * h)
            .map(|_| {
                if rng.chance(0.5) {
                    0.0
                } else if rng.chance(0.2) {
                    42.0
                } else {
                    rng.range(0.1, 99.9) as f32
                }
            })
            .collect();
        map(w, h, &data)
    }

    #[test]
    fn fast_morphology_equals_the_definition_at_every_size() {
        // Images narrower and shorter than the window (the outside ignored on both
        // sides at once), every radius the pipelines use and a few more, both axes.
        for (w, h) in [(1, 1), (1, 9), (9, 1), (4, 3), (23, 17), (40, 33)] {
            let m = random_map(w, h, (w * 100 + h) as u64);
            for r in [1, 2, 3, 4, 5, 7, 15, 16] {
                for op in [Extremum::Max, Extremum::Min] {
                    let mut pad = Vec::new();
                    let mut rows = DepthMap::empty(w, h);
                    row_extremum(&m, r, op, &mut rows.data, &mut pad);
                    assert_eq!(
                        rows,
                        line_extremum_by_scan(&m, r, true, op),
                        "{w}×{h} r {r}"
                    );
                    let mut cols = DepthMap::empty(w, h);
                    column_extremum(w, &m.data, r, op, &mut cols.data, &mut pad);
                    assert_eq!(
                        cols,
                        line_extremum_by_scan(&m, r, false, op),
                        "{w}×{h} r {r}"
                    );
                }
            }
            // Both paths of the squares (offset by offset up to radius 4, doubling above).
            for kernel in [
                Kernel::full(3),
                Kernel::full(9),
                Kernel::full(11),
                Kernel::full(31),
                Kernel::diamond(5),
                Kernel::diamond(7),
                Kernel::cross(3),
                Kernel::cross(7),
            ] {
                assert_eq!(
                    dilate(&m, &kernel),
                    morph_by_offsets(&m, &kernel, Extremum::Max)
                );
                assert_eq!(
                    erode(&m, &kernel),
                    morph_by_offsets(&m, &kernel, Extremum::Min)
                );
            }
        }
    }

    #[test]
    fn gaussian_equals_the_2d_definition_on_random_maps() {
        // OpenCV's kernel for (5, 5) with sigma 0 is [1, 4, 6, 4, 1] / 16.
        for (w, h) in [(1, 1), (2, 2), (3, 7), (23, 17)] {
            let m = random_map(w, h, 3 + w as u64);
            let (fast, slow) = (gaussian5(&m), gaussian5_by_definition(&m));
            for (a, b) in fast.data.iter().zip(&slow.data) {
                assert!((a - b).abs() <= 1e-5 * b.abs().max(1.0), "{w}×{h}: {a} {b}");
            }
        }
    }

    /// The bilateral filter evaluated per pixel with the exponential itself (what
    /// OpenCV's table approximates), in f64.
    fn bilateral_by_definition(m: &DepthMap, d: usize, sc: f64, ss: f64) -> DepthMap {
        let r = (d / 2) as i64;
        let (w, h) = (m.width as i64, m.height as i64);
        let mut out = DepthMap::empty(m.width, m.height);
        for y in 0..h {
            for x in 0..w {
                let c = m.get(x as usize, y as usize) as f64;
                let (mut acc, mut norm) = (0f64, 0f64);
                for dy in -r..=r {
                    for dx in -r..=r {
                        if dx * dx + dy * dy > r * r {
                            continue;
                        }
                        let v = m.get(reflect101(x + dx, w), reflect101(y + dy, h)) as f64;
                        let wt = (-((dx * dx + dy * dy) as f64) / (2.0 * ss * ss)).exp()
                            * (-(v - c) * (v - c) / (2.0 * sc * sc)).exp();
                        acc += wt * v;
                        norm += wt;
                    }
                }
                out.set(x as usize, y as usize, (acc / norm) as f32);
            }
        }
        out
    }

    #[test]
    fn bilateral_follows_the_definition_within_the_table_error() {
        // The colour table has 4096 bins over the value range (here about 100 m): linear
        // interpolation between bins 0.024 m apart moves a weight by well under 1e-3.
        for (w, h) in [(2, 2), (5, 3), (23, 17)] {
            let m = random_map(w, h, 9 + h as u64);
            for (sc, ss) in [(1.5, 2.0), (0.5, 2.0)] {
                let fast = bilateral(&m, 5, sc, ss);
                let slow = bilateral_by_definition(&m, 5, sc as f64, ss as f64);
                for (a, b) in fast.data.iter().zip(&slow.data) {
                    assert!((a - b).abs() < 2e-3, "{w}×{h} σ {sc}: {a} {b}");
                }
            }
        }
        // A constant image comes back as it is (OpenCV's shortcut).
        let flat = map(4, 4, &[7.0; 16]);
        assert_eq!(bilateral(&flat, 5, 1.5, 2.0), flat);
    }

    #[test]
    fn filling_where_asked_equals_dilating_everywhere() {
        // Few targets (visited one by one) and many (the whole dilation), borders too.
        for (w, h, seed) in [(1, 1, 1), (5, 4, 2), (23, 17, 3), (61, 40, 4)] {
            let m = random_map(w, h, seed);
            for kernel in [Kernel::full(5), Kernel::full(9), Kernel::full(31)] {
                for every in [1, 7, 101] {
                    let keep = |i: usize, d: f32| d < 0.1 && i.is_multiple_of(every);
                    let mut want = m.clone();
                    replace_where(&mut want, &dilate(&m, &kernel), keep);
                    let mut got = m.clone();
                    fill_where(&mut got, &kernel, keep);
                    assert_eq!(got, want, "{w}×{h} {kernel:?} every {every}");
                }
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
