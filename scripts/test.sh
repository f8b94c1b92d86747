#!/usr/bin/env bash
# The test command (README, CI): Rust workspace tests, the ONNX Runtime backend tests, and the
# Python training tests, and end to end the one-call training script of a lent GPU (datagen →
# train → export → pack) run tiny on the CPU, its models checked by Rust inference against PyTorch.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="$(scripts/setup-python.sh | tail -n 1)"
export PSGRASP_PYTHON="$VENV/bin/python"
ORT_LIB="$("$PSGRASP_PYTHON" -c 'import onnxruntime, os, glob; d = os.path.join(os.path.dirname(onnxruntime.__file__), "capi"); print(sorted(glob.glob(os.path.join(d, "libonnxruntime.so*")))[0])')"
export ORT_DYLIB_PATH="$ORT_LIB"
# The RealSense tests run through the real librealsense2: the venv's pyrealsense2 wheel, whose
# extension module exports its C API and needs libusb (installed here when missing, as root).
if [ "${PSGRASP_SKIP_REALSENSE:-}" != 1 ]; then
    LD_CACHE="$(ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null || true)"
    if ! grep -q 'libusb-1\.0\.so\.0' <<< "$LD_CACHE"; then
        if [ "$(id -u)" = 0 ] && command -v apt-get > /dev/null; then
            echo "== apt-get install libusb-1.0-0 (librealsense2 needs it)"
            apt-get install -y -qq libusb-1.0-0 > /dev/null 2>&1 \
                || { apt-get update -qq && apt-get install -y -qq libusb-1.0-0 > /dev/null; }
        else
            echo "librealsense2 (the RealSense tests) needs libusb: run 'sudo apt-get install -y libusb-1.0-0'" \
                 "(or set PSGRASP_SKIP_REALSENSE=1 to skip those tests)" >&2
            exit 1
        fi
    fi
    PSGRASP_REALSENSE_LIB="${PSGRASP_REALSENSE_LIB:-$("$PSGRASP_PYTHON" -c 'import glob, os, importlib.util; d = os.path.dirname(importlib.util.find_spec("pyrealsense2").origin); print(sorted(glob.glob(os.path.join(d, "pyrealsense2.cpython-*.so")))[0])')}"
    export PSGRASP_REALSENSE_LIB
fi
# One build for everything: the workspace with the ONNX Runtime backend compiled in (a second
# feature set would rebuild much of the dependency tree).
echo "== cargo test --workspace --features ort (ONNX Runtime: $ORT_DYLIB_PATH; librealsense2: ${PSGRASP_REALSENSE_LIB:-skipped})"
cargo test --workspace --features ort
echo "== pytest training/tests"
(cd training && OMP_NUM_THREADS=1 "$PSGRASP_PYTHON" -m pytest -q tests)
echo "== end to end: scripts/device-train.sh (psgrasp datagen → the two-stage model and the VGN-style baseline trained side by side (tiny) → ONNX export → packed runs) → Rust inference (tract + ort) against PyTorch"
E2E="$(mktemp -d)"
trap 'rm -rf "$E2E"' EXIT
cargo build --quiet --features ort --bin psgrasp
TINY_DEVICE_RUN=(--psgrasp "${CARGO_TARGET_DIR:-target}/debug/psgrasp" --scenes 3 --quick --seed 11 --minutes 5
                 --device cpu --threads 1)
scripts/device-train.sh "${TINY_DEVICE_RUN[@]}" --with-reference --work "$E2E/work" --out "$E2E/out" \
    8app=training/configs/tiny.toml vgn=training/configs/vgn-tiny.toml > "$E2E/device.log" 2>&1 \
    || { cat "$E2E/device.log"; exit 1; }
mkdir -p "$E2E/8app" "$E2E/vgn"
tar -xzf "$E2E/out/8app.tar.gz" -C "$E2E/8app"
tar -xzf "$E2E/out/vgn.tar.gz" -C "$E2E/vgn"
PSGRASP_TEST_MODEL_DIR="$E2E/8app/model" cargo test --workspace --features ort --test learned_model
PSGRASP_TEST_VGN_DIR="$E2E/vgn/model" cargo test --workspace --features ort --test vgn_model
# A run that fails leaves the others to finish and be packed with their checkpoint (a lent GPU's
# call is not wasted by one broken config); the call says so (exit 1, summary). Its datagen is
# time-boxed (--datagen-seconds) with a box it fits in, so all 3 scenes are kept.
printf '[train]\nlr = -1.0\n' > "$E2E/broken.toml"
rc=0
scripts/device-train.sh "${TINY_DEVICE_RUN[@]}" --no-preflight --datagen-seconds 600 --work "$E2E/work-broken" --out "$E2E/out-broken" \
    8app=training/configs/tiny.toml broken="$E2E/broken.toml" > "$E2E/broken.log" 2>&1 || rc=$?
grep -q "run broken (broken.toml): FAILED (exit 2)" "$E2E/out-broken/summary.txt" \
    && grep -q "run 8app (tiny.toml): [0-9]* iterations" "$E2E/out-broken/summary.txt" \
    && tar -tzf "$E2E/out-broken/8app.tar.gz" | grep -qx "checkpoints/latest.pt" \
    && grep -q "^datagen: 3 scenes, seed 11, objects procedural" "$E2E/out-broken/summary.txt" \
    && [ "$rc" = 1 ] || { echo "device-train.sh: a failed run did not leave the other run packed (exit $rc)"; cat "$E2E/broken.log"; exit 1; }
