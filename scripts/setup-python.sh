#!/usr/bin/env bash
# Creates (or reuses) the Python environment for training, export and the training tests:
# a venv at $PSGRASP_VENV (default ~/.cache/psgrasp-venv) with the pinned packages of
# training/requirements.txt (PyTorch from PyPI is the CUDA build, ~2.7 GB with its
# dependencies; it runs on the CPU too). Idempotent: a venv whose stamp matches the
# requirements file is reused as is. Prints the venv path on its last line.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${PSGRASP_VENV:-$HOME/.cache/psgrasp-venv}"
REQ=training/requirements.txt
WANT="$(sha256sum "$REQ" | cut -d' ' -f1)"
if [ -x "$VENV/bin/python" ] && [ "$(cat "$VENV/.psgrasp-requirements" 2>/dev/null)" = "$WANT" ]; then
    echo "$VENV"
    exit 0
fi
echo "setting up the Python environment in $VENV (first run downloads ~2.7 GB)" >&2
PY="${PYTHON:-python3}"
"$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install --quiet --upgrade pip >&2
"$VENV/bin/python" -m pip install --quiet -r "$REQ" >&2
"$VENV/bin/python" -c "import torch, onnx, onnxruntime, safetensors" >&2
echo "$WANT" > "$VENV/.psgrasp-requirements"
echo "$VENV"
