//! Frustum data sets: which frustums exist (from labels, jittered, or from 2D
//! detections), and seeded, parallel, thread-count-independent batches of them.

use crate::batch::FrustumBatch;
use crate::collate::collate;
use crate::config::FrustumConfig;
use crate::error::{FrustumError, Result, SkipCounts, SkipReason};
use crate::frame::{FrustumFrames, ProjectedFrame};
use crate::frustum::extract_frustum;
use crate::proposal::{extract_proposal_frustum, match_proposal};
use crate::rng::{Sampler, domain};
use crate::sample::{Augmentation, FrustumSample, SampleSource, build_sample};
use fusiondet_dataset::Class;
use fusiondet_geometry::count_points_in_box;
use fusiondet_kitti::{Box2d, Box3d, Detection2d, Object};
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};

/// One frustum of a data set: which frame, which 2D box, and where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct FrustumSpec {
    /// Index of the frame in the data set's [`FrameSource`].
    pub frame: usize,
    pub class: Class,
    /// The 2D box as made (label box after jitter, or detection box), before clipping.
    pub box2d: Box2d,
    /// The detection score (detection frustums).
    pub score: Option<f64>,
    /// Index of the ground-truth object in the frame's labels (labelled frustums).
    pub object: Option<usize>,
    /// Which copy of the object this is (0 for detections).
    pub copy: usize,
    /// The first-stage 3D box (camera frame) of a refinement frustum.
    pub proposal: Option<Box3d>,
}

/// A batch with the samples it was made from (their frames, scores and 2D boxes
/// are what inference needs to write results).
#[derive(Debug, Clone)]
pub struct PreparedBatch {
    pub batch: FrustumBatch,
    pub samples: Vec<FrustumSample>,
    /// Index of each sample in [`FrustumDataset::specs`].
    pub indices: Vec<usize>,
}

/// A set of frustums over a [`FrameSource`].
pub struct FrustumDataset<S: FrustumFrames> {
    source: S,
    config: FrustumConfig,
    specs: Vec<FrustumSpec>,
    /// Each spec's place among its own frame's specs (what names its stream under
    /// [`StreamKey::Frame`]).
    ordinal_in_frame: Vec<u64>,
    skips: SkipCounts,
}

/// What names a sample's random stream (its augmentation and point sampling).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamKey {
    /// Its place among the data set's frustums: training, where the set is fixed and
    /// every epoch draws anew.
    Index,
    /// Its frame's id and its place among that frame's frustums: inference, so that a
    /// frame's boxes do not depend on which other frames the split holds, and a split
    /// detected in chunks (or frame by frame) gives what it gives whole.
    Frame,
}

/// A 2D detection of any format, as frustum extraction reads it.
pub trait BoxDetection: Sync {
    /// The frame (scene) it was detected in.
    fn frame_id(&self) -> &str;
    fn class(&self) -> Class;
    fn bbox(&self) -> Box2d;
    fn score(&self) -> f64;
}

impl BoxDetection for Detection2d {
    fn frame_id(&self) -> &str {
        &self.frame_id
    }
    fn class(&self) -> Class {
        Class::Kitti(self.class)
    }
    fn bbox(&self) -> Box2d {
        self.bbox
    }
    fn score(&self) -> f64 {
        self.score
    }
}

/// A 2D detection with its frame and a class of any format (SUN RGB-D keeps a file of
/// them per scene, so the frame comes from the file name).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameDetection {
    pub frame_id: String,
    pub class: Class,
    pub bbox: Box2d,
    pub score: f64,
}

impl BoxDetection for FrameDetection {
    fn frame_id(&self) -> &str {
        &self.frame_id
    }
    fn class(&self) -> Class {
        self.class
    }
    fn bbox(&self) -> Box2d {
        self.bbox
    }
    fn score(&self) -> f64 {
        self.score
    }
}

