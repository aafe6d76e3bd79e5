"""Tests of the Python package on the repository's own data: the devkit's numbers of the
`mixed` case, VoteNet's numbers of the indoor case, the annos drop-in on generated cases
(against the file-based evaluation), readers round-tripping, and bad input."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

import fusiondet
from fusiondet import FusiondetError

ROOT = Path(__file__).resolve().parents[3]
MIXED = ROOT / "crates/eval/tests/data/mixed"
NESTED = ROOT / "crates/eval/tests/data/devkit-nested-boxes"
INDOOR = ROOT / "crates/eval/tests/data/indoor/votenet-random"
SAMPLE = ROOT / "data/kitti-sample"


def expected_rows(case):
    doc = json.loads((case / "expected.json").read_text())
    return {(r["class"], r["metric"], r["min_overlap"]): r for r in doc["results"]}


def check_against_devkit(rows, case, tol=0.01):
    expected = expected_rows(case)
    seen = 0
    for r in rows:
        e = expected.get((r["class"], r["metric"], r["min_overlap"]))
        if e is None:
            continue
        seen += 1
        for key in ("ap11", "ap40"):
            assert np.allclose(r[key], e[key], atol=tol), (r, e)
    return seen


def test_mixed_case_matches_the_devkit():
    out = fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", split=MIXED / "ids.txt")
    assert set(out) == {"results"}
    # 3 classes x 2 settings x 4 metrics, and every devkit row found among them.
    assert len(out["results"]) == 24
    # The devkit printed the 12 strict rows; each is compared, in both settings where the
    # loose one has the same minimum overlap (bbox and aos): 18 comparisons.
    ours = {(r["class"], r["metric"], r["min_overlap"]) for r in out["results"]}
    assert set(expected_rows(MIXED)) <= ours and len(expected_rows(MIXED)) == 12
    assert check_against_devkit(out["results"], MIXED) == 18


def test_same_dict_as_the_binary_json_layout():
    ids = (MIXED / "ids.txt").read_text().split()
    by_list = fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", split=ids[:50], classes=["Car"])
    assert {r["class"] for r in by_list["results"]} == {"Car"}
    assert set(by_list["results"][0]) == {"class", "metric", "min_overlap", "ap11", "ap40"}
    by_all = fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", split=ids, classes="Car")
    assert by_all["results"] != by_list["results"]


def test_a_baseline_adds_the_difference_and_its_interval(tmp_path):
    # The baseline: the mixed case's results with every tenth frame's detections gone.
    ids = (MIXED / "ids.txt").read_text().split()
    (tmp_path / "base").mkdir()
    for i, path in enumerate(sorted((MIXED / "det").iterdir())):
        (tmp_path / "base" / path.name).write_text("" if i % 10 == 0 else path.read_text())
    out = fusiondet.evaluate_kitti(
        MIXED / "gt", MIXED / "det", split=ids, classes="Car", baseline_dir=tmp_path / "base", resamples=100, seed=3
    )
    b = out["baseline"]
    assert (b["resamples"], b["resample_seed"], b["confidence"], b["frames"]) == (100, 3, 0.95, len(ids))
    row = next(r for r in b["rows"] if r["metric"] == "3d" and r["min_overlap"] == 0.7)
    main = next(r for r in out["results"] if r["metric"] == "3d" and r["min_overlap"] == 0.7)
    assert row["ap40"] == main["ap40"]
    for d in range(3):
        assert row["difference"][d] == row["ap40"][d] - row["baseline_ap40"][d]
        assert row["interval_low"][d] <= row["interval_high"][d]
    assert row["difference"][1] > 0
    with pytest.raises(fusiondet.FusiondetError, match="at least 2"):
        fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", split=ids, baseline_dir=MIXED / "det", resamples=1)
    # A frame without a result file in the baseline is named against the baseline's folder.
    (tmp_path / "base" / f"{ids[1]}.txt").unlink()
    with pytest.warns(UserWarning, match=r"1 frames have no result file in .*base") as caught:
        fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", split=ids, baseline_dir=tmp_path / "base", resamples=10)
    assert len(caught) == 1, [str(w.message) for w in caught]


def parse_text(text):
    """OpenPCDet's result_str as {(class, setting, "AP" | "AP_R40", metric): [e, m, h]}."""
    out, seen, head = {}, {}, None
    for line in text.splitlines():
        if "@" in line:
            cls, rest = line.split(" ", 1)
            kind = rest.split("@")[0]
            seen[(cls, kind)] = seen.get((cls, kind), -1) + 1
            head = (cls, seen[(cls, kind)], kind)
        else:
            metric, values = line.split("AP:")
            out[head + (metric.strip(),)] = [float(v) for v in values.split(",")]
    return out


