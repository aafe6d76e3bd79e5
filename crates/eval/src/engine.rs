//! The devkit's matching algorithm (cleanData, computeStatistics, getThresholds of
//! `evaluate_object.cpp`), re-expressed for speed without changing a single decision.
//!
//! Why it is fast:
//! * Each frame is prepared once per evaluated class: only the ground truth of the class
//!   and its neighbour, only the detections that can take part (the class's own, plus
//!   other classes' detections small enough to be "ignored detections", which the devkit
//!   lets absorb ground truth), and the overlap matrices of the three measures. The
//!   matrices are shared by the three difficulties, both overlap settings and every
//!   score threshold. DontCare regions reduce to one number per detection and measure
//!   (its largest overlap over the detection's own area), because the devkit only asks
//!   whether *some* region exceeds the minimum overlap.
//! * Per frame and task, only the (ground truth, detection) pairs with overlap above the
//!   minimum are kept as candidates: no devkit branch can select any other pair, so a
//!   detection without candidates is a false positive (or not) on its own and never
//!   changes the matching.
//! * The second pass runs, per frame, once per distinct set of above-threshold
//!   candidate detections rather than once per threshold: a frame's matching only
//!   changes when a threshold crosses one of their scores.
//! * Frames are processed in parallel in fixed chunks (rayon), summed in frame order so
//!   results are bit-identical from run to run; each chunk reuses one scratch buffer, so
//!   the inner loops do not allocate.
//!
//! The devkit's order-dependent tie-breaking is kept: ground truth and detections are
//! visited in file order, the first candidate wins ties.

use crate::frames::{FrameDet, FrameGt};
use crate::protocol::{Difficulty, N_SAMPLE_PTS, neighbour_class};
use fusiondet_geometry::{Normalization, overlap_2d, overlap_3d, overlap_bev};
use fusiondet_kitti::{Object, ObjectClass};
use rayon::prelude::*;

/// Frames per parallel work item.
const CHUNK: usize = 64;

/// The devkit's "no detection assigned" score sentinel.
const NO_DETECTION: f64 = -10_000_000.0;

/// Ground truth status at one difficulty (the devkit's `ignored_gt`; boxes of unrelated
/// classes, its -1, are not stored at all).
const GT_VALID: i8 = 0;
const GT_IGNORED: i8 = 1;
/// Detection status at one difficulty (the devkit's `ignored_det`).
const DET_VALID: i8 = 0;
const DET_IGNORED: i8 = 1;
const DET_OTHER: i8 = -1;

/// One evaluated class within one frame: the boxes that can matter and their overlaps.
pub(crate) struct ClassFrame {
    /// Index of each kept ground-truth box in the frame's object list (file order).
    pub gt_obj: Vec<u32>,
    /// Per difficulty: `GT_VALID` or `GT_IGNORED`.
    pub gt_ig: [Vec<i8>; 3],
    pub gt_alpha: Vec<f64>,
    /// Index of each kept detection in the frame's detection list (file order).
    pub det_obj: Vec<u32>,
    /// Per difficulty: `DET_VALID`, `DET_IGNORED` or `DET_OTHER`.
    pub det_ig: [Vec<i8>; 3],
    pub det_score: Vec<f64>,
    pub det_alpha: Vec<f64>,
    /// The (detection, overlaps) pairs that overlap at all, grouped by ground-truth box in
    /// detection order: ground-truth box g's are `pairs[pair_start[g]..pair_start[g + 1]]`,
    /// each with its overlap over the union per measure (bbox, bev, 3d). Kept sparse, not
    /// as an n_gt × n_det matrix: every pair left out has overlap 0 in every measure, which
    /// no devkit branch selects (the minimum overlaps are positive), and a dense indoor
    /// scene of 20,000 boxes a side would need gigabytes for the matrix.
    pub pairs: Vec<(u32, [f64; 3])>,
    pub pair_start: Vec<u32>,
    /// Per measure: the detection's largest overlap with a DontCare region, over its own area.
    pub dc: [Vec<f64>; 3],
}

