//! Stage one's choice of proposals as CubeCL kernels, for burn's GPU backends (cargo
//! features `wgpu` and `cuda`): the anchors ranked by their best class's logit, the top
//! `pre_max` decoded, and rotated bird's-eye NMS over them, all on the device, so that only
//! the kept anchors' rows (at most `post_max` a frame) come back to the host.
//!
//! Why: on the host the choice reads every anchor's predictions back (70,400 anchors a
//! frame at the published KITTI grid) and sorts, decodes and suppresses while the device
//! waits, in every training step and detected frame. Here the host waits only for the
//! kept rows and decodes those few in f64 exactly as before.
//!
//! - Ranking: a bitonic sort of each frame's anchors (padded to a power of two), one launch
//!   a merge step, best first by (logit, then the lower anchor). The host ranks by the
//!   sigmoid of the logit in f64, the same order except where that sigmoid rounds two
//!   logits above about 36.7 to 1.0: the host then keeps the lower anchor first.
//! - Decoding: one thread a ranked anchor, the residual coder and the direction bin in f32,
//!   as the host's `decode` and `DirectionBins::apply` in f64; each box is kept as its four
//!   footprint corners (counter-clockwise), its axis-aligned bounds and its area.
//! - Suppression: a mask of which later boxes each box overlaps by more than the threshold
//!   (one thread a box and 32 later ones: Sutherland–Hodgman clipping of one footprint by the
//!   other), then one cube a frame walks the boxes in rank order, keeping a box no kept box
//!   suppressed, with the mask's suppressed bits in shared memory. Both go
//!   [`SUPPRESSION_ROWS`] boxes at a time, the pass's state carried over, and a frame that
//!   has kept `post_max` skips the rest: the mask is made only for rows the pass may read
//!   (a training step ranks 9,000 boxes a frame, 40.5 M pairs, and keeps 512). That is the
//!   host's greedy NMS decision for decision; in f32 a pair whose IoU is within rounding of
//!   the threshold may be decided the other way.

use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::{CubeCount, CubeDim};
use fusiondet_nn::cube::{f32_buffer, float_rows, i32_buffer, launch_shape};
use kernels::{BOX_VALUES, MAX_WORDS, TILE};

/// The most anchors a frame ranks for suppression on the device: the greedy pass holds one
/// bit a ranked box in shared memory (2 KiB). More falls back to the host.
pub const MAX_RANKED: usize = MAX_WORDS * 32;

/// Ranked boxes a frame whose suppression-mask rows are made before the greedy pass reads
/// them (a training step ranks 9,000 and keeps 512; the pass usually stops within the first
/// rows).
pub const SUPPRESSION_ROWS: usize = 1024;

/// What a frame keeps and how its boxes are decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProposalSelection {
    /// Anchors ranked and decoded a frame (the host's `pre_max`).
    pub pre_max: usize,
    /// Boxes kept a frame at most.
    pub post_max: usize,
    /// A box is suppressed by a kept one it overlaps by more than this bird's-eye IoU.
    pub iou: f32,
    /// The direction classifier's bins (`DirectionBins`): first bin's start, the wrapping
    /// offset and the number of bins.
    pub dir_offset: f32,
    pub dir_limit_offset: f32,
    pub dir_bins: usize,
}

/// The kernels (see the module's documentation).
#[backend_extension(Cube)]
pub trait ProposalOps: Backend {
    /// From the anchor head's class logits [B, A, K], residual codes [B, A, 7] and direction
    /// logits [B, A, bins], and the anchors [A, 7] (x, y, z, dx, dy, dz, heading): each frame's
    /// number of kept boxes [B] and their rows of the predictions laid out [B · A, ·]
    /// (frame b's anchor a is row b·A + a), [B · post_max] in rank order, the unused
    /// slots 0.
    fn select_proposals(
        cls: FloatTensor<Self>,
        codes: FloatTensor<Self>,
        dir: FloatTensor<Self>,
        anchors: FloatTensor<Self>,
        selection: ProposalSelection,
    ) -> (IntTensor<Self>, IntTensor<Self>);
}