/// Stable 64-bit FNV-1a of a frame id, so that jitter depends on the frame, not on
/// its position in a split.
fn id_hash(id: &str) -> u64 {
    id.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// F-PointNet's 2D box jitter: centre moved by up to ±r·(w, h), width and height
/// scaled by a factor in [1 − r, 1 + r], all uniform.
pub fn jitter_box(b: &Box2d, r: f64, rng: &mut Sampler) -> Box2d {
    if r == 0.0 {
        return *b;
    }
    let (w, h) = (b.width(), b.height());
    let (cx, cy) = b.center();
    let cx = cx + w * rng.range(-r, r);
    let cy = cy + h * rng.range(-r, r);
    let w = w * rng.range(1.0 - r, 1.0 + r);
    let h = h * rng.range(1.0 - r, 1.0 + r);
    Box2d {
        x1: cx - 0.5 * w,
        y1: cy - 0.5 * h,
        x2: cx + 0.5 * w,
        y2: cy + 0.5 * h,
    }
}

/// The training frustums of one frame, and what was skipped.
fn label_specs(
    frame_index: usize,
    frame: &ProjectedFrame,
    config: &FrustumConfig,
    seed: u64,
) -> (Vec<FrustumSpec>, SkipCounts) {
    let mut specs = Vec::new();
    let mut skips = SkipCounts::default();
    for (oi, (obj, &class)) in frame.objects.iter().zip(&frame.classes).enumerate() {
        if !config.wants(class) {
            continue;
        }
        for copy in 0..config.augment.copies {
            let mut rng = Sampler::from_path(
                seed,
                &[domain::JITTER, id_hash(&frame.id), oi as u64, copy as u64],
            );
            let b = jitter_box(&obj.bbox, config.augment.box_jitter, &mut rng);
            let fp =
                match extract_frustum(frame, &b, config.depth_range, config.min_box_height_train) {
                    Ok(fp) => fp,
                    Err(reason) => {
                        skips.add(reason);
                        continue;
                    }
                };
            if config.min_object_points > 0 {
                let gt = fp.frame.box_to_frustum(&obj.box3d);
                if count_points_in_box(&gt, &fp.points) < config.min_object_points {
                    skips.add(SkipReason::NoObjectPoints);
                    continue;
                }
            }
            specs.push(FrustumSpec {
                frame: frame_index,
                class,
                box2d: b,
                score: None,
                object: Some(oi),
                copy,
                proposal: None,
            });
        }
    }
    (specs, skips)
}

impl<S: FrustumFrames> FrustumDataset<S> {
    /// Frustums from the ground-truth 2D boxes of the configured classes, `copies`
    /// per object, each with its own jitter drawn from `seed` (and the frame id, object
    /// and copy). Boxes that are outside the image, shorter than
    /// `min_box_height_train`, without points, or with fewer than `min_object_points`
    /// inside the ground truth are counted in [`Self::skips`] and left out. Samples get
    /// the configured flip and depth shift, drawn per epoch. Objects of other classes
    /// (DontCare, Van, ...) are not counted as skips.
    pub fn from_labels(source: S, config: FrustumConfig, seed: u64) -> Result<Self> {
        config.validate()?;
        let per_frame = (0..source.len())
            .into_par_iter()
            .map(|i| Ok(label_specs(i, &*source.frame(i)?, &config, seed)))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self::from_frames(
            source,
            config,
            per_frame,
            SkipCounts::default(),
        ))
    }

    /// The data set of per-frame specs and skips (in frame order) plus earlier `skips`.
    fn from_frames(
        source: S,
        config: FrustumConfig,
        per_frame: Vec<(Vec<FrustumSpec>, SkipCounts)>,
        mut skips: SkipCounts,
    ) -> Self {
        let mut specs = Vec::new();
        for (s, k) in per_frame {
            specs.extend(s);
            skips.merge(&k);
        }
        Self::with_specs(source, config, specs, skips)
    }

    fn with_specs(
        source: S,
        config: FrustumConfig,
        specs: Vec<FrustumSpec>,
        skips: SkipCounts,
    ) -> Self {
        let mut seen: HashMap<usize, u64> = HashMap::new();
        let ordinal_in_frame = specs
            .iter()
            .map(|spec| {
                let n = seen.entry(spec.frame).or_default();
                *n += 1;
                *n - 1
            })
            .collect();
        FrustumDataset {
            source,
            config,
            specs,
            ordinal_in_frame,
            skips,
        }
    }

    /// Frustums from 2D detections of the configured classes, in file order. Boxes
    /// outside the image, shorter than `min_box_height_test`, without points, or in a
    /// frame the source does not hold are counted in [`Self::skips`] and left out.
    pub fn from_detections<D: BoxDetection>(
        source: S,
        detections: &[D],
        config: FrustumConfig,
    ) -> Result<Self> {
        config.validate()?;
        let index: HashMap<&str, usize> =
            (0..source.len()).map(|i| (source.frame_id(i), i)).collect();
        let mut skips = SkipCounts::default();
        let mut by_frame: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (di, d) in detections.iter().enumerate() {
            if !config.wants(d.class()) {
                continue;
            }
            match index.get(d.frame_id()) {
                Some(&fi) => by_frame.entry(fi).or_default().push(di),
                None => skips.add(SkipReason::UnknownFrame),
            }
        }
        let groups: Vec<(usize, Vec<usize>)> = by_frame.into_iter().collect();
        let results = groups
            .par_iter()
            .map(|(fi, dets)| {
                let frame = source.frame(*fi)?;
                Ok(dets
                    .iter()
                    .map(|&di| {
                        let d = &detections[di];
                        let r = extract_frustum(
                            &frame,
                            &d.bbox(),
                            config.depth_range,
                            config.min_box_height_test,
                        );
                        (
                            di,
                            r.map(|_| FrustumSpec {
                                frame: *fi,
                                class: d.class(),
                                box2d: d.bbox(),
                                score: Some(d.score()),
                                object: None,
                                copy: 0,
                                proposal: None,
                            }),
                        )
                    })
                    .collect::<Vec<_>>())
            })
            .collect::<Result<Vec<_>>>()?;
        let mut all: Vec<_> = results.into_iter().flatten().collect();
        all.sort_by_key(|(di, _)| *di);
        let mut specs = Vec::new();
        for (_, r) in all {
            match r {
                Ok(s) => specs.push(s),
                Err(reason) => skips.add(reason),
            }
        }
        Ok(Self::with_specs(source, config, specs, skips))
    }

    /// Refinement frustums around first-stage results (`proposals`: frame id → result
    /// objects, as detection returns them), in frame-id then result order. The config
    /// must have a `proposal_crop`. With `train`, each proposal is matched to the
    /// ground truth it learns from ([`match_proposal`]); unmatched ones are counted
    /// and left out. Proposals of other classes are ignored; those of frames the
    /// source does not hold, outside the image or without points are counted.
    pub fn from_proposals(
        source: S,
        proposals: &BTreeMap<String, Vec<Object>>,
        config: FrustumConfig,
        train: bool,
    ) -> Result<Self> {
        config.validate()?;
        let Some(crop) = config.proposal_crop.clone() else {
            return Err(FrustumError::Config(
                "frustums around proposals need `[frustum.proposal_crop]` (a refinement stage)"
                    .into(),
            ));
        };
        let index: HashMap<&str, usize> =
            (0..source.len()).map(|i| (source.frame_id(i), i)).collect();
        let mut skips = SkipCounts::default();
        let mut groups: Vec<(usize, &[Object])> = Vec::new();
        for (id, objects) in proposals {
            match index.get(id.as_str()) {
                Some(&fi) => groups.push((fi, objects)),
                None => objects
                    .iter()
                    .filter(|o| config.wants(o.class.into()))
                    .for_each(|_| skips.add(SkipReason::UnknownFrame)),
            }
        }
        let per_frame = groups
            .par_iter()
            .map(|&(fi, objects)| {
                let frame = source.frame(fi)?;
                let mut specs = Vec::new();
                let mut skips = SkipCounts::default();
                for p in objects.iter().filter(|o| config.wants(o.class.into())) {
                    let object = if train {
                        match match_proposal(p, &frame.objects, crop.match_iou) {
                            Some(o) => Some(o),
                            None => {
                                skips.add(SkipReason::Unmatched);
                                continue;
                            }
                        }
                    } else {
                        None
                    };
                    match extract_proposal_frustum(
                        &frame,
                        &p.box3d,
                        &p.bbox,
                        &crop,
                        config.depth_range,
                    ) {
                        Ok(_) => specs.push(FrustumSpec {
                            frame: fi,
                            class: p.class.into(),
                            box2d: p.bbox,
                            score: p.score,
                            object,
                            copy: 0,
                            proposal: Some(p.box3d),
                        }),
                        Err(reason) => skips.add(reason),
                    }
                }
                Ok((specs, skips))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self::from_frames(source, config, per_frame, skips))
    }

    pub fn len(&self) -> usize {
        self.specs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.specs.is_empty()
    }

    pub fn specs(&self) -> &[FrustumSpec] {
        &self.specs
    }

    pub fn skips(&self) -> SkipCounts {
        self.skips
    }

    pub fn config(&self) -> &FrustumConfig {
        &self.config
    }

    pub fn source(&self) -> &S {
        &self.source
    }

    /// Sample `index` for `epoch`: its own random stream (from `seed`, `epoch` and
    /// `index` only) draws the augmentation (labelled frustums) and the point sampling.
    pub fn sample(&self, index: usize, seed: u64, epoch: u64) -> Result<FrustumSample> {
        self.sample_keyed(index, seed, epoch, StreamKey::Index)
    }

    /// [`Self::sample`] with its stream named by `key`.
    pub fn sample_keyed(
        &self,
        index: usize,
        seed: u64,
        epoch: u64,
        key: StreamKey,
    ) -> Result<FrustumSample> {
        let spec = &self.specs[index];
        let frame = self.source.frame(spec.frame)?;
        let stale = |reason| FrustumError::Stale {
            frame: frame.id.clone(),
            index,
            reason,
        };
        let fp = match (&spec.proposal, &self.config.proposal_crop) {
            (Some(p), Some(crop)) => {
                extract_proposal_frustum(&frame, p, &spec.box2d, crop, self.config.depth_range)
            }
            _ => extract_frustum(&frame, &spec.box2d, self.config.depth_range, 0.0),
        }
        .map_err(stale)?;
        let object = match spec.object {
            Some(o) => Some(
                &frame
                    .objects
                    .get(o)
                    .ok_or(stale(SkipReason::NoObjectPoints))?
                    .box3d,
            ),
            None => None,
        };
        let mut rng = match key {
            StreamKey::Index => Sampler::from_path(seed, &[domain::SAMPLE, epoch, index as u64]),
            StreamKey::Frame => Sampler::from_path(
                seed,
                &[
                    domain::FRAME_SAMPLE,
                    epoch,
                    id_hash(&frame.id),
                    self.ordinal_in_frame[index],
                ],
            ),
        };
        let augmentation = match object {
            Some(gt) => Augmentation::draw(
                &self.config.augment,
                self.config.depth_range,
                &fp.frame,
                gt,
                &mut rng,
            ),
            None => Augmentation::default(),
        };
        let source = SampleSource {
            frame_id: &frame.id,
            class: spec.class,
            score: spec.score,
            focal_v: frame.camera.fv(),
            p2: frame.camera.p2_rows(),
            object,
        };
        Ok(build_sample(
            &source,
            &fp,
            augmentation,
            &self.config,
            &mut rng,
        ))
    }

    /// The samples at `indices`, prepared in parallel (rayon's current pool), in order.
    pub fn prepare(
        &self,
        indices: &[usize],
        seed: u64,
        epoch: u64,
        key: StreamKey,
    ) -> Result<PreparedBatch> {
        let samples = indices
            .par_iter()
            .map(|&i| self.sample_keyed(i, seed, epoch, key))
            .collect::<Result<Vec<_>>>()?;
        Ok(PreparedBatch {
            batch: collate(&samples),
            samples,
            indices: indices.to_vec(),
        })
    }

    /// One training epoch: all frustums in an order shuffled from (`seed`, `epoch`),
    /// in batches of exactly `batch_size` (a last, smaller batch is dropped).
    pub fn epoch(&self, seed: u64, epoch: u64, batch_size: usize) -> Batches<'_, S> {
        let mut order: Vec<usize> = (0..self.len()).collect();
        Sampler::from_path(seed, &[domain::ORDER, epoch]).shuffle(&mut order);
        Batches::new(
            self,
            order,
            (seed, epoch, StreamKey::Index),
            batch_size,
            true,
        )
    }

    /// All frustums in data-set order, in batches of `batch_size` (the last may be
    /// smaller): for inference. Point sampling still draws from `seed`, in streams named
    /// by frame ([`StreamKey::Frame`]).
    pub fn in_order(&self, seed: u64, batch_size: usize) -> Batches<'_, S> {
        Batches::new(
            self,
            (0..self.len()).collect(),
            (seed, 0, StreamKey::Frame),
            batch_size,
            false,
        )
    }
}