impl ClassFrame {
    pub fn n_gt(&self) -> usize {
        self.gt_obj.len()
    }
    /// The overlapping (detection, overlaps) pairs of ground-truth box `g`, by detection.
    pub fn pairs_of(&self, g: usize) -> &[(u32, [f64; 3])] {
        &self.pairs[self.pair_start[g] as usize..self.pair_start[g + 1] as usize]
    }
    pub fn n_det(&self) -> usize {
        self.det_obj.len()
    }
}

/// Every frame prepared for every evaluated class: `frames[frame][class index]`.
pub(crate) struct Prepared {
    pub frames: Vec<Vec<ClassFrame>>,
}

/// Extra filtering for a breakdown bin, per frame and class (see `breakdown`).
pub(crate) struct BinMask {
    /// Per kept ground-truth box: outside the bin, so treated as ignored.
    pub gt_out: Vec<bool>,
    /// Per measure and kept detection: not charged to this bin if left unassigned.
    pub det_exempt: [Vec<bool>; 3],
}

/// One matching problem: a class, an overlap measure and its minimum overlap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Task {
    pub class_idx: usize,
    /// 0 bbox, 1 bev, 2 3d.
    pub overlap: usize,
    pub min_overlap: f64,
}

/// Accumulated statistics of one task at one difficulty, per score threshold.
#[derive(Debug, Clone, Default)]
pub(crate) struct Counts {
    /// Non-ignored ground truth (the recall denominator).
    pub n_gt: usize,
    /// Score thresholds from `get_thresholds`, descending.
    pub thresholds: Vec<f64>,
    pub tp: Vec<u64>,
    pub fp: Vec<u64>,
    pub fn_: Vec<u64>,
    /// Summed orientation similarity of the true positives (bbox tasks with AOS only).
    pub similarity: Vec<f64>,
}

#[derive(Debug, Clone, Copy, Default)]
struct Acc {
    tp: u64,
    fp: u64,
    fn_: u64,
    sim: f64,
}

impl std::ops::AddAssign for Acc {
    fn add_assign(&mut self, o: Acc) {
        self.tp += o.tp;
        self.fp += o.fp;
        self.fn_ += o.fn_;
        self.sim += o.sim;
    }
}

/// The devkit's detection height: |y1 − y2| converted to a 32-bit integer (truncated).
fn detection_height_px(o: &Object) -> i32 {
    (o.bbox.y1 - o.bbox.y2).abs() as i32
}

/// Whether a ground-truth object falls outside level `d` (KITTI's height, occlusion and
/// truncation limits).
pub(crate) fn gt_ignored(o: &Object, d: Difficulty) -> bool {
    let height = o.bbox.y2 - o.bbox.y1;
    o.occlusion > d.max_occlusion() || o.truncation > d.max_truncation() || height <= d.min_height()
}

fn overlap(m: usize, det: &Object, other: &Object, norm: Normalization) -> f64 {
    match m {
        0 => overlap_2d(&det.bbox, &other.bbox, norm),
        1 => overlap_bev(&det.box3d, &other.box3d, norm),
        _ => overlap_3d(&det.box3d, &other.box3d, norm),
    }
}

/// The most overlapping (ground truth, detection) pairs one frame and class may hold: at
/// 32 bytes a pair, about 1.6 GB. Only boxes piled on each other reach it.
pub(crate) const MAX_PAIRS: usize = 50_000_000;

/// Half the diagonal of a box's footprint: no footprint reaches further from its centre.
fn footprint_radius(b: &fusiondet_geometry::Box3d) -> f64 {
    0.5 * b.l.hypot(b.w)
}

/// Whether two boxes' footprints cannot intersect (their enclosing circles are apart), so
/// that their bird's-eye and 3D overlaps are 0 without clipping polygons.
fn footprints_apart(a: &fusiondet_geometry::Box3d, b: &fusiondet_geometry::Box3d) -> bool {
    let reach = footprint_radius(a) + footprint_radius(b);
    // The margin keeps the test conservative against rounding: it may only let pairs through.
    (a.x - b.x).hypot(a.z - b.z) > reach * (1.0 + 1e-9) + 1e-9
}

