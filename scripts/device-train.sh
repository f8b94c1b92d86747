#!/usr/bin/env bash
# Train the models of docs/evaluation.md in one call on a lent GPU (training/README.md, "Training
# on a lent GPU"): generate the training scenes on every core, train the runs side by side on the
# one GPU, each sized to the same wall-clock budget (`train --fit-minutes`), export them, and pack
# each run (model directory, latest checkpoint, per-step log, config, validation, console log) into
# OUT/NAME.tar.gz,
# with OUT/summary.txt saying what ran and how it ended. OUT is $OUT where set (the device
# machine's return folder), else out/device-run.
#
#   scripts/device-train.sh [--psgrasp BIN|BIN.xz] [--scenes N] [--seed S] [--minutes M]
#       [--datagen-config FILE] [--datagen-seconds S] [--objects SOURCE] [--mesh-archive FILE]
#       [--quick] [--device auto|cuda|cpu] [--threads T]
#       [--work DIR] [--out DIR] [--no-preflight] [--with-reference]
#       [NAME=TRAINING_CONFIG ...]
#
# Defaults: target/release/psgrasp, 1000 scenes, seed 2026, procedural objects, 6 minutes, device
# auto, 4 CPU threads per run, and the runs 8app=training/configs/gpu.toml,
# wo-kappa=training/configs/gpu-ablation-1app-cosine.toml, vgn=training/configs/gpu-vgn.toml.
# Python: $PSGRASP_PYTHON, else python3 (needs torch, numpy, safetensors, onnx, onnxruntime).
# Before the real data, a preflight trains the tiny configs (the two-stage model past its MLP
# warm-up, and the VGN-style net) on 3 quick scenes on the same device, and a preflight run that
# fails stops the other: a broken call ends within a minute and leaves device time for a fixed
# rerun. The real runs are independent: one that fails leaves the others to finish and be packed.
# Each pack holds the run's checkpoints/latest.pt (resume or re-export it here) unless that makes
# the pack exceed the 16 MiB a returned file may have; the summary then says it was left out.
# --objects meshes with --mesh-archive FILE (a tar.xz of ~/.cache/psgrasp/objects' ycb/ and
# random_urdfs/ folders, and its cache/ of convex decompositions if present) generates the scenes
# from the fetched meshes, as `psgrasp datagen` does here. --datagen-seconds S time-boxes the
# datagen (a slow labeler such as the physics check): one that is still running after S seconds
# is stopped and keeps the longest prefix of scenes, rounded down to a multiple of 20 (the
# validation split), with the manifest a plain `psgrasp datagen --scenes P` writes, so that the
# summary's P reproduces the data; one that finishes in time keeps every scene.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PSGRASP="$ROOT/target/release/psgrasp"
SCENES=1000
SEED=2026
MINUTES=6
DATAGEN_CONFIG=""
DATAGEN_SECONDS=0
OBJECTS=procedural
MESH_ARCHIVE=""
QUICK=()
DEVICE=auto
THREADS=4
WORK="${TMPDIR:-/tmp}/psgrasp-device-run"
OUT_DIR="${OUT:-$ROOT/out/device-run}"
PY="${PSGRASP_PYTHON:-python3}"
RUNS=()
PREFLIGHT=1
EXCLUDE=(--exclude=model/reference.safetensors)
# The device tool returns files of at most 16 MiB each.
RETURNED_FILE_MAX_BYTES=$((16 * 1024 * 1024))
die() { echo "device-train: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
    case "$1" in
        --psgrasp) PSGRASP="$2"; shift 2 ;;
        --scenes) SCENES="$2"; shift 2 ;;
        --seed) SEED="$2"; shift 2 ;;
        --minutes) MINUTES="$2"; shift 2 ;;
        --datagen-config) DATAGEN_CONFIG="$(realpath "$2")"; shift 2 ;;
        --datagen-seconds) DATAGEN_SECONDS="$2"; shift 2 ;;
        --objects) OBJECTS="$2"; shift 2 ;;
        --mesh-archive) MESH_ARCHIVE="$(realpath "$2")"; shift 2 ;;
        --quick) QUICK=(--quick); shift ;;
        --no-preflight) PREFLIGHT=0; shift ;;
        --with-reference) EXCLUDE=(); shift ;;
        --device) DEVICE="$2"; shift 2 ;;
        --threads) THREADS="$2"; shift 2 ;;
        --work) WORK="$2"; shift 2 ;;
        --out) OUT_DIR="$2"; shift 2 ;;
        -h | --help) sed -n '2,28p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *=*) RUNS+=("$1"); shift ;;
        *) die "unknown argument '$1' (see --help)" ;;
    esac