def annos_of(case, ids):
    gt, dt = [], []
    for i in ids:
        gt.append(fusiondet.read_label(case / "gt" / f"{i}.txt"))
        path = case / "det" / f"{i}.txt"
        if path.exists():
            dt.append(fusiondet.read_results(path))
        else:
            dt.append(empty_det())
    return gt, dt


def empty_det():
    return {
        "name": np.array([], dtype="<U10"),
        "truncated": np.zeros(0),
        "occluded": np.zeros(0),
        "alpha": np.zeros(0),
        "bbox": np.zeros((0, 4)),
        "dimensions": np.zeros((0, 3)),
        "location": np.zeros((0, 3)),
        "rotation_y": np.zeros(0),
        "score": np.zeros(0),
    }


def test_annos_drop_in_matches_the_devkit_on_mixed():
    ids = (MIXED / "ids.txt").read_text().split()
    gt, dt = annos_of(MIXED, ids)
    text, ret = fusiondet.get_official_eval_result(gt, dt, ["Car", "Pedestrian", "Cyclist"])
    expected = expected_rows(MIXED)
    printed = parse_text(text)
    for cls in ("Car", "Pedestrian", "Cyclist"):
        ov = {"Car": 0.7}.get(cls, 0.5)
        for metric, key in (("3d", "3d"), ("bev", "bev"), ("bbox", "image"), ("aos", "aos")):
            e = expected[(cls, metric, ov)]
            for d, diff in enumerate(("easy", "moderate", "hard")):
                assert abs(ret[f"{cls}_{key}/{diff}_R40"] - e["ap40"][d]) < 0.01
            assert np.allclose(printed[(cls, 0, "AP", metric)], e["ap11"], atol=0.01)
            assert np.allclose(printed[(cls, 0, "AP_R40", metric)], e["ap40"], atol=0.01)
    assert len(ret) == 3 * 4 * 3
    # OpenPCDet's layout: per class and setting, an AP and an AP_R40 block of 5 lines.
    lines = text.splitlines()
    assert len(lines) == 3 * 2 * 2 * 5
    assert lines[0] == "Car AP@0.70, 0.70, 0.70:"
    assert lines[5] == "Car AP_R40@0.70, 0.70, 0.70:"
    assert lines[10] == "Car AP@0.70, 0.50, 0.50:"
    assert lines[20] == "Pedestrian AP@0.50, 0.50, 0.50:"
    assert lines[30] == "Pedestrian AP@0.50, 0.25, 0.25:"
    car = ret["Car_3d/moderate_R40"]
    assert lines[8] == f"3d   AP:{ret['Car_3d/easy_R40']:.4f}, {car:.4f}, {ret['Car_3d/hard_R40']:.4f}"
    assert lines[9].startswith("aos  AP:")