fn prepare_class(
    gt: &[Object],
    det: &[Object],
    dontcare: &[&Object],
    class: ObjectClass,
) -> Result<ClassFrame, usize> {
    let neighbour = neighbour_class(class);
    let mut cf = ClassFrame {
        gt_obj: Vec::new(),
        gt_ig: Default::default(),
        gt_alpha: Vec::new(),
        det_obj: Vec::new(),
        det_ig: Default::default(),
        det_score: Vec::new(),
        det_alpha: Vec::new(),
        pairs: Vec::new(),
        pair_start: Vec::new(),
        dc: Default::default(),
    };
    for (i, o) in gt.iter().enumerate() {
        let exact = o.class == class;
        if !exact && Some(o.class) != neighbour {
            continue;
        }
        cf.gt_obj.push(i as u32);
        cf.gt_alpha.push(o.alpha);
        for d in Difficulty::ALL {
            let valid = exact && !gt_ignored(o, d);
            cf.gt_ig[d.index()].push(if valid { GT_VALID } else { GT_IGNORED });
        }
    }
    for (j, o) in det.iter().enumerate() {
        let height = detection_height_px(o) as f64;
        let status = Difficulty::ALL.map(|d| {
            if height < d.min_height() {
                DET_IGNORED
            } else if o.class == class {
                DET_VALID
            } else {
                DET_OTHER
            }
        });
        if status.iter().all(|&s| s == DET_OTHER) {
            continue;
        }
        cf.det_obj.push(j as u32);
        for (d, s) in status.iter().enumerate() {
            cf.det_ig[d].push(*s);
        }
        // `evaluate` has checked that every detection has a score.
        cf.det_score.push(o.score.unwrap_or(f64::NEG_INFINITY));
        cf.det_alpha.push(o.alpha);
    }
    let nd = cf.n_det();
    for m in 0..3 {
        cf.dc[m] = vec![0.0; nd];
    }
    for &gi in &cf.gt_obj {
        let gobj = &gt[gi as usize];
        cf.pair_start.push(cf.pairs.len() as u32);
        for (j, &dj) in cf.det_obj.iter().enumerate() {
            let dobj = &det[dj as usize];
            let bbox = overlap(0, dobj, gobj, Normalization::Union);
            let (bev, volume) = if footprints_apart(&dobj.box3d, &gobj.box3d) {
                (0.0, 0.0)
            } else {
                let bev = overlap(1, dobj, gobj, Normalization::Union);
                // No footprint intersection means no volume intersection either.
                let volume = if bev > 0.0 {
                    overlap(2, dobj, gobj, Normalization::Union)
                } else {
                    0.0
                };
                (bev, volume)
            };
            if bbox > 0.0 || bev > 0.0 || volume > 0.0 {
                if cf.pairs.len() == MAX_PAIRS {
                    return Err(cf.pairs.len());
                }
                cf.pairs.push((j as u32, [bbox, bev, volume]));
            }
        }
    }
    cf.pair_start.push(cf.pairs.len() as u32);
    for (j, &dj) in cf.det_obj.iter().enumerate() {
        let dobj = &det[dj as usize];
        for m in 0..3 {
            cf.dc[m][j] = dontcare
                .iter()
                .map(|r| overlap(m, dobj, r, Normalization::First))
                .fold(0.0, f64::max);
        }
    }
    Ok(cf)
}