done
if [ ${#RUNS[@]} -eq 0 ]; then
    RUNS=(8app=training/configs/gpu.toml wo-kappa=training/configs/gpu-ablation-1app-cosine.toml
          vgn=training/configs/gpu-vgn.toml)
fi
case "$PSGRASP" in
    *.xz) [ -f "$PSGRASP" ] || die "no compressed psgrasp binary at $PSGRASP" ;;
    *) [ -x "$PSGRASP" ] || die "no psgrasp binary at $PSGRASP (cargo build --release --bins, or --psgrasp BIN)" ;;
esac
[ -z "$DATAGEN_CONFIG" ] || [ -f "$DATAGEN_CONFIG" ] || die "no datagen config $DATAGEN_CONFIG"
[ -z "$MESH_ARCHIVE" ] || [ -f "$MESH_ARCHIVE" ] || die "no mesh archive $MESH_ARCHIVE"
[[ "$DATAGEN_SECONDS" =~ ^[0-9]+$ ]] || die "--datagen-seconds takes whole seconds"
NAMES=()
CONFIGS=()
for r in "${RUNS[@]}"; do
    name="${r%%=*}"
    cfg="${r#*=}"
    [[ "$name" =~ ^[A-Za-z0-9_-]+$ ]] || die "run name '$name': letters, digits, '_' and '-' only"
    [ -f "$cfg" ] || [ -f "$ROOT/$cfg" ] || die "run $name: no training config $cfg"
    [ -f "$cfg" ] || cfg="$ROOT/$cfg"
    NAMES+=("$name")
    CONFIGS+=("$(realpath "$cfg")")
done
"$PY" -c "import torch, numpy, safetensors, onnx, onnxruntime" \
    || die "$PY lacks torch, numpy, safetensors, onnx or onnxruntime"

# The work folder is emptied first: refuse one that this script did not make.
if [ -e "$WORK" ] && [ ! -e "$WORK/.psgrasp-device-run" ]; then
    die "--work $WORK exists and is not a folder of an earlier run; name a new one"
fi
rm -rf "$WORK"
mkdir -p "$WORK/runs" "$OUT_DIR"
touch "$WORK/.psgrasp-device-run"
SUMMARY="$OUT_DIR/summary.txt"
say() { echo "$*" | tee -a "$SUMMARY"; }
: > "$SUMMARY"
say "psgrasp device training run, $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(uname -n), $(nproc) cores"
say "commit: $(git -C "$ROOT" rev-parse HEAD 2>/dev/null || echo unknown)"
say "torch: $("$PY" -c 'import torch; print(torch.__version__, "| cuda:", torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none")')"
say "budget per run: $MINUTES min; device $DEVICE; $THREADS CPU threads per run"

# The carried binary (compressed to fit the call's 64 MiB) and meshes, unpacked into the work folder.
if [[ "$PSGRASP" == *.xz ]]; then
    xz -dc "$PSGRASP" > "$WORK/psgrasp" && chmod +x "$WORK/psgrasp" || die "cannot unpack $PSGRASP"
    PSGRASP="$WORK/psgrasp"
fi
MESH_ARGS=()
if [ -n "$MESH_ARCHIVE" ]; then
    mkdir -p "$WORK/objects"
    tar -xJf "$MESH_ARCHIVE" -C "$WORK/objects" || die "cannot unpack $MESH_ARCHIVE"
    MESH_ARGS=(--mesh-dir "$WORK/objects")
fi

export PYTHONPATH="$ROOT/training${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 OMP_NUM_THREADS="$THREADS"
export CUBLAS_WORKSPACE_CONFIG="${CUBLAS_WORKSPACE_CONFIG:-:4096:8}"

