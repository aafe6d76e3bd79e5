//! The 5×5 median as a comparator network run across whole rows, so every comparison
//! is a vector min/max over many pixels at once (no per-pixel sort, no branches).
//!
//! The network shares work between neighbouring pixels, in four stages per output row
//! (38 gates per pixel; the same merges without sharing between pixels took 78):
//!
//! 1. each column of 5 (the rows y−2..y+2, replicated at the border) is sorted once, and
//!    serves the 5 windows that contain it (9 gates);
//! 2. the columns 2j+1 and 2j+2 are merged into a sorted 10 (13 gates per 2 pixels);
//! 3. two such pairs, the four columns 2j+1 ..= 2j+4 that the windows of pixels 2j and
//!    2j+1 share, are merged as far as ranks 7..=12, the only ones of 20 that can be the
//!    13th of 25 (25 gates per 2 pixels);
//! 4. each of the two pixels merges those ranks with its own fifth column, column 2j or
//!    2j+5 (10 gates).
//!
//! Merges are Batcher's odd-even merge (Knuth, TAOCP 5.3.4, any lengths); comparisons
//! whose results no later step reads are dropped, and those of which one side is read
//! become a single min or max. A network of min/max gates commutes with every monotone
//! map, so one that selects the 13th of 25 for every 0/1 input does for every input (the
//! 0–1 principle): the tests check all 2^25 0/1 windows, which proves it.

use crate::scratch;
use fusiondet_kitti::DepthMap;
use rayon::prelude::*;
use std::sync::OnceLock;

/// What a gate writes: both sides, or only the one later steps read.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Gate {
    Both,
    /// Only `lo` (the minimum) is read later.
    Min,
    /// Only `hi` (the maximum) is read later.
    Max,
}

/// A comparator: afterwards wire `lo` holds the smaller value, wire `hi` the larger.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Op {
    lo: usize,
    hi: usize,
    gate: Gate,
}

/// Odd-even merge of two sorted wire lists; returns the wires in sorted order.
fn merge(a: &[usize], b: &[usize], net: &mut Vec<(usize, usize)>) -> Vec<usize> {
    if a.is_empty() {
        return b.to_vec();
    }
    if b.is_empty() {
        return a.to_vec();
    }
    if a.len() == 1 && b.len() == 1 {
        net.push((a[0], b[0]));
        return vec![a[0], b[0]];
    }
    let evens = |s: &[usize]| s.iter().step_by(2).copied().collect::<Vec<_>>();
    let odds = |s: &[usize]| s.iter().skip(1).step_by(2).copied().collect::<Vec<_>>();
    let v = merge(&evens(a), &evens(b), net);
    let w = merge(&odds(a), &odds(b), net);
    let mut out = vec![v[0]];
    let mut i = 0;
    while i < w.len() && i + 1 < v.len() {
        net.push((w[i], v[i + 1]));
        out.push(w[i]);
        out.push(v[i + 1]);
        i += 1;
    }
    out.extend(&w[i..]);
    out.extend(&v[(i + 1).min(v.len())..]);
    out
}

/// Sorting network for the wires `s` (merge sort of halves).
fn sort(s: &[usize], net: &mut Vec<(usize, usize)>) -> Vec<usize> {
    if s.len() <= 1 {
        return s.to_vec();
    }
    let (a, b) = s.split_at(s.len() / 2);
    let a = sort(a, net);
    let b = sort(b, net);
    merge(&a, &b, net)
}

/// Drops the comparators no wire of `needed` (read after the network) depends on and
/// narrows those read on one side; returns the gates and the input wires read.
fn prune(net: &[(usize, usize)], needed: &[usize], wires: usize) -> (Vec<Op>, Vec<bool>) {
    let mut live = vec![false; wires];
    for &n in needed {
        live[n] = true;
    }
    let mut ops = Vec::new();
    for &(lo, hi) in net.iter().rev() {
        let gate = match (live[lo], live[hi]) {
            (false, false) => continue,
            (true, true) => Gate::Both,
            (true, false) => Gate::Min,
            (false, true) => Gate::Max,
        };
        ops.push(Op { lo, hi, gate });
        live[lo] = true;
        live[hi] = true;
    }
    ops.reverse();
    (ops, live)
}