/// Prepares every frame for every class (in parallel over frames). A frame whose boxes
/// of one class overlap in more than [`MAX_PAIRS`] pairs is refused, naming it.
pub(crate) fn prepare(
    gt: &[FrameGt],
    det: &[FrameDet],
    classes: &[ObjectClass],
) -> Result<Prepared, crate::EvalError> {
    let frames = gt
        .par_iter()
        .zip(det.par_iter())
        .map(|(g, d)| {
            let dontcare: Vec<&Object> = g
                .objects
                .iter()
                .filter(|o| o.class == ObjectClass::DontCare)
                .collect();
            classes
                .iter()
                .map(|&c| {
                    prepare_class(&g.objects, &d.objects, &dontcare, c).map_err(|pairs| {
                        crate::EvalError::TooManyOverlaps {
                            frame: g.id.clone(),
                            class: c.to_string(),
                            pairs,
                        }
                    })
                })
                .collect()
        })
        .collect::<Result<Vec<Vec<ClassFrame>>, _>>()?;
    Ok(Prepared { frames })
}

/// Ground-truth status with the bin filter applied: out-of-bin boxes become ignored.
#[inline]
fn effective_gt_ig(cf: &ClassFrame, d: usize, g: usize, mask: Option<&BinMask>) -> i8 {
    let ig = cf.gt_ig[d][g];
    match mask {
        Some(m) if m.gt_out[g] => GT_IGNORED,
        _ => ig,
    }
}

fn count_valid_gt(cf: &ClassFrame, d: usize, mask: Option<&BinMask>) -> usize {
    (0..cf.n_gt())
        .filter(|&g| effective_gt_ig(cf, d, g, mask) == GT_VALID)
        .count()
}

/// Per-frame, per-task working memory, reused across frames so the loops do not allocate.
#[derive(Default)]
struct Scratch {
    assigned: Vec<bool>,
    /// (detection, overlap) pairs with overlap > min, grouped by ground-truth box in
    /// detection order: the only pairs any devkit branch can select.
    cand: Vec<(u32, f64)>,
    /// Ground-truth box g's candidates are `cand[cand_start[g]..cand_start[g + 1]]`.
    cand_start: Vec<u32>,
    is_cand: Vec<bool>,
    /// Detections that are a candidate of some box, ascending.
    cand_dets: Vec<u32>,
    /// Their scores, descending: the matching only changes when a threshold crosses one.
    cand_scores: Vec<f64>,
    /// Scores (descending) of the other detections that count as false positives
    /// whenever they are above the threshold.
    lone_fp_scores: Vec<f64>,
}

impl Scratch {
    /// Collects the candidate pairs of one task. A detection that overlaps no box by more
    /// than the minimum is never selected by any of the devkit's branches, so it cannot
    /// influence the matching: it is simply a false positive (or not) on its own.
    fn build(&mut self, cf: &ClassFrame, task: &Task) {
        let nd = cf.n_det();
        self.cand.clear();
        self.cand_start.clear();
        self.is_cand.clear();
        self.is_cand.resize(nd, false);
        for g in 0..cf.n_gt() {
            self.cand_start.push(self.cand.len() as u32);
            // Pairs left out of `pairs` overlap by 0, never above a (positive) minimum.
            for &(j, ov) in cf.pairs_of(g) {
                let o = ov[task.overlap];
                if o > task.min_overlap {
                    self.cand.push((j, o));
                    self.is_cand[j as usize] = true;
                }
            }
        }
        self.cand_start.push(self.cand.len() as u32);
        self.cand_dets.clear();
        self.cand_scores.clear();
        for j in 0..nd {
            if self.is_cand[j] {
                self.cand_dets.push(j as u32);
                self.cand_scores.push(cf.det_score[j]);
            }
        }
        self.cand_scores.sort_by(|a, b| b.total_cmp(a));
    }

    /// Fills `lone_fp_scores` for difficulty `d` (after `build`).
    fn lone_false_positives(
        &mut self,
        cf: &ClassFrame,
        d: usize,
        task: &Task,
        mask: Option<&BinMask>,
    ) {
        let dc = &cf.dc[task.overlap];
        let exempt = mask.map(|m| &m.det_exempt[task.overlap]);
        self.lone_fp_scores.clear();
        for j in 0..cf.n_det() {
            if !self.is_cand[j] && counts_as_fp(cf, d, j, dc, exempt, task.min_overlap) {
                self.lone_fp_scores.push(cf.det_score[j]);
            }
        }
        self.lone_fp_scores.sort_by(|a, b| b.total_cmp(a));
    }