/// [`ProposalOps::select_proposals`] on burn tensors of a CubeCL device (autodiff dropped:
/// nothing here is differentiated).
pub fn select_proposals(
    cls: Tensor<3>,
    codes: Tensor<3>,
    dir: Tensor<3>,
    anchors: Tensor<2>,
    selection: ProposalSelection,
) -> (Tensor<1, Int>, Tensor<1, Int>) {
    let (counts, rows) = <Dispatch as ProposalOps>::select_proposals(
        cls.inner().into_dispatch(),
        codes.inner().into_dispatch(),
        dir.inner().into_dispatch(),
        anchors.inner().into_dispatch(),
        selection,
    );
    (Tensor::from_dispatch(counts), Tensor::from_dispatch(rows))
}

/// The kernels, in CubeCL's language (its prelude names `Tensor` apart from burn's).
mod kernels {
    use cubecl::prelude::*;

    /// Words of the suppression mask's row held in shared memory by a frame's greedy pass.
    pub const MAX_WORDS: usize = 512;
    /// Values kept a decoded box: four corners (x, y), bounds (x0, y0, x1, y1), area.
    pub const BOX_VALUES: usize = 13;
    /// Slots a cube sorts in shared memory ([`bitonic_tile`]).
    pub const TILE: usize = 1024;

    /// Whether (key a, item a) ranks before (key b, item b): padding (items from `anchors`
    /// on) last, then the larger logit, then the lower anchor.
    #[cube]
    fn ranks_before(key_a: f32, item_a: i32, key_b: f32, item_b: i32, anchors: i32) -> bool {
        let mut before = false;
        if item_a >= anchors {
            if item_b >= anchors {
                before = item_a < item_b;
            }
        } else if item_b >= anchors || key_a > key_b {
            before = true;
        } else if key_a == key_b {
            before = item_a < item_b;
        }
        before
    }

    /// One thread a (frame, slot) of [B, slots]: the anchor's best class logit and its
    /// index, or padding past the last anchor.
    #[cube(launch_unchecked)]
    pub fn rank_keys(
        cls: &Tensor<f32>,
        keys: &mut Tensor<f32>,
        items: &mut Tensor<i32>,
        anchors: u32,
        classes: u32,
        slots: u32,
    ) {
        let pos = ABSOLUTE_POS;
        if pos >= keys.len() {
            terminate!();
        }
        let frame = pos / slots as usize;
        let slot = pos % slots as usize;
        let mut best = 0.0f32;
        if slot < anchors as usize {
            let at = frame * cls.stride(0) + slot * cls.stride(1);
            best = cls[at];
            for k in 1..classes as usize {
                let v = cls[at + k * cls.stride(2)];
                if v > best {
                    best = v;
                }
            }
        }
        keys[pos] = best;
        items[pos] = slot as i32;
    }

    /// One compare-exchange step of a bitonic sort over each frame's `slots` entries: the
    /// pair (i, i ^ stride) ordered best first where bit `block` of i is clear, else last.
    #[cube(launch_unchecked)]
    pub fn bitonic_step(
        keys: &mut Tensor<f32>,
        items: &mut Tensor<i32>,
        anchors: u32,
        slots: u32,
        block: u32,
        stride: u32,
    ) {
        let pos = ABSOLUTE_POS;
        if pos >= keys.len() {
            terminate!();
        }
        let base = (pos / slots as usize) * slots as usize;
        let i = pos % slots as usize;
        let j = i ^ stride as usize;
        if j > i {
            let p = base + i;
            let q = base + j;
            let best_first = (i & block as usize) == 0;
            let q_before = ranks_before(keys[q], items[q], keys[p], items[p], anchors as i32);
            if best_first == q_before {
                let key = keys[p];
                let item = items[p];
                keys[p] = keys[q];
                items[p] = items[q];
                keys[q] = key;
                items[q] = item;
            }
        }
    }

