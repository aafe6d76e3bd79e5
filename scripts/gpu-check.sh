#!/usr/bin/env bash
# One prepared run on a GPU machine: CPU-vs-GPU parity of the shipped models, detection speed
# on both, and seconds per training step of the published Voxel R-CNN and DASANet
# configurations. Meant for a lent machine with little time (about 8 minutes on one GPU with
# 16 CPU cores): everything it needs is simulated on the spot, every figure it prints is
# measured in this run, and it ends with one summary table.
#
#   scripts/gpu-check.sh                        # everything, binary from scripts/build-cuda.sh
#   FUSIONDET=/path/fusiondet DEVICE=cuda:0 scripts/gpu-check.sh
#   MODELS="fconvnet-car saf-car" TRAIN=0 scripts/gpu-check.sh    # part of it (see below)
#   DEVICE=cpu MODELS=fconvnet-car TRAIN_CONFIGS=configs/tiny-voxel-rcnn.toml scripts/gpu-check.sh
#                                               # a dry run of the script itself, CPU against CPU
#
# Environment (all optional):
#   FUSIONDET      the binary (default: target-cuda/release/fusiondet, else fusiondet on PATH)
#   DEVICE         the device to check against the CPU (default: cuda)
#   MODELS         shipped models to check, names of MODELS_DIR/<name>.bpk (default: all five)
#   MODELS_DIR     where their checkpoints are (default: models/ of this repository). A call
#                  to a lent machine sends at most 64 MiB: the five Car models are 70 MB, and
#                  the binary embeds all nine shipped models (125 MB of weights; xz takes
#                  about 9% off them): build the CUDA binary without them
#                  (EMBED_MODELS=0 scripts/build-cuda.sh; this script reads the models from
#                  disk), send the tree without models/ and data/, and split the models over
#                  calls with MODELS and
#                  MODELS_DIR (a git-ignored folder carried with the call); CHECK_OUT is kept
#                  between calls on a warm machine, so later calls reuse the simulated frames.
#                  The 2026-11-29 run took 164 s and 243 s in two calls; PREPARE_AB,
#                  STAGE_ONE_AB, PROPOSALS_AB, INNER_SPLIT_AB, PROFILE and TRAIN_QUERY_AB (added since,
#                  not yet run on a GPU) add eight benches, two checked detections, two profiled
#                  trainings, two profiled detections (each profiled run stopped after
#                  PROFILE_SECONDS) and two trainings: where a lent
#                  machine's minutes are short, the second call can leave them to a third
#                  (TRAIN=0 in one call, MODELS=" " in the other).
#                  With 15 minutes of device time a session, starts included, the issue's
#                  figures come first: AB=0 leaves every A/B run out, and two calls then cover
#                  what the targets need, the first
#                    AB=0 TRAIN_CPU=0 CPU_LOSS_CURVES="…" PROFILE_SECONDS=60 MODELS=" "
#                    (the published configurations: step times, frames/s, kernel profiles,
#                    loss curves against the CPU's given below; about 7 min
#                    estimated, not yet timed on a GPU)
#                  and the second
#                    AB=0 TRAIN=0   (the shipped models' parity and speed on both)
#                  with the A/Bs left to a session with minutes to spare.
#   AB             1 (default) or 0: whether the A/B runs below (QUERY_AB, TRAIN_QUERY_AB,
#                  PROPOSALS_AB, INNER_SPLIT_AB, SPARSE_AB, TABLES_AB, PREPARE_AB,
#                  STAGE_ONE_AB) run by default; each one's own variable still decides
#   TRAIN          1 (default) to time training steps, 0 to skip them
#   TRAIN_CONFIGS  configurations to time (default: the published Voxel R-CNN and DASANet)
#   TRAIN_CPU      1 (default) to time them on the CPU too; 0 runs them on the device only
#                  (the published DASANet's CPU run takes minutes a lent machine may not
#                  have): its loss curve is then printed for comparison with a CPU run made
#                  elsewhere on the same frames (same seeds, same simulator), or compared with
#                  the curves given in CPU_LOSS_CURVES
#   CPU_LOSS_CURVES  with TRAIN_CPU=0, the CPU's loss curve of each training configuration
#                  (`loss_curve` of both epochs' metrics lines, step by step) as
#                  name=loss,loss,… words. The default frames' (CPU runs of 2026-12-01 on a
#                  2-core machine: `fusiondet simulate --frames 48 --seed 2027 --val-fraction
#                  0.5`, both `gt-database` runs, then `train --epochs 2 --max-frames 8` of
#                  each published configuration; rerun them after a change to training):
#                    voxel-rcnn-car=3.8690762519836426,6.542089462280273,4.426336765289307,4.461228370666504,3.5165317058563232,7.462343215942383,3.214056968688965,2.328737735748291
#                    dasanet-car=13.488049507141113,6.217823028564453,11.987112998962402,4.381107807159424
#   CHECK_OUT      work directory (default: gpu-check-out in the repository, which git ignores;
#                  not OUT, which a remote runner may set to a fresh folder per call)
#   FRAMES         simulated frames, half of them val (default: 48)
#   REPEATS        bench repeats after the warm-up run (default: 3)
#   STEPS_FRAMES   training frames per epoch for the step timing (default: 8)
#   QUERY_AB       models also run on the device with the RoI grid query on the host
#                  (FUSIONDET_ROI_QUERY=host; a GPU's default in detection is its kernels):
#                  a `detect` that compares the kernels' rows with the host query's
#                  (FUSIONDET_ROI_QUERY=check), a `detect` with the host query compared box
#                  by box with the kernels' on the same device, and a bench, beside the
#                  default (default: voxel-rcnn-car dasanet-car; empty to skip)
#   PROPOSALS_AB   models also detect with stage one's proposals checked against the host's
#                  (FUSIONDET_PROPOSALS=check: a GPU's default ranks, decodes and suppresses
#                  them on the device; each frame whose proposals differ is counted), and the
#                  published configurations also bench with the proposals chosen on the host
#                  (FUSIONDET_PROPOSALS=host) (default: voxel-rcnn-car dasanet-car; empty to
#                  skip)
#   TRAIN_QUERY_AB the published configurations also train with the RoI grid query on the host
#                  (FUSIONDET_ROI_QUERY=host; a GPU's default in training, as in detection, is
#                  its kernels, the index turned around on the device): 1 or 0 (default: 1)
#   TABLES_AB      the published configurations' benches also run with the sparse kernels'
#                  tables built on the host (FUSIONDET_RULEBOOK_TABLES=host; by default the
#                  device searches them): 1 or 0 (default: 1)
#   PREPARE_AB     the published configurations' benches also run with one thread preparing
#                  frames beside the network (FUSIONDET_PREPARE_THREADS=1; beside a GPU the
#                  default is a quarter of the cores, 1 to 4): 1 or 0 (default: 1)
#   STAGE_ONE_AB   the published configurations' benches also run with each frame's stage one
#                  on the network's thread (FUSIONDET_STAGE_ONE_AHEAD=off; by default it runs
#                  on the threads that prepare frames, on a GPU on device streams of their
#                  own beside stage two): 1 or 0 (default: 1)
#   INNER_SPLIT_AB the published configurations' benches also run with the products of a long
#                  inner dimension and few output tiles unsplit (FUSIONDET_INNER_SPLIT=off;
#                  by default a GPU cuts TDIS's and the RoI head's first products into
#                  chunks of the inner dimension): 1 or 0 (default: 1)
#   PROFILE        the published configurations also train one more epoch and detect once with
#                  every kernel launch timed on the device (FUSIONDET_KERNEL_PROFILE; slower,
#                  so the step times and frames/s above are measured without it), summed per
#                  kernel, with the launches of at most 16 cubes counted apart: 1 or 0
#                  (default: 1); each profiled run is stopped after
#                  PROFILE_SECONDS (default: 150)
#   ARCHIVE        a file (e.g. $OUT/gpu-check.tar.xz on a lent machine, whose call brings back
#                  a few files under $OUT and nothing else): at the end, the run's logs, kernel
#                  profiles, bench outputs and training metrics are packed into it (not the
#                  simulated frames, models or result files), for reading every figure after
#                  the machine has gone back
#   FUSIONDET_AUTOTUNE_LOG  where burn's autotune writes the kernel it kept for each tuned
#                  shape (default: autotune.log in CHECK_OUT; see kernel_cache.rs)
#   SPARSE_AB      models also run on the device with the sparse convolution as a kernel
#                  map of burn's operations (FUSIONDET_SPARSE_RULES=kernel-map; a GPU's
#                  default is the CubeCL kernels): a `detect` compared box by box with the
#                  CPU's, and a bench; the training configurations are also timed with it
#                  (default: voxel-rcnn-car dasanet-car; empty to skip)
#
# What each figure is:
#   parity     `fusiondet compare` of the CPU's and the device's result files of the val frames:
#              every box paired, centres and sizes within 1 cm, headings within 0.01 rad,
#              scores within 1e-3 (the issue's tolerance), and the largest differences seen.
#   frames/s   `fusiondet bench` on the val frames, median of REPEATS runs after one warm-up,
#              without reading files (as `bench` always measures), on each device.
#   frames/s   of a published configuration: `bench` on the device of the model its device
#              training run wrote (two epochs: the weights are untrained, the work per frame is
#              the configuration's), with the defaults, the RoI grid query on the host, the
#              sparse kernels' tables built on the host (TABLES_AB), one thread preparing frames
#              (PREPARE_AB), stage one on the network's thread (STAGE_ONE_AB) and the kernel
#              map (SPARSE_AB).
#   s/step     a training run of two epochs of STEPS_FRAMES frames: the second epoch's seconds
#              divided by its steps (the first holds kernel compilation and tuning), on each
#              device (and on the device with the sparse kernels, SPARSE_AB); and the loss
#              of each step of both epochs (`loss_curve`), which must follow the CPU's within
#              float tolerance: the first step (the same data, seed and initial weights, drawn
#              on the CPU for every device, before any update) within 1e-4 of the CPU's, every
#              later one within 1e-3 (relative; a run outside counts as a failed check).
#   sparse     one submanifold layer of 20,000 sites on the device, in the layout the device
#              takes (and with the kernels, SPARSE_AB): its output, input gradient and weight
#              gradient against the CPU's, each relative to the CPU's largest value (printed
#              by `bench`; about 1e-7 where it differentiates right; on lavapipe burn's kernel
#              map gave an input gradient off by 1e0)
#   repeated   burn's select_assign with Add over rows repeated 27 times (a gather's backward,
#              in every training graph) on the device against the CPU (printed by `bench`)
#   norm       training's largest batch norm + ReLU (RoI grid pooling's position layer in a
#              published Voxel R-CNN step: 884,736 rows × 32) forward and backward on the
#              device, through the project's kernels and through burn's generic operations
#              (FUSIONDET_CUSTOM_OPS=off), ms each and their γ/β gradients against the CPU's
#              (printed by `bench`)
#   layer      training's widest point-wise layer (that position layer, 3 → 32 over the
#              same rows) forward and backward on the device, its weight gradient summed in
#              chunks of rows and as burn's one product (FUSIONDET_CUSTOM_OPS=off), ms each
#              and their weight gradients against the CPU's (printed by `bench`)
#   product    the largest relative error of one 512×512 f32 matrix product on each device
#              (printed by `bench`): about 1e-7 where products run in f32, about 1e-4 where
#              tensor cores round their inputs to TF32.
#   start-up   seconds of a whole `detect` process on the CPU and on the device, for the
#              first model, and of a second one on the device: what compiling and tuning
#              kernels costs a process, and what the on-disk kernel cache gives back
#              (FUSIONDET_KERNEL_CACHE, see crates/pipeline/src/kernel_cache.rs).
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"

