"""fusiondet: the exact KITTI and SUN RGB-D evaluations and the KITTI readers, from Python.

The work is done by the Rust crates of the ``fusiondet`` binary (``fusiondet-eval``,
``fusiondet-kitti``) through the ``_native`` extension, with the GIL released while it runs.
This module only converts arguments and results between numpy/dicts and that extension.
See docs/python.md in the repository.
"""

from __future__ import annotations

import json
import os
import warnings
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from ._native import FusiondetError

__all__ = [
    "FusiondetError",
    "evaluate_kitti",
    "evaluate_sunrgbd",
    "get_official_eval_result",
    "read_calib",
    "read_label",
    "read_results",
    "read_velodyne",
]

PathLike = Union[str, "os.PathLike[str]"]

# OpenPCDet's class indices, so that `current_classes` may be given as ints as there.
_CLASS_BY_INDEX = {0: "Car", 1: "Pedestrian", 2: "Cyclist", 3: "Van", 4: "Person_sitting", 5: "Truck"}
_DIFFICULTIES = ("easy", "moderate", "hard")


def _split_args(label_dir: PathLike, split: Any) -> Tuple[Optional[List[str]], Optional[str]]:
    """(ids, split file) from `split`: None, a list of ids, a file path, or a split name
    such as ``"val"`` (then ``ImageSets/<name>.txt`` of the KITTI root two levels above
    ``label_dir``, i.e. ``ROOT/training/label_2``)."""
    if split is None:
        return None, None
    if isinstance(split, (list, tuple)):
        return [str(s) for s in split], None
    path = os.fspath(split)
    if os.path.exists(path) or os.sep in path or path.endswith(".txt"):
        return None, path
    root = os.path.dirname(os.path.dirname(os.path.abspath(os.fspath(label_dir))))
    named = os.path.join(root, "ImageSets", path + ".txt")
    if not os.path.exists(named):
        raise FusiondetError(
            f"split `{path}`: neither a file nor a split name ({named} does not exist); "
            "pass a list of ids, a split file or the name of a file in ImageSets/"
        )
    return None, named


def _warn_missing(missing: List[str], result_dir: PathLike, what: str) -> None:
    if missing:
        shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
        warnings.warn(
            f"{len(missing)} {what} have no result file in {os.fspath(result_dir)} "
            f"(evaluated as {what} without detections): {shown}",
            stacklevel=3,
        )


def evaluate_kitti(
    label_dir: PathLike,
    result_dir: PathLike,
    split: Any = None,
    classes: Optional[Sequence[str]] = None,
    breakdown: bool = False,
    velodyne_dir: Optional[PathLike] = None,
    calib_dir: Optional[PathLike] = None,
    baseline_dir: Optional[PathLike] = None,
    resamples: int = 1000,
    seed: int = 0,
    confidence: float = 0.95,
) -> Dict[str, Any]:
    """The official KITTI evaluation (devkit protocol, AP11 and AP_R40 in percent) of a
    ``label_2``-style directory and a result directory: the same dict as
    ``fusiondet eval --json`` writes, ``{"results": [{"class", "metric", "min_overlap",
    "ap11", "ap40"}, ...]}`` plus ``"breakdown"`` with ``breakdown=True`` (which needs
    ``velodyne_dir`` and ``calib_dir``). ``split``: a list of ids, a split file or a split
    name; default every label file. A missing result file is a frame without detections
    (a warning names them). ``baseline_dir``: another model's results on the same frames;
    adds ``"baseline"``, AP_R40 of both, their difference and its interval over
    ``resamples`` resamples of the frames (as ``fusiondet eval --baseline``). Bad input
    raises ``FusiondetError`` with file:line:field."""
    ids, split_file = _split_args(label_dir, split)
    text, missing, baseline_missing = _native.evaluate_kitti_json(
        os.fspath(label_dir),
        os.fspath(result_dir),
        ids,
        split_file,
        None if classes is None else [str(c) for c in ([classes] if isinstance(classes, str) else classes)],
        bool(breakdown),
        None if velodyne_dir is None else os.fspath(velodyne_dir),
        None if calib_dir is None else os.fspath(calib_dir),
        None if baseline_dir is None else os.fspath(baseline_dir),
        int(resamples),
        int(seed),
        float(confidence),
    )
    _warn_missing(missing, result_dir, "frames")
    if baseline_dir is not None:
        _warn_missing(baseline_missing, baseline_dir, "frames")
    return json.loads(text)