    fn candidates(&self, g: usize) -> &[(u32, f64)] {
        &self.cand[self.cand_start[g] as usize..self.cand_start[g + 1] as usize]
    }
}

/// Whether an unassigned above-threshold detection is a false positive: a valid
/// detection, not inside a DontCare region ("stuff") and, in a breakdown bin, not
/// charged to another bin.
#[inline]
fn counts_as_fp(
    cf: &ClassFrame,
    d: usize,
    j: usize,
    dc: &[f64],
    exempt: Option<&Vec<bool>>,
    min: f64,
) -> bool {
    cf.det_ig[d][j] == DET_VALID && !exempt.is_some_and(|e| e[j]) && dc[j] <= min
}

/// First pass (`compute_fp = false`): each ground-truth box takes the highest-scoring
/// unassigned candidate (ignored detections included); pushes the scores of the
/// valid box–valid detection pairs. Needs `s.build` for this task.
fn pass1(cf: &ClassFrame, d: usize, mask: Option<&BinMask>, s: &mut Scratch, v: &mut Vec<f64>) {
    if s.cand.is_empty() {
        return;
    }
    s.assigned.clear();
    s.assigned.resize(cf.n_det(), false);
    let det_ig = &cf.det_ig[d];
    for g in 0..cf.n_gt() {
        let mut det_idx = usize::MAX;
        let mut best = NO_DETECTION;
        for &(j, _) in s.candidates(g) {
            let j = j as usize;
            if det_ig[j] == DET_OTHER || s.assigned[j] {
                continue;
            }
            if cf.det_score[j] > best {
                det_idx = j;
                best = cf.det_score[j];
            }
        }
        if det_idx == usize::MAX {
            continue;
        }
        s.assigned[det_idx] = true;
        if effective_gt_ig(cf, d, g, mask) == GT_VALID && det_ig[det_idx] == DET_VALID {
            v.push(cf.det_score[det_idx]);
        }
    }
}

/// Second pass (`compute_fp = true`) at score threshold `thresh`, over the candidate
/// pairs: each ground-truth box takes the unassigned above-threshold candidate of
/// greatest overlap, preferring valid detections over ignored ones exactly as the
/// devkit's three-branch rule does. False positives are counted among the candidate
/// detections only (the others are counted by the caller). Needs `s.build`.
fn pass2(
    cf: &ClassFrame,
    d: usize,
    task: &Task,
    thresh: f64,
    mask: Option<&BinMask>,
    aos: bool,
    s: &mut Scratch,
) -> Acc {
    let det_ig = &cf.det_ig[d];
    let mut acc = Acc::default();
    s.assigned.clear();
    s.assigned.resize(cf.n_det(), false);
    for g in 0..cf.n_gt() {
        let mut det_idx = usize::MAX;
        let mut max_iou = 0.0;
        let mut assigned_ignored_det = false;
        for &(j, o) in s.candidates(g) {
            let j = j as usize;
            let ig = det_ig[j];
            if ig == DET_OTHER || s.assigned[j] || cf.det_score[j] < thresh {
                continue;
            }
            // Every candidate has o > min.
            if (o > max_iou || assigned_ignored_det) && ig == DET_VALID {
                max_iou = o;
                det_idx = j;
                assigned_ignored_det = false;
            } else if det_idx == usize::MAX && ig == DET_IGNORED {
                det_idx = j;
                assigned_ignored_det = true;
            }
        }
        let gt_ig = effective_gt_ig(cf, d, g, mask);
        if det_idx == usize::MAX {
            if gt_ig == GT_VALID {
                acc.fn_ += 1;
            }
        } else if gt_ig == GT_IGNORED || det_ig[det_idx] == DET_IGNORED {
            s.assigned[det_idx] = true;
        } else {
            acc.tp += 1;
            if aos {
                acc.sim += (1.0 + (cf.gt_alpha[g] - cf.det_alpha[det_idx]).cos()) / 2.0;
            }
            s.assigned[det_idx] = true;
        }
    }
    let dc = &cf.dc[task.overlap];
    let exempt = mask.map(|m| &m.det_exempt[task.overlap]);
    for &j in &s.cand_dets {
        let j = j as usize;
        if !s.assigned[j]
            && cf.det_score[j] >= thresh
            && counts_as_fp(cf, d, j, dc, exempt, task.min_overlap)
        {
            acc.fp += 1;
        }
    }
    acc
}

