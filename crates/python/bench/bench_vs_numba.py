"""Benchmark (not a test): fusiondet's `get_official_eval_result` and `evaluate_kitti` against
the numba port of the devkit (`kitti_object_eval_python`, as shipped in OpenPCDet) on a
generated 3,769-frame case (the size of KITTI's val split).

The port is not part of this repository and is never copied into it: pass the folder that
holds its `kitti_object_eval_python/` (eval.py, rotate_iou.py) with --port. Its rotated IoU is
a numba.cuda kernel; with --cpu-iou (the default when no CUDA device is present) the port's
own device functions are compiled for the CPU by numba instead (the module text is rewritten
in a temporary folder: decorators and local arrays only, the arithmetic untouched), and a
plain loop replaces the kernel launch. Reported: the first call (numba compiles then), a warm
call, and the largest AP difference over every key of the result dict.

    python crates/python/bench/bench_vs_numba.py --port /tmp/numba_port [--frames 3769]
"""

import argparse
import importlib
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import fusiondet

CLASSES = np.array(["Car", "Pedestrian", "Cyclist", "Van", "Person_sitting", "DontCare"])
PROBS = np.array([0.55, 0.15, 0.08, 0.08, 0.02, 0.12])


def generate(n_frames, seed):
    """Ground truth like KITTI's (about 8 objects a frame, mostly cars) and detections:
    noisy copies with some misses, duplicates and random false positives. Every value is
    rounded to the files' 2 decimals; scores to 4."""
    rng = np.random.default_rng(seed)
    gt, dt = [], []
    for _ in range(n_frames):
        n = int(rng.integers(1, 16))
        names = rng.choice(CLASSES, n, p=PROBS)
        z = rng.uniform(4, 70, n)
        x = rng.uniform(-15, 15, n)
        l = np.where(names == "Car", rng.uniform(3.5, 4.8, n), rng.uniform(0.5, 1.9, n))
        w = np.where(names == "Car", rng.uniform(1.5, 1.9, n), rng.uniform(0.5, 0.8, n))
        h = np.where(names == "Car", rng.uniform(1.4, 1.7, n), rng.uniform(1.5, 1.9, n))
        u = 720 * x / z + 620
        hpx = 720 * h / z
        wpx = 720 * np.maximum(l, w) / z
        bbox = np.stack([u - wpx / 2, 190 - hpx / 2, u + wpx / 2, 190 + hpx / 2], 1)
        g = {
            "name": names,
            "truncated": np.round(rng.choice([0.0, 0.0, 0.0, 0.2, 0.4], n), 2),
            "occluded": rng.choice([0, 0, 1, 1, 2, 3], n),
            "alpha": np.round(rng.uniform(-3.1, 3.1, n), 2),
            "bbox": np.round(np.clip(bbox, 0, 1241), 2),
            "dimensions": np.round(np.stack([l, h, w], 1), 2),
            "location": np.round(np.stack([x, np.full(n, 1.6), z], 1), 2),
            "rotation_y": np.round(rng.uniform(-3.1, 3.1, n), 2),
        }
        gt.append(g)
        keep = (names != "DontCare") & (rng.uniform(0, 1, n) < 0.85)
        m = int(keep.sum())
        d = {k: np.asarray(v)[keep].copy() for k, v in g.items()}
        d["bbox"] = np.round(d["bbox"] + rng.normal(0, 2.5, (m, 4)), 2)
        d["location"] = np.round(d["location"] + rng.normal(0, 0.15, (m, 3)) * [1, 0.3, 1], 2)
        d["dimensions"] = np.round(d["dimensions"] * rng.normal(1, 0.04, (m, 3)), 2)
        d["rotation_y"] = np.round(d["rotation_y"] + rng.normal(0, 0.08, m), 2)
        d["alpha"] = np.round(d["alpha"] + rng.normal(0, 0.08, m), 2)
        d["truncated"] = np.zeros(m)
        d["occluded"] = np.zeros(m, dtype=np.int64)
        d["score"] = np.round(rng.uniform(0.3, 1.0, m), 4)
        k = int(rng.integers(0, 4))
        fp = {key: v[rng.integers(0, m, k)] if m else v[:0] for key, v in d.items()}
        if m:
            fp["location"] = np.round(fp["location"] + rng.uniform(-6, 6, (k, 3)) * [1, 0, 1], 2)
            fp["bbox"] = np.round(fp["bbox"] + rng.uniform(-60, 60, (k, 1)), 2)
            fp["score"] = np.round(rng.uniform(0.0, 0.7, k), 4)
        dt.append({key: np.concatenate([d[key], fp[key]]) for key in d})
    return gt, dt


