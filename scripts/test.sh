#!/usr/bin/env bash
# The test command (README, CI): Rust workspace tests, the ONNX Runtime backend tests, and the
# Python training tests (train → export → Rust inference end to end).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="$(scripts/setup-python.sh | tail -n 1)"
export PSGRASP_PYTHON="$VENV/bin/python"
ORT_LIB="$("$PSGRASP_PYTHON" -c 'import onnxruntime, os, glob; d = os.path.join(os.path.dirname(onnxruntime.__file__), "capi"); print(sorted(glob.glob(os.path.join(d, "libonnxruntime.so*")))[0])')"
export ORT_DYLIB_PATH="$ORT_LIB"
echo "== cargo test --workspace"
cargo test --workspace
echo "== cargo test -p psgrasp-inference --features ort (ONNX Runtime: $ORT_DYLIB_PATH)"
cargo test -p psgrasp-inference --features ort
echo "== pytest training/tests"
(cd training && OMP_NUM_THREADS=1 "$PSGRASP_PYTHON" -m pytest -q tests)