def test_nested_boxes_are_scored_exactly():
    ids = (NESTED / "ids.txt").read_text().split()
    gt, dt = annos_of(NESTED, ids)
    text, _ = fusiondet.get_official_eval_result(gt, dt, "Car")
    printed = parse_text(text)
    # The devkit scores this nested pair as IoU 0 (AP11 0); the exact answer is one hit.
    assert printed[("Car", 0, "AP", "bev")][0] == round(100.0 / 11.0, 4)
    assert printed[("Car", 0, "AP", "3d")][0] == round(100.0 / 11.0, 4)


def random_annos(rng, n_frames, with_score):
    classes = np.array(["Car", "Pedestrian", "Cyclist", "Van", "DontCare"])
    annos = []
    for _ in range(n_frames):
        n = int(rng.integers(0, 8))
        x1 = rng.uniform(0, 1100, n)
        y1 = rng.uniform(100, 300, n)
        anno = {
            "name": classes[rng.integers(0, len(classes), n)],
            "truncated": np.round(rng.uniform(0, 0.6, n), 2),
            "occluded": rng.integers(0, 3, n),
            "alpha": np.round(rng.uniform(-3, 3, n), 2),
            "bbox": np.round(np.stack([x1, y1, x1 + rng.uniform(10, 150, n), y1 + rng.uniform(10, 120, n)], 1), 2),
            "dimensions": np.round(np.stack([rng.uniform(0.5, 5, n), rng.uniform(1.4, 2, n), rng.uniform(0.5, 2, n)], 1), 2),
            "location": np.round(np.stack([rng.uniform(-10, 10, n), rng.uniform(1, 2, n), rng.uniform(5, 60, n)], 1), 2),
            "rotation_y": np.round(rng.uniform(-3.1, 3.1, n), 2),
        }
        if with_score:
            anno["score"] = np.round(rng.uniform(0, 1, n), 4)
        annos.append(anno)
    return annos


def jitter(rng, gt):
    """Detections: noisy copies of the ground truth plus a few random boxes."""
    out = []
    for g, extra in zip(gt, random_annos(rng, len(gt), True)):
        n = len(g["name"])
        keep = g["name"] != "DontCare"
        d = {k: np.asarray(v)[keep] for k, v in g.items()}
        m = int(keep.sum())
        d["bbox"] = np.round(d["bbox"] + rng.normal(0, 3, (m, 4)), 2)
        d["location"] = np.round(d["location"] + rng.normal(0, 0.2, (m, 3)), 2)
        d["rotation_y"] = np.round(d["rotation_y"] + rng.normal(0, 0.1, m), 2)
        d["score"] = np.round(rng.uniform(0, 1, m), 4)
        extra = {k: v[extra["name"] != "DontCare"] for k, v in extra.items()}
        out.append({k: np.concatenate([d[k], extra[k]]) for k in d})
        assert n >= m
    return out