bin="${FUSIONDET:-}"
if [ -z "$bin" ]; then
    if [ -x target-cuda/release/fusiondet ]; then
        bin="$repo/target-cuda/release/fusiondet"
    else
        bin="$(command -v fusiondet || true)"
    fi
fi
[ -n "$bin" ] && [ -x "$bin" ] || {
    echo "error: no fusiondet binary: build one with scripts/build-cuda.sh or set FUSIONDET" >&2
    exit 2
}
device="${DEVICE:-cuda}"
models="${MODELS:-fconvnet-car saf-car fcam-car voxel-rcnn-car dasanet-car}"
models_dir="${MODELS_DIR:-$repo/models}"
train="${TRAIN:-1}"
train_configs="${TRAIN_CONFIGS:-configs/voxel-rcnn-car.toml configs/dasanet-car.toml}"
train_cpu="${TRAIN_CPU:-1}"
out="${CHECK_OUT:-$repo/gpu-check-out}"
archive="${ARCHIVE:+$(realpath -m "$ARCHIVE")}"
frames="${FRAMES:-48}"
repeats="${REPEATS:-3}"
steps_frames="${STEPS_FRAMES:-8}"
# AB=0 turns every A/B run off unless its own variable is set.
case "${AB:-1}" in
    1) ab_models="voxel-rcnn-car dasanet-car"; ab_flag=1 ;;
    0) ab_models=""; ab_flag=0 ;;
    *) echo "error: AB=${AB} must be 1 or 0" >&2; exit 2 ;;