    /// The bitonic steps of strides below a tile, in shared memory: one cube a tile of
    /// `tile` (≤ [`TILE`]) consecutive slots of a frame, one unit a compare-exchange pair,
    /// for every merge level `block` from `first_block` to `last_block` (doubling) and
    /// every stride from min(block, tile) / 2 down to 1: the same pairs in the same order as
    /// [`bitonic_step`] launched stride by stride.
    #[cube(launch_unchecked)]
    pub fn bitonic_tile(
        keys: &mut Tensor<f32>,
        items: &mut Tensor<i32>,
        anchors: u32,
        slots: u32,
        tile: u32,
        first_block: u32,
        last_block: u32,
    ) {
        let start = CUBE_POS_X as usize * tile as usize;
        let unit = UNIT_POS as usize;
        let half = tile as usize / 2;
        let mut tile_keys = Shared::<[f32]>::new_slice(comptime!(TILE));
        let mut tile_items = Shared::<[i32]>::new_slice(comptime!(TILE));
        if unit < half {
            tile_keys[unit] = keys[start + unit];
            tile_items[unit] = items[start + unit];
            tile_keys[unit + half] = keys[start + unit + half];
            tile_items[unit + half] = items[start + unit + half];
        }
        sync_cube();
        let mut block = first_block as usize;
        while block <= last_block as usize {
            let mut stride = block / 2;
            if stride > half {
                stride = half;
            }
            while stride > 0 {
                if unit < half {
                    let i = 2 * stride * (unit / stride) + unit % stride;
                    let j = i + stride;
                    // The slot's index in its frame (a frame's slots are a whole number of
                    // tiles) sets the direction, as in `bitonic_step`.
                    let best_first = (((start + i) % slots as usize) & block) == 0;
                    let q_before = ranks_before(
                        tile_keys[j],
                        tile_items[j],
                        tile_keys[i],
                        tile_items[i],
                        anchors as i32,
                    );
                    if best_first == q_before {
                        let key = tile_keys[i];
                        let item = tile_items[i];
                        tile_keys[i] = tile_keys[j];
                        tile_items[i] = tile_items[j];
                        tile_keys[j] = key;
                        tile_items[j] = item;
                    }
                }
                sync_cube();
                stride /= 2;
            }
            block *= 2;
        }
        if unit < half {
            keys[start + unit] = tile_keys[unit];
            items[start + unit] = tile_items[unit];
            keys[start + unit + half] = tile_keys[unit + half];
            items[start + unit + half] = tile_items[unit + half];
        }
    }

