//! The entry point on in-memory data: checks the input, prepares the frames, runs the
//! devkit passes once per distinct (class, measure, minimum overlap) and assembles rows.

use crate::engine::{self, Task};
use crate::error::EvalError;
use crate::frames::{FrameDet, FrameGt};
use crate::protocol::{Metric, OverlapSetting, is_evaluated};
use crate::report::{EvalReport, MetricResult, PrCurve};
use fusiondet_kitti::ObjectClass;

/// What to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalConfig {
    /// Classes to evaluate (Car, Pedestrian, Cyclist, in the order to report them).
    pub classes: Vec<ObjectClass>,
    /// Overlap settings; every row is reported once per setting.
    pub settings: Vec<OverlapSetting>,
}

impl Default for EvalConfig {
    /// The three benchmark classes under the official and the looser overlap setting.
    fn default() -> Self {
        EvalConfig {
            classes: ObjectClass::EVALUATED.to_vec(),
            settings: vec![OverlapSetting::STRICT, OverlapSetting::LOOSE],
        }
    }
}

/// Checks that the frames pair up, detections carry finite scores and the
/// configuration names only evaluated classes.
pub(crate) fn validate(
    gt: &[FrameGt],
    det: &[FrameDet],
    cfg: &EvalConfig,
) -> Result<(), EvalError> {
    if cfg.classes.is_empty() {
        return Err(EvalError::Class("no class to evaluate".into()));
    }
    if let Some(c) = cfg.classes.iter().find(|c| !is_evaluated(**c)) {
        return Err(EvalError::Class(format!(
            "class `{c}` is not evaluated by the KITTI benchmark (choose from Car, Pedestrian, Cyclist)"
        )));
    }
    if cfg.settings.is_empty() {
        return Err(EvalError::Class("no overlap setting given".into()));
    }
    if gt.len() != det.len() {
        return Err(EvalError::FrameCount {
            gt: gt.len(),
            det: det.len(),
        });
    }
    for (index, (g, d)) in gt.iter().zip(det).enumerate() {
        if g.id != d.id {
            return Err(EvalError::FrameMismatch {
                index,
                gt_id: g.id.clone(),
                det_id: d.id.clone(),
            });
        }
        if let Some(i) = d
            .objects
            .iter()
            .position(|o| !o.score.is_some_and(f64::is_finite))
        {
            return Err(EvalError::MissingScore {
                frame: d.id.clone(),
                index: i,
            });
        }
    }
    Ok(())
}

/// A reported (class, setting, metric) and the matching task that answers it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct RowTask {
    pub class_idx: usize,
    pub setting: usize,
    pub metric: Metric,
    pub task: usize,
}

/// The distinct matching problems for `metrics` (deduplicated: e.g. Car bbox is 0.7 in
/// both settings and is computed once), and the rows in report order
/// (class, setting, metric).
pub(crate) fn tasks_for(cfg: &EvalConfig, metrics: &[Metric]) -> (Vec<Task>, Vec<RowTask>) {
    let mut tasks: Vec<Task> = Vec::new();
    let mut rows = Vec::new();
    for (ci, &class) in cfg.classes.iter().enumerate() {
        for (s, setting) in cfg.settings.iter().enumerate() {
            for &metric in metrics {
                let task = Task {
                    class_idx: ci,
                    overlap: metric.overlap_index(),
                    min_overlap: setting.min_overlap(class, metric).expect("validated class"),
                };
                let ti = match tasks.iter().position(|t| *t == task) {
                    Some(i) => i,
                    None => {
                        tasks.push(task);
                        tasks.len() - 1
                    }
                };
                rows.push(RowTask {
                    class_idx: ci,
                    setting: s,
                    metric,
                    task: ti,
                });
            }
        }
    }
    (tasks, rows)
}

/// Evaluates detections against ground truth exactly as the official KITTI devkit
/// (`evaluate_object.cpp`, 41 recall samples) does. `gt[i]` and `det[i]` must be the
/// same frame. Classes without ground truth get AP 0 (the devkit's result).
pub fn evaluate(
    gt: &[FrameGt],
    det: &[FrameDet],
    cfg: &EvalConfig,
) -> Result<EvalReport, EvalError> {
    validate(gt, det, cfg)?;
    // The devkit drops AOS altogether when any detection has the "no orientation" alpha.
    let aos_computed = det
        .iter()
        .all(|f| f.objects.iter().all(|o| o.alpha != -10.0));
    let metrics: &[Metric] = if aos_computed {
        &Metric::ALL
    } else {
        &Metric::OVERLAPS
    };
    // AOS rows reuse the bbox matching (with similarity accumulated).
    let (tasks, rows) = tasks_for(cfg, metrics);
    let prepared = engine::prepare(gt, det, &cfg.classes)?;
    let counts = engine::run(&prepared, &tasks, None, aos_computed);
    let results = rows
        .iter()
        .map(|r| {
            let aos = r.metric == Metric::Aos;
            let curves = std::array::from_fn(|d| PrCurve::from_counts(&counts[r.task][d], aos));
            let class = cfg.classes[r.class_idx];
            let min = cfg.settings[r.setting]
                .min_overlap(class, r.metric)
                .expect("validated class");
            MetricResult::new(class, r.metric, r.setting, min, curves)
        })
        .collect();
    Ok(EvalReport {
        frames: gt.len(),
        classes: cfg.classes.clone(),
        settings: cfg.settings.clone(),
        aos_computed,
        results,
    })
}