esac
query_ab="${QUERY_AB-$ab_models}"
train_query_ab="${TRAIN_QUERY_AB:-$ab_flag}"
proposals_ab="${PROPOSALS_AB-$ab_models}"
inner_split_ab="${INNER_SPLIT_AB:-$ab_flag}"
sparse_ab="${SPARSE_AB-$ab_models}"
tables_ab="${TABLES_AB:-$ab_flag}"
prepare_ab="${PREPARE_AB:-$ab_flag}"
stage_one_ab="${STAGE_ONE_AB:-$ab_flag}"
profile="${PROFILE:-1}"
profile_seconds="${PROFILE_SECONDS:-150}"
export FUSIONDET_AUTOTUNE_LOG="${FUSIONDET_AUTOTUNE_LOG:-$out/autotune.log}"

for m in $models; do
    [ -f "$models_dir/$m.bpk" ] || {
        echo "error: $models_dir/$m.bpk not found (MODELS_DIR, MODELS)" >&2
        exit 2
    }
done

started=$(date +%s)
stamp() { echo "[$(($(date +%s) - started)) s] $*"; }
summary=()
failures=0
# A summary line, printed as soon as it is known too (a run cut off by a time limit keeps it).
record() {
    summary+=("$1")
    echo "  => $1"
}

echo "fusiondet GPU check: $("$bin" --version), device $device, $(date -u +%FT%TZ)"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
echo "CPU: $(nproc) cores"

# 1. Frames: simulated street scenes (half val) with their 2D detections, and the two
#    ground-truth databases the voxel trainings paste from. Kept between calls.
data="$out/sim"
if [ ! -f "$data/ImageSets/val.txt" ]; then
    stamp "simulating $frames frames"
    "$bin" simulate --out "$data" --frames "$frames" --seed 2027 --val-fraction 0.5 >/dev/null
fi
if [ "$train" = 1 ]; then
    [ -d "$data/gt_database/train" ] || "$bin" gt-database --data "$data" >/dev/null
    [ -d "$data/gt_database/train-pseudo" ] || "$bin" gt-database --data "$data" --pseudo >/dev/null
fi

# Seconds a command took, its output to a log.
timed() {
    local log="$1"
    shift
    local t0 t1
    t0=$(date +%s%N)
    "$@" >"$log" 2>&1
    t1=$(date +%s%N)
    awk -v ns="$((t1 - t0))" 'BEGIN { printf "%.1f", ns / 1e9 }'
}
# `bench` of a checkpoint on a device into a log, with the RoI grid query where given (`host`,
# `device`) or where the device runs it, and the sparse convolution's layout where given
# (`kernels`, `kernel-map`), and where the sparse kernels' tables are built where given
# (`host`, `device`), and how many threads prepare frames where given; a failed bench shows as a
# missing frames/s figure, never stops the script. With `no_probes=1` in its environment the
# bench prints its speed only (`--no-probes`): the arithmetic probes after it take seconds of
# the lent machine each time, and the summary reads them from the default benches alone.
bench_into() {
    local log="$1" ckpt="$2" dev="$3" query="${4:-}" sparse="${5:-}" tables="${6:-}" preparers="${7:-}"
    env ${query:+FUSIONDET_ROI_QUERY="$query"} ${sparse:+FUSIONDET_SPARSE_RULES="$sparse"} \
        ${tables:+FUSIONDET_RULEBOOK_TABLES="$tables"} ${preparers:+FUSIONDET_PREPARE_THREADS="$preparers"} \
        "$bin" bench --checkpoint "$ckpt" --data "$data" ${no_probes:+--no-probes} \
        --repeats "$repeats" --device "$dev" >"$log" 2>&1 || true
}
frames_per_second() { grep -o '[0-9.]* frames/s' "$1" | head -1 | cut -d' ' -f1; }
# A bench log → its f32 matrix product's largest relative error (matmul_precision.rs).
product_error() { grep -o 'largest error [0-9.e+-]*' "$1" | head -1 | cut -d' ' -f3; }
stage_ms() { # a bench log → its stages in ms a frame: "voxelize 3.1, 3D backbone (…) 83.5, …"
    # `bench` lists each stage's time over one run of all its frames (its first line: "N frames").
    local frames
    frames="$(grep -o '[0-9]* frames,' "$1" | head -1 | grep -o '[0-9]*' || true)"
    awk -v n="${frames:-1}" '/ ms +[0-9.]+%$/ { ms = $(NF - 2); $NF = ""; $(NF - 1) = ""; $(NF - 2) = "";
        sub(/^ +/, ""); sub(/ +$/, ""); printf "%s%s %.1f", (k++ ? ", " : ""), $0, ms / (n > 0 ? n : 1) }' "$1"
}