/// Iterator over the batches of an epoch; each batch is prepared when asked for.
pub struct Batches<'a, S: FrustumFrames> {
    dataset: &'a FrustumDataset<S>,
    order: Vec<usize>,
    seed: u64,
    epoch: u64,
    key: StreamKey,
    batch_size: usize,
    next: usize,
    end: usize,
}

impl<'a, S: FrustumFrames> Batches<'a, S> {
    fn new(
        dataset: &'a FrustumDataset<S>,
        order: Vec<usize>,
        (seed, epoch, key): (u64, u64, StreamKey),
        batch_size: usize,
        drop_last: bool,
    ) -> Self {
        assert!(batch_size > 0, "batch size must be positive");
        let end = if drop_last {
            order.len() / batch_size * batch_size
        } else {
            order.len()
        };
        Batches {
            dataset,
            order,
            seed,
            epoch,
            key,
            batch_size,
            next: 0,
            end,
        }
    }

    /// The sample order of the whole epoch.
    pub fn order(&self) -> &[usize] {
        &self.order[..self.end]
    }
}

impl<S: FrustumFrames> Iterator for Batches<'_, S> {
    type Item = Result<PreparedBatch>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.next >= self.end {
            return None;
        }
        let stop = (self.next + self.batch_size).min(self.end);
        let indices = &self.order[self.next..stop];
        self.next = stop;
        Some(
            self.dataset
                .prepare(indices, self.seed, self.epoch, self.key),
        )
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = (self.end - self.next).div_ceil(self.batch_size);
        (n, Some(n))
    }
}

impl<S: FrustumFrames> ExactSizeIterator for Batches<'_, S> {}