/// The stages' gates and which of their outputs are read.
struct Network {
    /// Sorting a column: wires 0..5 top to bottom; sorted rank k on `col_out[k]`.
    column: Vec<Op>,
    col_out: [usize; 5],
    /// Merging two sorted columns: wires 0..5 and 5..10; sorted rank k on `pair_out[k]`.
    pair: Vec<Op>,
    pair_out: [usize; 10],
    /// Merging two pairs (four columns) into the ranks a window needs of them: wires
    /// 0..10 and 10..20; rank `FOUR_LO + k` on `four_out[k]`.
    four: Vec<Op>,
    four_out: [usize; FOUR_RANKS],
    /// The window: the four columns' needed ranks on wires 0..FOUR_RANKS, the fifth
    /// column's sorted 5 after them; the median ends on `median_out`.
    window: Vec<Op>,
    median_out: usize,
    /// Which ranks of the column sort and of the pair merge are read at all.
    col_ranks: [bool; 5],
    pair_ranks: [bool; 10],
    /// Which of the four columns' ranks the window reads.
    four_ranks: [bool; FOUR_RANKS],
}

/// With 5 more values to come, only ranks 12 − 5 ..= 12 of the 20 in four columns can
/// be the 13th of 25.
const FOUR_LO: usize = 7;
const FOUR_RANKS: usize = 6;

fn network() -> &'static Network {
    static NET: OnceLock<Network> = OnceLock::new();
    NET.get_or_init(|| {
        // The window: ranks 7..=12 of four columns merged with the fifth column.
        let mut net = Vec::new();
        let t: Vec<usize> = (0..FOUR_RANKS).collect();
        let c: Vec<usize> = (FOUR_RANKS..FOUR_RANKS + 5).collect();
        let all = merge(&t, &c, &mut net);
        let median_out = all[12 - FOUR_LO];
        let (window, live) = prune(&net, &[median_out], FOUR_RANKS + 5);
        let mut four_ranks = [false; FOUR_RANKS];
        four_ranks.copy_from_slice(&live[..FOUR_RANKS]);
        let mut col_ranks = [false; 5];
        col_ranks.copy_from_slice(&live[FOUR_RANKS..]);

        let mut net = Vec::new();
        let a: Vec<usize> = (0..10).collect();
        let b: Vec<usize> = (10..20).collect();
        let sorted = merge(&a, &b, &mut net);
        let four_out: [usize; FOUR_RANKS] = std::array::from_fn(|k| sorted[FOUR_LO + k]);
        let needed: Vec<usize> = (0..FOUR_RANKS)
            .filter(|&k| four_ranks[k])
            .map(|k| four_out[k])
            .collect();
        let (four, live) = prune(&net, &needed, 20);
        let pair_ranks: [bool; 10] = std::array::from_fn(|k| live[k] || live[10 + k]);

        let mut net = Vec::new();
        let sorted = merge(&[0, 1, 2, 3, 4], &[5, 6, 7, 8, 9], &mut net);
        let needed: Vec<usize> = (0..10)
            .filter(|&k| pair_ranks[k])
            .map(|k| sorted[k])
            .collect();
        let (pair, live) = prune(&net, &needed, 10);
        let pair_out: [usize; 10] = sorted.try_into().expect("10 wires");
        for k in 0..5 {
            col_ranks[k] |= live[k] || live[5 + k];
        }

        let mut net = Vec::new();
        let sorted = sort(&[0, 1, 2, 3, 4], &mut net);
        let needed: Vec<usize> = (0..5)
            .filter(|&k| col_ranks[k])
            .map(|k| sorted[k])
            .collect();
        let (column, _) = prune(&net, &needed, 5);
        Network {
            column,
            col_out: sorted.try_into().expect("5 wires"),
            pair,
            pair_out,
            four,
            four_out,
            window,
            median_out,
            col_ranks,
            pair_ranks,
            four_ranks,
        }
    })
}

/// Pixels per block: the wires of one block (25 × 64 floats) stay in L1.
const LANES: usize = 64;
type Lane = [f32; LANES];