def load_port(port_dir, cpu_iou):
    """Imports the port from `port_dir`; with `cpu_iou`, from a rewritten copy."""
    if not cpu_iou:
        sys.path.insert(0, port_dir)
        return importlib.import_module("kitti_object_eval_python.eval")
    tmp = tempfile.mkdtemp(prefix="numba_port_cpu_")
    dst = os.path.join(tmp, "kitti_object_eval_python")
    shutil.copytree(os.path.join(port_dir, "kitti_object_eval_python"), dst)
    path = os.path.join(dst, "rotate_iou.py")
    src = open(path).read()
    src = src.replace("from numba import cuda", "")
    src = re.sub(r"@cuda\.jit\(.*?\)\s*\n(?=def )", "@numba.njit\n", src, flags=re.S)
    # error_model="numpy": a division by zero gives inf/NaN as on the GPU, where numba.cuda
    # raises nothing (the CPU default would raise ZeroDivisionError, e.g. on parallel edges).
    src = src.replace("@numba.njit\n", '@numba.njit(error_model="numpy")\n')
    src = src.replace("cuda.local.array(", "np.zeros(").replace("dtype=numba.float32", "dtype=np.float32")
    src += '''

@numba.njit(error_model="numpy")
def _iou_all_pairs_cpu(boxes, query_boxes, criterion):
    iou = np.zeros((boxes.shape[0], query_boxes.shape[0]), dtype=np.float32)
    for n in range(boxes.shape[0]):
        for k in range(query_boxes.shape[0]):
            iou[n, k] = devRotateIoUEval(query_boxes[k], boxes[n], criterion)
    return iou


def rotate_iou_gpu_eval(boxes, query_boxes, criterion=-1, device_id=0):
    b = np.ascontiguousarray(boxes, dtype=np.float32)
    q = np.ascontiguousarray(query_boxes, dtype=np.float32)
    return _iou_all_pairs_cpu(b, q, np.int32(criterion))
'''
    open(path, "w").write(src)
    sys.path.insert(0, tmp)
    return importlib.import_module("kitti_object_eval_python.eval")


def timed(f):
    t = time.perf_counter()
    out = f()
    return time.perf_counter() - t, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--port", required=True, help="folder holding kitti_object_eval_python/")
    ap.add_argument("--frames", type=int, default=3769)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cpu-iou", action="store_true", help="run the port's IoU on the CPU")
    args = ap.parse_args()
    cpu_iou = args.cpu_iou
    if not cpu_iou:
        try:
            from numba import cuda

            cpu_iou = not cuda.is_available()
        except ImportError:
            cpu_iou = True
    gt, dt = generate(args.frames, args.seed)
    n_gt = sum(len(g["name"]) for g in gt)
    n_dt = sum(len(d["name"]) for d in dt)
    print(f"{args.frames} frames, {n_gt} ground-truth objects, {n_dt} detections")
    classes = ["Car", "Pedestrian", "Cyclist"]

    t1, (ours_text, ours) = timed(lambda: fusiondet.get_official_eval_result(gt, dt, classes))
    t2, _ = timed(lambda: fusiondet.get_official_eval_result(gt, dt, classes))
    print(f"fusiondet.get_official_eval_result: first {t1:.3f} s, warm {t2:.3f} s")

    with tempfile.TemporaryDirectory() as d:
        os.mkdir(os.path.join(d, "gt"))
        os.mkdir(os.path.join(d, "det"))
        sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
        from test_fusiondet import parse_text, write_kitti

        for i, (g, r) in enumerate(zip(gt, dt)):
            write_kitti(Path(d, "gt", f"{i:06d}.txt"), g)
            write_kitti(Path(d, "det", f"{i:06d}.txt"), r)
        t3, _ = timed(lambda: fusiondet.evaluate_kitti(os.path.join(d, "gt"), os.path.join(d, "det")))
        print(f"fusiondet.evaluate_kitti (files, parsing included): {t3:.3f} s")

    port = load_port(args.port, cpu_iou)
    where = "IoU kernel on the CPU (numba njit)" if cpu_iou else "IoU kernel on the GPU (numba.cuda)"
    p1, (theirs_text, theirs) = timed(lambda: port.get_official_eval_result(gt, dt, classes))
    p2, _ = timed(lambda: port.get_official_eval_result(gt, dt, classes))
    print(f"numba port ({where}): first {p1:.3f} s (compilation included), warm {p2:.3f} s")
    print(f"warm ratio: {p2 / t2:.0f}x; first-call ratio: {p1 / t1:.0f}x")

    assert set(ours) == set(theirs), (sorted(ours), sorted(theirs))
    diffs = sorted(((abs(float(ours[k]) - float(theirs[k])), k) for k in ours), reverse=True)
    print(f"result_dict: same {len(diffs)} keys; largest AP differences (fusiondet vs port):")
    for diff, k in diffs[:5]:
        print(f"  {k}: {float(ours[k]):.4f} vs {float(theirs[k]):.4f} (|diff| {diff:.4f})")
    a, b = parse_text(ours_text), parse_text(theirs_text)
    assert set(a) == set(b)
    rows = sorted(((max(abs(x - y) for x, y in zip(a[k], b[k])), k) for k in a), reverse=True)
    print(f"result_str: same {len(rows)} rows; largest differences (AP11 and AP_R40, both settings):")
    for diff, k in rows[:5]:
        print(f"  {k}: {a[k]} vs {b[k]} (|diff| {diff:.4f})")


if __name__ == "__main__":
    main()