def evaluate_sunrgbd(label_dir: PathLike, result_dir: PathLike, split: Any = None) -> Dict[str, Any]:
    """SUN RGB-D's indoor evaluation (VoteNet's protocol, exact rotated 3D IoU): the same
    dict as ``fusiondet eval --dataset sunrgbd --json``, ``{"results": [{"class", "iou",
    "ap"}, ...], "map": {"0.25": m, "0.5": m}}``, AP in percent, ``None`` for a class
    without ground truth. ``split``: a list of ids or a split file; default every label file."""
    if split is None or isinstance(split, (list, tuple)):
        ids, split_file = (None if split is None else [str(s) for s in split]), None
    else:
        ids, split_file = None, os.fspath(split)
    text, missing = _native.evaluate_sunrgbd_json(os.fspath(label_dir), os.fspath(result_dir), ids, split_file)
    _warn_missing(missing, result_dir, "scenes")
    return json.loads(text)


_ANNO_KEYS = (("truncated", 1), ("occluded", 1), ("alpha", 1), ("bbox", 4), ("dimensions", 3),
              ("location", 3), ("rotation_y", 1))


def _pack(annos: Sequence[Dict[str, Any]], what: str, need_score: bool) -> Tuple[List[str], List[int], bytes]:
    """Annotations (OpenPCDet/mmdetection3d dicts of numpy arrays) as the flat buffers
    `_native.evaluate_annos` reads: names, objects per frame, and 15 f64 per object.
    Checked per frame, converted once per key (a per-frame conversion cost more than the
    evaluation itself on 3,769 frames)."""
    keys = _ANNO_KEYS + ((("score", 1),) if need_score else ())
    names: List[str] = []
    counts: List[int] = []
    columns: Dict[str, list] = {key: [] for key, _ in keys}
    for f, anno in enumerate(annos):
        try:
            name = np.asarray(anno["name"]).reshape(-1)
            n = name.shape[0]
            for key, width in keys:
                a = np.asarray(anno[key])
                if a.size != n * width:
                    raise FusiondetError(
                        f"{what}[{f}]['{key}']: {a.size} values for {n} objects (expected {n} x {width})"
                    )
                columns[key].append(a.reshape(-1))
        except KeyError as e:
            listed = ", ".join(["name"] + [k for k, _ in keys])
            raise FusiondetError(f"{what}[{f}]: missing key {e} (annos need {listed})") from None
        except (TypeError, ValueError, AttributeError) as e:
            if isinstance(e, FusiondetError):
                raise
            raise FusiondetError(f"{what}[{f}]: {e}") from None
        names.extend(name.tolist())
        counts.append(n)
    total = len(names)
    parts = []
    for key, width in keys:
        try:
            col = np.concatenate(columns[key]).astype(np.float64) if columns[key] else np.zeros(0)
        except (TypeError, ValueError) as e:
            raise FusiondetError(f"{what}: '{key}' is not numeric: {e}") from None
        parts.append(col.reshape(total, width))
    if not need_score:
        parts.append(np.full((total, 1), np.nan))
    values = np.hstack(parts)
    return [str(s) for s in names], counts, np.ascontiguousarray(values, dtype="<f8").tobytes()


def get_official_eval_result(
    gt_annos: Sequence[Dict[str, Any]],
    dt_annos: Sequence[Dict[str, Any]],
    current_classes: Any,
    PR_detail_dict: Optional[Dict[str, Any]] = None,
) -> Tuple[str, Dict[str, float]]:
    """Drop-in for ``get_official_eval_result`` of OpenPCDet's ``kitti_object_eval_python``:
    the same arguments (lists of annos dicts with numpy arrays, one dt anno per gt anno;
    ``dimensions`` in the annos order l, h, w) and the same ``(result_str, result_dict)``
    text and keys (``Car_3d/moderate_R40``, ...: AP_R40 of the strict setting; the
    AP11 figures are in the text), computed by the exact evaluation.
    ``current_classes``: names or OpenPCDet indices of Car, Pedestrian, Cyclist (Van,
    Person_sitting and Truck, which OpenPCDet also accepts, raise ``FusiondetError``: the
    benchmark protocol has no neighbour rule for them). ``PR_detail_dict`` is accepted and
    left untouched. Differences from the numba port: docs/python.md."""
    del PR_detail_dict  # accepted for the drop-in signature; curves are not filled in
    if not isinstance(current_classes, (list, tuple)):
        current_classes = [current_classes]
    names = []
    for c in current_classes:
        if isinstance(c, str):
            names.append(c)
        elif int(c) in _CLASS_BY_INDEX:
            names.append(_CLASS_BY_INDEX[int(c)])
        else:
            raise FusiondetError(f"current_classes: unknown class index {c} (0 Car, 1 Pedestrian, 2 Cyclist)")
    if len(gt_annos) != len(dt_annos):
        raise FusiondetError(
            f"{len(gt_annos)} gt_annos but {len(dt_annos)} dt_annos: pass one dt anno per gt anno, in the same order"
        )
    gt = _pack(gt_annos, "gt_annos", need_score=False)
    dt = _pack(dt_annos, "dt_annos", need_score=True)
    aos, rows = _native.evaluate_annos(*gt, *dt, names)

    table: Dict[Tuple[str, int, str], Tuple[float, List[float], List[float]]] = {}
    for cls, setting, metric, min_overlap, ap11, ap40 in rows:
        table[(cls, setting, metric)] = (min_overlap, list(ap11), list(ap40))

    result = ""
    ret: Dict[str, float] = {}
    for cls in dict.fromkeys(names):
        for setting in (0, 1):
            overlaps = [table[(cls, setting, m)][0] for m in ("bbox", "bev", "3d")]
            for r40 in (False, True):
                k = 2 if r40 else 1
                head = "AP_R40" if r40 else "AP"
                result += f"{cls} {head}@{overlaps[0]:.2f}, {overlaps[1]:.2f}, {overlaps[2]:.2f}:\n"
                for metric, label in (("bbox", "bbox"), ("bev", "bev "), ("3d", "3d  ")):
                    ap = table[(cls, setting, metric)][k]
                    result += f"{label} AP:{ap[0]:.4f}, {ap[1]:.4f}, {ap[2]:.4f}\n"
                if aos:
                    ap = table[(cls, setting, "aos")][k]
                    result += f"aos  AP:{ap[0]:.2f}, {ap[1]:.2f}, {ap[2]:.2f}\n"
                    if setting == 0 and r40:
                        for d, diff in enumerate(_DIFFICULTIES):
                            ret[f"{cls}_aos/{diff}_R40"] = ap[d]
            if setting == 0:
                for metric, key in (("3d", "3d"), ("bev", "bev"), ("bbox", "image")):
                    ap = table[(cls, setting, metric)][2]
                    for d, diff in enumerate(_DIFFICULTIES):
                        ret[f"{cls}_{key}/{diff}_R40"] = ap[d]
    return result, ret