# 2. Per shipped model: detect on both devices, compare, bench on both.
# One figure of a `fusiondet compare` report: largest LOG 'centre offset' → its value, or ?.
largest() {
    grep -o "largest $2 *[0-9.]*" "$1" | grep -o '[0-9.]*$' || echo "?"
}
first=1
for m in $models; do
    ckpt="$models_dir/$m.bpk"
    det="$out/detect/$m"
    rm -rf "$det"
    mkdir -p "$det"
    stamp "$m: detect on cpu and $device"
    t_cpu=$(timed "$det/cpu.log" "$bin" detect --checkpoint "$ckpt" --data "$data" --split val --out "$det/cpu") || {
        echo "  cpu detect failed:"; tail -5 "$det/cpu.log"; failures=$((failures + 1)); continue; }
    t_dev=$(timed "$det/dev.log" "$bin" detect --checkpoint "$ckpt" --data "$data" --split val --out "$det/dev" --device "$device") || {
        echo "  $device detect failed:"; tail -5 "$det/dev.log"; failures=$((failures + 1)); continue; }
    if "$bin" compare "$det/cpu" "$det/dev" >"$det/compare.log" 2>&1; then
        parity="same"
    else
        parity="DIFFERENT"
        failures=$((failures + 1))
    fi
    sed 's/^/  /' "$det/compare.log"
    offset=$(largest "$det/compare.log" 'centre offset')
    score=$(largest "$det/compare.log" 'score change')
    boxes=$(grep -o 'paired [0-9]*' "$det/compare.log" | grep -o '[0-9]*' || echo "?")
    if [ "$first" = 1 ]; then
        # A second process on the device: what the kernel cache (kernel_cache.rs) saves.
        t_again=$(timed "$det/dev-again.log" "$bin" detect --checkpoint "$ckpt" --data "$data" --split val \
            --out "$det/dev-again" --device "$device") || t_again="failed"
        record "start-up: detect of $(wc -l <"$data/ImageSets/val.txt") frames with $m: cpu ${t_cpu} s, $device ${t_dev} s, $device again ${t_again} s"
        first=0
    fi
    stamp "$m: bench on cpu and $device"
    # The CPU's probes are read from the first model's bench only.
    no_probes="${precision_recorded:-}" bench_into "$det/bench-cpu.log" "$ckpt" cpu
    bench_into "$det/bench-dev.log" "$ckpt" "$device"
    fps_cpu=$(frames_per_second "$det/bench-cpu.log" || true)
    fps_dev=$(frames_per_second "$det/bench-dev.log" || true)
    [ -n "$fps_dev" ] || { echo "  $device bench failed:"; tail -5 "$det/bench-dev.log"; failures=$((failures + 1)); }
    host_query=""
    if [[ " $query_ab " == *" $m "* ]]; then
        # The kernels' rows against the host query's, level by level (roi_pool.rs, QueryPlace).
        FUSIONDET_ROI_QUERY=check "$bin" detect --checkpoint "$ckpt" --data "$data" --split val \
            --out "$det/dev-check" --device "$device" >"$det/dev-check.log" 2>&1 || true
        checked=$(grep -c '^RoI query check' "$det/dev-check.log" || true)
        differing=$(grep '^RoI query check' "$det/dev-check.log" | grep -vc ': 0 of ' || true)
        record "$(printf '%-16s RoI query kernels on %s: %s of %s levels checked differ from the host query' \
            "$m" "$device" "$differing" "$checked")"
        grep '^RoI query check' "$det/dev-check.log" | grep -v ': 0 of ' | head -3 | sed 's/^/  /' || true
        # The boxes of the host query against the kernels' (the default) on the same device
        # (the same products, so only the query differs).
        if FUSIONDET_ROI_QUERY=host "$bin" detect --checkpoint "$ckpt" --data "$data" --split val \
            --out "$det/dev-host-query" --device "$device" >"$det/dev-host-query.log" 2>&1; then
            "$bin" compare "$det/dev-host-query" "$det/dev" >"$det/compare-host-query.log" 2>&1 &&
                kparity="same" || kparity="DIFFERENT"
            record "$(printf '%-16s boxes with the RoI query kernels against the host query on %s: %s (%s)' \
                "$m" "$device" "$kparity" "$(grep -o 'boxes [0-9]* / [0-9]*, paired [0-9]*' "$det/compare-host-query.log" | head -1), largest centre offset $(largest "$det/compare-host-query.log" 'centre offset') m")"
        else
            record "$m: detect with the host RoI query failed: $(tail -1 "$det/dev-host-query.log")"
            failures=$((failures + 1))
        fi
        no_probes=1 bench_into "$det/bench-dev-host-query.log" "$ckpt" "$device" host
        host_query=" (host RoI query $(frames_per_second "$det/bench-dev-host-query.log" || echo '?'))"
    fi
    if [[ " $proposals_ab " == *" $m "* ]]; then
        # The device's proposals against the host's, frame by frame (voxel_rcnn/proposals.rs,
        # ProposalPlace); the boxes are the host's, so only the count of differing frames says
        # anything.
        if FUSIONDET_PROPOSALS=check "$bin" detect --checkpoint "$ckpt" --data "$data" --split val \
            --out "$det/dev-proposals-check" --device "$device" >"$det/dev-proposals-check.log" 2>&1; then
            record "$(printf '%-16s proposals chosen on %s: %s of %s frames differ from the host'"'"'s' \
                "$m" "$device" "$(grep -c '^proposals check' "$det/dev-proposals-check.log" || true)" \
                "$(grep -c . "$data/ImageSets/val.txt")")"
            grep '^proposals check' "$det/dev-proposals-check.log" | head -3 | sed 's/^/  /' || true
        else
            record "$m: detect with FUSIONDET_PROPOSALS=check failed: $(tail -1 "$det/dev-proposals-check.log")"
            failures=$((failures + 1))
        fi
    fi
    if [[ " $sparse_ab " == *" $m "* ]]; then
        # The sparse convolution as a kernel map of burn's operations (sparse/rulebook.rs in
        # the nn crate) instead of the CubeCL kernels: its boxes against the CPU's, its speed.
        if FUSIONDET_SPARSE_RULES=kernel-map "$bin" detect --checkpoint "$ckpt" --data "$data" \
            --split val --out "$det/dev-sparse" --device "$device" >"$det/dev-sparse.log" 2>&1; then
            "$bin" compare "$det/cpu" "$det/dev-sparse" >"$det/compare-sparse.log" 2>&1 &&
                sparity="same" || sparity="DIFFERENT"
            bench_into "$det/bench-dev-sparse.log" "$ckpt" "$device" "" kernel-map
            record "$(printf '%-16s sparse convolution as a kernel map on %s: parity with the cpu %s (%s, centre %s m, score %s), frames/s %s; stages: %s' \
                "$m" "$device" "$sparity" "$(grep -o 'boxes [0-9]* / [0-9]*, paired [0-9]*' "$det/compare-sparse.log" | head -1)" \
                "$(largest "$det/compare-sparse.log" 'centre offset')" "$(largest "$det/compare-sparse.log" 'score change')" \
                "$(frames_per_second "$det/bench-dev-sparse.log" || echo '?')" "$(stage_ms "$det/bench-dev-sparse.log")")"
        else
            record "$m: detect with the sparse convolution as a kernel map failed: $(tail -1 "$det/dev-sparse.log")"
            failures=$((failures + 1))
        fi
    fi
    record "$(printf '%-16s parity %-9s (%s boxes, centre %s m, score %s)  frames/s cpu %s, %s %s%s' \
        "$m" "$parity" "$boxes" "$offset" "$score" "${fps_cpu:-?}" "$device" "${fps_dev:-?}" "$host_query")"
    record "$(printf '%-16s stages on %s, ms a frame: %s' "$m" "$device" "$(stage_ms "$det/bench-dev.log")")"
    # The sparse gradient probe of each device bench (the default layout, and the kernel map).
    for log in "$det/bench-dev.log" "$det/bench-dev-sparse.log"; do
        probe="$(grep -o 'sparse convolution on this device.*' "$log" 2>/dev/null | head -1 || true)"
        if [ -n "$probe" ]; then
            record "$(printf '%-16s %s' "$m" "$probe")"
        fi
    done
    if [ -z "${precision_recorded:-}" ]; then
        record "f32 matrix product, largest relative error: cpu $(product_error "$det/bench-cpu.log" || echo '?'), $device $(product_error "$det/bench-dev.log" || echo '?') (TF32 inputs: about 1e-4)"
        record "repeated-row additions (every gather's backward) on $device, largest relative difference from the cpu: $(grep -o 'repeated-row additions.*: [0-9.e+-]*$' "$det/bench-dev.log" | grep -o '[0-9.e+-]*$' || echo '?') (about 1e-7 where right; 1e0 on lavapipe), $(grep -o 'into 20001, [0-9.]* ms' "$det/bench-dev.log" | grep -o '[0-9.]* ms' || echo '?') a run"
        norm="$(grep -o 'training batch norm + ReLU on this device.*' "$det/bench-dev.log" | head -1 || true)"
        record "${norm:-training batch norm probe: not printed by the $device bench}"
        layer="$(grep -o 'training point-wise layer on this device.*' "$det/bench-dev.log" | head -1 || true)"
        record "${layer:-training point-wise layer probe: not printed by the $device bench}"
        precision_recorded=1
    fi