/// The smaller of two NaN-free values, as a comparison (the vector min instruction).
#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a < b { b } else { a }
}

/// Runs `ops` on a block of wires, each gate a vector min/max over the block's pixels.
/// Each gate computes whole new lanes before storing them: written as in-place selects,
/// LLVM turns them into stores of only the changed pixels, one at a time.
fn run(ops: &[Op], wires: &mut [Lane]) {
    /// Pixels per step: two vectors' worth, held in registers between load and store.
    const STEP: usize = 8;
    for op in ops {
        for c in (0..LANES).step_by(STEP) {
            let a: [f32; STEP] = wires[op.lo][c..c + STEP].try_into().expect("a step");
            let b: [f32; STEP] = wires[op.hi][c..c + STEP].try_into().expect("a step");
            if op.gate != Gate::Max {
                let lo: [f32; STEP] = std::array::from_fn(|k| min(a[k], b[k]));
                wires[op.lo][c..c + STEP].copy_from_slice(&lo);
            }
            if op.gate != Gate::Min {
                let hi: [f32; STEP] = std::array::from_fn(|k| max(a[k], b[k]));
                wires[op.hi][c..c + STEP].copy_from_slice(&hi);
            }
        }
    }
}

/// Copies `src[from..]` into a lane (what is beyond `src` stays as it was). A whole
/// lane is copied as a fixed-size array: inlined moves rather than a `memmove` call.
#[inline(always)]
fn load(lane: &mut Lane, src: &[f32], from: usize) {
    if let Some(whole) = src.get(from..from + LANES) {
        *lane = whole.try_into().expect("a lane");
    } else {
        let n = src.len().saturating_sub(from);
        lane[..n].copy_from_slice(&src[from..]);
    }
}

/// Copies a lane into `dst[at..]`, as much as fits.
#[inline(always)]
fn store(dst: &mut [f32], at: usize, lane: &Lane) {
    if let Some(whole) = dst.get_mut(at..at + LANES) {
        whole.copy_from_slice(lane);
    } else {
        let n = dst.len() - at;
        dst[at..].copy_from_slice(&lane[..n]);
    }
}

/// Output rows a task of [`median5`] computes.
const BAND_ROWS: usize = 16;

