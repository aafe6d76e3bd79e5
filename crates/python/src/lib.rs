//! `fusiondet._native`: the Rust half of the Python package. Thin glue only: every
//! function here parses arguments, calls `fusiondet-eval` / `fusiondet-kitti` (the crates the
//! `fusiondet` binary uses) with the GIL released, and hands back plain Python values
//! (JSON text, tuples, little-endian byte buffers) that `fusiondet/__init__.py` turns into
//! dicts and numpy arrays.

use fusiondet_eval::indoor::{IOU_THRESHOLDS, evaluate_indoor, indoor_json, load_indoor_dirs};
use fusiondet_eval::{
    EvalConfig, FrameDet, FrameGt, JsonExtras, Resampling, count_lidar_points, evaluate,
    evaluate_breakdown, frame_ids, load_dirs, paired_bootstrap, parse_classes, read_result_file,
    to_json,
};
use fusiondet_kitti::{Box2d, Box3d, Object, ObjectClass};
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use std::path::{Path, PathBuf};

create_exception!(
    _native,
    FusiondetError,
    PyValueError,
    "Bad input: the message names the file, line and field at fault (or the annotation \
     entry), and what to do."
);

/// Any displayable error as a `FusiondetError` carrying its message.
fn err(e: impl std::fmt::Display) -> PyErr {
    FusiondetError::new_err(e.to_string())
}

/// Numbers per object in the annotation buffers `fusiondet/__init__.py` packs: truncated,
/// occluded, alpha, bbox (4), dimensions (l, h, w: the annos order), location (3),
/// rotation_y, score (NaN for none).
const ANNO_COLS: usize = 15;

/// Frame ids: an explicit list, else a split file, else every label file.
fn resolve_ids(
    label_dir: &Path,
    split_ids: Option<Vec<String>>,
    split_file: Option<PathBuf>,
) -> Result<Vec<String>, PyErr> {
    match split_ids {
        Some(ids) if ids.is_empty() => Err(err("split: the list of frame ids is empty")),
        Some(ids) => Ok(ids),
        None => frame_ids(label_dir, split_file.as_deref()).map_err(err),
    }
}

/// The KITTI evaluation of a label and a result directory: `(json, missing_result_ids,
/// missing_baseline_ids)`, the JSON exactly as `fusiondet eval --json` writes it (the last
/// list empty without `baseline_dir`).
#[pyfunction]
#[pyo3(signature = (label_dir, result_dir, split_ids=None, split_file=None, classes=None, breakdown=false, velodyne_dir=None, calib_dir=None, baseline_dir=None, resamples=1000, seed=0, confidence=0.95))]
#[allow(clippy::too_many_arguments)]
fn evaluate_kitti_json(
    py: Python<'_>,
    label_dir: PathBuf,
    result_dir: PathBuf,
    split_ids: Option<Vec<String>>,
    split_file: Option<PathBuf>,
    classes: Option<Vec<String>>,
    breakdown: bool,
    velodyne_dir: Option<PathBuf>,
    calib_dir: Option<PathBuf>,
    baseline_dir: Option<PathBuf>,
    resamples: usize,
    seed: u64,
    confidence: f64,
) -> PyResult<(String, Vec<String>, Vec<String>)> {
    let mut cfg = EvalConfig::default();
    if let Some(list) = classes {
        cfg.classes = parse_classes(&list.join(",")).map_err(|m| err(format!("classes: {m}")))?;
    }
    let lidar = match (breakdown, velodyne_dir, calib_dir) {
        (true, Some(v), Some(c)) => Some((v, c)),
        (true, _, _) => {
            return Err(err(
                "breakdown=True needs both velodyne_dir and calib_dir (the LiDAR points inside each box are counted from them)",
            ));
        }
        (false, None, None) => None,
        (false, _, _) => {
            return Err(err(
                "velodyne_dir and calib_dir are only used with breakdown=True",
            ));
        }
    };
    let ids = resolve_ids(&label_dir, split_ids, split_file)?;
    py.detach(|| {
        let frames = load_dirs(&label_dir, &result_dir, &ids).map_err(err)?;
        let report = evaluate(&frames.gt, &frames.det, &cfg).map_err(err)?;
        let rows = match &lidar {
            Some((v, c)) => {
                let points = count_lidar_points(&frames.gt, &frames.det, v, c).map_err(err)?;
                Some(
                    evaluate_breakdown(&frames.gt, &frames.det, &cfg, Some(&points))
                        .map_err(err)?,
                )
            }
            None => None,
        };
        let mut baseline_missing = Vec::new();
        let versus = match &baseline_dir {
            Some(dir) => {
                let baseline = load_dirs(&label_dir, dir, &ids).map_err(err)?;
                baseline_missing = baseline.missing_results;
                let resampling = Resampling {
                    resamples,
                    seed,
                    confidence,
                };
                Some(
                    paired_bootstrap(&frames.gt, &frames.det, &baseline.det, &cfg, resampling)
                        .map_err(err)?,
                )
            }
            None => None,
        };
        let extras = JsonExtras {
            breakdown: rows.as_deref(),
            errors: None,
            baseline: versus.as_ref(),
        };
        Ok((
            to_json(&report, extras),
            frames.missing_results,
            baseline_missing,
        ))
    })
}

