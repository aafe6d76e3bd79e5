"""Generates a SUN RGB-D-format evaluation case (label/, result/, split.txt), runs VoteNet's
evaluation on it, checks VoteNet's IoU against an exact one (shapely) on every pair it compares,
and prints the APs in percent.

    python generate.py SEED OUT_DIR N_SCENES      (this case: 1 OUT 20)

Needs numpy, scipy and shapely, and VoteNet's utils/box_util.py and utils/eval_det.py beside
it (github.com/facebookresearch/votenet; not part of this repository). Its utils/metric_util.py
imports torch for an axis-aligned IoU the oriented evaluation never calls: a stub defining
`calc_iou` does. Lines of classes outside the ten are written to the files but not given to
VoteNet, whose eval_det would make them classes of their own: fusiondet ignores them.
"""
import os, sys, random, warnings
import numpy as np
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from box_util import box3d_iou, get_3d_box
from eval_det import eval_det_multiprocessing, get_iou_obb
from shapely.geometry import Polygon

CLASSES = ['bed','table','sofa','chair','toilet','desk','dresser','night_stand','bookshelf','bathtub']
MEAN = {'bed':(2.0,1.6,1.0),'table':(1.2,0.7,0.75),'sofa':(1.9,0.9,0.8),'chair':(0.55,0.55,0.85),
        'toilet':(0.7,0.45,0.75),'desk':(1.2,0.6,0.75),'dresser':(0.9,0.5,1.0),'night_stand':(0.45,0.45,0.55),
        'bookshelf':(0.9,0.35,1.7),'bathtub':(1.6,0.75,0.5)}

def fmt(v, nd):
    s = f"{v:.{nd}f}"
    return "0" if float(s) == 0 else s.rstrip('0').rstrip('.') if '.' in s else s

def gen(seed, out, n_scenes, absent=('bathtub',)):
    rng = random.Random(seed)
    used = [c for c in CLASSES if c not in absent]
    scores = set()
    def score():
        while True:
            s = round(rng.uniform(0.01, 0.99), 6)
            if s not in scores:
                scores.add(s); return s
    ids = [f"{100+k:06d}" for k in range(n_scenes)]
    os.makedirs(f"{out}/label", exist_ok=True); os.makedirs(f"{out}/result", exist_ok=True)
    for sid in ids:
        gts, dets = [], []
        for _ in range(rng.randint(1, 6)):
            c = rng.choice(used)
            m = MEAN[c]
            box = [rng.uniform(-2.5,2.5), rng.uniform(1.0,6.0), rng.uniform(-1.2,0.2)] + \
                  [m[k]*rng.uniform(0.8,1.2) for k in range(3)] + [rng.uniform(-np.pi,np.pi)]
            gts.append((c, box))
            if rng.random() < 0.85:
                d = [box[0]+rng.gauss(0,0.12), box[1]+rng.gauss(0,0.12), box[2]+rng.gauss(0,0.08)] + \
                    [box[3+k]*rng.uniform(0.85,1.15) for k in range(3)] + [box[6]+rng.gauss(0,0.25)]
                dets.append((c, d, score()))
                if rng.random() < 0.25:   # a duplicate, shifted a little more
                    d2 = [d[0]+rng.gauss(0,0.15), d[1]+rng.gauss(0,0.15)] + d[2:6] + [d[6]+rng.gauss(0,0.3)]
                    dets.append((c, d2, score()))
            if rng.random() < 0.15:       # the right place, the wrong class
                dets.append((rng.choice([o for o in used if o != c]), list(box), score()))
        for _ in range(rng.randint(0, 3)):  # false positives anywhere
            c = rng.choice(used); m = MEAN[c]
            dets.append((c, [rng.uniform(-2.5,2.5), rng.uniform(1.0,6.0), rng.uniform(-1.2,0.2)] +
                         [m[k]*rng.uniform(0.8,1.2) for k in range(3)] + [rng.uniform(-np.pi,np.pi)], score()))
        if rng.random() < 0.3:            # a class outside the ten, in both files
            gts.append(('lamp', [0,3,0,0.3,0.3,0.5,0])); dets.append(('lamp', [0,3,0,0.3,0.3,0.5,0], score()))
        rng.shuffle(dets)
        def line(c, b):
            return " ".join([c] + [fmt(v, 4) for v in b[:6]] + [fmt(b[6], 5)] + ["0", "0", "100", "100"])
        with open(f"{out}/label/{sid}.txt", "w") as f:
            f.write("# class cx cy cz dx dy dz yaw x1 y1 x2 y2\n")
            for c, b in gts: f.write(line(c, b) + "\n")
        with open(f"{out}/result/{sid}.txt", "w") as f:
            for c, b, s in dets: f.write(line(c, b) + " " + fmt(s, 6) + "\n")
    with open(f"{out}/split.txt", "w") as f:
        f.write("\n".join(ids) + "\n")
    return ids

def read(path, with_score):
    out = []
    for l in open(path):
        if l.startswith('#') or not l.strip(): continue
        f = l.split()
        out.append((f[0], [float(v) for v in f[1:8]], float(f[12]) if with_score else None))
    return out

def corners(b):
    return get_3d_box(np.array(b[3:6]), -b[6], np.array([b[0], -b[2], b[1]]))

def exact_iou(a, b):
    def poly(b):
        c, s = np.cos(b[6]), np.sin(b[6])
        return Polygon([(b[0]+c*x-s*y, b[1]+s*x+c*y) for x, y in
                        [(b[3]/2,b[4]/2),(-b[3]/2,b[4]/2),(-b[3]/2,-b[4]/2),(b[3]/2,-b[4]/2)]])
    hov = max(0.0, min(a[2]+a[5]/2, b[2]+b[5]/2) - max(a[2]-a[5]/2, b[2]-b[5]/2))
    inter = poly(a).intersection(poly(b)).area * hov
    return inter / (a[3]*a[4]*a[5] + b[3]*b[4]*b[5] - inter)

def run(out, ids):
    gt_all, pred_all = {}, {}
    worst = 0.0
    for i, sid in enumerate(ids):
        g = [(c, b) for c, b, _ in read(f"{out}/label/{sid}.txt", False) if c in CLASSES]
        d = [(c, b, s) for c, b, s in read(f"{out}/result/{sid}.txt", True) if c in CLASSES]
        for c, b, _ in d:
            for c2, b2 in g:
                if c2 == c:
                    v = box3d_iou(corners(b), corners(b2))[0]
                    worst = max(worst, abs(v - exact_iou(b, b2)))
        gt_all[i] = [(c, corners(b)) for c, b in g]
        pred_all[i] = [(c, corners(b), s) for c, b, s in d]
    print("largest |VoteNet IoU - exact IoU| over compared pairs:", worst)
    for t in (0.25, 0.5):
        with open(os.devnull, "w") as devnull:
            old = sys.stdout; sys.stdout = devnull
            try:
                rec, prec, ap = eval_det_multiprocessing(pred_all, gt_all, ovthresh=t, get_iou_func=get_iou_obb)
            finally:
                sys.stdout = old
        print(f"iou {t}: mAP {100*np.mean(list(ap.values()))!r}")
        for c in CLASSES:
            if c in ap: print(f"  {c}: {100*ap[c]!r}")

if __name__ == "__main__":
    warnings.simplefilter("ignore")
    seed, out, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    ids = gen(seed, out, n)
    run(out, ids)