def write_kitti(path, anno):
    """Writes an annos dict as a label/result file (dimensions back to h, w, l)."""
    lines = []
    for i in range(len(anno["name"])):
        l, h, w = anno["dimensions"][i]
        cols = [
            anno["name"][i],
            f"{anno['truncated'][i]:.2f}",
            str(int(anno["occluded"][i])),
            f"{anno['alpha'][i]:.2f}",
            *(f"{v:.2f}" for v in anno["bbox"][i]),
            f"{h:.2f}", f"{w:.2f}", f"{l:.2f}",
            *(f"{v:.2f}" for v in anno["location"][i]),
            f"{anno['rotation_y'][i]:.2f}",
        ]
        if "score" in anno:
            cols.append(f"{anno['score'][i]:.4f}")
        lines.append(" ".join(cols))
    path.write_text("\n".join(lines) + ("\n" if lines else ""))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_annos_drop_in_agrees_with_the_file_evaluation(tmp_path, seed):
    rng = np.random.default_rng(seed)
    gt = random_annos(rng, 60, False)
    dt = jitter(rng, gt)
    (tmp_path / "gt").mkdir()
    (tmp_path / "det").mkdir()
    ids = [f"{i:06d}" for i in range(len(gt))]
    for i, g, d in zip(ids, gt, dt):
        write_kitti(tmp_path / "gt" / f"{i}.txt", g)
        write_kitti(tmp_path / "det" / f"{i}.txt", d)
    text, ret = fusiondet.get_official_eval_result(gt, dt, [0, 1, 2])
    printed = parse_text(text)
    files = fusiondet.evaluate_kitti(tmp_path / "gt", tmp_path / "det", split=ids)
    key = {"3d": "3d", "bev": "bev", "bbox": "image", "aos": "aos"}
    loose = {"Car": [0.7, 0.5, 0.5, 0.7], "Pedestrian": [0.5, 0.25, 0.25, 0.5], "Cyclist": [0.5, 0.25, 0.25, 0.5]}
    checked = 0
    for r in files["results"]:
        m = ("bbox", "bev", "3d", "aos").index(r["metric"])
        strict = r["min_overlap"] == (0.7 if r["class"] == "Car" else 0.5)
        if strict:
            for d, diff in enumerate(("easy", "moderate", "hard")):
                assert ret[f"{r['class']}_{key[r['metric']]}/{diff}_R40"] == pytest.approx(r["ap40"][d], abs=1e-9)
        for setting in (0, 1):
            if r["min_overlap"] == (loose[r["class"]][m] if setting else (0.7 if r["class"] == "Car" else 0.5)):
                digits = 2 if r["metric"] == "aos" else 4
                assert printed[(r["class"], setting, "AP", r["metric"])] == [round(v, digits) for v in r["ap11"]]
                assert printed[(r["class"], setting, "AP_R40", r["metric"])] == [round(v, digits) for v in r["ap40"]]
                checked += 1
    # 24 rows; bbox and aos have the same overlap in both settings and are checked twice.
    assert checked == 36
    # Non-trivial: some AP well above 0 and below 100.
    assert any(0 < v < 100 for v in ret.values())


def test_identical_footprints_and_perfect_detections_score_100():
    rng = np.random.default_rng(5)
    # Enough boxes (> 40 per class and difficulty): with fewer, the devkit's recall sampling
    # leaves AP_R40 below 100 even for perfect detections.
    gt = random_annos(rng, 500, False)
    dt = []
    for g in gt:
        # Spread the boxes so that no two overlap: each detection can only match its own box.
        j = np.arange(len(g["name"]))
        g["bbox"][:, 0] = 160.0 * j + 5
        g["bbox"][:, 2] = 160.0 * j + 105
        g["location"][:, 0] = 6.0 * j
        g["location"][:, 2] = 10.0 + 8.0 * j
        # Fully visible, untruncated, 50 px tall: in every difficulty.
        g["bbox"][:, 3] = g["bbox"][:, 1] + 50
        g["truncated"][:] = 0
        g["occluded"][:] = 0
        keep = g["name"] != "DontCare"
        d = {k: np.asarray(v)[keep] for k, v in g.items()}
        d["score"] = np.linspace(1, 0.5, int(keep.sum()))
        dt.append(d)
    _, ret = fusiondet.get_official_eval_result(gt, dt, ["Car", "Pedestrian", "Cyclist"])
    for cls in ("Car", "Pedestrian", "Cyclist"):
        for key in ("3d", "bev", "image"):
            for diff in ("easy", "moderate", "hard"):
                assert ret[f"{cls}_{key}/{diff}_R40"] == pytest.approx(100.0), (cls, key, diff)