done

# 3. Training steps of the published configurations, on both devices.
step_seconds() { # metrics.jsonl → the second epoch's seconds per step
    sed -n 2p "$1" | grep -o '"batches":[0-9]*\|"seconds":[0-9.e+-]*' | cut -d: -f2 | paste -sd' ' |
        awk '{ if ($1 > 0) printf "%.3f", $2 / $1; else print "?" }'
}
step_parts() { # metrics.jsonl → the second epoch's seconds per step: data wait / forward+loss / backward+update / the data thread's own time making a batch
    local line batches
    line="$(sed -n 2p "$1")"
    batches="$(echo "$line" | grep -o '"batches":[0-9]*' | cut -d: -f2)"
    for k in data_wait forward_loss backward_update data_prepare; do
        echo "$line" | grep -o "\"$k\":[0-9.e+-]*" | cut -d: -f2
    done | awk -v n="${batches:-0}" '{ if (n > 0) printf "%s%.3f", (NR > 1 ? "/" : ""), $1 / n }'
}
forward_parts() { # metrics.jsonl → the second epoch's forward pass per step, by part (voxel family)
    local line batches
    line="$(sed -n 2p "$1")"
    batches="$(echo "$line" | grep -o '"batches":[0-9]*' | cut -d: -f2)"
    echo "$line" | grep -o '"forward_parts":{[^}]*}' | sed 's/^"forward_parts":{//; s/}$//' | tr ',' '\n' |
        awk -F: -v n="${batches:-0}" '{ gsub(/"/, "", $1); if (n > 0) printf "%s%s %.3f", (NR > 1 ? ", " : ""), $1, $2 / n }'
}
# metrics.jsonl → every epoch's `loss_curve`, joined: "loss,loss,…" (empty if there is none).
loss_curve() {
    grep -o '"loss_curve":\[[^]]*\]' "$1" | sed 's/^"loss_curve":\[//; s/\]$//' | paste -sd, -
}
# A device's loss curve against the reference's, step by step (relative to the reference's
# magnitude, or 1 below it) → "first step D1, at most D (step k of n)", and exit status 1
# where the first step is over 1e-4 or a later one over 1e-3 of the reference's (or there
# is nothing to compare).
curve_difference() {
    awk -v a="$1" -v b="$2" 'BEGIN {
        n = split(a, x, ","); m = split(b, y, ","); if (m < n) n = m
        if (n == 0 || a == "" || b == "") { print "?"; exit 1 }
        worst = -1; bad = 0
        for (i = 1; i <= n; i++) {
            d = x[i] - y[i]; if (d < 0) d = -d
            r = x[i] < 0 ? -x[i] : x[i]; r = d / (r > 1 ? r : 1)
            if (i == 1) first = r
            if (r > worst) { worst = r; at = i }
            if (r > (i == 1 ? 1e-4 : 1e-3)) bad = 1
        }
        printf "first step %.2e, at most %.2e (step %d of %d)\n", first, worst, at, n
        exit bad
    }'
}
# A kernel profile (FUSIONDET_KERNEL_PROFILE: a "| 41.2µs | kind | op_hash" line per launch, e.g.
# "| 19.7ms | KernelScalarBinop | AddOp_832f80fc") and a count of units (training steps, frames)
# → launches and device time per unit, then the twelve kernels that took most, by kind and op
# without generics or hash: "KernelScalarBinop:AddOp ×launches ms, …".
kernel_profile() {
    local log="$1" units="$2"
    [ -s "$log" ] && [ "${units:-0}" -gt 0 ] || { echo "?"; return; }
    # A record a launch: "| <time> | <kernel>…", then (CubeCL's `full` level) the kernel's
    # arguments over several lines, ending in "CubeCount (x, y, z)". Kernels are named by their
    # type and their first type parameter (KernelBinop:MulOp); launches of at most 16 cubes,
    # which leave most of a GPU idle, are counted apart.
    awk '
        function flush() {
            if (have) { t[name] += ms; n[name]++; if (cubes > 0 && cubes <= 16) { few++; few_ms += ms } }
            have = 0; cubes = 0
        }
        /^\| / {
            flush()
            fields = split($0, f, "|"); d = f[2]; gsub(/ /, "", d); s = f[3]; sub(/^ +/, "", s)
            base = s; sub(/<.*/, "", base); sub(/: .*$/, "", base); sub(/ +$/, "", base); sub(/.*::/, "", base)
            sub(/_[0-9a-f]+$/, "", base)
            name = base
            if (index(s, "<") > 0) { g = s; sub(/^[^<]*</, "", g); sub(/[,>].*$/, "", g); sub(/.*::/, "", g); name = base ":" g }
            # CubeCL'"'"'s `basic` level: "| <time> | KernelBinop | MulOp_<hash>".
            if (fields >= 4) { g = f[4]; gsub(/ /, "", g); sub(/_[0-9a-f]+$/, "", g); name = base ":" g }
            ms = d + 0
            if (d ~ /ns$/) ms /= 1e6; else if (d ~ /µs$/) ms /= 1e3; else if (d ~ /ms$/) ms += 0;
            else if (d ~ /s$/) ms *= 1e3; else next
            have = 1
        }
        /CubeCount \(/ { c = $0; sub(/.*CubeCount \(/, "", c); split(c, x, /[,) ]+/); cubes = x[1] * x[2] * x[3] }
        END {
            flush()
            for (k in t) printf "%.6f\t%d\t%s\n", t[k], n[k], k
            if (few + 0 > 0 || few_ms + 0 > 0) printf "few\t%d\t%.6f\n", few, few_ms
        }' "$log" | sort -t"$(printf '\t')" -k1,1gr |
        awk -F'\t' -v u="$units" '
            $1 == "few" { few = sprintf("; launches of at most 16 cubes: %.1f, %.2f ms", $2 / u, $3 / u); next }
            { total += $1; count += $2; if (++k <= 12) top = top sprintf("%s%s ×%.1f %.2f ms", (k > 1 ? ", " : ""), $3, $2 / u, $1 / u) }
            END { printf "%.0f launches, %.1f ms of device time%s; by kernel: %s", count / u, total / u, few, top }'
}
# A profiled run that failed (exit status, configuration, what, device, its log) → a summary
# line: stopped at PROFILE_SECONDS (status 124), or its log's last line.
profile_failed() {
    local reason
    reason="$(tail -1 "$5")"
    [ "$1" = 124 ] && reason="stopped after $profile_seconds s"
    record "$(printf '%-26s kernel profile of %s on %s failed: %s' "$2" "$3" "$4" "$reason")"
}
if [ "$train" = 1 ]; then
    for config in $train_configs; do
        name="$(basename "$config" .toml)"
        row=()
        curves=()
        runs=("$device")
        [ "$train_cpu" = 1 ] && runs=(cpu "$device")
        [ -n "$sparse_ab" ] && runs+=("$device+kernel-map")
        [ "$train_query_ab" = 1 ] && runs+=("$device+host-query")
        for r in "${runs[@]}"; do
            # A run is a device, or a device and one former default (+kernel-map, +host-query).
            d="${r%%+*}"
            variant="${r#"$d"}"
            variant="${variant#+}"
            sparse=""
            query=""
            [ "$variant" = kernel-map ] && sparse=kernel-map
            [ "$variant" = host-query ] && query=host
            run="$out/train/$name-${r//:/-}"
            rm -rf "$run"
            mkdir -p "$out/train"
            stamp "$name: two epochs of $steps_frames frames on $r"
            if env ${sparse:+FUSIONDET_SPARSE_RULES="$sparse"} ${query:+FUSIONDET_ROI_QUERY="$query"} "$bin" train --config "$config" \
                --data "$data" --out "$run" --epochs 2 \
                --max-frames "$steps_frames" --device "$d" >"$run.log" 2>&1; then
                row+=("$r $(step_seconds "$run/metrics.jsonl") s/step (data/forward/backward/making a batch $(step_parts "$run/metrics.jsonl"); forward: $(forward_parts "$run/metrics.jsonl"))")
                curves+=("$(loss_curve "$run/metrics.jsonl")")
                if [ "$d" != cpu ] && [ -z "$variant" ] && [ -f "$run/model.bpk" ]; then
                    # The configuration's detection speed on the device: the defaults, the
                    # RoI query on the host, the sparse convolution as a kernel map.
                    no_probes=1 bench_into "$run-bench.log" "$run/model.bpk" "$d"
                    no_probes=1 bench_into "$run-bench-host-query.log" "$run/model.bpk" "$d" host
                    record "$(printf '%-26s bench on %s: %s frames/s (host RoI query %s)' "$name" "$d" \
                        "$(frames_per_second "$run-bench.log" || echo '?')" \
                        "$(frames_per_second "$run-bench-host-query.log" || echo '?')")"
                    record "$(printf '%-26s stages on %s, ms a frame: %s' "$name" "$d" "$(stage_ms "$run-bench.log")")"
                    if [ "$tables_ab" = 1 ]; then
                        no_probes=1 bench_into "$run-bench-host-tables.log" "$run/model.bpk" "$d" "" "" host
                        record "$(printf '%-26s bench on %s with the sparse kernels'"'"' tables built on the host: %s frames/s; stages: %s' \
                            "$name" "$d" "$(frames_per_second "$run-bench-host-tables.log" || echo '?')" "$(stage_ms "$run-bench-host-tables.log")")"
                    fi
                    if [ "$prepare_ab" = 1 ]; then
                        no_probes=1 bench_into "$run-bench-one-preparer.log" "$run/model.bpk" "$d" "" "" "" 1
                        record "$(printf '%-26s bench on %s with one thread preparing frames: %s frames/s; stages: %s' \
                            "$name" "$d" "$(frames_per_second "$run-bench-one-preparer.log" || echo '?')" "$(stage_ms "$run-bench-one-preparer.log")")"
                    fi
                    if [ -n "$proposals_ab" ]; then
                        FUSIONDET_PROPOSALS=host no_probes=1 bench_into "$run-bench-host-proposals.log" "$run/model.bpk" "$d"
                        record "$(printf '%-26s bench on %s with the proposals chosen on the host: %s frames/s; stages: %s' \
                            "$name" "$d" "$(frames_per_second "$run-bench-host-proposals.log" || echo '?')" "$(stage_ms "$run-bench-host-proposals.log")")"
                    fi
                    if [ "$inner_split_ab" = 1 ]; then
                        FUSIONDET_INNER_SPLIT=off no_probes=1 bench_into "$run-bench-unsplit.log" "$run/model.bpk" "$d"
                        record "$(printf '%-26s bench on %s with long inner dimensions unsplit: %s frames/s; stages: %s' \
                            "$name" "$d" "$(frames_per_second "$run-bench-unsplit.log" || echo '?')" "$(stage_ms "$run-bench-unsplit.log")")"
                    fi
                    if [ "$stage_one_ab" = 1 ]; then
                        FUSIONDET_STAGE_ONE_AHEAD=off no_probes=1 bench_into "$run-bench-stage-one-behind.log" "$run/model.bpk" "$d"
                        record "$(printf '%-26s bench on %s with stage one on the network'"'"'s thread: %s frames/s; stages: %s' \
                            "$name" "$d" "$(frames_per_second "$run-bench-stage-one-behind.log" || echo '?')" "$(stage_ms "$run-bench-stage-one-behind.log")")"
                    fi
                    if [ "$profile" = 1 ]; then
                        # Every launch timed on its own: one more epoch, and a detection of the val
                        # frames, each given at most PROFILE_SECONDS.
                        prof="$run-profile"
                        rm -rf "$prof" "$prof-train.kernels" "$prof-detect.kernels"
                        if FUSIONDET_KERNEL_PROFILE="$prof-train.kernels" timeout "$profile_seconds" "$bin" train --config "$config" \
                            --data "$data" --out "$prof" --epochs 1 --max-frames "$steps_frames" \
                            --device "$d" >"$prof-train.log" 2>&1; then
                            steps="$(head -1 "$prof/metrics.jsonl" | grep -o '"batches":[0-9]*' | cut -d: -f2 || true)"
                            # Device time against the unprofiled step's wall time: far below
                            # it, the device waits for the host.
                            record "$(printf '%-26s kernels on %s a training step: %s; the unprofiled second epoch: %s s a step' "$name" "$d" \
                                "$(kernel_profile "$prof-train.kernels" "${steps:-0}")" "$(step_seconds "$run/metrics.jsonl")")"
                        else
                            profile_failed $? "$name" training "$d" "$prof-train.log"
                        fi
                        # `detect` rather than `bench`, whose probes would be counted too.
                        rm -rf "$prof-detect"
                        if FUSIONDET_KERNEL_PROFILE="$prof-detect.kernels" timeout "$profile_seconds" "$bin" detect --checkpoint "$run/model.bpk" \
                            --data "$data" --out "$prof-detect" --device "$d" >"$prof-detect.log" 2>&1; then
                            detected="$(grep -c . "$data/ImageSets/val.txt" || true)"
                            record "$(printf '%-26s kernels on %s a detected frame: %s' "$name" "$d" \
                                "$(kernel_profile "$prof-detect.kernels" "${detected:-0}")")"
                        else
                            profile_failed $? "$name" detection "$d" "$prof-detect.log"
                        fi
                    fi
                    if [ -n "$sparse_ab" ]; then
                        no_probes=1 bench_into "$run-bench-sparse.log" "$run/model.bpk" "$d" "" kernel-map
                        record "$(printf '%-26s bench on %s with the sparse convolution as a kernel map: %s frames/s; stages: %s' \
                            "$name" "$d" "$(frames_per_second "$run-bench-sparse.log" || echo '?')" "$(stage_ms "$run-bench-sparse.log")")"
                    fi
                fi
            else
                echo "  training on $r failed:"; tail -5 "$run.log" || true
                failures=$((failures + 1))
                row+=("$r failed")
                curves+=("")
            fi
        done
        # The CPU's loss curve: this run's, or given for this configuration in
        # CPU_LOSS_CURVES (name=loss,loss,…), which every device run follows within tolerance.
        reference=""
        if [ "$train_cpu" = 1 ]; then
            reference="${curves[0]:-}"
        else
            for pair in ${CPU_LOSS_CURVES:-}; do
                [ "${pair%%=*}" = "$name" ] && reference="${pair#*=}"
            done
        fi
        first_device=1
        [ "$train_cpu" = 1 ] && first_device=2
        agree=()
        if [ -n "$reference" ]; then
            for ((i = first_device - 1; i < ${#curves[@]}; i++)); do
                # A failed training is counted above.
                [ -n "${curves[$i]}" ] || { agree+=("?"); continue; }
                if difference="$(curve_difference "$reference" "${curves[$i]}")"; then
                    agree+=("$difference")
                else
                    agree+=("$difference: outside tolerance")
                    failures=$((failures + 1))
                fi
            done
        fi
        # Each run's first step: its curve's first value ("?" for a failed run).
        firsts=()
        for curve in "${curves[@]}"; do
            first="${curve%%,*}"
            firsts+=("${first:-?}")
        done
        record "$(printf '%-26s %s; first-step loss %s; loss curve against the CPU'"'"'s: %s' \
            "$name" "$(IFS=,; echo "${row[*]}")" "$(IFS=/; echo "${firsts[*]:-?}")" \
            "$( [ "${#agree[@]}" -gt 0 ] && (IFS=/; echo "${agree[*]}") || echo '?')")"
        for ((i = 0; i < ${#curves[@]}; i++)); do
            record "$(printf '%-26s loss curve, %s: %s' "$name" "${runs[$i]}" "${curves[$i]:-?}")"
        done
    done
fi

echo
echo "== summary ($(($(date +%s) - started)) s, device $device, binary $bin)"
printf '%s\n' "${summary[@]}"
if [ -s "$FUSIONDET_AUTOTUNE_LOG" ]; then
    # CubeCL logs "Fastest result <kernel>-<shape key>. Top 3 times: …" for each shape it tunes
    # (shapes tuned by an earlier process come from the cache and are not logged again).
    echo "autotune kept (kernel × tuned shapes): $(grep -o 'Fastest result [A-Za-z0-9_:]*' "$FUSIONDET_AUTOTUNE_LOG" \
        | cut -d' ' -f3 | sort | uniq -c | sort -rn | awk '{ printf "%s%s × %s", (n++ ? ", " : ""), $2, $1 }'); log $FUSIONDET_AUTOTUNE_LOG"
fi
if [ -n "$archive" ]; then
    # Text the run wrote (logs, `.kernels` profiles, metrics, the summary), relative to $out.
    printf '%s\n' "${summary[@]}" >"$out/summary.txt"
    (cd "$out" && find . -type f \( -name '*.log' -o -name '*.kernels' -o -name '*.jsonl' \
        -o -name 'summary.txt' \) -not -path './sim/*' -print0 \
        | tar --null -T - -cf - | xz -9 >"$archive") \
        && echo "archive: $archive ($(du -h "$archive" | cut -f1))" \
        || echo "archive: could not write $archive"
fi
if [ "$failures" -gt 0 ]; then
    echo "$failures check(s) failed (logs under $out)"
    exit 1
fi