/// The SUN RGB-D evaluation of a label and a result directory: `(json, missing_result_ids)`,
/// the JSON exactly as `fusiondet eval --dataset sunrgbd --json` writes it.
#[pyfunction]
#[pyo3(signature = (label_dir, result_dir, split_ids=None, split_file=None))]
fn evaluate_sunrgbd_json(
    py: Python<'_>,
    label_dir: PathBuf,
    result_dir: PathBuf,
    split_ids: Option<Vec<String>>,
    split_file: Option<PathBuf>,
) -> PyResult<(String, Vec<String>)> {
    let ids = resolve_ids(&label_dir, split_ids, split_file)?;
    py.detach(|| {
        let loaded = load_indoor_dirs(&label_dir, &result_dir, &ids).map_err(err)?;
        let report = evaluate_indoor(&loaded.scenes, &IOU_THRESHOLDS).map_err(err)?;
        Ok((indoor_json(&report), loaded.missing_results))
    })
}

/// Builds the objects of every frame from the packed annotations; `what` is `gt_annos` or
/// `dt_annos`, for messages that point at the entry at fault.
fn unpack(
    what: &str,
    names: &[String],
    counts: &[usize],
    values: &[u8],
    need_score: bool,
) -> PyResult<Vec<Vec<Object>>> {
    let total: usize = counts.iter().sum();
    if names.len() != total || values.len() != total * ANNO_COLS * 8 {
        return Err(err(format!(
            "{what}: {} names and {} values for {total} objects (internal packing error)",
            names.len(),
            values.len() / 8
        )));
    }
    let nums: Vec<f64> = values
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().expect("8-byte chunk")))
        .collect();
    let mut frames = Vec::with_capacity(counts.len());
    let mut k = 0;
    for (f, &n) in counts.iter().enumerate() {
        let mut objects = Vec::with_capacity(n);
        for i in 0..n {
            let at = |field: &str| format!("{what}[{f}]['{field}'][{i}]");
            let class = ObjectClass::parse(&names[k]).ok_or_else(|| {
                err(format!(
                    "{}: unknown class `{}` (KITTI spelling: Car, Van, Truck, Pedestrian, Person_sitting, Cyclist, Tram, Misc, DontCare)",
                    at("name"),
                    names[k]
                ))
            })?;
            let v = &nums[k * ANNO_COLS..(k + 1) * ANNO_COLS];
            let fields = [
                "truncated",
                "occluded",
                "alpha",
                "bbox",
                "bbox",
                "bbox",
                "bbox",
                "dimensions",
                "dimensions",
                "dimensions",
                "location",
                "location",
                "location",
                "rotation_y",
            ];
            if let Some(j) = (0..fields.len()).find(|&j| !v[j].is_finite()) {
                return Err(err(format!(
                    "{}: {} is not a finite number",
                    at(fields[j]),
                    v[j]
                )));
            }
            let score = if v[14].is_nan() { None } else { Some(v[14]) };
            if need_score && !score.is_some_and(f64::is_finite) {
                return Err(err(format!(
                    "{}: detections need a finite score, found {}",
                    at("score"),
                    v[14]
                )));
            }
            objects.push(Object {
                class,
                truncation: v[0],
                occlusion: v[1] as i32,
                alpha: v[2],
                bbox: Box2d {
                    x1: v[3],
                    y1: v[4],
                    x2: v[5],
                    y2: v[6],
                },
                box3d: Box3d {
                    l: v[7],
                    h: v[8],
                    w: v[9],
                    x: v[10],
                    y: v[11],
                    z: v[12],
                    ry: v[13],
                },
                score,
            });
            k += 1;
        }
        frames.push(objects);
    }
    Ok(frames)
}

/// One reported row: class, overlap setting (0 strict, 1 loose), metric, minimum overlap,
/// AP11 and AP_R40 (easy, moderate, hard), in percent.
type Row = (String, usize, String, f64, [f64; 3], [f64; 3]);