    /// One thread a ranked anchor (frame, rank < ranked): its box decoded (the host's
    /// `decode` and `DirectionBins::apply`), written as [`BOX_VALUES`] values.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn decode_ranked(
        items: &Tensor<i32>,
        anchors: &Tensor<f32>,
        codes: &Tensor<f32>,
        dir: &Tensor<f32>,
        boxes: &mut Tensor<f32>,
        slots: u32,
        ranked: u32,
        bins: u32,
        dir_offset: f32,
        dir_limit_offset: f32,
        period: f32,
    ) {
        let pos = ABSOLUTE_POS;
        if pos * BOX_VALUES >= boxes.len() {
            terminate!();
        }
        let frame = pos / ranked as usize;
        let rank = pos % ranked as usize;
        let a = items[frame * slots as usize + rank] as usize;
        let at = a * anchors.stride(0);
        let s = anchors.stride(1);
        let (ax, ay) = (anchors[at], anchors[at + s]);
        let (adx, ady) = (anchors[at + 3 * s], anchors[at + 4 * s]);
        let aheading = anchors[at + 6 * s];
        let c = frame * codes.stride(0) + a * codes.stride(1);
        let cs = codes.stride(2);
        let diagonal = (adx * adx + ady * ady).sqrt();
        let x = codes[c] * diagonal + ax;
        let y = codes[c + cs] * diagonal + ay;
        let dx = codes[c + 3 * cs].exp() * adx;
        let dy = codes[c + 4 * cs].exp() * ady;
        let mut heading = codes[c + 6 * cs] + aheading;

        let d = frame * dir.stride(0) + a * dir.stride(1);
        let mut bin = 0usize;
        for k in 1..bins as usize {
            if dir[d + k * dir.stride(2)] > dir[d + bin * dir.stride(2)] {
                bin = k;
            }
        }
        let shifted = heading - dir_offset;
        heading = shifted - (shifted / period + dir_limit_offset).floor() * period
            + dir_offset
            + period * f32::cast_from(bin as u32);

        let (sin, cos) = (heading.sin(), heading.cos());
        let (hx, hy) = (dx / 2.0f32, dy / 2.0f32);
        let out = pos * BOX_VALUES;
        let mut x0 = x;
        let mut y0 = y;
        let mut x1 = x;
        let mut y1 = y;
        for k in 0..4usize {
            // Counter-clockwise: (hx, −hy), (hx, hy), (−hx, hy), (−hx, −hy).
            let mut u = hx;
            if k >= 2 {
                u = -hx;
            }
            let mut v = hy;
            if k == 0 || k == 3 {
                v = -hy;
            }
            let cx = x + cos * u - sin * v;
            let cy = y + sin * u + cos * v;
            boxes[out + 2 * k] = cx;
            boxes[out + 2 * k + 1] = cy;
            if cx < x0 {
                x0 = cx;
            }
            if cy < y0 {
                y0 = cy;
            }
            if cx > x1 {
                x1 = cx;
            }
            if cy > y1 {
                y1 = cy;
            }
        }
        boxes[out + 8] = x0;
        boxes[out + 9] = y0;
        boxes[out + 10] = x1;
        boxes[out + 11] = y1;
        boxes[out + 12] = dx * dy;
    }

    /// Which side of the directed line (x0, y0) → (x1, y1) the point lies on: positive to
    /// its left.
    #[cube]
    fn side(x0: f32, y0: f32, x1: f32, y1: f32, px: f32, py: f32) -> f32 {
        (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0)
    }

    /// The area of box `a`'s footprint clipped by box `b`'s (both counter-clockwise;
    /// Sutherland–Hodgman, a convex polygon of at most 8 vertices).
    #[cube]
    fn intersection_area(boxes: &Tensor<f32>, a: usize, b: usize) -> f32 {
        let mut px = Array::<f32>::new(16usize);
        let mut py = Array::<f32>::new(16usize);
        let mut qx = Array::<f32>::new(16usize);
        let mut qy = Array::<f32>::new(16usize);
        for k in 0..4usize {
            px[k] = boxes[a * BOX_VALUES + 2 * k];
            py[k] = boxes[a * BOX_VALUES + 2 * k + 1];
        }
        let mut n = 4usize;
        for e in 0..4usize {
            let f = (e + 1) % 4;
            let ex0 = boxes[b * BOX_VALUES + 2 * e];
            let ey0 = boxes[b * BOX_VALUES + 2 * e + 1];
            let ex1 = boxes[b * BOX_VALUES + 2 * f];
            let ey1 = boxes[b * BOX_VALUES + 2 * f + 1];
            let mut m = 0usize;
            for k in 0..n {
                let next = (k + 1) % n;
                let ds = side(ex0, ey0, ex1, ey1, px[k], py[k]);
                let dt = side(ex0, ey0, ex1, ey1, px[next], py[next]);
                if ds >= 0.0f32 {
                    qx[m] = px[k];
                    qy[m] = py[k];
                    m += 1;
                }
                // The edge crosses the line: one end inside, the other outside (so ds ≠ dt).
                let mut crosses = false;
                if ds >= 0.0f32 {
                    if dt < 0.0f32 {
                        crosses = true;
                    }
                } else if dt >= 0.0f32 {
                    crosses = true;
                }
                if crosses {
                    let r = ds / (ds - dt);
                    qx[m] = px[k] + r * (px[next] - px[k]);
                    qy[m] = py[k] + r * (py[next] - py[k]);
                    m += 1;
                }
            }
            for k in 0..m {
                px[k] = qx[k];
                py[k] = qy[k];
            }
            n = m;
        }
        let mut twice = 0.0f32;
        for k in 0..n {
            let next = (k + 1) % n;
            twice += px[k] * py[next] - px[next] * py[k];
        }
        twice.abs() / 2.0f32
    }

    /// Whether box `a` and box `b` overlap by more than `threshold` (the host's bound test,
    /// then the IoU).
    #[cube]
    fn suppresses(boxes: &Tensor<f32>, a: usize, b: usize, threshold: f32) -> bool {
        let (oa, ob) = (a * BOX_VALUES, b * BOX_VALUES);
        let mut apart = false;
        if boxes[oa + 8] >= boxes[ob + 10] {
            apart = true;
        }
        if boxes[ob + 8] >= boxes[oa + 10] {
            apart = true;
        }
        if boxes[oa + 9] >= boxes[ob + 11] {
            apart = true;
        }
        if boxes[ob + 9] >= boxes[oa + 11] {
            apart = true;
        }
        let mut overlaps = false;
        if !apart {
            let inter = intersection_area(boxes, a, b);
            let union = boxes[oa + 12] + boxes[ob + 12] - inter;
            // (Both sides of a `&&` are evaluated in a kernel; here both are plain values.)
            // The host clamps the ratio to 1, which a threshold below 1 never sees.
            if inter > 0.0f32 && union > 0.0f32 {
                overlaps = inter / union > threshold;
            }
        }
        overlaps
    }

    /// One thread a (frame, box i, word w) for the boxes i of rows `first_row ..
    /// first_row + rows`: bit t of the word set where box 32w + t comes after box i and
    /// overlaps it by more than `threshold`. A frame whose greedy pass is `done` is skipped:
    /// its later rows are never read.
    #[cube(launch_unchecked)]
    // Nested, not `&&`: a kernel evaluates both sides, and box j exists only below `ranked`.
    #[allow(clippy::collapsible_if, clippy::too_many_arguments)]
    pub fn overlap_mask(
        boxes: &Tensor<f32>,
        done: &Tensor<u32>,
        mask: &mut Tensor<u32>,
        ranked: u32,
        words: u32,
        first_row: u32,
        rows: u32,
        threshold: f32,
    ) {
        let pos = ABSOLUTE_POS;
        let per_frame = (rows * words) as usize;
        let frame = pos / per_frame;
        if frame >= done.len() {
            terminate!();
        }
        let w = pos % words as usize;
        let i = first_row as usize + (pos % per_frame) / words as usize;
        if i >= ranked as usize || done[frame] != 0u32 {
            terminate!();
        }
        let row = frame * ranked as usize + i;
        let frame_first = row - i;
        let mut bits = 0u32;
        for t in 0..32usize {
            let j = w * 32 + t;
            if j > i && j < ranked as usize {
                if suppresses(boxes, row, frame_first + j, threshold) {
                    bits |= 1u32 << t as u32;
                }
            }
        }
        mask[row * words as usize + w] = bits;
    }

    /// One cube a frame, over the boxes of rows `first_row .. end_row` in rank order: each
    /// kept unless a kept box suppressed it, until `post` are kept. Writes the kept boxes'
    /// prediction rows (`kept`, zeros beforehand) and carries the frame's state to the next
    /// rows: its suppressed bits (`removed`, copied into shared memory and back), its count
    /// (`counts`) and whether it is `done` (`post` kept).
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn greedy_keep(
        mask: &Tensor<u32>,
        items: &Tensor<i32>,
        kept: &mut Tensor<i32>,
        counts: &mut Tensor<i32>,
        removed: &mut Tensor<u32>,
        done: &mut Tensor<u32>,
        ranked: u32,
        words: u32,
        slots: u32,
        post: u32,
        anchors: u32,
        first_row: u32,
        end_row: u32,
    ) {
        let frame = CUBE_POS_X as usize;
        let unit = UNIT_POS as usize;
        let units = CUBE_DIM as usize;
        // The same value for every unit of the cube: all leave together.
        if done[frame] != 0u32 {
            terminate!();
        }
        let mut shared = Shared::<[u32]>::new_slice(comptime!(MAX_WORDS));
        let state = frame * words as usize;
        let mut w = unit;
        while w < words as usize {
            shared[w] = removed[state + w];
            w += units;
        }
        // Every unit has also read `done` before unit 0 may write it below.
        sync_cube();
        let mut count = counts[frame] as usize;
        // Every unit reads the same words and keeps the same count, so all leave the scan
        // together, at the chunk's last box or once `post` are kept (the rest could not be).
        let mut i = first_row as usize;
        while i < end_row as usize && count < post as usize {
            let word = shared[i / 32];
            let keep = ((word >> (i % 32) as u32) & 1u32) == 0u32;
            // Every unit has read the word before any writes it.
            sync_cube();
            if keep {
                if unit == 0 {
                    kept[frame * post as usize + count] =
                        (frame * anchors as usize) as i32 + items[frame * slots as usize + i];
                }
                count += 1;
                let row = (frame * ranked as usize + i) * words as usize;
                let mut v = unit;
                while v < words as usize {
                    shared[v] |= mask[row + v];
                    v += units;
                }
            }
            sync_cube();
            i += 1;
        }
        let mut v = unit;
        while v < words as usize {
            removed[state + v] = shared[v];
            v += units;
        }
        if unit == 0 {
            counts[frame] = count as i32;
            if count >= post as usize {
                done[frame] = 1u32;
            }
        }
    }
}