/// The devkit's `getThresholds`: from the true-positive scores (sorted descending here),
/// keep a score whenever the recall it gives is the best approximation of the next
/// 1/40 recall sample.
pub(crate) fn get_thresholds(v: &mut [f64], n_gt: usize) -> Vec<f64> {
    v.sort_by(|a, b| b.total_cmp(a));
    let n = n_gt as f64;
    let mut t = Vec::new();
    let mut current_recall = 0.0;
    for i in 0..v.len() {
        let l_recall = (i + 1) as f64 / n;
        let last = i + 1 == v.len();
        let r_recall = if last { l_recall } else { (i + 2) as f64 / n };
        if (r_recall - current_recall) < (current_recall - l_recall) && !last {
            continue;
        }
        t.push(v[i]);
        current_recall += 1.0 / (N_SAMPLE_PTS as f64 - 1.0);
    }
    t
}

/// Runs both passes for every task at every difficulty. `masks[frame][class]` applies a
/// breakdown bin; `aos` adds orientation similarity to the bbox tasks.
///
/// Frames are split into fixed chunks processed in parallel and summed in frame order,
/// so the floating-point similarity sums are identical from run to run.
pub(crate) fn run(
    prep: &Prepared,
    tasks: &[Task],
    masks: Option<&[Vec<BinMask>]>,
    aos: bool,
) -> Vec<[Counts; 3]> {
    let every_frame: Vec<usize> = (0..prep.frames.len()).collect();
    run_frames(prep, &every_frame, tasks, masks, aos)
}