/// The devkit evaluation of packed OpenPCDet-style annotations: `(aos_computed, rows)`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn evaluate_annos(
    py: Python<'_>,
    gt_names: Vec<String>,
    gt_counts: Vec<usize>,
    gt_values: &Bound<'_, PyBytes>,
    dt_names: Vec<String>,
    dt_counts: Vec<usize>,
    dt_values: &Bound<'_, PyBytes>,
    classes: Vec<String>,
) -> PyResult<(bool, Vec<Row>)> {
    if gt_counts.len() != dt_counts.len() {
        return Err(err(format!(
            "{} ground-truth frames (gt_annos) but {} detection frames (dt_annos): pass one dt anno per gt anno, in the same order",
            gt_counts.len(),
            dt_counts.len()
        )));
    }
    let cfg = EvalConfig {
        classes: parse_classes(&classes.join(","))
            .map_err(|m| err(format!("current_classes: {m}")))?,
        ..EvalConfig::default()
    };
    let gt_objects = unpack(
        "gt_annos",
        &gt_names,
        &gt_counts,
        gt_values.as_bytes(),
        false,
    )?;
    let dt_objects = unpack(
        "dt_annos",
        &dt_names,
        &dt_counts,
        dt_values.as_bytes(),
        true,
    )?;
    py.detach(|| {
        let gt: Vec<FrameGt> = gt_objects
            .into_iter()
            .enumerate()
            .map(|(i, o)| FrameGt::new(i.to_string(), o))
            .collect();
        let det: Vec<FrameDet> = dt_objects
            .into_iter()
            .enumerate()
            .map(|(i, o)| FrameDet::new(i.to_string(), o))
            .collect();
        let report = evaluate(&gt, &det, &cfg).map_err(err)?;
        let rows = report
            .results
            .iter()
            .map(|r| {
                (
                    r.class.as_str().to_string(),
                    r.setting,
                    r.metric.as_str().to_string(),
                    r.min_overlap,
                    r.ap11,
                    r.ap40,
                )
            })
            .collect();
        Ok((report.aos_computed, rows))
    })
}

/// Objects as `(names, values)`: values packed like [`ANNO_COLS`], little-endian f64.
fn pack<'py>(py: Python<'py>, objects: &[Object]) -> (Vec<String>, Bound<'py, PyBytes>) {
    let names = objects
        .iter()
        .map(|o| o.class.as_str().to_string())
        .collect();
    let mut bytes = Vec::with_capacity(objects.len() * ANNO_COLS * 8);
    for o in objects {
        let (b, d) = (&o.bbox, &o.box3d);
        let row = [
            o.truncation,
            f64::from(o.occlusion),
            o.alpha,
            b.x1,
            b.y1,
            b.x2,
            b.y2,
            d.l,
            d.h,
            d.w,
            d.x,
            d.y,
            d.z,
            d.ry,
            o.score.unwrap_or(f64::NAN),
        ];
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    (names, PyBytes::new(py, &bytes))
}

/// A `label_2` file (15 columns; 16 accepted) as `(names, packed values)`.
#[pyfunction]
fn read_label_packed<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Vec<String>, Bound<'py, PyBytes>)> {
    let objects = py
        .detach(|| fusiondet_kitti::read_objects(&path))
        .map_err(err)?;
    Ok(pack(py, &objects))
}

/// A result file (16 columns, the score last) as `(names, packed values)`.
#[pyfunction]
fn read_results_packed<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Vec<String>, Bound<'py, PyBytes>)> {
    let objects = py
        .detach(|| read_result_file(&path))
        .map_err(err)?
        .ok_or_else(|| {
            err(format!(
                "{}: no such result file (check the path)",
                path.display()
            ))
        })?;
    Ok(pack(py, &objects))
}

/// A velodyne scan as little-endian float32 bytes, 4 per point (x, y, z, reflectance).
#[pyfunction]
fn read_velodyne_bytes<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyBytes>> {
    let points = py
        .detach(|| fusiondet_kitti::read_velodyne(&path))
        .map_err(err)?;
    let mut bytes = Vec::with_capacity(points.len() * 16);
    for p in &points {
        for v in p {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    Ok(PyBytes::new(py, &bytes))
}

/// A calibration file as `[(key, row-major values)]` for P0–P3, R0_rect, Tr_velo_to_cam and
/// Tr_imu_to_velo.
#[pyfunction]
fn read_calib_lists(py: Python<'_>, path: PathBuf) -> PyResult<Vec<(String, Vec<f64>)>> {
    let c = py
        .detach(|| fusiondet_kitti::read_calib(&path))
        .map_err(err)?;
    let flat34 = |m: &[[f64; 4]; 3]| m.iter().flatten().copied().collect::<Vec<f64>>();
    let mut out: Vec<(String, Vec<f64>)> =
        c.p.iter()
            .enumerate()
            .map(|(i, m)| (format!("P{i}"), flat34(m)))
            .collect();
    out.push((
        "R0_rect".into(),
        c.r0_rect.iter().flatten().copied().collect(),
    ));
    out.push(("Tr_velo_to_cam".into(), flat34(&c.tr_velo_to_cam)));
    out.push(("Tr_imu_to_velo".into(), flat34(&c.tr_imu_to_velo)));
    Ok(out)
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("FusiondetError", m.py().get_type::<FusiondetError>())?;
    m.add("ANNO_COLS", ANNO_COLS)?;
    m.add_function(wrap_pyfunction!(evaluate_kitti_json, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_sunrgbd_json, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_annos, m)?)?;
    m.add_function(wrap_pyfunction!(read_label_packed, m)?)?;
    m.add_function(wrap_pyfunction!(read_results_packed, m)?)?;
    m.add_function(wrap_pyfunction!(read_velodyne_bytes, m)?)?;
    m.add_function(wrap_pyfunction!(read_calib_lists, m)?)?;
    Ok(())
}