/// The 5×5 median, the border replicated (see the module documentation).
pub fn median5(map: &DepthMap) -> DepthMap {
    let (w, h) = (map.width, map.height);
    if map.data.is_empty() {
        return map.clone();
    }
    let mut out = scratch::map(w, h);
    let net = network();
    let row_has_data: Vec<bool> = map
        .data
        .chunks_exact(w)
        .map(|row| row.iter().any(|&d| d != 0.0))
        .collect();
    let clamp_row = |y: i64| y.clamp(0, h as i64 - 1) as usize;
    let outputs = w.div_ceil(2);
    // Each source row with the border replicated by 2 on each side (padded x = x + 2),
    // its even and odd columns apart: a pixel pair (2j, 2j+1) shares the four columns
    // 2j+1 ..= 2j+4, and every stage then reads contiguous slices.
    let pw = w + 4;
    let (ne, no) = (pw.div_ceil(2), pw / 2);
    let mut even = scratch::take(h * ne);
    let mut odd = scratch::take(h * no);
    for (y, row) in map.data.chunks_exact(w).enumerate() {
        let at = |px: usize| row[px.saturating_sub(2).min(w - 1)];
        for (j, e) in even[y * ne..(y + 1) * ne].iter_mut().enumerate() {
            *e = at(2 * j);
        }
        for (j, o) in odd[y * no..(y + 1) * no].iter_mut().enumerate() {
            *o = at(2 * j + 1);
        }
    }
    // Bands of output rows in parallel (each row depends only on the source rows, so the
    // result is the same whatever the threads): one frame's medians were the largest step
    // of IP-Basic, on the data thread beside a GPU's network.
    let (even_rows, odd_rows) = (&even[..], &odd[..]);
    out.data
        .par_chunks_mut(BAND_ROWS * w)
        .enumerate()
        .for_each(|(band, dst)| {
            // Sorted columns by rank, even and odd; pairs (2j+1, 2j+2) merged, by rank.
            let mut col_even = vec![vec![0f32; ne]; 5];
            let mut col_odd = vec![vec![0f32; no]; 5];
            let mut pairs = vec![vec![0f32; no]; 10];
            let mut wires = vec![[0f32; LANES]; 20];
            let mut tail = vec![[0f32; LANES]; FOUR_RANKS + 5];
            let mut window = vec![[0f32; LANES]; FOUR_RANKS + 5];
            for (dy, dst) in dst.chunks_exact_mut(w).enumerate() {
                let y = band * BAND_ROWS + dy;
                let rows: [usize; 5] = std::array::from_fn(|d| clamp_row(y as i64 + d as i64 - 2));
                if !rows.iter().any(|&r| row_has_data[r]) {
                    dst.fill(0.0);
                    continue;
                }
                for (src, n, cols) in [(even_rows, ne, &mut col_even), (odd_rows, no, &mut col_odd)]
                {
                    for x0 in (0..n).step_by(LANES) {
                        for (k, &r) in rows.iter().enumerate() {
                            load(&mut wires[k], &src[r * n..(r + 1) * n], x0);
                        }
                        run(&net.column, &mut wires[..5]);
                        for k in (0..5).filter(|&k| net.col_ranks[k]) {
                            store(&mut cols[k], x0, &wires[net.col_out[k]]);
                        }
                    }
                }
                // Pair j: columns 2j+1 (odd j) and 2j+2 (even j+1).
                for x0 in (0..no).step_by(LANES) {
                    for k in (0..5).filter(|&k| net.col_ranks[k]) {
                        load(&mut wires[k], &col_odd[k], x0);
                        load(&mut wires[5 + k], &col_even[k], x0 + 1);
                    }
                    run(&net.pair, &mut wires[..10]);
                    for k in (0..10).filter(|&k| net.pair_ranks[k]) {
                        store(&mut pairs[k], x0, &wires[net.pair_out[k]]);
                    }
                }
                for x0 in (0..outputs).step_by(LANES) {
                    // Columns 2j+1 ..= 2j+4: pairs j and j+1.
                    for k in (0..10).filter(|&k| net.pair_ranks[k]) {
                        load(&mut wires[k], &pairs[k], x0);
                        load(&mut wires[10 + k], &pairs[k], x0 + 1);
                    }
                    run(&net.four, &mut wires);
                    for k in (0..FOUR_RANKS).filter(|&k| net.four_ranks[k]) {
                        tail[k] = wires[net.four_out[k]];
                    }
                    // Pixel 2j adds column 2j (even j), pixel 2j+1 column 2j+5 (odd j+2).
                    for (cols, shift, parity) in [(&col_even, 0, 0), (&col_odd, 2, 1)] {
                        window[..FOUR_RANKS].copy_from_slice(&tail[..FOUR_RANKS]);
                        for k in (0..5).filter(|&k| net.col_ranks[k]) {
                            load(&mut window[FOUR_RANKS + k], &cols[k], x0 + shift);
                        }
                        run(&net.window, &mut window);
                        let median = &window[net.median_out];
                        for (i, &m) in median.iter().enumerate() {
                            if let Some(d) = dst.get_mut(2 * (x0 + i) + parity) {
                                *d = m;
                            }
                        }
                    }
                }
            }
        });
    scratch::give(even);
    scratch::give(odd);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image_ops::median5_by_sorting;

    /// Runs the three stages for one window of 25 values (row-major, 5 × 5) on any type
    /// with a min and a max: f32 here, or 64 0/1 windows packed as bits.
    fn window_median<T: Copy + Default>(
        window: &[T; 25],
        min: impl Fn(T, T) -> T + Copy,
        max: impl Fn(T, T) -> T + Copy,
    ) -> T {
        let net = network();
        let apply = |ops: &[Op], w: &mut [T]| {
            for op in ops {
                let (p, q) = (w[op.lo], w[op.hi]);
                match op.gate {
                    Gate::Both => {
                        w[op.lo] = min(p, q);
                        w[op.hi] = max(p, q);
                    }
                    Gate::Min => w[op.lo] = min(p, q),
                    Gate::Max => w[op.hi] = max(p, q),
                }
            }
        };
        let mut cols = [[T::default(); 5]; 5];
        for (x, col) in cols.iter_mut().enumerate() {
            let mut w: [T; 5] = std::array::from_fn(|y| window[y * 5 + x]);
            apply(&net.column, &mut w);
            *col = std::array::from_fn(|k| w[net.col_out[k]]);
        }
        let pair = |x: usize| {
            let mut w: [T; 10] = std::array::from_fn(|i| {
                if i < 5 {
                    cols[x][i]
                } else {
                    cols[x + 1][i - 5]
                }
            });
            apply(&net.pair, &mut w);
            std::array::from_fn::<T, 10, _>(|k| w[net.pair_out[k]])
        };
        // Columns 1..=4 as the shared four, column 0 as the window's own.
        let (a, b) = (pair(1), pair(3));
        let mut w: [T; 20] = std::array::from_fn(|i| if i < 10 { a[i] } else { b[i - 10] });
        apply(&net.four, &mut w);
        let mut last: [T; FOUR_RANKS + 5] = std::array::from_fn(|i| {
            if i < FOUR_RANKS {
                w[net.four_out[i]]
            } else {
                cols[0][i - FOUR_RANKS]
            }
        });
        apply(&net.window, &mut last);
        last[net.median_out]
    }

    #[test]
    fn the_network_selects_the_median_of_every_0_1_window() {
        // Bit j of word m is window number 64·m + j; cell i of that window is bit i of
        // its number. 2^25 windows in 2^19 words: the 0–1 principle's whole premise.
        let low: [u64; 6] = std::array::from_fn(|i| {
            (0..64u64)
                .filter(|j| j >> i & 1 == 1)
                .fold(0, |a, j| a | 1 << j)
        });
        for m in 0u64..1 << 19 {
            // Cells 0..6 vary within the word (bit i of j), cells 6..25 are bit i − 6 of m.
            let window: [u64; 25] = std::array::from_fn(|i| {
                if i < 6 {
                    low[i]
                } else if m >> (i - 6) & 1 == 1 {
                    u64::MAX
                } else {
                    0
                }
            });
            let got = window_median(&window, |a, b| a & b, |a, b| a | b);
            // The median of 0/1 values is 1 exactly when at least 13 of them are 1.
            let want = (0..64u64).fold(0, |acc, j| {
                let ones = m.count_ones() + j.count_ones();
                acc | ((ones >= 13) as u64) << j
            });
            assert_eq!(got, want, "word {m}");
        }
    }

    #[test]
    fn the_network_is_smaller_than_a_sort() {
        // Per pixel: one column sort, half a pair merge, half a four-column merge and one
        // window's gates (a full sort of 25 takes well over 100 comparators).
        let net = network();
        let per_pixel = net.column.len() + (net.pair.len() + net.four.len()) / 2 + net.window.len();
        eprintln!(
            "gates {} {} {} {}",
            net.column.len(),
            net.pair.len(),
            net.four.len(),
            net.window.len()
        );
        assert!(per_pixel < 60, "{per_pixel}");
    }

    #[test]
    fn rows_equal_sorting_on_random_maps_with_borders_and_empty_pixels() {
        let mut rng = fusiondet_dataset::rng::Sampler::new(11);
        // Widths around the block size, tiny images (the border replicated more than
        // once), many repeated values and empty rows.
        for (w, h) in [
            (1, 1),
            (2, 3),
            (5, 5),
            (7, 2),
            (63, 9),
            (64, 6),
            (65, 7),
            (131, 12),
        ] {
            let data: Vec<f32> = (0..w * h)
                .map(|i| {
                    if (i / w) % 5 == 4 || rng.chance(0.4) {
                        0.0
                    } else if rng.chance(0.3) {
                        7.5
                    } else {
                        rng.range(0.1, 95.0) as f32
                    }
                })
                .collect();
            let m = DepthMap {
                width: w,
                height: h,
                data,
            };
            assert_eq!(median5(&m), median5_by_sorting(&m), "{w}×{h}");
        }
        let empty = DepthMap::empty(70, 8);
        assert_eq!(median5(&empty), empty);
    }
}