def test_label_reader_round_trips(tmp_path):
    src = SAMPLE / "training/label_2/000000.txt"
    anno = fusiondet.read_label(src)
    assert "score" not in anno
    assert anno["bbox"].shape == (len(anno["name"]), 4)
    first = src.read_text().split("\n")[0].split()
    assert anno["name"][0] == first[0]
    # dimensions come back in the annos order l, h, w (the file stores h, w, l).
    assert list(anno["dimensions"][0]) == [float(first[10]), float(first[8]), float(first[9])]
    write_kitti(tmp_path / "again.txt", anno)
    again = fusiondet.read_label(tmp_path / "again.txt")
    for k in anno:
        assert np.array_equal(anno[k], again[k]), k
    anno["score"] = np.linspace(0.9, 0.1, len(anno["name"]))
    write_kitti(tmp_path / "det.txt", anno)
    det = fusiondet.read_results(tmp_path / "det.txt")
    assert np.allclose(det["score"], np.round(anno["score"], 4))


def test_velodyne_and_calib_readers():
    scan = SAMPLE / "training/velodyne/000000.bin"
    pts = fusiondet.read_velodyne(scan)
    assert pts.dtype == np.float32 and pts.shape[1] == 4
    assert np.array_equal(pts, np.fromfile(scan, dtype="<f4").reshape(-1, 4))
    calib = fusiondet.read_calib(SAMPLE / "training/calib/000000.txt")
    text = {l.split(":")[0]: l.split(":")[1].split() for l in (SAMPLE / "training/calib/000000.txt").read_text().splitlines() if ":" in l}
    assert np.array_equal(calib["P2"].ravel(), np.array(text["P2"], dtype=float))
    assert calib["R0_rect"].shape == (3, 3) and calib["velo_to_rect"].shape == (4, 4)
    # A LiDAR point in front of the car projects into the image.
    p = np.array([10.0, 0.0, 0.0, 1.0])
    u, v, w = calib["velo_to_image"] @ p
    assert w > 0 and 0 < u / w < 1300 and 0 < v / w < 400


def test_sunrgbd_matches_votenet():
    out = fusiondet.evaluate_sunrgbd(INDOOR / "label", INDOOR / "result", split=INDOOR / "split.txt")
    # VoteNet's eval_det.py on this case (pinned in crates/eval/src/indoor/reference.rs).
    assert out["map"]["0.25"] == pytest.approx(58.721007266758896, abs=1e-9)
    assert out["map"]["0.5"] == pytest.approx(24.726977210637337, abs=1e-9)
    bed = [r for r in out["results"] if r["class"] == "bed"]
    assert [r["ap"] for r in bed] == pytest.approx([73.63636363636363, 67.5])
    assert [r["ap"] for r in out["results"] if r["class"] == "bathtub"] == [None, None]


def test_bad_label_line_names_file_line_field(tmp_path):
    bad = tmp_path / "000000.txt"
    bad.write_text("Car 0.00 0 -0.20 1 2 3 4 1.5 1.6 4.0 1 2 3 0.1\nCar 0.00 0 abc 1 2 3 4 1.5 1.6 4.0 1 2 3 0.1\n")
    with pytest.raises(FusiondetError, match=r"000000.txt:2: field `alpha`"):
        fusiondet.read_label(bad)
    (tmp_path / "det").mkdir()
    with pytest.raises(FusiondetError, match=r"000000.txt:2: field `alpha`"):
        fusiondet.evaluate_kitti(tmp_path, tmp_path / "det")
    assert issubclass(FusiondetError, ValueError)


def test_bad_results_and_readers(tmp_path):
    no_score = tmp_path / "r.txt"
    no_score.write_text("Car 0.00 0 -0.20 1 2 3 4 1.5 1.6 4.0 1 2 3 0.1\n")
    with pytest.raises(FusiondetError, match=r"r.txt:1: field `score`"):
        fusiondet.read_results(no_score)
    with pytest.raises(FusiondetError, match="no such result file"):
        fusiondet.read_results(tmp_path / "missing.txt")
    short = tmp_path / "short.bin"
    short.write_bytes(b"\0" * 20)
    with pytest.raises(FusiondetError, match="multiple of 16"):
        fusiondet.read_velodyne(short)
    calib = tmp_path / "c.txt"
    calib.write_text("P0: 1 2 3\n")
    with pytest.raises(FusiondetError, match="c.txt"):
        fusiondet.read_calib(calib)
    with pytest.raises(FusiondetError, match="breakdown=True needs"):
        fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", breakdown=True)
    with pytest.raises(FusiondetError, match="split `nosuch`"):
        fusiondet.evaluate_kitti(MIXED / "gt", MIXED / "det", split="nosuch")


