#!/usr/bin/env bash
# The test command (README, CI): Rust workspace tests, the ONNX Runtime backend tests, and the
# Python training tests (train → export → Rust inference end to end, for the two-stage model and
# the VGN-style baseline).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="$(scripts/setup-python.sh | tail -n 1)"
export PSGRASP_PYTHON="$VENV/bin/python"
ORT_LIB="$("$PSGRASP_PYTHON" -c 'import onnxruntime, os, glob; d = os.path.join(os.path.dirname(onnxruntime.__file__), "capi"); print(sorted(glob.glob(os.path.join(d, "libonnxruntime.so*")))[0])')"
export ORT_DYLIB_PATH="$ORT_LIB"
# One build for everything: the workspace with the ONNX Runtime backend compiled in (a second
# feature set would rebuild much of the dependency tree).
echo "== cargo test --workspace --features ort (ONNX Runtime: $ORT_DYLIB_PATH)"
cargo test --workspace --features ort
echo "== pytest training/tests"
(cd training && OMP_NUM_THREADS=1 "$PSGRASP_PYTHON" -m pytest -q tests)
echo "== end to end: psgrasp datagen → tiny training → ONNX export → Rust inference (tract + ort) against PyTorch"
E2E="$(mktemp -d)"
trap 'rm -rf "$E2E"' EXIT
cargo run --quiet --features ort --bin psgrasp -- datagen --scenes 3 --quick --quiet --seed 11 --out "$E2E/data"
(cd training && OMP_NUM_THREADS=1 "$PSGRASP_PYTHON" -m psgrasp_training train \
    --config configs/tiny.toml --data "$E2E/data" --out "$E2E/run" > "$E2E/train.log" 2>&1) \
    || { cat "$E2E/train.log"; exit 1; }
PSGRASP_TEST_MODEL_DIR="$E2E/run/model" cargo test --workspace --features ort --test learned_model
echo "== end to end: the VGN-style baseline (tiny training on the same scenes → export → Rust tract + ort against PyTorch)"
(cd training && OMP_NUM_THREADS=1 "$PSGRASP_PYTHON" -m psgrasp_training train \
    --config configs/vgn-tiny.toml --data "$E2E/data" --out "$E2E/vgn" > "$E2E/vgn.log" 2>&1) \
    || { cat "$E2E/vgn.log"; exit 1; }
PSGRASP_TEST_VGN_DIR="$E2E/vgn/model" cargo test --workspace --features ort --test vgn_model