# train_side_by_side DATA DIR MINUTES STOP NAME=CONFIG...: the runs side by side on one device,
# each fitted to MINUTES (DIR/NAME, console log DIR/NAME.log); with STOP=stop the first run that
# fails stops the others (exit 143), with STOP=independent the others go on. Exit codes land in
# RCS, in argument order.
train_side_by_side() {
    local data="$1" dir="$2" minutes="$3" stop="$4" r pid rc p i
    shift 4
    local -a pids=() left=() keep=()
    local -A by_pid=()
    mkdir -p "$dir"
    for r in "$@"; do
        "$PY" -m psgrasp_training train --config "${r#*=}" --data "$data" --out "$dir/${r%%=*}" \
            --fit-minutes "$minutes" --device "$DEVICE" --threads "$THREADS" > "$dir/${r%%=*}.log" 2>&1 &
        pids+=($!)
    done
    left=("${pids[@]}")
    while [ ${#left[@]} -gt 0 ]; do
        rc=0
        pid=""
        wait -n -p pid "${left[@]}" || rc=$?
        by_pid[$pid]=$rc
        keep=()
        for p in "${left[@]}"; do [ "$p" = "$pid" ] || keep+=("$p"); done
        left=("${keep[@]}")
        if [ "$stop" = stop ] && [ "$rc" -ne 0 ] && [ ${#left[@]} -gt 0 ]; then kill "${left[@]}" 2>/dev/null || true; fi
    done
    RCS=()
    for i in "${!pids[@]}"; do RCS[$i]=${by_pid[${pids[$i]}]}; done
}

# 1. The training scenes start on every core, in the background, while the preflight runs.
t0=$SECONDS
# datagen_args N: the arguments of a datagen of the first N scenes.
datagen_args() {
    DATAGEN_ARGS=(datagen --scenes "$1" --objects "$OBJECTS" "${MESH_ARGS[@]}" --difficulty train
        --seed "$SEED" --out "$WORK/data" --quiet "${QUICK[@]}" ${DATAGEN_CONFIG:+--config "$DATAGEN_CONFIG"})
}
datagen_args "$SCENES"
if [ "$DATAGEN_SECONDS" -gt 0 ]; then
    timeout "$DATAGEN_SECONDS" "$PSGRASP" "${DATAGEN_ARGS[@]}" > "$WORK/datagen.log" 2>&1 &
else
    "$PSGRASP" "${DATAGEN_ARGS[@]}" > "$WORK/datagen.log" 2>&1 &
fi
DATAGEN_PID=$!
stop_datagen() { kill "$DATAGEN_PID" 2>/dev/null || true; wait "$DATAGEN_PID" 2>/dev/null || true; }

# 2. Preflight: the tiny configs on this device, on 3 quick scenes.
if [ "$PREFLIGHT" = 1 ]; then
    t1=$SECONDS
    "$PSGRASP" datagen --scenes 3 --quick --objects procedural --seed 11 --out "$WORK/preflight-data" \
        --quiet > "$WORK/preflight-datagen.log" 2>&1 \
        || { stop_datagen; cat "$WORK/preflight-datagen.log" >&2; die "preflight datagen failed"; }
    PRE=("8app=$ROOT/training/configs/tiny.toml" "vgn=$ROOT/training/configs/vgn-tiny.toml")
    train_side_by_side "$WORK/preflight-data" "$WORK/preflight" 5 stop "${PRE[@]}"
    for i in "${!PRE[@]}"; do
        name="${PRE[$i]%%=*}"
        if [ "${RCS[$i]}" -ne 0 ]; then
            stop_datagen
            say "preflight $name: FAILED (exit ${RCS[$i]}); last lines:"
            tail -n 25 "$WORK/preflight/$name.log" | tee -a "$SUMMARY"
            cp "$WORK/preflight/$name.log" "$OUT_DIR/preflight-$name.log"
            exit 1
        fi
    done
    say "preflight: tiny 8app and vgn trained and exported on device $DEVICE in $((SECONDS - t1)) s (beside the datagen)"
fi

rc=0
wait "$DATAGEN_PID" || rc=$?
if [ "$DATAGEN_SECONDS" -gt 0 ] && [ "$rc" = 124 ]; then
    # The longest prefix of listed scenes, a multiple of 20; then the manifest of exactly those.
    SCENES="$("$PY" -c 'import json, sys
listed = {s["index"] for s in json.load(open(sys.argv[1]))["scenes"]}
p = 0
while p in listed:
    p += 1
print(min(p, int(sys.argv[2])) // 20 * 20)' "$WORK/data/manifest.json" "$SCENES")"
    [ "$SCENES" -gt 0 ] || die "datagen made no 20 scenes in $DATAGEN_SECONDS s"
    rm -f "$WORK/data/manifest.json"
    datagen_args "$SCENES"
    "$PSGRASP" "${DATAGEN_ARGS[@]}" >> "$WORK/datagen.log" 2>&1 || { cat "$WORK/datagen.log" >&2; die "datagen failed"; }
    say "datagen: time-boxed to $DATAGEN_SECONDS s, kept the first $SCENES scenes"
else
    [ "$rc" = 0 ] || { cat "$WORK/datagen.log" >&2; die "datagen failed (exit $rc)"; }
fi
say "datagen: $SCENES scenes, seed $SEED, objects $OBJECTS${DATAGEN_CONFIG:+, config $DATAGEN_CONFIG}${QUICK[*]:+ (quick labels)}: $((SECONDS - t0)) s"
say "  manifest sha256 $(sha256sum "$WORK/data/manifest.json" | cut -d' ' -f1); $(tail -n 3 "$WORK/datagen.log" | tr '\n' ' ')"

# 3. The runs side by side, each sized to the same budget, then packed.
t0=$SECONDS
ARGS=()
for i in "${!NAMES[@]}"; do ARGS+=("${NAMES[$i]}=${CONFIGS[$i]}"); done
train_side_by_side "$WORK/data" "$WORK/runs" "$MINUTES" independent "${ARGS[@]}"
FAILED=0
for i in "${!NAMES[@]}"; do
    rc="${RCS[$i]}"
    name="${NAMES[$i]}"
    run="$WORK/runs/$name"
    mkdir -p "$run"
    cp "$WORK/runs/$name.log" "$run/train.log" 2>/dev/null || true
    cp "$WORK/datagen.log" "$run/datagen.log" 2>/dev/null || true
    [ -z "$DATAGEN_CONFIG" ] || cp "$DATAGEN_CONFIG" "$run/datagen-config.toml"
    cp "$WORK/data/manifest.json" "$run/dataset-manifest.json" 2>/dev/null || true
    if [ "$rc" -ne 0 ] || [ ! -f "$run/model/card.json" ]; then
        FAILED=1
        say "run $name ($(basename "${CONFIGS[$i]}")): FAILED (exit $rc); last lines:"
        tail -n 15 "$WORK/runs/$name.log" | tee -a "$SUMMARY"
    else
        iterations="$("$PY" -c 'import json, sys; print(json.load(open(sys.argv[1]))["training"]["iterations"])' \
            "$run/model/card.json")"
        fitted="$(grep -o 'fitted to .*' "$run/train.log" | tail -n 1 || true)"
        say "run $name ($(basename "${CONFIGS[$i]}")): $iterations iterations${fitted:+ ($fitted)}"
        say "  final $(grep -o 'validation @ .*' "$run/train.log" | tail -n 1)"
    fi
    # Pack what there is: a failed run's console log still says why.
    files=()
    for f in model log.csv config.json dataset.json validation.json train.log datagen.log \
             datagen-config.toml dataset-manifest.json; do
        [ -e "$run/$f" ] && files+=("$f")
    done
    # The export's reference inputs and outputs (30 MB for base 16; returned files are limited to
    # 16 MiB each) stay behind unless --with-reference.
    # The checkpoint goes in unless the pack would then exceed a returned file's limit.
    if [ -f "$run/checkpoints/latest.pt" ]; then
        tar -czf "$OUT_DIR/$name.tar.gz" "${EXCLUDE[@]}" -C "$run" "${files[@]}" checkpoints/latest.pt
        if [ "$(stat -c %s "$OUT_DIR/$name.tar.gz")" -le "$RETURNED_FILE_MAX_BYTES" ]; then
            continue
        fi
        rm -f "$OUT_DIR/$name.tar.gz"
        say "  $name: checkpoints/latest.pt left out (the pack would exceed 16 MiB)"
    fi
    [ ${#files[@]} -eq 0 ] || tar -czf "$OUT_DIR/$name.tar.gz" "${EXCLUDE[@]}" -C "$run" "${files[@]}"
done
say "training: $((SECONDS - t0)) s for ${#NAMES[@]} runs side by side"
ls -l "$OUT_DIR" | tee -a "$SUMMARY"
exit "$FAILED"