def test_bad_annos_point_at_the_entry():
    rng = np.random.default_rng(3)
    gt = random_annos(rng, 4, False)
    gt[1] = random_annos(np.random.default_rng(9), 1, False)[0]
    while len(gt[1]["name"]) == 0:
        gt[1] = random_annos(rng, 1, False)[0]
    dt = [dict(g, score=np.ones(len(g["name"]))) for g in gt]
    bad = [dict(d) for d in dt]
    del bad[2]["score"]
    with pytest.raises(FusiondetError, match=r"dt_annos\[2\]: missing key 'score'"):
        fusiondet.get_official_eval_result(gt, bad, "Car")
    bad = [dict(d) for d in dt]
    bad[1]["name"] = np.array(["car"] * len(bad[1]["name"]))
    with pytest.raises(FusiondetError, match=r"dt_annos\[1\]\['name'\]\[0\]: unknown class `car`"):
        fusiondet.get_official_eval_result(gt, bad, "Car")
    bad = [dict(d) for d in dt]
    bad[1]["location"] = bad[1]["location"].copy()
    bad[1]["location"][0, 2] = np.nan
    with pytest.raises(FusiondetError, match=r"dt_annos\[1\]\['location'\]\[0\]: NaN is not a finite"):
        fusiondet.get_official_eval_result(gt, bad, "Car")
    bad = [dict(d) for d in dt]
    bad[1]["bbox"] = bad[1]["bbox"][:, :3]
    with pytest.raises(FusiondetError, match=r"dt_annos\[1\]\['bbox'\]"):
        fusiondet.get_official_eval_result(gt, bad, "Car")
    with pytest.raises(FusiondetError, match="4 gt_annos but 3 dt_annos"):
        fusiondet.get_official_eval_result(gt, dt[:3], "Car")
    with pytest.raises(FusiondetError, match="not evaluated"):
        fusiondet.get_official_eval_result(gt, dt, "Van")


def test_split_name_and_breakdown_on_the_kitti_sample(tmp_path):
    labels = SAMPLE / "training/label_2"
    ids = (SAMPLE / "ImageSets/val.txt").read_text().split()
    for i in ids:
        anno = fusiondet.read_label(labels / f"{i}.txt")
        keep = anno["name"] != "DontCare"
        det = {k: v[keep] for k, v in anno.items()}
        det["score"] = np.linspace(0.9, 0.5, int(keep.sum()))
        write_kitti(tmp_path / f"{i}.txt", det)
    out = fusiondet.evaluate_kitti(
        labels,
        tmp_path,
        split="val",
        breakdown=True,
        velodyne_dir=SAMPLE / "training/velodyne",
        calib_dir=SAMPLE / "training/calib",
    )
    assert set(out) == {"results", "breakdown"}
    assert {r["by"] for r in out["breakdown"]} == {"distance", "occlusion", "lidar_points"}
    by_list = fusiondet.evaluate_kitti(labels, tmp_path, split=ids)
    assert by_list["results"] == out["results"]

    # Every ground-truth box lies in exactly one distance bin and one LiDAR-points bin.
    def total(by):
        rows = [r for r in out["breakdown"] if r["by"] == by and r["class"] == "Car" and r["metric"] == "3d"]
        return np.sum([r["n_gt"] for r in rows if r["min_overlap"] == 0.7], axis=0)

    assert np.array_equal(total("distance"), total("lidar_points"))
    assert np.sum(total("distance")) > 0