impl ProposalOps for CubeBackend {
    fn select_proposals(
        cls: CubeTensor,
        codes: CubeTensor,
        dir: CubeTensor,
        anchors: CubeTensor,
        selection: ProposalSelection,
    ) -> (CubeTensor, CubeTensor) {
        let (cls, codes, dir, anchors) = (
            float_rows(cls),
            float_rows(codes),
            float_rows(dir),
            float_rows(anchors),
        );
        let client = cls.client.clone();
        let device = cls.device.clone();
        let [frames, num_anchors, classes] = [0, 1, 2].map(|d| cls.meta.shape()[d]);
        let post = selection.post_max;
        let ranked = selection.pre_max.min(num_anchors);
        assert!(
            ranked <= MAX_RANKED,
            "{ranked} ranked anchors a frame: the device's NMS holds at most {MAX_RANKED}"
        );
        let zeros = |len: usize, dtype| {
            burn_cubecl::ops::numeric::zeros_client(
                client.clone(),
                device.clone(),
                [len].into(),
                dtype,
            )
        };
        // Every frame's count, and its `post` kept rows in rank order: 0 until kept (a row a
        // gather may read).
        let counts = zeros(frames, burn::tensor::DType::I32);
        let kept = zeros(frames * post, burn::tensor::DType::I32);
        if frames == 0 || post == 0 || ranked == 0 {
            // Nothing to keep.
            return (counts, kept);
        }
        // Rank.
        let slots = num_anchors.next_power_of_two();
        let keys = f32_buffer(&cls, frames * slots);
        let items = i32_buffer(&cls, frames * slots);
        let (count, dim) = launch_shape(&client, frames * slots);
        // SAFETY: threads past the last slot return first; a slot below the anchors reads its
        // own frame's and anchor's K logits through the strides; each writes its own entry.
        unsafe {
            kernels::rank_keys::launch_unchecked(
                &client,
                count.clone(),
                dim,
                cls.into_tensor_arg(),
                keys.clone().into_tensor_arg(),
                items.clone().into_tensor_arg(),
                num_anchors as u32,
                classes as u32,
                slots as u32,
            );
        }
        // Strides of at least a tile one launch each; the shorter ones of a merge level (all
        // levels up to a tile at once) in shared memory, one cube a tile.
        let tile = slots.min(TILE);
        let tile_launch = |first_block: usize, last_block: usize| {
            // SAFETY: one cube a tile of `tile` slots (a power of two dividing `slots`, so a
            // tile lies within a frame); its first tile / 2 units each load, exchange and
            // store a pair of the tile's slots, in shared memory of TILE ≥ tile entries;
            // barriers run in uniform control flow (the loops' bounds are scalars).
            unsafe {
                kernels::bitonic_tile::launch_unchecked(
                    &client,
                    CubeCount::Static((frames * slots / tile) as u32, 1, 1),
                    CubeDim::new_1d((TILE / 2) as u32),
                    keys.clone().into_tensor_arg(),
                    items.clone().into_tensor_arg(),
                    num_anchors as u32,
                    slots as u32,
                    tile as u32,
                    first_block as u32,
                    last_block as u32,
                );
            }
        };
        tile_launch(2, tile);
        let mut block = tile * 2;
        while block <= slots {
            let mut stride = block / 2;
            while stride >= tile {
                // SAFETY: a thread touches its slot and its partner slot ^ stride (below
                // `slots`, a power of two, within its frame) and only when the partner is
                // the later, so no two threads touch one entry.
                unsafe {
                    kernels::bitonic_step::launch_unchecked(
                        &client,
                        count.clone(),
                        dim,
                        keys.clone().into_tensor_arg(),
                        items.clone().into_tensor_arg(),
                        num_anchors as u32,
                        slots as u32,
                        block as u32,
                        stride as u32,
                    );
                }
                stride /= 2;
            }
            tile_launch(block, block);
            block *= 2;
        }

        // Decode the ranked.
        let boxes = f32_buffer(&keys, frames * ranked * BOX_VALUES);
        let (count, dim) = launch_shape(&client, frames * ranked);
        let period = std::f32::consts::TAU / selection.dir_bins as f32;
        // SAFETY: threads past the last ranked anchor return first; a ranked slot holds an
        // anchor (padding sorts after every anchor and `ranked` ≤ anchors), whose rows of the
        // anchors, codes and direction logits are read through their strides; a thread
        // writes its own box.
        unsafe {
            kernels::decode_ranked::launch_unchecked(
                &client,
                count,
                dim,
                items.clone().into_tensor_arg(),
                anchors.into_tensor_arg(),
                codes.into_tensor_arg(),
                dir.into_tensor_arg(),
                boxes.clone().into_tensor_arg(),
                slots as u32,
                ranked as u32,
                selection.dir_bins as u32,
                selection.dir_offset,
                selection.dir_limit_offset,
                period,
            );
        }

        // Suppress, SUPPRESSION_ROWS ranked boxes at a time: their mask rows, then the greedy
        // pass over them. Once a frame has kept `post` boxes its later rows are skipped, so
        // the mask costs the rows the pass reads, not every pair of ranked boxes.
        let words = ranked.div_ceil(32);
        let mask = burn_cubecl::ops::numeric::empty_device_dtype(
            client.clone(),
            device.clone(),
            [frames * ranked * words].into(),
            burn::tensor::DType::U32,
        );
        let removed = zeros(frames * words, burn::tensor::DType::U32);
        let done = zeros(frames, burn::tensor::DType::U32);
        let mut first_row = 0;
        while first_row < ranked {
            let rows = SUPPRESSION_ROWS.min(ranked - first_row);
            let (count, dim) = launch_shape(&client, frames * rows * words);
            // SAFETY: threads past the last frame, past `ranked` or of a done frame return
            // first; a word's boxes are its frame's (i and j below `ranked`), read whole from
            // the decoded boxes; each writes its word of row i.
            unsafe {
                kernels::overlap_mask::launch_unchecked(
                    &client,
                    count,
                    dim,
                    boxes.clone().into_tensor_arg(),
                    done.clone().into_tensor_arg(),
                    mask.clone().into_tensor_arg(),
                    ranked as u32,
                    words as u32,
                    first_row as u32,
                    rows as u32,
                    selection.iou,
                );
            }
            // SAFETY: one cube a frame (a done frame's cube returns as a whole); its units
            // share `words` ≤ MAX_WORDS entries of shared memory (asserted above through
            // `ranked`), each copying and ORing the words unit, unit + CUBE_DIM, …; barriers
            // run in uniform control flow (the loop's bounds and the count are the same for
            // every unit); unit 0 alone writes the frame's kept slots, count and flag.
            unsafe {
                kernels::greedy_keep::launch_unchecked(
                    &client,
                    CubeCount::Static(frames as u32, 1, 1),
                    CubeDim::new_1d(256),
                    mask.clone().into_tensor_arg(),
                    items.clone().into_tensor_arg(),
                    kept.clone().into_tensor_arg(),
                    counts.clone().into_tensor_arg(),
                    removed.clone().into_tensor_arg(),
                    done.clone().into_tensor_arg(),
                    ranked as u32,
                    words as u32,
                    slots as u32,
                    post as u32,
                    num_anchors as u32,
                    first_row as u32,
                    (first_row + rows) as u32,
                );
            }
            first_row += rows;
        }
        (counts, kept)
    }
}