def _annos(names: List[str], packed: bytes, with_score: bool) -> Dict[str, np.ndarray]:
    v = np.frombuffer(packed, dtype="<f8").reshape(-1, _native.ANNO_COLS)
    anno = {
        "name": np.array(names, dtype="<U14").reshape(-1),
        "truncated": v[:, 0].copy(),
        "occluded": v[:, 1].astype(np.int64),
        "alpha": v[:, 2].copy(),
        "bbox": v[:, 3:7].copy(),
        "dimensions": v[:, 7:10].copy(),
        "location": v[:, 10:13].copy(),
        "rotation_y": v[:, 13].copy(),
    }
    if with_score:
        anno["score"] = v[:, 14].copy()
    return anno


def read_label(path: PathLike) -> Dict[str, np.ndarray]:
    """A KITTI ``label_2`` file as an annos dict (OpenPCDet's keys: ``name``, ``truncated``,
    ``occluded``, ``alpha``, ``bbox`` (N, 4), ``dimensions`` (N, 3) in the order l, h, w,
    ``location`` (N, 3), ``rotation_y``); ``score`` too when the file has a 16th column."""
    names, packed = _native.read_label_packed(os.fspath(path))
    anno = _annos(names, packed, with_score=True)
    if np.isnan(anno["score"]).all():
        del anno["score"]
    return anno


def read_results(path: PathLike) -> Dict[str, np.ndarray]:
    """A KITTI result file (label format with the score as 16th column) as an annos dict
    with ``score``; a line without a score raises ``FusiondetError``."""
    names, packed = _native.read_results_packed(os.fspath(path))
    return _annos(names, packed, with_score=True)


def read_velodyne(path: PathLike) -> np.ndarray:
    """A KITTI velodyne scan as a float32 array (N, 4): x, y, z, reflectance."""
    return np.frombuffer(_native.read_velodyne_bytes(os.fspath(path)), dtype="<f4").reshape(-1, 4).astype(np.float32)


def read_calib(path: PathLike) -> Dict[str, np.ndarray]:
    """A KITTI calibration file: ``P0``..``P3`` (3, 4), ``R0_rect`` (3, 3),
    ``Tr_velo_to_cam`` and ``Tr_imu_to_velo`` (3, 4), and the projections built from them:
    ``velo_to_rect`` (4, 4) = R0_rect · Tr_velo_to_cam (LiDAR → rectified camera) and
    ``velo_to_image`` (3, 4) = P2 · velo_to_rect (LiDAR → left colour image, homogeneous)."""
    out: Dict[str, np.ndarray] = {}
    for key, values in _native.read_calib_lists(os.fspath(path)):
        out[key] = np.array(values, dtype=np.float64).reshape(3, 3 if key == "R0_rect" else 4)
    r0 = np.eye(4)
    r0[:3, :3] = out["R0_rect"]
    tr = np.eye(4)
    tr[:3, :] = out["Tr_velo_to_cam"]
    out["velo_to_rect"] = r0 @ tr
    out["velo_to_image"] = out["P2"] @ out["velo_to_rect"]
    return out