/// [`run`] on the prepared frames `order` names, in that order and as often as it names
/// them: a frame named twice counts twice (a bootstrap resample of the frames).
pub(crate) fn run_frames(
    prep: &Prepared,
    order: &[usize],
    tasks: &[Task],
    masks: Option<&[Vec<BinMask>]>,
    aos: bool,
) -> Vec<[Counts; 3]> {
    let slots = tasks.len() * 3;
    let mask_of = |fi: usize, ci: usize| masks.map(|m| &m[fi][ci]);

    // Pass 1: true-positive scores and ground-truth counts.
    let partial: Vec<(Vec<Vec<f64>>, Vec<usize>)> = order
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut v = vec![Vec::new(); slots];
            let mut n = vec![0usize; slots];
            let mut s = Scratch::default();
            for &fi in chunk {
                let classes = &prep.frames[fi];
                for (ti, task) in tasks.iter().enumerate() {
                    let cf = &classes[task.class_idx];
                    let mask = mask_of(fi, task.class_idx);
                    s.build(cf, task);
                    for d in 0..3 {
                        n[ti * 3 + d] += count_valid_gt(cf, d, mask);
                        pass1(cf, d, mask, &mut s, &mut v[ti * 3 + d]);
                    }
                }
            }
            (v, n)
        })
        .collect();
    let mut scores = vec![Vec::new(); slots];
    let mut n_gt = vec![0usize; slots];
    for (v, n) in partial {
        for (a, b) in scores.iter_mut().zip(v) {
            a.extend(b);
        }
        for (a, b) in n_gt.iter_mut().zip(n) {
            *a += b;
        }
    }

    let thresholds: Vec<Vec<f64>> = scores
        .iter_mut()
        .zip(&n_gt)
        .map(|(v, &n)| get_thresholds(v, n))
        .collect();
    let mut offsets = Vec::with_capacity(slots + 1);
    offsets.push(0);
    for t in &thresholds {
        offsets.push(offsets.last().unwrap() + t.len());
    }
    let total = *offsets.last().unwrap();

    // Pass 2: counts at every threshold. A frame's matching only changes when a
    // threshold crosses one of its candidate detections' scores, so it is recomputed
    // only then; lone false positives are added by counting scores.
    let partial: Vec<Vec<Acc>> = order
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut acc = vec![Acc::default(); total];
            let mut s = Scratch::default();
            for &fi in chunk {
                let classes = &prep.frames[fi];
                for (ti, task) in tasks.iter().enumerate() {
                    if (0..3).all(|d| thresholds[ti * 3 + d].is_empty()) {
                        continue;
                    }
                    let cf = &classes[task.class_idx];
                    let mask = mask_of(fi, task.class_idx);
                    let with_aos = aos && task.overlap == 0;
                    s.build(cf, task);
                    for d in 0..3 {
                        let slot = ti * 3 + d;
                        let th = &thresholds[slot];
                        if th.is_empty() {
                            continue;
                        }
                        s.lone_false_positives(cf, d, task, mask);
                        let out = &mut acc[offsets[slot]..offsets[slot + 1]];
                        let mut level = usize::MAX;
                        let mut stat = Acc::default();
                        let (mut kc, mut kf) = (0, 0);
                        for (i, &t) in th.iter().enumerate() {
                            while kc < s.cand_scores.len() && s.cand_scores[kc] >= t {
                                kc += 1;
                            }
                            while kf < s.lone_fp_scores.len() && s.lone_fp_scores[kf] >= t {
                                kf += 1;
                            }
                            if kc != level {
                                level = kc;
                                stat = if kc == 0 {
                                    Acc {
                                        fn_: count_valid_gt(cf, d, mask) as u64,
                                        ..Acc::default()
                                    }
                                } else {
                                    pass2(cf, d, task, t, mask, with_aos, &mut s)
                                };
                            }
                            out[i] += stat;
                            out[i].fp += kf as u64;
                        }
                    }
                }
            }
            acc
        })
        .collect();
    let mut accs = vec![Acc::default(); total];
    for part in partial {
        for (x, y) in accs.iter_mut().zip(part) {
            *x += y;
        }
    }

    (0..tasks.len())
        .map(|ti| {
            std::array::from_fn(|d| {
                let slot = ti * 3 + d;
                let part = &accs[offsets[slot]..offsets[slot + 1]];
                Counts {
                    n_gt: n_gt[slot],
                    thresholds: thresholds[slot].clone(),
                    tp: part.iter().map(|a| a.tp).collect(),
                    fp: part.iter().map(|a| a.fp).collect(),
                    fn_: part.iter().map(|a| a.fn_).collect(),
                    similarity: part.iter().map(|a| a.sim).collect(),
                }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds_follow_the_recall_samples() {
        // One ground truth, one true positive: a single threshold.
        assert_eq!(get_thresholds(&mut [0.9], 1), [0.9]);
        // 80 ground truth, 80 true positives: every second score (recall step 1/80 vs 1/40), plus the last.
        let mut v: Vec<f64> = (0..80).map(|i| 1.0 - i as f64 / 100.0).collect();
        let t = get_thresholds(&mut v, 80);
        assert_eq!(t.len(), 41);
        assert_eq!(t[0], 1.0);
        assert_eq!(*t.last().unwrap(), v[79]);
        // Never more than 41 thresholds.
        for n in 1..200 {
            let mut v: Vec<f64> = (0..n).map(|i| i as f64).collect();
            assert!(get_thresholds(&mut v, n).len() <= N_SAMPLE_PTS);
        }
    }

    #[test]
    fn detection_height_is_truncated_like_the_devkit() {
        let mut o =
            crate::frames::tests_support::det(ObjectClass::Car, [0.0, 0.0, 10.0, 24.9], 0.5);
        assert_eq!(detection_height_px(&o), 24);
        o.bbox.y2 = 25.7;
        assert_eq!(detection_height_px(&o), 25);
    }
}
