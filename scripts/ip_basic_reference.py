#!/usr/bin/env python3
"""Runs IP-Basic's own code (Ku et al., github.com/kujason/ip_basic) on the sparse inputs
written by `cargo run -p fusiondet-depth --example reference_io -- inputs ...`, so both
implementations see identical float32 inputs.

    python3 scripts/ip_basic_reference.py IP_BASIC_CHECKOUT IN_DIR OUT_DIR \
        fast|multiscale gaussian|bilateral extrapolate|no [OURS_DIR]

Writes OUT_DIR/<id>.f32 (their completion, little-endian float32, row-major) and prints
their fill time per frame on one thread (median of 5 runs per frame). With OURS_DIR (our
completions of the same inputs, same format), prints the largest absolute difference and
how many pixels differ. Needs numpy and opencv-python(-headless).
"""
import os
import statistics
import sys
import time

import cv2
import numpy as np


def main():
    checkout, in_dir, out_dir, method, blur, extrapolate = sys.argv[1:7]
    ours_dir = sys.argv[7] if len(sys.argv) > 7 else None
    sys.path.insert(0, checkout)
    from ip_basic import depth_map_utils  # their module, from their checkout

    cv2.setNumThreads(1)
    extrapolate = extrapolate == "extrapolate"
    os.makedirs(out_dir, exist_ok=True)
    times, worst, differing, pixels, empty_mismatch = [], 0.0, 0, 0, 0
    for line in open(os.path.join(in_dir, "sizes.txt")):
        frame_id, w, h = line.split()
        raw = np.fromfile(os.path.join(in_dir, frame_id + ".f32"), dtype="<f4")
        sparse = raw.reshape(int(h), int(w))

        def run():
            depth = sparse.copy()  # fill_in_fast works in place
            if method == "fast":
                return depth_map_utils.fill_in_fast(
                    depth, extrapolate=extrapolate, blur_type=blur)
            return depth_map_utils.fill_in_multiscale(
                depth, extrapolate=extrapolate, blur_type=blur)[0]

        runs = []
        for _ in range(5):
            start = time.perf_counter()
            dense = run()
            runs.append(time.perf_counter() - start)
        times.append(statistics.median(runs))
        # What is left at or below 0.1 m was never re-inverted: no depth. Their demo's
        # 16-bit PNG rounds the bilateral filter's 1e-8 leftovers there to 0; so do we.
        theirs = np.where(dense > 0.1, dense, 0).astype("<f4")
        theirs.tofile(os.path.join(out_dir, frame_id + ".f32"))
        if ours_dir:
            ours = np.fromfile(os.path.join(ours_dir, frame_id + ".f32"), dtype="<f4")
            ours = ours.reshape(theirs.shape)
            diff = np.abs(ours.astype(np.float64) - theirs.astype(np.float64))
            worst = max(worst, float(diff.max()))
            differing += int((diff > 0).sum())
            empty_mismatch += int(((ours == 0) != (theirs == 0)).sum())
            pixels += diff.size
    print(f"{method} {blur} {'extrapolate' if extrapolate else 'no-extrapolate'}: "
          f"{len(times)} frames, fill time median {1000 * statistics.median(times):.2f} ms "
          f"(one thread, OpenCV {cv2.__version__})")
    if ours_dir:
        print(f"  against ours: max |difference| {worst:.3g} m, {differing} of {pixels} "
              f"pixels differ, {empty_mismatch} differ in being empty")


if __name__ == "__main__":
    main()
